//! Thermal planning end to end (seed 000, `--thermal`): two clusters of
//! small parts packed close, cut on the shipped flatbed cutter's mild steel.
//! The plain route cuts one cluster after the other, each part next to the
//! one just cut; with the critical temperatures set under what that route
//! meets, the thermal planner finds a route that meets none of them, the
//! same on every run, and the command line reports the heat.

use std::path::{Path, PathBuf};
use std::process::Command;

use laserd::config::MachineConfig;
use laserd::plan::PlannerKind;
use laserd::program::LineKind;
use laserd::run;
use laserd_sim::controller::Faults;

fn flatbed() -> MachineConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    MachineConfig::load(Some(&path)).unwrap()
}

/// Two 4 x 4 clusters of 30 mm squares, 6 mm apart, 800 mm from each other.
fn clusters(dir: &Path) -> PathBuf {
    let mut paths = String::new();
    for (cx, cy) in [(100.0, 100.0), (900.0, 100.0)] {
        for i in 0..4 {
            for j in 0..4 {
                let (x, y) = (cx + 36.0 * i as f64, cy + 36.0 * j as f64);
                paths.push_str(&format!("<path d=\"M{x} {y} h30 v30 h-30 z\" fill=\"none\" stroke=\"#000000\"/>\n"));
            }
        }
    }
    let path = dir.join("clusters.svg");
    std::fs::write(&path, format!("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"1200mm\" height=\"400mm\" viewBox=\"0 0 1200 400\">\n{paths}</svg>\n")).unwrap();
    path
}

#[test]
fn the_thermal_route_meets_no_critical_temperature_the_plain_route_meets() {
    let dir = tempfile::tempdir().unwrap();
    let job = clusters(dir.path());
    let mut machine = flatbed();
    machine.thermal.enabled = true;
    // Critical temperatures out of reach: the plain route is kept as it is.
    let material = machine.material.as_mut().unwrap();
    (material.critical_pierce, material.critical_cut, material.critical_corner) = (2000.0, 2000.0, 2000.0);
    let plain = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap().report.thermal.unwrap();
    assert_eq!((plain.thermal_violations, plain.plain_violations, plain.iterations), (0, 0, 0));
    let peak = |feature: &str| plain.operations.iter().filter(|o| o.feature == feature).map(|o| o.celsius).fold(f64::NAN, f64::max);
    let (pierce, cut, corner) = (peak("pierce"), peak("cut"), peak("corner"));
    assert!(pierce > 25.0 && cut > 25.0 && corner > 25.0, "the plain route heats the plate: {pierce} {cut} {corner}");
    // Each a fifth of the way from the air to what the plain route met.
    let under = |t: f64| t - 0.2 * (t - 20.0);
    let material = machine.material.as_mut().unwrap();
    (material.critical_pierce, material.critical_cut, material.critical_corner) = (under(pierce), under(cut), under(corner));
    let planned = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap();
    let thermal = planned.report.thermal.clone().unwrap();
    assert!(thermal.plain_violations > 0, "the plain route now violates");
    assert_eq!(thermal.thermal_violations, 0, "{thermal:?}");
    assert!(thermal.iterations > 0);
    assert!(thermal.operations.iter().all(|o| o.celsius < o.critical_c));
    assert_eq!(planned.report.precedence_violations, Some(0));
    // Cooling costs air, not much time: under 5 % more here.
    assert!(thermal.planned_time_s < 1.05 * thermal.plain_time_s, "{} against {}", thermal.planned_time_s, thermal.plain_time_s);
    // The same route on every run.
    let again = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap();
    assert_eq!(again.program.lines.iter().map(|l| &l.text).collect::<Vec<_>>(), planned.program.lines.iter().map(|l| &l.text).collect::<Vec<_>>());
}

#[test]
fn thermal_on_the_command_line_reports_the_heat_or_names_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let job = clusters(dir.path());
    // The shipped cutter with two constructions at most (this test is about the report).
    let shipped = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml")).unwrap();
    assert!(shipped.contains("iterations = 40"));
    let config = dir.path().join("cutter.toml");
    std::fs::write(&config, shipped.replace("iterations = 40", "iterations = 2")).unwrap();
    let plot = dir.path().join("plan.svg");
    let out = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["plan", job.to_str().unwrap(), "--config", config.to_str().unwrap(), "--thermal", "--json", "--plot", plot.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let thermal = &report["thermal"];
    assert!(thermal["thermal_violations"].is_u64() && thermal["max_overheat_c"].is_f64() && thermal["hottest"]["celsius"].is_f64(), "{thermal}");
    let ops = thermal["operations"].as_array().unwrap();
    let count = |f: &str| ops.iter().filter(|o| o["feature"] == f).count() as u64;
    assert_eq!(count("pierce"), report["pierces"].as_u64().unwrap(), "one check per pierce");
    assert!(count("cut") >= 4 * 32 && count("corner") >= 2 * 32, "each side a cut, the turns corners");
    assert!(thermal["iterations"].as_u64().unwrap() <= 2);
    // The heat map beside the plan's picture: cells, the scale, the hottest ringed.
    let heat = std::fs::read_to_string(dir.path().join("plan.heat.svg")).unwrap();
    assert!(heat.matches("<rect").count() > 20 && heat.contains("°C") && heat.contains("<circle"), "{}", &heat[..heat.len().min(500)]);
    // The default machine has no material: refused, naming what is missing.
    let galvo = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_laserd")).args(["plan", job.to_str().unwrap(), "--config", galvo.to_str().unwrap(), "--thermal"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("[material]"), "{}", String::from_utf8_lossy(&out.stderr));
    let mut machine = flatbed();
    machine.material = None;
    let err = laserd::thermal::model_of(&machine).unwrap_err().to_string();
    assert!(err.contains("[material]"), "{err}");
    machine = flatbed();
    machine.laser.watts = None;
    let err = laserd::thermal::model_of(&machine).unwrap_err().to_string();
    assert!(err.contains("laser.watts"), "{err}");
}

