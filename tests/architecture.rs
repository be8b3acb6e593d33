//! ARCHITECTURE.md stays true: short, every file or folder it names exists,
//! and every invariant it states names a test that exists.
//!
//! A path is a backticked token starting with a top-level folder of the
//! workspace (`src/plan/`, `sim/src/controller/hold.rs`); a test reference is
//! a path followed by `::name` (`tests/safe_stop.rs::abort_leaves_laser_off`),
//! and the file must define `fn name`. An invariant is a list item that
//! starts with "**Invariant**".

use std::path::Path;

const ROOTS: [&str; 9] = [
    "src/", "sim/", "tests/", "fuzz/", "bench/", "config/", "docs/", "samples/", ".ci/",
];
const MAX_LINES: usize = 250;

fn document() -> String {
    std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md is readable")
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Backticked tokens of a line.
fn code_spans(line: &str) -> impl Iterator<Item = &str> {
    line.split('`').skip(1).step_by(2)
}

/// (path, optional test name) of a token that names a workspace file or folder.
fn reference(token: &str) -> Option<(&str, Option<&str>)> {
    if !ROOTS.iter().any(|r| token.starts_with(r)) || token.contains(' ') {
        return None;
    }
    Some(match token.split_once("::") {
        Some((path, name)) => (path, Some(name)),
        None => (token, None),
    })
}

#[test]
fn is_short() {
    let lines = document().lines().count();
    assert!(
        lines < MAX_LINES,
        "ARCHITECTURE.md has {lines} lines; keep it under {MAX_LINES}"
    );
}

#[test]
fn every_named_path_and_test_exists() {
    let mut missing = Vec::new();
    let mut checked = 0;
    for (n, line) in document().lines().enumerate() {
        for (path, test) in code_spans(line).filter_map(reference) {
            checked += 1;
            let file = root().join(path);
            if !file.exists() {
                missing.push(format!("line {}: `{path}` does not exist", n + 1));
                continue;
            }
            if let Some(name) = test {
                let text = std::fs::read_to_string(&file).unwrap_or_default();
                if !text.contains(&format!("fn {name}(")) {
                    missing.push(format!("line {}: `{path}` defines no test `{name}`", n + 1));
                }
            }
        }
    }
    assert!(
        checked > 20,
        "ARCHITECTURE.md names only {checked} paths: the code map is missing"
    );
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md is out of date:\n{}",
        missing.join("\n")
    );
}

#[test]
fn every_invariant_names_its_test() {
    let (mut unbacked, mut invariants) = (Vec::new(), 0);
    for (n, line) in document().lines().enumerate() {
        if line.starts_with("- **Invariant**") {
            invariants += 1;
            let backed = code_spans(line).filter_map(reference).any(|(_, test)| test.is_some());
            if !backed {
                unbacked.push(format!("line {}: {line}", n + 1));
            }
        }
    }
    assert!(invariants >= 10, "ARCHITECTURE.md states only {invariants} invariants");
    assert!(unbacked.is_empty(), "invariants without a test (`path::test_name`):\n{}", unbacked.join("\n"));
}

/// Every folder and source file of both crates is named: by its path, or
/// by its last components (`sender/link.rs`, `hold.rs`) in the section that
/// maps its folder. `mod.rs`, `lib.rs` and `tests.rs` go with their folder.
#[test]
fn every_module_is_named() {
    let doc = document();
    let spans: Vec<&str> = doc.lines().flat_map(code_spans).map(|s| s.split("::").next().unwrap_or(s)).collect();
    let named = |path: &str| spans.iter().any(|s| {
        let s = s.trim_end_matches('/');
        path == s || path.ends_with(&format!("/{s}"))
    });
    let mut unnamed = Vec::new();
    for top in ["src", "sim/src"] {
        let mut stack = vec![root().join(top)];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).expect("source folders are readable").flatten() {
                let path = entry.path();
                let relative = path.strip_prefix(root()).unwrap().to_string_lossy().into_owned();
                if path.is_dir() {
                    stack.push(path);
                } else if !relative.ends_with(".rs") || ["mod.rs", "lib.rs", "tests.rs"].iter().any(|f| relative.ends_with(&format!("/{f}"))) {
                    continue;
                }
                if !named(&relative) {
                    unnamed.push(relative);
                }
            }
        }
    }
    unnamed.sort();
    assert!(unnamed.is_empty(), "ARCHITECTURE.md does not name: {}", unnamed.join(", "));
}

