//! Issue 18, item 6: the same job, config and seed give a byte-identical
//! program whatever the machine's load and the number of threads, unless a
//! time limit ends a search first (and then the report says so).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicBool, Ordering};

use laserd::gen::sheet;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A galvo job: seed 003's family with 278 geometries in 18 fields.
fn galvo_job() -> (PathBuf, PathBuf) {
    (root().join("tests/data/galvo/SC278C18.svg"), root().join("config/laserd.toml"))
}

/// A generated sheet of nested parts (about 60 elements) on the flatbed cutter.
fn cutting_job(dir: &Path) -> (PathBuf, PathBuf) {
    let params = sheet::SheetParams::with_target(60);
    let path = dir.join("sheet.svg");
    std::fs::write(&path, sheet::to_svg(&sheet::generate_sheet(&params, 7), &params)).unwrap();
    (path, root().join("config/flatbed-cutter.toml"))
}

/// `laserd plan` of `job` with `planner`; the program's bytes and the report.
fn plan(job: &Path, config: &Path, planner: &str, threads: Option<&str>, extra: &[&str]) -> (Vec<u8>, serde_json::Value) {
    let dir = tempfile::tempdir().unwrap();
    let program = dir.path().join("out.nc");
    let out = laserd(job, config, planner, threads, &[&["-o", program.to_str().unwrap()], extra].concat());
    assert!(out.status.success(), "{planner}: {}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    (std::fs::read(&program).unwrap(), report)
}

fn laserd(job: &Path, config: &Path, planner: &str, threads: Option<&str>, extra: &[&str]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_laserd"));
    command.args(["plan", job.to_str().unwrap(), "--config", config.to_str().unwrap(), "--planner", planner, "--json"]).args(extra);
    match threads {
        Some(n) => command.env("LASERD_THREADS", n),
        None => command.env_remove("LASERD_THREADS"),
    };
    command.output().expect("laserd runs")
}

/// `f` while two threads spin on the cores.
fn while_busy<R>(f: impl FnOnce() -> R) -> R {
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1));
                }
            });
        }
        let result = f();
        stop.store(true, Ordering::Relaxed);
        result
    })
}

fn assert_same(what: &str, a: &(Vec<u8>, serde_json::Value), b: &(Vec<u8>, serde_json::Value)) {
    assert!(!a.0.is_empty(), "{what}: a program");
    assert!(a.0 == b.0, "{what}: the programs differ ({} and {} bytes)", a.0.len(), b.0.len());
    assert_eq!(a.1["idle_stroke_mm"], b.1["idle_stroke_mm"], "{what}");
    for report in [&a.1, &b.1] {
        assert_eq!(report["search_stopped_by"], "budget", "{what}: {report}");
    }
}

#[test]
fn the_same_job_plans_the_same_on_a_busy_machine() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [("hha", galvo_job()), ("hga", (root().join("tests/data/galvo/SC32C2.svg"), root().join("config/laserd.toml"))), ("ecp", cutting_job(dir.path()))];
    for (planner, (job, config)) in cases {
        let quiet = plan(&job, &config, planner, None, &[]);
        let busy = while_busy(|| plan(&job, &config, planner, None, &[]));
        assert_same(planner, &quiet, &busy);
    }
}

#[test]
fn the_same_job_plans_the_same_on_one_thread_and_on_several() {
    let dir = tempfile::tempdir().unwrap();
    for (planner, (job, config)) in [("hha", galvo_job()), ("ecp", cutting_job(dir.path()))] {
        let one = plan(&job, &config, planner, Some("1"), &[]);
        let several = plan(&job, &config, planner, Some("3"), &[]);
        assert_same(planner, &one, &several);
    }
}

#[test]
fn a_time_limit_that_ends_the_search_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let (job, config) = cutting_job(dir.path());
    let (program, report) = plan(&job, &config, "ecp", None, &["--time-limit", "0.01"]);
    assert!(!program.is_empty());
    assert_eq!(report["search_stopped_by"], "time-limit", "{report}");
    assert_eq!(report["precedence_violations"], 0, "a capped search still keeps every rule");
}

#[test]
fn an_unreadable_thread_count_is_refused_by_name() {
    let (job, config) = galvo_job();
    for bad in ["0", "many", "100000"] {
        let out = laserd(&job, &config, "hha", Some(bad), &[]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{bad}: {err}");
        assert!(err.contains("LASERD_THREADS") && err.contains("from 1 to 256"), "{bad}: {err}");
    }
}