/// Rest intervals without the laser (same position, time passing, power 0)
/// as (start, end, where); back-to-back ones at one place are one.
fn dark_rests(knots: &[laserd_sim::controller::Knot]) -> Vec<(f64, f64, laserd::job::Point)> {
    let mut rests: Vec<(f64, f64, laserd::job::Point)> = Vec::new();
    for w in knots.windows(2).filter(|w| w[0].pos == w[1].pos && w[1].t > w[0].t && w[1].power == 0.0) {
        let at = laserd::program::tcp_of(&w[0].pos);
        match rests.last_mut() {
            Some(last) if last.1 == w[0].t && (last.2 - at).norm() < 1e-9 => last.1 = w[1].t,
            _ => rests.push((w[0].t, w[1].t, at)),
        }
    }
    rests
}

#[test]
fn where_no_order_keeps_the_plate_cool_the_program_waits_dark_before_the_hot_paths() {
    let dir = tempfile::tempdir().unwrap();
    // One cluster of nine squares: whatever the order, the last ones are cut
    // beside hot ones.
    let mut paths = String::new();
    for i in 0..3 {
        for j in 0..3 {
            let (x, y) = (100.0 + 36.0 * i as f64, 100.0 + 36.0 * j as f64);
            paths.push_str(&format!("<path d=\"M{x} {y} h30 v30 h-30 z\" fill=\"none\" stroke=\"#000000\"/>\n"));
        }
    }
    let job = dir.path().join("cluster.svg");
    std::fs::write(&job, format!("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"400mm\" height=\"400mm\" viewBox=\"0 0 400 400\">\n{paths}</svg>\n")).unwrap();
    let mut machine = flatbed();
    machine.thermal.enabled = true;
    machine.thermal.iterations = 1;
    let material = machine.material.as_mut().unwrap();
    (material.critical_pierce, material.critical_cut, material.critical_corner) = (60.0, 70.0, 60.0);
    let planned = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap();
    let thermal = planned.report.thermal.clone().unwrap();
    assert!(thermal.plain_violations > 0 && thermal.cooled_operations > 0 && thermal.thermal_wait_s > 1.0, "{thermal:?}");
    // With the waits, no operation meets its critical temperature.
    assert_eq!(thermal.thermal_violations, 0, "{thermal:?}");
    assert!(thermal.operations.iter().all(|o| o.celsius < o.critical_c));
    // Each path's wait in 50 ms steps (as Grbl counts a dwell), rounded up.
    let waits: Vec<(laserd::job::Point, f64)> = planned.sequence.paths().filter(|p| p.cooling_wait > 0.0).map(|p| (p.start(), p.cooling_wait)).collect();
    let total: f64 = waits.iter().map(|w| w.1).sum();
    assert!(waits.iter().all(|w| ((w.1 / 0.05) - (w.1 / 0.05).round()).abs() < 1e-6), "{waits:?}");
    assert!(total >= thermal.thermal_wait_s - 1e-9 && total <= thermal.thermal_wait_s + 0.05 * waits.len() as f64, "{total} vs {}", thermal.thermal_wait_s);
    // In the program: dwells of the cooling kind adding up to the waits, the trajectory holding them.
    let dwelt: f64 = planned.program.lines.iter().filter(|l| l.kind == LineKind::Cool && l.text.starts_with("G4P")).map(|l| l.text[3..].parse::<f64>().unwrap()).sum();
    assert!((dwelt - total).abs() < 1e-6, "{dwelt} vs {total}");
    assert!(planned.report.lower_bound_s >= total && planned.report.trajectory_time_s >= planned.report.lower_bound_s);
    // The plan's picture rings each place the machine waits, with its seconds.
    let picture = laserd::plot::plot(&planned.job, &planned.sequence, &planned.trajectory, &machine, None);
    assert_eq!(picture.matches(r#"class="cooling-wait""#).count(), waits.len());
    assert!(waits.iter().all(|w| picture.contains(&format!("<title>cooling wait {}</title>", laserd::report::duration(w.1)))));
    assert!(picture.contains("cooling waits ("), "the legend names them");
    // On the simulator: the machine stands at each hot path's start with the
    // laser off for its wait, within every limit, and the job's time holds them.
    let dry = run::dry_run(&planned, &machine, &dir.path().join("cool.mcap"), Faults::default()).unwrap();
    assert!(dry.outcome.completed, "{:?}", dry.outcome.stop_reason);
    let sim = dry.report.sim.as_ref().unwrap();
    assert_eq!((sim.limit_violations, sim.laser_state_errors), (0, 0), "{sim:?}");
    assert!((sim.job_time_s - sim.planner_starved_s - planned.report.trajectory_time_s).abs() < 1e-3, "{sim:?}");
    let rests = dark_rests(&dry.log.knots);
    for (at, wait) in &waits {
        assert!(rests.iter().any(|r| (r.2 - at).norm() < 1e-3 && r.1 - r.0 >= wait - 1e-6), "no dark rest of {wait} s at {at:?}: {rests:?}");
    }
}
