//! Imports follow the pipeline: no module of the laserd library refers to a
//! later one. `LAYERS` below is the one place that order is written down.
//!
//! Every `crate::<module>` in src/**/*.rs counts, in `use` lines, inside
//! `use crate::{a, b::c}` groups and in fully qualified paths in code, tests
//! included. src/main.rs and src/cli/ are the binary: their `crate::` is the
//! binary's own modules, and they stand above every library module. The
//! simulator crate (sim/, laserd-sim) is a separate crate below laserd; its
//! modules are not checked here.

use std::path::{Path, PathBuf};

/// The library's top-level modules, lowest first. A module may refer to
/// itself and to the ones before it, never to one after it.
const LAYERS: &[&str] = &[
    // Shared base: errors, a job's geometry, the machine's config and limits,
    // threads, how scanner and stage share the work.
    "error",
    "parallel",
    "job",
    "config",
    "mode",
    // The pipeline.
    "import",
    "topology",
    // The plate heat model the cutting planner checks its routes with.
    "thermal",
    "plan",
    "motion",
    "program",
    "stream",
    // Above the pipeline: figures of a run, its recording and report, plots,
    // instance generators, whole runs, benchmarks, the service, the command line.
    "figures",
    "record",
    "report",
    "plot",
    "gen",
    "run",
    "bench",
    "daemon",
    "cli",
];

fn rank(module: &str) -> Option<usize> {
    LAYERS.iter().position(|&m| m == module)
}

/// The top-level module a source file belongs to: `src/plan/ecp/ils.rs` is in
/// `plan`, `src/config.rs` in `config`, `src/main.rs` in `cli`.
fn module_of(src: &Path, file: &Path) -> String {
    let relative = file.strip_prefix(src).expect("under src/");
    let first = relative.components().next().expect("a path").as_os_str().to_string_lossy();
    match first.strip_suffix(".rs") {
        Some("main") => "cli".to_string(),
        Some(name) => name.to_string(),
        None => first.to_string(),
    }
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The text of a line outside `//` comments (doc comments name modules in
/// prose and links; they import nothing).
fn code_of(line: &str) -> &str {
    match line.find("//") {
        Some(at) => &line[..at],
        None => line,
    }
}

/// The top-level modules `source` refers to through `crate::`, each with its
/// line number (1-based). A `use crate::{a, b::{c}}` group names a and b, on
/// the lines they are written on.
fn crate_references(source: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    // Inside a `crate::{` group: the depth of braces, and whether the next
    // name is a top-level module (after `{` or `,` at depth 1).
    let mut group_depth = 0usize;
    let mut expect_name = false;
    for (index, raw) in source.lines().enumerate() {
        let line = code_of(raw);
        let mut rest = line;
        loop {
            if group_depth > 0 {
                let Some(c) = rest.chars().next() else { break };
                let ident: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if !ident.is_empty() {
                    if expect_name && group_depth == 1 {
                        found.push((index + 1, ident.clone()));
                    }
                    expect_name = false;
                    rest = &rest[ident.len()..];
                    continue;
                }
                match c {
                    '{' => group_depth += 1,
                    '}' => group_depth -= 1,
                    ',' => expect_name = group_depth == 1,
                    _ => {}
                }
                rest = &rest[c.len_utf8()..];
                continue;
            }
            let Some(at) = rest.find("crate::") else { break };
            // `my_crate::` is another path, not this crate.
            let before = rest[..at].chars().next_back();
            rest = &rest[at + "crate::".len()..];
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                continue;
            }
            if let Some(group) = rest.strip_prefix('{') {
                group_depth = 1;
                expect_name = true;
                rest = group;
                continue;
            }
            let ident: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            if !ident.is_empty() {
                found.push((index + 1, ident.clone()));
                rest = &rest[ident.len()..];
            }
        }
    }
    found
}

/// Every reference from a module to a later one: "file:line: a -> b".
fn backwards_imports(root: &Path) -> Vec<String> {
    let src = root.join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut broken = Vec::new();
    for file in files {
        let from = module_of(&src, &file);
        if from == "lib" {
            continue; // the crate root only declares the modules
        }
        let from_rank = rank(&from).unwrap_or_else(|| panic!("{}: module `{from}` is not in LAYERS (tests/layers.rs): add it", file.display()));
        let text = std::fs::read_to_string(&file).unwrap();
        for (line, to) in crate_references(&text) {
            // The binary's `crate::` is the binary's own modules (cli), above everything.
            if from == "cli" {
                continue;
            }
            let Some(to_rank) = rank(&to) else {
                // `crate::SomeItem` at the crate root, or a module LAYERS misses.
                assert!(!to.starts_with(|c: char| c.is_lowercase()), "{}:{line}: `crate::{to}` is not in LAYERS (tests/layers.rs): add it", file.display());
                continue;
            };
            if to_rank > from_rank {
                let shown = file.strip_prefix(root).unwrap_or(&file).display().to_string();
                broken.push(format!("{shown}:{line}: {from} -> {to} ({to} comes later in the pipeline)"));
            }
        }
    }
    broken
}

#[test]
fn no_module_imports_a_later_one() {
    let broken = backwards_imports(Path::new(env!("CARGO_MANIFEST_DIR")));
    assert!(broken.is_empty(), "backwards imports (order: {}):\n{}", LAYERS.join(" < "), broken.join("\n"));
}

#[test]
fn every_library_module_has_a_layer() {
    let lib = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs")).unwrap();
    for line in lib.lines() {
        if let Some(name) = line.trim().strip_prefix("pub mod ").and_then(|rest| rest.strip_suffix(';')) {
            assert!(rank(name).is_some(), "src/lib.rs: module `{name}` is not in LAYERS (tests/layers.rs)");
        }
    }
}

#[test]
fn references_are_found_in_use_lines_groups_and_code() {
    let source = "\
use crate::plan::Sequence;
use crate::{job::Point, stream::{self, LinkEvent},
    motion};
// crate::daemon in a comment imports nothing
fn f() { let x = crate::record::open(); let y = my_crate::gen::x(); }
";
    let found = crate_references(source);
    let expected: Vec<(usize, String)> =
        [(1, "plan"), (2, "job"), (2, "stream"), (3, "motion"), (5, "record")].iter().map(|&(l, m)| (l, m.to_string())).collect();
    assert_eq!(found, expected);
}

#[test]
fn a_backwards_import_is_named_with_its_file_line_and_modules() {
    // A copy of the tree's layout with one planner importing the recorder.
    let root = std::env::temp_dir().join(format!("laserd-layers-{}", std::process::id()));
    let plan = root.join("src/plan");
    std::fs::create_dir_all(&plan).unwrap();
    std::fs::write(root.join("src/job.rs"), "pub struct Job;\n").unwrap();
    std::fs::write(plan.join("mod.rs"), "use crate::job::Job;\n\nfn f() {\n    crate::record::start();\n}\n").unwrap();
    let broken = backwards_imports(&root);
    std::fs::remove_dir_all(&root).unwrap();
    assert_eq!(broken, vec!["src/plan/mod.rs:4: plan -> record (record comes later in the pipeline)".to_string()]);
}
