//! Stage-only jobs (a plain XY laser, no scanner) run through their vertices
//! at speed: a job of circles comes near its bound in a dry-run, inside every
//! limit; marks without a pierce take the laser-off moves' speed over.

use std::path::Path;
use std::process::Command;

/// The `dry-run --json` report of `elements` stroked `stroke` on a 400 x 200
/// mm sheet, on the flatbed cutter, with `args` added.
fn dry_run_on_the_flatbed_cutter(elements: &str, stroke: &str, args: &[&str]) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"400mm\" height=\"200mm\" viewBox=\"0 0 400 200\">\n\
         <g fill=\"none\" stroke=\"{stroke}\" stroke-width=\"0.1\">\n{elements}</g></svg>\n"
    );
    let job = dir.path().join("job.svg");
    std::fs::write(&job, svg).unwrap();
    let cutter = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["dry-run", job.to_str().unwrap(), "--config", cutter.to_str().unwrap(), "--json"])
        .args(args)
        .current_dir(dir.path())
        .output()
        .expect("laserd runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["mode"], "stage-only");
    report
}

#[test]
fn a_stage_only_job_of_circles_runs_near_its_bound_within_every_limit() {
    // Ten circles of 10 mm radius, cut (a pierce each) at 50 mm/s on the flatbed cutter.
    let circles: String = (0..10).map(|k| format!("<circle cx=\"{}\" cy=\"100\" r=\"10\"/>\n", 50 + 30 * k)).collect();
    let report = dry_run_on_the_flatbed_cutter(&circles, "#000000", &["--planner", "ecp"]);
    let (time, bound) = (report["trajectory_time_s"].as_f64().unwrap(), report["lower_bound_s"].as_f64().unwrap());
    // Stopping at every vertex took 2.2 times the bound here.
    assert!(time <= 1.15 * bound, "{time} s against a bound of {bound} s");
    let sim = &report["sim"];
    assert_eq!(sim["limit_breaches"].as_array().unwrap().len(), 0, "{sim}");
    assert!(sim["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.02, "{sim}");
    assert!(sim["peak_stage_use"].as_f64().unwrap() <= 1.0, "{sim}");
    assert!(sim["job_time_s"].as_f64().unwrap() <= 1.15 * bound, "{sim}");
}

#[test]
fn a_stage_only_job_without_pierces_runs_its_laser_off_moves_into_the_marks_at_speed() {
    // Dashes along a line on the flatbed cutter's engrave layer (no pierce):
    // G0 and G1 in a row, which Grbl takes at its junction speed (here: in line).
    let dashes: String = (0..8).map(|k| format!("<line x1=\"{}\" y1=\"100\" x2=\"{}\" y2=\"100\"/>\n", 50 + 15 * k, 60 + 15 * k)).collect();
    let report = dry_run_on_the_flatbed_cutter(&dashes, "#0000ff", &[]);
    let sim = &report["sim"];
    assert_eq!(sim["limit_breaches"].as_array().unwrap().len(), 0, "{sim}");
    assert_eq!(sim["laser_state_errors"], 0, "{sim}");
    assert!(sim["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.02, "{sim}");
    // lower_bound_s: the dashes at full speed, the laser-off moves from rest
    // to rest. Starting and ending every dash at rest took 1.88 times it.
    let (time, bound) = (sim["job_time_s"].as_f64().unwrap(), report["lower_bound_s"].as_f64().unwrap());
    assert!(time <= 1.1 * bound, "{time} s against a bound of {bound} s");
}
