//! A bank of damped resonators for modal sound synthesis (van den Doel, Kry and Pai,
//! "FoleyAutomatic", SIGGRAPH 2001): mode i obeys `q'' + 2 xi w q' + w^2 q = p(t)`, and an
//! impulse J at a sample instant makes `q(t) = J / w_d e^(-xi w t) sin(w_d t)` after it.
//! Sampled every h seconds, that is exactly the two-pole recursion
//!
//! `y[n] = a1 y[n-1] + a2 y[n-2] + b x[n-1]`, `a1 = 2 R cos(w_d h)`, `a2 = -R^2`,
//! `b = R sin(w_d h) / w_d`, `R = e^(-xi w h)`
//!
//! (impulse invariance: no frequency warping, sample-accurate onsets). The output adds
//! `g_i y_i[n]` over the modes.
//!
//! Inputs are sparse in time: `events` lists `(sample, source, weight)`, sorted by sample,
//! and mode i receives `weight * drive[source * m + i]` at that sample (a hit's force
//! profile spread over a few samples, the same modal gains for each).
//!
//! [`resonate`] is the scalar twin of [`resonate_x4`] (four modes per `f64x4`, sixteen
//! per pass over the samples, the state in registers across the whole buffer); both give
//! the same bits (the sum over modes runs in the same order).

use wide::f64x4;

/// The filter coefficients of `m` modes, structure of arrays; `m` a multiple of [`PASS`]
/// (pad with zero modes).
#[derive(Clone, Copy, Debug)]
pub struct Bank<'a> {
    pub a1: &'a [f64],
    pub a2: &'a [f64],
    pub b: &'a [f64],
    pub gain: &'a [f64],
}

impl Bank<'_> {
    fn m(&self) -> usize {
        self.a1.len()
    }
}

/// Coefficients `(a1, a2, b)` of a mode of angular frequency `w` (rad/s) and damping
/// ratio `xi` in `[0, 1)` at sample interval `h` (s); see the module docs.
pub fn coefficients(w: f64, xi: f64, h: f64) -> (f64, f64, f64) {
    let wd = w * (1.0 - xi * xi).sqrt();
    let r = (-xi * w * h).exp();
    (2.0 * r * (wd * h).cos(), -r * r, r * (wd * h).sin() / wd)
}

/// Modes per pass over the samples: four groups of four lanes, whose recursions are
/// independent, so the processor overlaps their latency (one group at a time ran 33
/// times faster than real time for 1,000 modes; four, see the benchmark).
pub const PASS: usize = 16;

/// Adds the bank's output to `out` (one value per sample), from the states `y1`, `y2`
/// (the last two outputs of each mode) and `x` (each mode's input at the sample before
/// `out[0]`, which enters `out[0]`; all three updated, so a sound rendered in pieces is
/// the sound rendered at once) and the inputs of `events`. Scalar twin
/// of [`resonate_x4`]: the same operations in the same order (per pass of [`PASS`]
/// modes, lane by lane the sum over the pass's four groups, then the four lanes).
pub fn resonate(
    bank: Bank<'_>,
    y1: &mut [f64],
    y2: &mut [f64],
    x_in: &mut [f64],
    events: &[(usize, usize, f64)],
    drive: &[f64],
    out: &mut [f64],
) {
    let m = bank.m();
    assert!(
        m.is_multiple_of(PASS),
        "pad the bank to a multiple of {PASS} modes"
    );
    for base in (0..m).step_by(PASS) {
        let mut x: [f64; PASS] = std::array::from_fn(|k| x_in[base + k]);
        let mut ev = 0;
        for (n, o) in out.iter_mut().enumerate() {
            let mut acc = [0.0; 4];
            for (k, xk) in x.iter().enumerate() {
                let i = base + k;
                let y = bank.a1[i] * y1[i] + bank.a2[i] * y2[i] + bank.b[i] * xk;
                y2[i] = y1[i];
                y1[i] = y;
                // Lane k % 4 of group k / 4.
                if k < 4 {
                    acc[k % 4] = bank.gain[i] * y;
                } else {
                    acc[k % 4] += bank.gain[i] * y;
                }
            }
            *o += (acc[0] + acc[1]) + (acc[2] + acc[3]);
            x = [0.0; PASS];
            while ev < events.len() && events[ev].0 == n {
                let (_, s, w) = events[ev];
                for (k, xk) in x.iter_mut().enumerate() {
                    *xk += w * drive[s * m + base + k];
                }
                ev += 1;
            }
        }
        x_in[base..base + PASS].copy_from_slice(&x);
    }
}

