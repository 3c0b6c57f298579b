//! Modal sound synthesis (issue 16; course notes section 17; van den Doel, Kry and Pai
//! 2001; O'Brien, Shen and Gatchalian 2002): struck objects that ring.
//!
//! With M-orthonormal modes `phi_i`, Rayleigh damping `C = alpha M + beta K` keeps the
//! modes apart: mode i obeys `q'' + 2 xi_i w_i q' + w_i^2 q = phi_i . f(t)` with
//! `xi_i = (alpha / w_i + beta w_i) / 2`. A hit at vertex v along the unit direction d
//! with impulse J (N s) over a contact time tau is a half-sine force
//! `F(t) = J pi / (2 tau) sin(pi t / tau)`; each sample receives the impulse of its
//! interval, and mode i the share `phi_i(v) . d`. Each mode is one damped resonator
//! (`largestep_kernels::modal`, four per SIMD register, impulse invariant: exact at the
//! samples). The sound is a pressure proxy, the sum of the modes' accelerations
//! `w_i^2 q_i` (O'Brien et al. radiate the surface's normal acceleration; the radiation
//! efficiency of each mode is left out).
//!
//! Modes are culled, and counted: above `max_frequency` (20 kHz, and below Nyquist),
//! critically or over damped (`xi >= 1`: no ring), and quiet ones whose peak
//! acceleration from the hits is below `quiet` times the loudest mode's.

use crate::solve::Modes;
use largestep_kernels::modal::{coefficients, resonate_x4, Bank, PASS};
use std::f64::consts::PI;

/// Rayleigh damping `C = alpha M + beta K` (alpha in 1/s, beta in s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rayleigh {
    pub alpha: f64,
    pub beta: f64,
}

impl Rayleigh {
    /// The damping ratio of a mode of angular frequency `w` (rad/s).
    pub fn ratio(&self, w: f64) -> f64 {
        0.5 * (self.alpha / w + self.beta * w)
    }
}

/// A strike.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// When (s from the start of the sound).
    pub time: f64,
    /// Where: a vertex of the mesh.
    pub vertex: usize,
    /// Along what (need not be unit; not zero).
    pub direction: [f64; 3],
    /// Impulse (N s).
    pub impulse: f64,
    /// Contact time (s) of the half-sine force; 0 for a single-sample impulse.
    pub duration: f64,
}

/// Settings of [`synthesize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoundParams {
    /// Samples per second.
    pub sample_rate: u32,
    /// Length of the sound (s).
    pub duration: f64,
    /// Modes above this frequency (Hz) are culled.
    pub max_frequency: f64,
    /// Modes whose peak acceleration is below this fraction of the loudest mode's are
    /// culled.
    pub quiet: f64,
}

impl Default for SoundParams {
    fn default() -> Self {
        Self {
            sample_rate: 44_100,
            duration: 2.0,
            max_frequency: 20_000.0,
            quiet: 1e-4,
        }
    }
}

/// Most seconds of sound [`synthesize`] makes (ten minutes).
pub const MAX_SECONDS: f64 = 600.0;

/// A synthesised sound and what went into it.
#[derive(Clone, Debug, Default)]
pub struct Sound {
    /// The pressure proxy, one value per sample (arbitrary units; see the module docs).
    pub samples: Vec<f64>,
    pub sample_rate: u32,
    /// Damped frequencies (Hz) and decay rates `xi w` (1/s) of the modes sounded.
    pub frequencies_hz: Vec<f64>,
    pub decay_rates: Vec<f64>,
    /// Modes culled: above the frequency limit, over damped, too quiet.
    pub culled_high: usize,
    pub culled_overdamped: usize,
    pub culled_quiet: usize,
}

/// What is wrong with a synthesis request.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SoundError {
    #[error("hit {index}: {message}")]
    Hit { index: usize, message: String },
    #[error("{0}")]
    Params(String),
}

/// How a strike's impulse is spread over the samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pulse {
    /// A half-sine force over this contact time (s; one sample when shorter than one):
    /// an impact.
    HalfSine(f64),
    /// A constant force over this time (s): a steady push, such as a resting contact's
    /// share of one simulation step.
    Box(f64),
}

