//! Studies: error against run time, observed orders and stability, written as
//! `NAME.md` (tables, the error measure and the reference stated), `NAME.svg` and `NAME.png`
//! (log-log error against run time, one curve per method) and `NAME.json` (all numbers).

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
pub const NAMES: [&str; 3] = ["integrators", "jello-stability", "jello-accuracy"];

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
