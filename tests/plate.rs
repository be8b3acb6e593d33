//! The plate (`[plate]`, seed 000's "removing complexity"): outlines on its
//! edge are not cut, cuts start from the edge without a pierce, skeleton and
//! remnant cuts join the route, clamps fix what they hold; through the
//! command line as a user runs it, and on generated sheets.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The flatbed cutter's config with `plate` (TOML) appended.
fn config_with(dir: &Path, plate: &str) -> PathBuf {
    let base = std::fs::read_to_string(root().join("config/flatbed-cutter.toml")).unwrap();
    let path = dir.join("machine.toml");
    std::fs::write(&path, format!("{base}\n{plate}\n")).unwrap();
    path
}

fn laserd(args: &[&str], config: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_laserd")).args(args).arg("--config").arg(config).output().unwrap()
}

fn report(args: &[&str], config: &Path) -> Value {
    let out = laserd(args, config);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn the_sample_on_its_plate_leaves_the_edge_uncut_and_dry_runs_within_limits() {
    let dir = tempfile::tempdir().unwrap();
    let sample = root().join("samples/cut-parts.dxf");
    let job = sample.to_str().unwrap();
    let free = report(&["plan", job, "--json"], &root().join("config/flatbed-cutter.toml"));
    assert_eq!(free["edge_length_saved_mm"], Value::Null);
    // A 250 x 150 mm plate: the sample's part at x = 0 lies on its left edge
    // with its 40 mm side.
    let plate = config_with(dir.path(), "[plate]\nwidth = 250.0\nheight = 150.0\n");
    let on_plate = report(&["plan", job, "--json"], &plate);
    let saved = on_plate["edge_length_saved_mm"].as_f64().unwrap();
    assert!((saved - 40.0).abs() < 1e-6, "{saved}");
    let drop = free["cut_length_mm"].as_f64().unwrap() - on_plate["cut_length_mm"].as_f64().unwrap();
    assert!((drop - saved).abs() < 1e-6, "cut length drops by the edge length: {drop} vs {saved}");
    assert!(on_plate["edge_starts"].as_u64().unwrap() >= 1, "the part on the edge is cut from it");
    // The search weighs pierces against air: no more pierces than in free space.
    assert!(on_plate["pierces"].as_u64().unwrap() <= free["pierces"].as_u64().unwrap());
    assert_eq!((on_plate["skeleton_cuts"].as_u64(), on_plate["remnant_cuts"].as_u64()), (Some(0), Some(0)));
    // Skeleton cut into 100 mm pieces, the remnant kept, a clamp at the
    // left edge: a dry-run on the simulator keeps every rule and limit.
    let scrap = config_with(
        dir.path(),
        "[plate]\nwidth = 250.0\nheight = 150.0\nskeleton_piece = 100.0\nremnant = \"auto\"\nremnant_min = 20.0\n[[plate.clamp]]\nx = 0.0\ny = 30.0\n",
    );
    let recording = dir.path().join("run.mcap");
    let run = report(&["dry-run", job, "--json", "--record", recording.to_str().unwrap()], &scrap);
    assert_eq!(run["precedence_violations"], 0);
    assert!(run["skeleton_cuts"].as_u64().unwrap() > 0 && run["remnant_cuts"].as_u64().unwrap() > 0, "{run}");
    assert_eq!(run["sim"]["limit_violations"], 0, "{run}");
    let cut_more = run["cut_length_mm"].as_f64().unwrap() - on_plate["cut_length_mm"].as_f64().unwrap();
    assert!(cut_more > 0.0, "the skeleton and remnant cuts are cut: {cut_more}");
}

#[test]
fn a_generated_sheet_with_parts_on_its_edge() {
    let machine = laserd::config::MachineConfig::load(Some(&root().join("config/flatbed-cutter.toml"))).unwrap();
    let r = laserd::bench::plate_bench(&machine, 150, 2, 400.0, None).unwrap();
    let saved = r.on_plate.edge_length_saved_mm.unwrap();
    assert!(saved > 0.0);
    assert!((r.cut_length_drop_mm - saved).abs() <= 1e-9 * saved.max(1.0), "cut length drops by the edge length exactly: {} vs {saved}", r.cut_length_drop_mm);
    assert_eq!(r.free.edge_starts, 0);
    assert!(r.on_plate.edge_starts > 0 && r.on_plate.pierces < r.free.pierces, "{:?} {:?}", r.on_plate, r.free);
    for run in [&r.on_plate, &r.scrap_in_route, &r.scrap_after] {
        assert_eq!(run.precedence_violations, Some(0), "{run:?}");
    }
    assert!(r.scrap_in_route.skeleton_cuts.unwrap() > 0);
    // The same cuts either way, in the route or after it.
    assert!((r.scrap_in_route.cut_length_mm - r.scrap_after.cut_length_mm).abs() < 1e-6);
}

#[test]
fn bad_plate_settings_and_parts_off_the_plate_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let job = root().join("samples/cut-parts.dxf");
    let job = job.to_str().unwrap();
    for (plate, named) in [
        ("[plate]\nwidth = 0.0\nheight = 150.0\n", "plate.width"),
        ("[plate]\nwidth = 250.0\nheight = 150.0\nskeleton_piece = 1.0\n", "plate.skeleton_piece"),
        ("[plate]\nwidth = 250.0\nheight = 150.0\nlayer = \"nope\"\n", "plate.layer"),
        ("[plate]\nwidth = 250.0\nheight = 150.0\nremnant = \"most\"\n", "remnant"),
        ("[plate]\nwidth = 250.0\nheight = 150.0\n[[plate.clamp]]\nx = 0.0\ny = 0.0\nradius = 1e9\n", "plate.clamp[0].radius"),
        // The job reaches x = 235: off a 200 mm plate.
        ("[plate]\nwidth = 200.0\nheight = 150.0\n", "off the plate"),
        ("[plate]\nwidth = 250.0\nheight = 150.0\nremnant = [0.0, 0.0, 100.0, 100.0]\n", "[plate] remnant"),
    ] {
        let out = laserd(&["plan", job], &config_with(dir.path(), plate));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(named), "{plate}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    // A planner that does not know the plate's rules is refused on one.
    let out = laserd(&["plan", job, "--planner", "nearest"], &config_with(dir.path(), "[plate]\nwidth = 250.0\nheight = 150.0\n"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--planner auto or ecp"), "{err}");
}

#[test]
fn a_job_file_carries_its_plate() {
    let dir = tempfile::tempdir().unwrap();
    let plate = config_with(dir.path(), "[plate]\nwidth = 250.0\nheight = 150.0\n");
    let job_file = dir.path().join("job.json");
    let sample = root().join("samples/cut-parts.dxf");
    let out = laserd(&["import", sample.to_str().unwrap(), "-o", job_file.to_str().unwrap()], &plate);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let written: Value = serde_json::from_slice(&std::fs::read(&job_file).unwrap()).unwrap();
    assert_eq!(written["plate"]["width"], 250.0);
    // Planned on a machine whose config has no plate: the job's is used.
    let cutter = root().join("config/flatbed-cutter.toml");
    let r = report(&["plan", job_file.to_str().unwrap(), "--json"], &cutter);
    assert!((r["edge_length_saved_mm"].as_f64().unwrap() - 40.0).abs() < 1e-6, "{r}");
    // A job file's plate is checked as a config's.
    let mut bad = written.clone();
    bad["plate"]["skeleton_piece"] = serde_json::json!(-1.0);
    std::fs::write(&job_file, bad.to_string()).unwrap();
    let out = laserd(&["plan", job_file.to_str().unwrap()], &cutter);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("job.json") && err.contains("plate.skeleton_piece"), "{err}");
    let schema = Command::new(env!("CARGO_BIN_EXE_laserd")).arg("job-schema").output().unwrap();
    assert!(String::from_utf8_lossy(&schema.stdout).contains("skeleton_piece"));
}