/// Which strikes decide the quiet cull of a [`Synth`].
#[derive(Clone, Copy, Debug)]
pub enum Cull<'a> {
    /// The strikes are these hits (known before the sound starts).
    Hits(&'a [Hit]),
    /// Any unit impulse at any of these vertices, in any direction (the surface, for
    /// strikes that arrive while the sound plays: contacts).
    Anywhere(&'a [u32]),
}

/// A bank of damped resonators, one per mode that rings, that renders a sound piece by
/// piece: strikes may arrive while it plays (the contact impulses of a running
/// simulation, [`Synth::strike`]), each rendered from the first sample not yet
/// rendered. [`synthesize`] is a `Synth` given all its hits at once.
#[derive(Clone, Debug)]
pub struct Synth {
    rate: f64,
    /// Vertices of the mesh.
    n: usize,
    /// Modes in the bank (a multiple of `PASS`; the padding is silent).
    m: usize,
    a1: Vec<f64>,
    a2: Vec<f64>,
    b: Vec<f64>,
    gain: Vec<f64>,
    y1: Vec<f64>,
    y2: Vec<f64>,
    /// Each mode's input at the last sample rendered, which enters the next one.
    x: Vec<f64>,
    /// The shapes of the modes in the bank, `[vertex][component][slot]`: a strike's drive
    /// row is three contiguous rows of `m`.
    shapes: Vec<f64>,
    /// Inputs not yet rendered: `(absolute sample, source, impulse)`, sorted.
    pending: Vec<(u64, usize, f64)>,
    /// Drive rows of the sources `pending` refers to, `m` each.
    sources: Vec<f64>,
    /// Samples rendered so far.
    rendered: u64,
    /// Scratch for [`Synth::render`].
    events: Vec<(usize, usize, f64)>,
    /// What rings and what was culled (`samples` stays empty).
    info: Sound,
}

impl Synth {
    /// The bank for `modes` (rigid ones skipped) with `damping`, at `params`' sample rate
    /// and frequency limit; modes quieter than `params.quiet` times the loudest, for the
    /// strikes `cull` describes, are left out (module docs).
    pub fn new(
        modes: &Modes,
        damping: Rayleigh,
        params: &SoundParams,
        cull: Cull<'_>,
    ) -> Result<Synth, SoundError> {
        let rate = params.sample_rate as f64;
        if !(8_000.0..=384_000.0).contains(&rate) {
            return Err(SoundError::Params(format!(
                "sample rate {} Hz: expected 8,000 to 384,000",
                params.sample_rate
            )));
        }
        if !(damping.alpha >= 0.0
            && damping.beta >= 0.0
            && damping.alpha.is_finite()
            && damping.beta.is_finite())
        {
            return Err(SoundError::Params(format!(
                "Rayleigh damping must be finite and not negative, not alpha {} and beta {}",
                damping.alpha, damping.beta
            )));
        }
        let count = modes.eigenvalues.len();
        let n = modes.vectors.len().checked_div(count).unwrap_or(0) / 3;
        let h = 1.0 / rate;
        let mut info = Sound {
            sample_rate: params.sample_rate,
            ..Sound::default()
        };
        // The modes that ring: index, w, xi.
        let nyquist = 0.5 * rate;
        let mut ringing: Vec<(usize, f64, f64)> = Vec::new();
        for j in modes.rigid..count {
            let w = modes.eigenvalues[j].max(0.0).sqrt();
            let f = w / (2.0 * PI);
            if f > params.max_frequency.min(nyquist) || w == 0.0 {
                info.culled_high += usize::from(w > 0.0);
                continue;
            }
            let xi = damping.ratio(w);
            if xi >= 1.0 {
                info.culled_overdamped += 1;
                continue;
            }
            ringing.push((j, w, xi));
        }
        // Peak acceleration of each mode, w^2 J |share| / w_d, over the strikes.
        let loudness: Vec<f64> = ringing
            .iter()
            .map(|&(j, w, xi)| {
                let phi = modes.mode(j);
                let wd = w * (1.0 - xi * xi).sqrt();
                let share = match cull {
                    Cull::Hits(hits) => hits
                        .iter()
                        .filter(|hit| hit.vertex < n)
                        .map(|hit| {
                            let v = hit.vertex;
                            let d = hit.direction;
                            let len = d.iter().map(|c| c * c).sum::<f64>().sqrt();
                            let s =
                                (phi[v] * d[0] + phi[n + v] * d[1] + phi[2 * n + v] * d[2]) / len;
                            (hit.impulse * s).abs()
                        })
                        .filter(|s| s.is_finite())
                        .fold(0.0, f64::max),
                    Cull::Anywhere(vertices) => vertices
                        .iter()
                        .filter(|&&v| (v as usize) < n)
                        .map(|&v| {
                            let v = v as usize;
                            (phi[v].powi(2) + phi[n + v].powi(2) + phi[2 * n + v].powi(2)).sqrt()
                        })
                        .fold(0.0, f64::max),
                };
                w * w * share / wd
            })
            .collect();
        let loudest = loudness.iter().fold(0.0f64, |a, &b| a.max(b));
        let kept: Vec<usize> = (0..ringing.len())
            .filter(|&i| loudness[i] > params.quiet * loudest && loudness[i] > 0.0)
            .collect();
        info.culled_quiet = ringing.len() - kept.len();
        // The bank, padded with silent modes to whole passes of the kernel.
        let m = kept.len().div_ceil(PASS) * PASS;
        let (mut a1, mut a2, mut b, mut gain) =
            (vec![0.0; m], vec![0.0; m], vec![0.0; m], vec![0.0; m]);
        let mut shapes = vec![0.0; 3 * n * m];
        for (slot, &i) in kept.iter().enumerate() {
            let (j, w, xi) = ringing[i];
            let (c1, c2, cb) = coefficients(w, xi, h);
            (a1[slot], a2[slot], b[slot], gain[slot]) = (c1, c2, cb, w * w);
            let phi = modes.mode(j);
            for v in 0..n {
                for c in 0..3 {
                    shapes[(3 * v + c) * m + slot] = phi[c * n + v];
                }
            }
            info.frequencies_hz
                .push(w * (1.0 - xi * xi).sqrt() / (2.0 * PI));
            info.decay_rates.push(xi * w);
        }
        Ok(Synth {
            rate,
            n,
            m,
            a1,
            a2,
            b,
            gain,
            y1: vec![0.0; m],
            y2: vec![0.0; m],
            x: vec![0.0; m],
            shapes,
            pending: Vec::new(),
            sources: Vec::new(),
            rendered: 0,
            events: Vec::new(),
            info,
        })
    }

    /// What rings (damped frequencies, decay rates) and what was culled; its `samples`
    /// are empty.
    pub fn info(&self) -> &Sound {
        &self.info
    }

    /// Vertices of the mesh the modes are of.
    pub fn vertex_count(&self) -> usize {
        self.n
    }

    /// Samples rendered so far.
    pub fn rendered(&self) -> u64 {
        self.rendered
    }

    /// The sample whose interval holds time `t` (s), `floor(t r)` with a millionth of a
    /// sample's slack against rounding (so `k / r` maps to k). Rendering up to
    /// `sample_at(t)` leaves that sample for strikes arriving at t.
    pub fn sample_at(&self, t: f64) -> u64 {
        (t * self.rate + 1e-6).floor().max(0.0) as u64
    }

    /// Schedules a strike at vertex `vertex` with impulse `impulse` (N s, a vector: its
    /// direction is the strike's) from `time` (s), spread over its samples as `pulse`
    /// says. A strike before the first sample not yet rendered starts there.
    pub fn strike(
        &mut self,
        time: f64,
        vertex: usize,
        impulse: [f64; 3],
        pulse: Pulse,
    ) -> Result<(), String> {
        let duration = match pulse {
            Pulse::HalfSine(d) | Pulse::Box(d) => d,
        };
        if vertex >= self.n {
            return Err(format!(
                "vertex {vertex} out of range ({} vertices)",
                self.n
            ));
        }
        if !(impulse.iter().all(|c| c.is_finite())
            && time.is_finite()
            && (0.0..=1.0).contains(&duration))
        {
            return Err(format!(
                "impulse {impulse:?} N s at {time} s over {duration} s: the impulse and time must be finite, the contact time 0 to 1 s"
            ));
        }
        if impulse == [0.0; 3] || self.m == 0 {
            return Ok(());
        }
        let m = self.m;
        let source = self.sources.len() / m;
        let row = &self.shapes[3 * vertex * m..3 * (vertex + 1) * m];
        self.sources.extend(
            (0..m).map(|k| {
                row[k] * impulse[0] + row[m + k] * impulse[1] + row[2 * m + k] * impulse[2]
            }),
        );
        let h = 1.0 / self.rate;
        let n0 = ((time * self.rate).round().max(0.0) as u64).max(self.rendered);
        let before = self.pending.len();
        match pulse {
            // The half-sine's share of the impulse in each sample it spans.
            Pulse::HalfSine(d) if d > h => {
                let span = (d * self.rate).ceil() as u64;
                for k in 0..span {
                    let t0 = (k as f64 * h).min(d);
                    let t1 = ((k + 1) as f64 * h).min(d);
                    let w = 0.5 * ((PI * t0 / d).cos() - (PI * t1 / d).cos());
                    if w != 0.0 {
                        self.pending.push((n0.saturating_add(k), source, w));
                    }
                }
            }
            // Each sample interval [k h, (k + 1) h) takes the share of [t, t + d) it
            // overlaps: boxes of consecutive intervals add up to the same input in every
            // sample, so a steady push is a steady input (no ripple at the rate of the
            // pushes).
            Pulse::Box(d) if d > 0.0 => {
                let t = time.max(0.0);
                let first = self.sample_at(t);
                let last = ((t + d) * self.rate).ceil() as u64;
                for k in first..last.max(first.saturating_add(1)) {
                    let (a, b) = (k as f64 * h, (k + 1) as f64 * h);
                    let w = ((t + d).min(b) - t.max(a)).max(0.0) / d;
                    if w > 0.0 {
                        // A share due before the first sample not rendered joins it.
                        self.pending.push((k.max(self.rendered), source, w));
                    }
                }
            }
            Pulse::Box(_) => self.pending.push((n0, source, 1.0)),
            Pulse::HalfSine(_) => self.pending.push((n0, source, 1.0)),
        }
        // Stable: strikes at one sample keep their order of arrival.
        if !self.pending[before.saturating_sub(1)..].is_sorted_by_key(|e| e.0) {
            self.pending.sort_by_key(|e| e.0);
        }
        Ok(())
    }

    /// Adds the next `out.len()` samples of the sound to `out`.
    pub fn render(&mut self, out: &mut [f64]) {
        let end = self.rendered + out.len() as u64;
        let due = self.pending.partition_point(|e| e.0 < end);
        self.events.clear();
        self.events.extend(
            self.pending[..due]
                .iter()
                .map(|&(s, src, w)| ((s - self.rendered) as usize, src, w)),
        );
        if self.m > 0 {
            resonate_x4(
                Bank {
                    a1: &self.a1,
                    a2: &self.a2,
                    b: &self.b,
                    gain: &self.gain,
                },
                &mut self.y1,
                &mut self.y2,
                &mut self.x,
                &self.events,
                &self.sources,
                out,
            );
        }
        self.pending.drain(..due);
        self.rendered = end;
        // Drop the drive rows nothing refers to any more (renumbering the rest).
        if self.pending.is_empty() {
            self.sources.clear();
        } else if self.pending.iter().all(|e| e.1 > 0) {
            let first = self.pending.iter().map(|e| e.1).min().unwrap_or(0);
            self.sources.drain(..first * self.m);
            for e in &mut self.pending {
                e.1 -= first;
            }
        }
    }
}

/// The sound of `hits` on the body whose modes are `modes` (rigid ones are skipped), with
/// `damping` (module docs): a [`Synth`] given all its hits, rendered for
/// `params.duration`.
pub fn synthesize(
    modes: &Modes,
    damping: Rayleigh,
    hits: &[Hit],
    params: &SoundParams,
) -> Result<Sound, SoundError> {
    if !(params.duration > 0.0 && params.duration <= MAX_SECONDS) {
        return Err(SoundError::Params(format!(
            "duration {} s: expected more than 0 and at most {MAX_SECONDS}",
            params.duration
        )));
    }
    let mut synth = Synth::new(modes, damping, params, Cull::Hits(hits))?;
    for (index, hit) in hits.iter().enumerate() {
        let bad = |message: String| SoundError::Hit { index, message };
        let len = hit.direction.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(len > 0.0 && len.is_finite()) {
            return Err(bad(format!(
                "direction {:?} is zero or not finite",
                hit.direction
            )));
        }
        if !(hit.time >= 0.0 && hit.time < params.duration) {
            return Err(bad(format!(
                "time {} s outside the sound (0 to {} s)",
                hit.time, params.duration
            )));
        }
        let impulse = hit.direction.map(|c| hit.impulse * c / len);
        synth
            .strike(hit.time, hit.vertex, impulse, Pulse::HalfSine(hit.duration))
            .map_err(bad)?;
    }
    let mut samples = vec![0.0; (params.duration * synth.rate).round() as usize];
    synth.render(&mut samples);
    Ok(Sound {
        samples,
        ..synth.info
    })
}

/// A material for modal sound: elastic constants and Rayleigh damping.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoundMaterial {
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Density (kg/m^3).
    pub density: f64,
    /// Rayleigh damping.
    pub damping: Rayleigh,
}

