//! What an input may ask of this machine: memory, steps, file sizes.
//!
//! Every size an input gives (vertex counts, grid resolutions, the number of steps a run
//! takes) is checked against these limits *before* anything is allocated or run, and a
//! refusal names the field and what it would take. The defaults come from the machine:
//! the memory budget is half the smallest of its physical memory, the process's
//! address-space limit (`ulimit -v`) and its control group's memory limit, so that a
//! refused scene is refused with a message instead of an abort; `largestep run
//! --max-memory` and `--max-steps` change them.

use std::fmt;

/// Limits on what inputs may ask for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Memory a scene's models may be estimated to need (bytes).
    pub max_memory: u64,
    /// Steps a run may take (the scene's duration over its dt, or frames times steps
    /// per frame).
    pub max_steps: u64,
    /// Largest input file read (bytes): scenes, meshes, distance grids, world files.
    pub max_file_bytes: u64,
}

/// Steps a run may take by default: a hundred million (a day of the 32^3 jello at RK4).
pub const DEFAULT_MAX_STEPS: u64 = 100_000_000;

/// Largest input file by default (bytes), when the memory budget allows it.
pub const DEFAULT_MAX_FILE_BYTES: u64 = 1 << 30;

impl Default for Limits {
    fn default() -> Self {
        Limits::with_memory(machine_memory() / 2)
    }
}

impl Limits {
    /// Limits with a memory budget of `max_memory` bytes: the default step limit, and
    /// files up to a quarter of the budget (at most [`DEFAULT_MAX_FILE_BYTES`]; text
    /// parses into about as much memory as it takes).
    pub fn with_memory(max_memory: u64) -> Limits {
        Limits {
            max_memory,
            max_steps: DEFAULT_MAX_STEPS,
            max_file_bytes: (max_memory / 4).min(DEFAULT_MAX_FILE_BYTES),
        }
    }

    /// No limits (tests, trusted input).
    pub fn unlimited() -> Limits {
        Limits {
            max_memory: u64::MAX,
            max_steps: u64::MAX,
            max_file_bytes: u64::MAX,
        }
    }

    /// `Ok` when `bytes` fit the memory budget, else the reason (naming `what` needs
    /// them). Sizes are f64 so that a product of input sizes cannot overflow before it is
    /// checked.
    pub fn memory(&self, what: &str, bytes: f64) -> Result<(), String> {
        if bytes.is_finite() && bytes <= self.max_memory as f64 {
            Ok(())
        } else {
            Err(format!(
                "{what} needs about {}, more than the memory budget of {} (set it with --max-memory)",
                Bytes(bytes),
                Bytes(self.max_memory as f64)
            ))
        }
    }

    /// `Ok` when a run of `steps` steps fits the step limit, else the reason.
    pub fn steps(&self, what: &str, steps: f64) -> Result<(), String> {
        if steps.is_finite() && steps <= self.max_steps as f64 {
            Ok(())
        } else {
            Err(format!(
                "{what} takes {steps:.3e} steps, more than the limit of {:.3e} (set it with --max-steps)",
                self.max_steps as f64
            ))
        }
    }
}

/// A byte count for people: `3.5 GB`, `120 MB`, `4.0 kB`.
#[derive(Clone, Copy, Debug)]
pub struct Bytes(pub f64);

impl fmt::Display for Bytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let b = self.0;
        if !b.is_finite() || b >= 1e18 {
            return write!(f, "{b:.3e} bytes");
        }
        let (v, unit) = if b >= 1e12 {
            (b / 1e12, "TB")
        } else if b >= 1e9 {
            (b / 1e9, "GB")
        } else if b >= 1e6 {
            (b / 1e6, "MB")
        } else if b >= 1e3 {
            (b / 1e3, "kB")
        } else {
            return write!(f, "{b:.0} bytes");
        };
        write!(f, "{v:.1} {unit}")
    }
}

/// The memory this process may use (bytes): the smallest of the physical memory
/// (`/proc/meminfo`), the address-space limit (`/proc/self/limits`) and the control
/// group's limit (`/sys/fs/cgroup/memory.max`); 4 GiB where none can be read.
pub fn machine_memory() -> u64 {
    let mut best: Option<u64> = None;
    let mut take = |v: Option<u64>| {
        if let Some(v) = v {
            best = Some(best.map_or(v, |b| b.min(v)));
        }
    };
    let read = |p: &str| std::fs::read_to_string(p).ok();
    take(read("/proc/meminfo").and_then(|s| {
        s.lines()
            .find(|l| l.starts_with("MemTotal:"))
            .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
            .map(|kib| kib * 1024)
    }));
    take(read("/proc/self/limits").and_then(|s| {
        s.lines()
            .find(|l| l.starts_with("Max address space"))
            .and_then(|l| l.split_whitespace().nth(3)?.parse::<u64>().ok())
    }));
    take(read("/sys/fs/cgroup/memory.max").and_then(|s| s.trim().parse::<u64>().ok()));
    best.unwrap_or(4 << 30)
}
