//! Grbl as the yardstick (issue 19, item 2): any G-code file dry-run as it
//! is (`dry-run FILE.nc --keep-order`), and `bench motion --vs-grbl`, which
//! times laserd's plan against the same path as plain `G1 F` moves on
//! Grbl's planner.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn laserd(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(args)
        .current_dir(dir)
        .env_remove("LASERD_CONFIG")
        .env("XDG_CONFIG_HOME", dir.join("no-user-config"))
        .output()
        .expect("laserd runs")
}

fn json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

fn cutter() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml")
}

/// The flatbed cutter with a jerk limit no trapezoid of Grbl's breaks (Grbl
/// plans none), its Grbl accelerating at the machine's whole limit.
fn cutter_without_jerk_limit(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(cutter()).unwrap();
    assert!(text.contains("max_jerk = 250000.0"));
    let path = dir.join("cutter.toml");
    let text = text.replace("max_jerk = 250000.0", "max_jerk = 1.0e12");
    std::fs::write(&path, text).unwrap();
    path
}

/// A small file along X only (no corner for Grbl's junction speeds to cut):
/// 10 mm, then 50 mm marking, then 60 mm back, all at 10 mm/s.
const ALONG_X: &str = "G21 G90 G94\n(a comment)\nG1 X10 F600\nM4 S500\nG1 X60\nM5\nG1 X0\nM2\n";

#[test]
fn a_gcode_file_kept_in_order_runs_on_both_motion_models_with_the_sim_figures() {
    let dir = tempfile::tempdir().unwrap();
    let config = cutter_without_jerk_limit(dir.path());
    std::fs::write(dir.path().join("along.nc"), ALONG_X).unwrap();
    let mut times = vec![];
    for motion in ["timed", "grbl"] {
        let report = json(&laserd(&["dry-run", "along.nc", "--keep-order", "--motion", motion, "--config", config.to_str().unwrap(), "--json"], dir.path()));
        assert_eq!(report["planner"], "keep-order");
        assert_eq!(report["motion"], motion);
        assert_eq!(report["program_lines"], 8);
        // What needs a plan is null: there is none.
        for planned in ["trajectory_time_s", "lower_bound_s"] {
            assert!(report[planned].is_null(), "{planned}: {report}");
        }
        let sim = &report["sim"];
        assert!(sim["max_tcp_deviation_mm"].is_null(), "{sim}");
        assert_eq!(sim["limit_breaches"], serde_json::json!([]), "{sim}");
        assert_eq!(sim["limit_violations"], 0);
        assert!(sim["lines_sent"].as_u64().unwrap() >= 7, "{sim}");
        assert!(sim["link_utilization"].as_f64().unwrap() > 0.0, "{sim}");
        assert!(sim["planner_starved_s"].as_f64().unwrap() >= 0.0, "{sim}");
        // 120 mm at 10 mm/s; Grbl's ramps at 5000 mm/s² add milliseconds.
        let t = sim["job_time_s"].as_f64().unwrap();
        assert!((12.0..12.1).contains(&t), "{motion}: {t}");
        assert!(dir.path().join("along.mcap").exists());
        times.push(t);
    }
    assert!(times[1] > times[0], "Grbl accelerates, the timed controller jumps to speed: {times:?}");
}

#[test]
fn a_bad_gcode_line_is_an_error_naming_the_line_and_without_keep_order_gcode_is_planned_anew() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("bad.gcode"), "G21 G90\nG1 X10 F600\nG1 X20 G0 Y5\n").unwrap();
    let out = laserd(&["dry-run", "bad.gcode", "--keep-order", "--config", cutter().to_str().unwrap()], dir.path());
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.gcode:3 `G1 X20 G0 Y5`: error:"), "{err}");
    assert!(!dir.path().join("bad.mcap").exists(), "nothing ran");
    // Without --keep-order the file's laser moves are a job, planned anew:
    // its one cut, 50 mm at S500 F600, within the limits.
    std::fs::write(dir.path().join("ok.ngc"), ALONG_X).unwrap();
    let out = laserd(&["dry-run", "ok.ngc", "--json", "--config", cutter().to_str().unwrap()], dir.path());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report = json(&out);
    assert_eq!(report["geometries"], 1, "{report}");
    assert_eq!(report["sim"]["limit_violations"], 0, "{report}");
    // Planning flags mean nothing for a file streamed as it is: refused by name.
    let out = laserd(&["dry-run", "ok.ngc", "--keep-order", "--mode", "stage-only", "--config", cutter().to_str().unwrap()], dir.path());
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--mode: ok.ngc is streamed as it is (--keep-order), not planned"), "{err}");
        // --keep-order is for G-code only.
    std::fs::write(dir.path().join("a.svg"), "<svg xmlns=\"http://www.w3.org/2000/svg\"/>").unwrap();
    let err = String::from_utf8_lossy(&laserd(&["dry-run", "a.svg", "--keep-order"], dir.path()).stderr).to_string();
    assert!(err.contains("a.svg: --keep-order streams a G-code file as it is"), "{err}");
}