/// The material presets of `[sound] material`: steel, glass, wood and ceramic as
/// tabulated by Zheng and James, "Toward high-quality modal contact sound" (SIGGRAPH
/// 2011), Table 1, which fitted the damping to recordings (steel: rho 7850, E 200 GPa,
/// nu 0.29, alpha 5, beta 3e-8; ceramic: 2700, 74 GPa, 0.19, 6, 1e-7; glass: 2600, 62
/// GPa, 0.20, 1, 1e-7; wood: 750, 11 GPa, 0.25, 60, 2e-6). Aluminium (not in that table):
/// the FEM's handbook constants (69 GPa, 0.33, 2700 kg/m^3) with alpha 0 and beta 5e-7,
/// the pair listed for aluminium with Lu and Culbertson 2023 (Table I); we read it from a
/// secondary listing, not from the paper.
pub const SOUND_MATERIALS: &[(&str, SoundMaterial)] = &[
    (
        "steel",
        SoundMaterial {
            young: 2.0e11,
            poisson: 0.29,
            density: 7850.0,
            damping: Rayleigh {
                alpha: 5.0,
                beta: 3e-8,
            },
        },
    ),
    (
        "aluminium",
        SoundMaterial {
            young: 6.9e10,
            poisson: 0.33,
            density: 2700.0,
            damping: Rayleigh {
                alpha: 0.0,
                beta: 5e-7,
            },
        },
    ),
    (
        "glass",
        SoundMaterial {
            young: 6.2e10,
            poisson: 0.20,
            density: 2600.0,
            damping: Rayleigh {
                alpha: 1.0,
                beta: 1e-7,
            },
        },
    ),
    (
        "wood",
        SoundMaterial {
            young: 1.1e10,
            poisson: 0.25,
            density: 750.0,
            damping: Rayleigh {
                alpha: 60.0,
                beta: 2e-6,
            },
        },
    ),
    (
        "ceramic",
        SoundMaterial {
            young: 7.4e10,
            poisson: 0.19,
            density: 2700.0,
            damping: Rayleigh {
                alpha: 6.0,
                beta: 1e-7,
            },
        },
    ),
];

/// The preset called `name` (see [`SOUND_MATERIALS`]).
pub fn sound_material(name: &str) -> Option<SoundMaterial> {
    SOUND_MATERIALS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|&(_, m)| m)
}
