//! Studies: error against run time, observed orders and stability, written as
//! `NAME.md` (tables, the error measure and the reference stated), `NAME.svg` and `NAME.png`
//! (log-log error against run time, one curve per method) and `NAME.json` (all numbers).

mod cloth;
mod integrators;
mod jello;

use std::path::Path;

/// Study failures.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StudyError {
    /// No study of that name.
    #[error("unknown study `{0}`; available: {names}", names = NAMES.join(", "))]
    Unknown(String),
    /// Writing the report failed.
    #[error("{path}: {message}")]
    Write {
        /// The file.
        path: String,
        /// What failed.
        message: String,
    },
}

/// Study names.
pub const NAMES: [&str; 5] = [
    "integrators",
    "jello-stability",
    "jello-accuracy",
    "cloth-accuracy",
    "cloth-stability",
];

/// Runs the study `name`, writing its report into `out`; returns a short text summary.
pub fn run(name: &str, out: &Path, quick: bool) -> Result<String, StudyError> {
    std::fs::create_dir_all(out).map_err(|e| StudyError::Write {
        path: out.display().to_string(),
        message: e.to_string(),
    })?;
    match name {
        "integrators" => integrators::run(out, quick),
        "jello-stability" => jello::stability(out, quick),
        "jello-accuracy" => jello::accuracy(out, quick),
        "cloth-accuracy" => cloth::accuracy(out, quick),
        "cloth-stability" => cloth::stability(out, quick),
        other => Err(StudyError::Unknown(other.to_string())),
    }
}

pub(crate) fn write_file(path: &Path, text: &str) -> Result<(), StudyError> {
    crate::io::write_atomically(path, |w| w.write_all(text.as_bytes())).map_err(|e| {
        StudyError::Write {
            path: path.display().to_string(),
            message: e.to_string(),
        }
    })
}

/// The largest distance between corresponding points of two component-major position
/// arrays (m).
pub(crate) fn max_distance(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() / 3;
    (0..n)
        .map(|i| {
            (0..3)
                .map(|c| (a[c * n + i] - b[c * n + i]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// Least-squares slope of log error against log dt over `(dt, error)` points: the
/// observed order; `None` with fewer than three points.
pub(crate) fn log_slope(points: &[(f64, f64)]) -> Option<f64> {
    let fit: Vec<(f64, f64)> = points.iter().map(|&(d, e)| (d.ln(), e.ln())).collect();
    (fit.len() >= 3).then(|| {
        let nf = fit.len() as f64;
        let (sx, sy) = fit.iter().fold((0.0, 0.0), |(a, b), p| (a + p.0, b + p.1));
        let (mx, my) = (sx / nf, sy / nf);
        let num: f64 = fit.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let den: f64 = fit.iter().map(|p| (p.0 - mx).powi(2)).sum();
        num / den
    })
}
