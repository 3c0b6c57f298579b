//! The layout rules of `docs/architecture.md`, checked on the source tree: the scene layer
//! names no domain outside its one registry, physics and `io` never import the renderer,
//! and the architecture document names only paths that exist.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The `.rs` files under `dir` (recursively), with their text.
fn sources(dir: &Path) -> Vec<(PathBuf, String)> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return out;
    };
    for e in entries {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(sources(&p));
        } else if p.extension().is_some_and(|x| x == "rs") {
            let text = std::fs::read_to_string(&p).unwrap();
            out.push((p, text));
        }
    }
    out
}

/// The domains: every folder under `src/` whose `scene.rs` registers a table.
fn domains() -> Vec<String> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(root().join("src")).unwrap() {
        let p = e.unwrap().path();
        if p.join("scene.rs").is_file() && p.file_name().unwrap() != "scene" {
            out.push(p.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    out.sort();
    out
}

#[test]
fn the_scene_layer_names_no_domain_outside_its_registry() {
    let domains = domains();
    assert!(
        domains.contains(&"cloth".to_string()) && domains.contains(&"mass_spring".to_string()),
        "{domains:?}"
    );
    for (path, text) in sources(&root().join("src/scene")) {
        if path.ends_with("registry.rs") {
            continue;
        }
        for d in &domains {
            assert!(
                !text.contains(&format!("{d}::")),
                "{} names the domain `{d}`: only src/scene/registry.rs may",
                path.display()
            );
        }
    }
    // Every domain is in the registry.
    let registry = std::fs::read_to_string(root().join("src/scene/registry.rs")).unwrap();
    for d in &domains {
        assert!(
            registry.contains(&format!("crate::{d}::scene::build")),
            "{d} is not registered"
        );
    }
}

#[test]
fn physics_and_io_never_import_the_renderer() {
    let mut dirs: Vec<String> = domains();
    dirs.extend(["collide", "loads", "simulation", "integrate", "solve", "io"].map(String::from));
    for d in dirs {
        for (path, text) in sources(&root().join("src").join(&d)) {
            assert!(
                !text.contains("crate::render") && !text.contains("render::"),
                "{} imports the renderer",
                path.display()
            );
        }
    }
}

/// The backquoted words of a Markdown text that look like paths in the repository: they
/// start with one of its top-level entries (`src/`, `docs/`, `../shared/`, ...) or end in
/// a file extension, and hold no Rust path (`::`), placeholder (`<`, `*`) or space
/// (`dF/dx` in a formula is not a path).
fn paths_in(text: &str) -> Vec<String> {
    let tops = [
        "src/",
        "kernels/",
        "tests/",
        "benches/",
        "docs/",
        "scenes/",
        ".ci/",
        "../shared/",
    ];
    let mut out = Vec::new();
    for (i, part) in text.split('`').enumerate() {
        if i % 2 == 0 {
            continue; // outside backquotes
        }
        let word = part.trim_end_matches(['.', ',', ':']);
        let looks_like_path = tops.iter().any(|t| word.starts_with(t))
            || [".rs", ".toml", ".md", ".png", ".svg", ".json"]
                .iter()
                .any(|e| word.ends_with(e));
        let plain = !word.is_empty()
            && word
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c));
        if looks_like_path && plain && !word.contains("::") {
            out.push(word.to_string());
        }
    }
    out
}

#[test]
fn the_architecture_document_names_only_paths_that_exist() {
    let text = std::fs::read_to_string(root().join("docs/architecture.md")).unwrap();
    let paths = paths_in(&text);
    assert!(paths.len() > 30, "found only {} paths", paths.len());
    // Output files a run or a study writes (`run.svg`, `NAME.md`) are not in the tree.
    let written = [
        "run.svg",
        "run.png",
        "energy.csv",
        "animation.gif",
        "contact-sheet.png",
        "NAME.md",
        "NAME.svg",
        "NAME.png",
        "NAME.json",
    ];
    let missing: Vec<&String> = paths
        .iter()
        .filter(|p| !written.contains(&p.as_str()))
        .filter(|p| !root().join(p).exists())
        .collect();
    assert!(
        missing.is_empty(),
        "docs/architecture.md names paths that do not exist: {missing:?}"
    );
}

#[test]
fn path_detection_finds_paths_and_skips_code() {
    let found = paths_in(
        "see `src/cloth/mod.rs`, `collide::Obstacle`, `src/<domain>/`, `dF/dx`, `x` and `Cargo.toml`.",
    );
    assert_eq!(found, ["src/cloth/mod.rs", "Cargo.toml"]);
}
