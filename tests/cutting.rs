//! The cutting planner end to end: a generated sheet of nested parts written
//! as SVG, imported as any job, planned with `--planner ecp` and dry-run on
//! the shipped flatbed cutter (every cut pierced).

use std::path::{Path, PathBuf};

use laserd::config::MachineConfig;
use laserd::plan::ecp::sheet;
use laserd::plan::PlannerKind;
use laserd::run;
use laserd_sim::controller::Faults;

fn flatbed(time_limit: f64) -> MachineConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let mut machine = MachineConfig::load(Some(&path)).unwrap();
    machine.cutting.time_limit = time_limit;
    machine
}

fn sheet_svg(dir: &Path, elements: usize, seed: u64) -> PathBuf {
    let params = sheet::SheetParams::with_target(elements);
    let path = dir.join(format!("sheet-{elements}-{seed}.svg"));
    std::fs::write(&path, sheet::to_svg(&sheet::generate_sheet(&params, seed), &params)).unwrap();
    path
}

#[test]
fn ecp_keeps_every_rule_where_nearest_does_not_and_moves_less_air() {
    let dir = tempfile::tempdir().unwrap();
    let machine = flatbed(2.0);
    for seed in [1, 2] {
        let job = sheet_svg(dir.path(), 300, seed);
        let ecp = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap();
        let nearest = run::plan(&job, &machine, PlannerKind::Nearest, None).unwrap();
        assert_eq!(ecp.report.planner, "ecp");
        assert_eq!(ecp.report.precedence_violations, Some(0), "seed {seed}");
        // Whole parts nearest first cut holes after their parts have fallen.
        assert!(nearest.report.precedence_violations.unwrap() > 0, "seed {seed}");
        assert!(
            ecp.report.idle_stroke_mm < nearest.report.idle_stroke_mm,
            "seed {seed}: ecp {} vs nearest {}",
            ecp.report.idle_stroke_mm,
            nearest.report.idle_stroke_mm
        );
        // Every element is cut once: the marked length is the geometry's,
        // less what common cuts save (each shared edge drawn twice, cut once).
        let cut: f64 = ecp.sequence.paths().map(|p| p.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum::<f64>()).sum();
        let drawn: f64 = nearest.sequence.paths().map(|p| p.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum::<f64>()).sum();
        assert!(cut < drawn && cut > 0.8 * drawn, "seed {seed}: cut {cut} of {drawn} drawn");
        assert!(ecp.report.plan_time_s < 2.0 + 1.0, "the time limit holds: {}", ecp.report.plan_time_s);
    }
}

#[test]
fn a_cut_sheet_dry_runs_within_the_limits_with_a_pierce_at_every_entry() {
    let dir = tempfile::tempdir().unwrap();
    let machine = flatbed(1.0);
    let job = sheet_svg(dir.path(), 120, 3);
    let planned = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap();
    let paths = planned.sequence.paths().count();
    let dwells = planned.program.lines.iter().filter(|l| l.text.starts_with("G4")).count();
    assert_eq!(dwells, paths, "one pierce per cut entry");
    let recording = dir.path().join("sheet.mcap");
    let dry = run::dry_run(&planned, &machine, &recording, Faults::default()).unwrap();
    let sim = dry.report.sim.as_ref().unwrap();
    assert_eq!(sim.limit_violations, 0, "{sim:?}");
    assert!(sim.alarms.is_empty(), "{:?}", sim.alarms);
    assert_eq!(dry.report.precedence_violations, Some(0));
    // The pierces are machine time: at least paths × pierce_time.
    assert!(sim.job_time_s > paths as f64 * 0.2, "{} s for {paths} pierces", sim.job_time_s);
    assert!(dry.outcome.completed, "{:?}", dry.outcome);
}

#[test]
fn bad_cutting_settings_name_the_setting() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let text = std::fs::read_to_string(path).unwrap();
    for (from, to, name) in [
        ("pierce_cost = 20.0", "pierce_cost = -1.0", "cutting.pierce_cost"),
        ("common_cut_tolerance = 0.01", "common_cut_tolerance = nan", "cutting.common_cut_tolerance"),
        ("corner_angle = 30.0", "corner_angle = 270.0", "cutting.corner_angle"),
        ("time_limit = 10.0", "time_limit = 0.0", "cutting.time_limit"),
        ("search = \"ils\"", "search = \"annealing\"", "annealing"),
    ] {
        assert!(text.contains(from), "{from}");
        let err = MachineConfig::parse(&text.replace(from, to), "bad.toml").unwrap_err().to_string();
        assert!(err.contains(name), "{err}");
    }
}
