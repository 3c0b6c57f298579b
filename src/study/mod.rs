//! Studies: error against run time, observed orders and stability, written as
//! `NAME.md` (tables, the error measure and the reference stated), `NAME.svg` and `NAME.png`
//! (log-log error against run time, one curve per method) and `NAME.json` (all numbers).

#[cfg(feature = "cloth")]
mod cloth;
mod collide;
#[cfg(feature = "fem")]
mod fem;
#[cfg(feature = "fluid")]
mod fluid;
#[cfg(feature = "fluid")]
pub use fluid::poisson_problem;
#[cfg(feature = "anim")]
mod anim;
mod integrators;
#[cfg(feature = "mass-spring")]
mod jello;
#[cfg(feature = "modal")]
mod modal;
mod problems;
#[cfg(feature = "rigid")]
mod rigid;

use std::cell::Cell;
use std::path::Path;

/// How far a study has got, for progress bars: its cases (one method's sweep, one
/// stability search, one reference run) done out of those it announced. `report(done,
/// total, what)` is called after each case.
pub struct Progress<'a> {
    done: Cell<usize>,
    total: Cell<usize>,
    report: &'a dyn Fn(usize, usize, &str),
}

impl<'a> Progress<'a> {
    /// Progress reported to `report(done, total, what just finished)`.
    pub fn new(report: &'a dyn Fn(usize, usize, &str)) -> Self {
        Progress {
            done: Cell::new(0),
            total: Cell::new(0),
            report,
        }
    }

    /// No reporting.
    pub fn silent() -> Progress<'static> {
        Progress::new(&|_, _, _| {})
    }

    /// Announces `n` more cases.
    pub(crate) fn expect(&self, n: usize) {
        self.total.set(self.total.get() + n);
        (self.report)(self.done.get(), self.total.get(), "");
    }

    /// One case done.
    pub(crate) fn tick(&self, what: &str) {
        self.done.set(self.done.get() + 1);
        (self.report)(self.done.get(), self.total.get().max(self.done.get()), what);
    }
}

/// Study failures.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StudyError {
    /// No study of that name.
    #[error("unknown study `{0}`; available: {names}", names = names().join(", "))]
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

/// A study: its name and what runs it (into a folder, quick or not).
type Study = (
    &'static str,
    fn(&Path, bool, &Progress<'_>) -> Result<String, StudyError>,
);

/// The studies of the domains built in.
const STUDIES: &[Study] = &[
    ("integrators", integrators::run),
    #[cfg(feature = "mass-spring")]
    ("jello-stability", jello::stability),
    #[cfg(feature = "mass-spring")]
    ("jello-accuracy", jello::accuracy),
    #[cfg(feature = "cloth")]
    ("cloth-accuracy", cloth::accuracy),
    #[cfg(feature = "cloth")]
    ("cloth-stability", cloth::stability),
    #[cfg(feature = "fem")]
    ("fem-accuracy", fem::accuracy),
    #[cfg(feature = "fem")]
    ("fem-stability", fem::stability),
    #[cfg(feature = "fem")]
    ("fem-steps", fem::steps),
    #[cfg(feature = "modal")]
    ("modes", modal::modes),
    #[cfg(feature = "fluid")]
    ("fluids", fluid::fluids),
    #[cfg(feature = "fluid")]
    ("poisson", fluid::poisson),
    #[cfg(feature = "fluid")]
    ("cavity", fluid::cavity_study),
    ("distance-fields", collide::distance_fields),
    #[cfg(feature = "rigid")]
    ("rigid-integrators", rigid::integrators),
    #[cfg(feature = "rigid")]
    ("rigid-contacts", rigid::contacts),
    #[cfg(feature = "rigid")]
    ("rigid-reuse", rigid::reuse),
    #[cfg(feature = "anim")]
    ("anim-ik", anim::ik),
    #[cfg(feature = "anim")]
    ("anim-sampling", anim::sampling),
];

/// The names of the studies built in.
pub fn names() -> Vec<&'static str> {
    STUDIES.iter().map(|(name, _)| *name).collect()
}

/// Runs the study `name`, writing its report into `out` and its progress to `progress`;
/// returns a short text summary.
pub fn run(
    name: &str,
    out: &Path,
    quick: bool,
    progress: &Progress<'_>,
) -> Result<String, StudyError> {
    std::fs::create_dir_all(out).map_err(|e| StudyError::Write {
        path: out.display().to_string(),
        message: e.to_string(),
    })?;
    match STUDIES.iter().find(|(n, _)| *n == name) {
        Some((_, study)) => study(out, quick, progress),
        None => Err(StudyError::Unknown(name.to_string())),
    }
}

/// Writes a study's `NAME.svg` and `NAME.png` (the panels, `cols` per row, each `size`
/// pixels) and `NAME.json` (its numbers) into `out`.
pub(crate) fn write_plot_and_numbers(
    out: &Path,
    name: &str,
    panels: &[crate::plot::Panel],
    cols: usize,
    size: (u32, u32),
    numbers: &impl serde::Serialize,
) -> Result<(), StudyError> {
    let stem = out.join(name);
    crate::plot::write_panels(&stem, panels, cols, size).map_err(|message| StudyError::Write {
        path: stem.display().to_string(),
        message,
    })?;
    let json = serde_json::to_string_pretty(numbers).expect("study numbers serialize");
    write_file(&out.join(format!("{name}.json")), &json)
}

/// One solid curve per `(label, points)`, its colour and marker by its position: a
/// study's sweeps as a panel's curves.
#[cfg(any(feature = "cloth", feature = "fem"))]
pub(crate) fn solid_curves(
    sweeps: impl IntoIterator<Item = (String, Vec<(f64, f64)>)>,
) -> Vec<(usize, crate::plot::Curve)> {
    sweeps
        .into_iter()
        .enumerate()
        .map(|(i, (label, points))| {
            let curve = crate::plot::Curve {
                label,
                points,
                dashed: false,
            };
            (i, curve)
        })
        .collect()
}

/// One log-log curve per name: the points `keep` gives it, through `f`, those with
/// positive coordinates.
#[cfg(any(feature = "rigid", feature = "anim"))]
pub(crate) fn curves_by<P>(
    names: &[&str],
    points: &[P],
    keep: impl Fn(&P, &str) -> bool,
    f: &dyn Fn(&P) -> (f64, f64),
) -> Vec<(usize, crate::plot::Curve)> {
    names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            (
                k,
                crate::plot::Curve {
                    label: (*name).into(),
                    points: points
                        .iter()
                        .filter(|p| keep(p, name))
                        .map(f)
                        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
                        .collect(),
                    dashed: false,
                },
            )
        })
        .collect()
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
#[cfg(any(feature = "mass-spring", feature = "cloth"))]
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
#[cfg(any(feature = "mass-spring", feature = "cloth"))]
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