/// [`resonate`] with four modes per `f64x4` and four of those per pass.
pub fn resonate_x4(
    bank: Bank<'_>,
    y1: &mut [f64],
    y2: &mut [f64],
    x_in: &mut [f64],
    events: &[(usize, usize, f64)],
    drive: &[f64],
    out: &mut [f64],
) {
    let m = bank.m();
    assert!(
        m.is_multiple_of(PASS),
        "pad the bank to a multiple of {PASS} modes"
    );
    let load = |v: &[f64], i: usize| f64x4::new([v[i], v[i + 1], v[i + 2], v[i + 3]]);
    for base in (0..m).step_by(PASS) {
        let at = |g: usize| base + 4 * g;
        let a1: [f64x4; 4] = std::array::from_fn(|g| load(bank.a1, at(g)));
        let a2: [f64x4; 4] = std::array::from_fn(|g| load(bank.a2, at(g)));
        let b: [f64x4; 4] = std::array::from_fn(|g| load(bank.b, at(g)));
        let gain: [f64x4; 4] = std::array::from_fn(|g| load(bank.gain, at(g)));
        let mut s1: [f64x4; 4] = std::array::from_fn(|g| load(y1, at(g)));
        let mut s2: [f64x4; 4] = std::array::from_fn(|g| load(y2, at(g)));
        let mut x: [f64x4; 4] = std::array::from_fn(|g| load(x_in, at(g)));
        let mut ev = 0;
        for (n, o) in out.iter_mut().enumerate() {
            let mut acc = f64x4::ZERO;
            for g in 0..4 {
                let y = a1[g] * s1[g] + a2[g] * s2[g] + b[g] * x[g];
                s2[g] = s1[g];
                s1[g] = y;
                acc = if g == 0 {
                    gain[g] * y
                } else {
                    acc + gain[g] * y
                };
            }
            let acc = acc.to_array();
            *o += (acc[0] + acc[1]) + (acc[2] + acc[3]);
            x = [f64x4::ZERO; 4];
            while ev < events.len() && events[ev].0 == n {
                let (_, s, w) = events[ev];
                for (g, xg) in x.iter_mut().enumerate() {
                    *xg += f64x4::splat(w) * load(drive, s * m + at(g));
                }
                ev += 1;
            }
        }
        for g in 0..4 {
            y1[at(g)..at(g) + 4].copy_from_slice(&s1[g].to_array());
            y2[at(g)..at(g) + 4].copy_from_slice(&s2[g].to_array());
            x_in[at(g)..at(g) + 4].copy_from_slice(&x[g].to_array());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The four-lane bank gives the scalar twin's bits, modes, states and sparse inputs
    /// alike (pseudo-random coefficients of stable resonators).
    #[test]
    fn lanes_match_the_scalar_twin() {
        let m = 2 * PASS;
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut c = (vec![], vec![], vec![], vec![]);
        for _ in 0..m {
            let (a1, a2, b) = coefficients(1000.0 + 20000.0 * rnd(), 0.1 * rnd(), 1.0 / 44100.0);
            c.0.push(a1);
            c.1.push(a2);
            c.2.push(b);
            c.3.push(rnd() - 0.5);
        }
        let bank = Bank {
            a1: &c.0,
            a2: &c.1,
            b: &c.2,
            gain: &c.3,
        };
        let drive: Vec<f64> = (0..3 * m).map(|_| rnd() - 0.5).collect();
        let events = vec![
            (0, 0, 1.0),
            (0, 2, 0.5),
            (7, 1, -2.0),
            (300, 0, 0.25),
            (301, 2, 1.5),
        ];
        let (mut y1, mut y2, mut x1) = (vec![0.1; m], vec![-0.05; m], vec![0.02; m]);
        let (mut z1, mut z2, mut x2) = (y1.clone(), y2.clone(), x1.clone());
        let (mut a, mut b) = (vec![0.0; 1000], vec![0.0; 1000]);
        resonate(bank, &mut y1, &mut y2, &mut x1, &events, &drive, &mut a);
        resonate_x4(bank, &mut z1, &mut z2, &mut x2, &events, &drive, &mut b);
        assert_eq!(a, b);
        assert_eq!((&y1, &y2, &x1), (&z1, &z2, &x2));
        // In two pieces, the input at the last sample of the first carried into the
        // second: the same sound as at once.
        let (mut w1, mut w2, mut xw) = (vec![0.1; m], vec![-0.05; m], vec![0.02; m]);
        let mut c = vec![0.0; 1000];
        let split = 301; // event (300, 0) is the first piece's last sample
        let (early, late): (Vec<_>, Vec<_>) = events.iter().partition(|e| e.0 < split);
        let late: Vec<_> = late.iter().map(|&(n, s, w)| (n - split, s, w)).collect();
        let (c0, c1) = c.split_at_mut(split);
        resonate_x4(bank, &mut w1, &mut w2, &mut xw, &early, &drive, c0);
        resonate_x4(bank, &mut w1, &mut w2, &mut xw, &late, &drive, c1);
        assert_eq!(c, b);
    }
}
