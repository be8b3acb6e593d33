//! Stage-only jobs (a plain XY laser, no scanner) run through their vertices
//! at speed: a job of circles comes near its bound in a dry-run, inside every limit.

use std::path::Path;
use std::process::Command;

#[test]
fn a_stage_only_job_of_circles_runs_near_its_bound_within_every_limit() {
    let dir = tempfile::tempdir().unwrap();
    // Ten circles of 10 mm radius, cut (a pierce each) at 50 mm/s on the flatbed cutter.
    let circles: String = (0..10).map(|k| format!("<circle cx=\"{}\" cy=\"100\" r=\"10\"/>\n", 50 + 30 * k)).collect();
    let svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"400mm\" height=\"200mm\" viewBox=\"0 0 400 200\">\n\
         <g fill=\"none\" stroke=\"#000000\" stroke-width=\"0.1\">\n{circles}</g></svg>\n"
    );
    let job = dir.path().join("circles.svg");
    std::fs::write(&job, svg).unwrap();
    let cutter = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["dry-run", job.to_str().unwrap(), "--config", cutter.to_str().unwrap(), "--planner", "ecp", "--json"])
        .current_dir(dir.path())
        .output()
        .expect("laserd runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["mode"], "stage-only");
    let (time, bound) = (report["trajectory_time_s"].as_f64().unwrap(), report["lower_bound_s"].as_f64().unwrap());
    // Stopping at every vertex took 2.2 times the bound here.
    assert!(time <= 1.15 * bound, "{time} s against a bound of {bound} s");
    let sim = &report["sim"];
    assert_eq!(sim["limit_breaches"].as_array().unwrap().len(), 0, "{sim}");
    assert!(sim["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.02, "{sim}");
    assert!(sim["peak_stage_use"].as_f64().unwrap() <= 1.0, "{sim}");
    assert!(sim["job_time_s"].as_f64().unwrap() <= 1.15 * bound, "{sim}");
}
