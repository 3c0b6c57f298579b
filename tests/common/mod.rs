//! Helpers shared by the test files (each includes this as `mod common;`).

/// Runs study `name` with `--quick` into a fresh temporary folder: the folder, the summary
/// line, the report (`name.md`) and the numbers (`name.json`).
#[cfg(feature = "cli")]
pub fn quick_study(name: &str) -> (std::path::PathBuf, String, String, Vec<serde_json::Value>) {
    let out = std::env::temp_dir().join(format!("largestep-{name}-{}", std::process::id()));
    let progress = largestep::study::Progress::silent();
    let summary = largestep::study::run(name, &out, true, &progress).unwrap();
    let read = |ext: &str| std::fs::read_to_string(out.join(format!("{name}.{ext}"))).unwrap();
    let (md, json) = (read("md"), serde_json::from_str(&read("json")).unwrap());
    (out, summary, md, json)
}