/// A single long cut takes about as long either way; a circle, flattened
/// into short segments, runs on Grbl's planner at nearly its feed, well
/// below the time of its segments each from rest to rest.
#[test]
fn vs_grbl_reports_both_times_a_line_alike_and_a_circle_faster_than_rest_to_rest() {
    let dir = tempfile::tempdir().unwrap();
    let svg = |shape: &str| format!("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"300mm\" height=\"300mm\" viewBox=\"0 0 300 300\"><g fill=\"none\" stroke=\"#000000\" stroke-width=\"0.1\">{shape}</g></svg>");
    std::fs::write(dir.path().join("line.svg"), svg("<path d=\"M 50 150 L 250 150\"/>")).unwrap();
    std::fs::write(dir.path().join("circle.svg"), svg("<circle cx=\"150\" cy=\"150\" r=\"10\"/>")).unwrap();
    let report = json(&laserd(&["bench", "motion", "--vs-grbl", "line.svg", "circle.svg", "--config", cutter().to_str().unwrap(), "--json"], dir.path()));
    let machine = laserd::config::MachineConfig::load(Some(&cutter())).unwrap();
    assert_eq!(report["junction_deviation_mm"].as_f64().unwrap(), machine.motion.corner_tolerance);
    assert_eq!(report["mode"], "stage-only");
    let cases = report["jobs"].as_array().unwrap();
    let f = |case: &serde_json::Value, name: &str| case[name].as_f64().unwrap_or_else(|| panic!("{name}: {case}"));
    // The cut layer: 50 mm/s, a pierce of 0.2 s.
    let (speed, pierce) = (50.0, 0.2);
    for case in cases {
        assert_eq!(f(case, "laserd_limit_breaches"), 0.0, "{case}");
        assert!((f(case, "ratio") - f(case, "laserd_job_time_s") / f(case, "grbl_job_time_s")).abs() < 1e-9, "{case}");
        assert!(f(case, "laserd_job_time_s") >= f(case, "lower_bound_s") - 1e-6, "{case}");
        let broken = case["grbl_limits_broken"].as_array().unwrap();
        assert_eq!(broken.len() as f64, f(case, "grbl_limit_breaches"), "{case}");
        assert!(broken.iter().all(|b| b.as_str().is_some_and(|b| b.contains("times its limit"))), "{case}");
    }
    let (line, circle) = (&cases[0], &cases[1]);
    let line_time = 200.0 / speed + pierce;
    for t in [f(line, "laserd_job_time_s"), f(line, "grbl_job_time_s")] {
        assert!(t >= line_time && t < line_time * 1.05, "line: {t} vs {line_time}: {line}");
    }
    assert!((f(line, "ratio") - 1.0).abs() < 0.05, "{line}");
    // The circle's segments as laserd imported them, each from rest to rest
    // at the cut's speed within the stage's limits.
    let job = laserd::import::import_job(&dir.path().join("circle.svg"), &machine).unwrap();
    let points = &job.geometries[0].points;
    let limits = laserd::config::Limits { velocity: speed, ..machine.stage_limits() };
    let rest_to_rest: f64 = points
        .iter()
        .zip(points.iter().cycle().skip(1))
        .map(|(a, b)| laserd::motion::rest_to_rest_time((*b - *a).norm(), limits).unwrap())
        .sum::<f64>()
        + pierce;
    let at_feed = job.geometries[0].length() / speed + pierce;
    let grbl = f(circle, "grbl_job_time_s");
    assert!(grbl >= at_feed - 1e-6 && grbl < 0.8 * rest_to_rest, "circle on Grbl {grbl}: at feed {at_feed}, rest to rest {rest_to_rest}: {circle}");
}
