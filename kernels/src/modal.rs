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
//! [`resonate`] is the scalar twin of [`resonate_x4`] (four modes per `f64x4`, the state
//! in registers across the whole buffer); both give the same bits (the sum over modes
//! runs in the same order: lanes of a group, then groups).

use wide::f64x4;

/// The filter coefficients of `m` modes, structure of arrays; `m` a multiple of 4 for
/// [`resonate_x4`] (pad with zero modes).
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

/// Adds the bank's output to `out` (one value per sample), from the states `y1`, `y2`
/// (the last two outputs of each mode; updated) and the inputs of `events`. Scalar twin.
pub fn resonate(
    bank: Bank<'_>,
    y1: &mut [f64],
    y2: &mut [f64],
    events: &[(usize, usize, f64)],
    drive: &[f64],
    out: &mut [f64],
) {
    let m = bank.m();
    let groups = m.div_ceil(4);
    for g in 0..groups {
        // Per group of four, as the lanes do, so that the sums agree to the bit.
        let lanes = 4 * g..(4 * g + 4).min(m);
        let mut x = [0.0; 4];
        let mut ev = 0;
        for (n, o) in out.iter_mut().enumerate() {
            let mut acc = [0.0; 4];
            for (l, i) in lanes.clone().enumerate() {
                let y = bank.a1[i] * y1[i] + bank.a2[i] * y2[i] + bank.b[i] * x[l];
                y2[i] = y1[i];
                y1[i] = y;
                acc[l] = bank.gain[i] * y;
            }
            *o += (acc[0] + acc[1]) + (acc[2] + acc[3]);
            x = [0.0; 4];
            while ev < events.len() && events[ev].0 == n {
                let (_, s, w) = events[ev];
                for (l, i) in lanes.clone().enumerate() {
                    x[l] += w * drive[s * m + i];
                }
                ev += 1;
            }
        }
    }
}

/// [`resonate`] with four modes per `f64x4`.
pub fn resonate_x4(
    bank: Bank<'_>,
    y1: &mut [f64],
    y2: &mut [f64],
    events: &[(usize, usize, f64)],
    drive: &[f64],
    out: &mut [f64],
) {
    let m = bank.m();
    assert!(m % 4 == 0, "pad the bank to a multiple of four modes");
    let load = |v: &[f64], i: usize| f64x4::new([v[i], v[i + 1], v[i + 2], v[i + 3]]);
    for g in 0..m / 4 {
        let i = 4 * g;
        let (a1, a2, b, gain) = (
            load(bank.a1, i),
            load(bank.a2, i),
            load(bank.b, i),
            load(bank.gain, i),
        );
        let (mut s1, mut s2) = (load(y1, i), load(y2, i));
        let mut x = f64x4::ZERO;
        let mut ev = 0;
        for (n, o) in out.iter_mut().enumerate() {
            let y = a1 * s1 + a2 * s2 + b * x;
            s2 = s1;
            s1 = y;
            let acc = (gain * y).to_array();
            *o += (acc[0] + acc[1]) + (acc[2] + acc[3]);
            x = f64x4::ZERO;
            while ev < events.len() && events[ev].0 == n {
                let (_, s, w) = events[ev];
                x += f64x4::splat(w) * load(drive, s * m + i);
                ev += 1;
            }
        }
        y1[i..i + 4].copy_from_slice(&s1.to_array());
        y2[i..i + 4].copy_from_slice(&s2.to_array());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The four-lane bank gives the scalar twin's bits, modes, states and sparse inputs
    /// alike (pseudo-random coefficients of stable resonators).
    #[test]
    fn lanes_match_the_scalar_twin() {
        let m = 12;
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
        let (mut y1, mut y2) = (vec![0.1; m], vec![-0.05; m]);
        let (mut z1, mut z2) = (y1.clone(), y2.clone());
        let (mut a, mut b) = (vec![0.0; 1000], vec![0.0; 1000]);
        resonate(bank, &mut y1, &mut y2, &events, &drive, &mut a);
        resonate_x4(bank, &mut z1, &mut z2, &events, &drive, &mut b);
        assert_eq!(a, b);
        assert_eq!((y1, y2), (z1, z2));
    }
}
