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
use std::path::Path;

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

/// The sound of `hits` on the body whose modes are `modes` (rigid ones are skipped), with
/// `damping` (module docs).
pub fn synthesize(
    modes: &Modes,
    damping: Rayleigh,
    hits: &[Hit],
    params: &SoundParams,
) -> Result<Sound, SoundError> {
    let rate = params.sample_rate as f64;
    if !(8_000.0..=384_000.0).contains(&rate) {
        return Err(SoundError::Params(format!(
            "sample rate {} Hz: expected 8,000 to 384,000",
            params.sample_rate
        )));
    }
    if !(params.duration > 0.0 && params.duration <= MAX_SECONDS) {
        return Err(SoundError::Params(format!(
            "duration {} s: expected more than 0 and at most {MAX_SECONDS}",
            params.duration
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
    let samples = (params.duration * rate).round() as usize;
    // Each hit's unit direction, checked.
    let mut dirs = Vec::with_capacity(hits.len());
    for (index, hit) in hits.iter().enumerate() {
        let bad = |message: String| SoundError::Hit { index, message };
        if hit.vertex >= n {
            return Err(bad(format!(
                "vertex {} out of range ({n} vertices)",
                hit.vertex
            )));
        }
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
        if !(hit.impulse.is_finite() && hit.duration >= 0.0 && hit.duration <= 1.0) {
            return Err(bad(format!(
                "impulse {} N s and contact time {} s: the impulse must be finite, the contact time 0 to 1 s",
                hit.impulse, hit.duration
            )));
        }
        dirs.push(hit.direction.map(|c| c / len));
    }
    let mut sound = Sound {
        sample_rate: params.sample_rate,
        ..Sound::default()
    };
    // The modes that ring: (w, xi, their share of each hit).
    let nyquist = 0.5 * rate;
    let mut ringing: Vec<(f64, f64, Vec<f64>)> = Vec::new();
    for j in modes.rigid..count {
        let w = modes.eigenvalues[j].max(0.0).sqrt();
        let f = w / (2.0 * PI);
        if f > params.max_frequency.min(nyquist) || w == 0.0 {
            sound.culled_high += usize::from(w > 0.0);
            continue;
        }
        let xi = damping.ratio(w);
        if xi >= 1.0 {
            sound.culled_overdamped += 1;
            continue;
        }
        let phi = modes.mode(j);
        let share = hits
            .iter()
            .zip(&dirs)
            .map(|(hit, d)| {
                let v = hit.vertex;
                phi[v] * d[0] + phi[n + v] * d[1] + phi[2 * n + v] * d[2]
            })
            .collect();
        ringing.push((w, xi, share));
    }
    // Peak acceleration of each mode: w^2 J |share| / w_d, over the hits.
    let loudness: Vec<f64> = ringing
        .iter()
        .map(|(w, xi, share)| {
            let wd = w * (1.0 - xi * xi).sqrt();
            hits.iter()
                .zip(share)
                .map(|(hit, s)| (w * w * hit.impulse * s / wd).abs())
                .fold(0.0, f64::max)
        })
        .collect();
    let loudest = loudness.iter().fold(0.0f64, |a, &b| a.max(b));
    let kept: Vec<usize> = (0..ringing.len())
        .filter(|&i| loudness[i] > params.quiet * loudest && loudness[i] > 0.0)
        .collect();
    sound.culled_quiet = ringing.len() - kept.len();
    // The bank, padded with silent modes to whole passes of the kernel.
    let m = kept.len().div_ceil(PASS) * PASS;
    let (mut a1, mut a2, mut b, mut gain) =
        (vec![0.0; m], vec![0.0; m], vec![0.0; m], vec![0.0; m]);
    let mut drive = vec![0.0; hits.len() * m];
    for (slot, &i) in kept.iter().enumerate() {
        let (w, xi, share) = &ringing[i];
        let (c1, c2, cb) = coefficients(*w, *xi, h);
        (a1[slot], a2[slot], b[slot], gain[slot]) = (c1, c2, cb, w * w);
        for (e, s) in share.iter().enumerate() {
            drive[e * m + slot] = *s;
        }
        sound
            .frequencies_hz
            .push(w * (1.0 - xi * xi).sqrt() / (2.0 * PI));
        sound.decay_rates.push(xi * w);
    }
    // Each hit's impulse per sample: the half-sine's integral over the sample.
    let mut events: Vec<(usize, usize, f64)> = Vec::new();
    for (e, hit) in hits.iter().enumerate() {
        let n0 = (hit.time * rate).round() as usize;
        let span = (hit.duration * rate).ceil().max(1.0) as usize;
        for k in 0..span {
            let weight = if hit.duration <= h {
                if k == 0 {
                    hit.impulse
                } else {
                    0.0
                }
            } else {
                let t0 = (k as f64 * h).min(hit.duration);
                let t1 = ((k + 1) as f64 * h).min(hit.duration);
                0.5 * hit.impulse
                    * ((PI * t0 / hit.duration).cos() - (PI * t1 / hit.duration).cos())
            };
            if n0 + k < samples && weight != 0.0 {
                events.push((n0 + k, e, weight));
            }
        }
    }
    events.sort_by_key(|&(s, e, _)| (s, e));
    let (mut y1, mut y2) = (vec![0.0; m], vec![0.0; m]);
    sound.samples = vec![0.0; samples];
    resonate_x4(
        Bank {
            a1: &a1,
            a2: &a2,
            b: &b,
            gain: &gain,
        },
        &mut y1,
        &mut y2,
        &events,
        &drive,
        &mut sound.samples,
    );
    Ok(sound)
}

/// Writes `sound` as a 16-bit mono WAV (hound), scaled so its loudest sample is 0.9 of
/// full scale; written to a temporary file first, so an existing file stays whole if
/// writing fails.
pub fn write_wav(path: &Path, sound: &Sound) -> std::io::Result<()> {
    let peak = sound.samples.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
    let scale = if peak > 0.0 {
        0.9 * i16::MAX as f64 / peak
    } else {
        0.0
    };
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: sound.sample_rate,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut bytes = std::io::Cursor::new(Vec::new());
    {
        let mut w = hound::WavWriter::new(&mut bytes, spec).map_err(std::io::Error::other)?;
        for &s in &sound.samples {
            w.write_sample((s * scale).round() as i16)
                .map_err(std::io::Error::other)?;
        }
        w.finalize().map_err(std::io::Error::other)?;
    }
    crate::io::write_atomically(path, |w| w.write_all(bytes.get_ref()))
}
