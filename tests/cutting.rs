//! The cutting planner end to end: a generated sheet of nested parts written
//! as SVG, imported as any job, planned with `--planner ecp` (and `auto`, the
//! default, which takes it for layers that pierce) and dry-run on
//! the shipped flatbed cutter (every cut pierced).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use laserd::config::MachineConfig;
use laserd::gen::sheet;
use laserd::plan::PlannerKind;
use laserd::run;
use laserd_sim::controller::Faults;

fn flatbed(time_limit: f64) -> MachineConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let mut machine = MachineConfig::load(Some(&path)).unwrap();
    machine.cutting.time_limit = Some(time_limit);
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
fn a_cut_sheet_dry_runs_within_the_limits_with_a_pierce_at_every_entry_off_the_kerf() {
    let dir = tempfile::tempdir().unwrap();
    let machine = flatbed(1.0);
    let job = sheet_svg(dir.path(), 120, 3);
    let planned = run::plan(&job, &machine, PlannerKind::Ecp, None).unwrap();
    let all: Vec<_> = planned.sequence.paths().collect();
    let paths = all.iter().filter(|p| p.pierce).count();
    let dwells = planned.program.lines.iter().filter(|l| l.text.starts_with("G4")).count();
    assert_eq!(dwells, paths, "one pierce per cut entry");
    assert_eq!(planned.report.pierces, paths);
    // Only a cut that goes on where the one before ended (the kerf is
    // there) starts without a pierce.
    for (i, p) in all.iter().enumerate() {
        assert_eq!(p.pierce, i == 0 || all[i - 1].end() != p.start(), "path {i}");
    }
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
        ("[cutting]\n", "[cutting]\ntime_limit = 0.0\n", "cutting.time_limit"),
        ("search = \"ils\"", "search = \"annealing\"", "annealing"),
    ] {
        assert!(text.contains(from), "{from}");
        let err = MachineConfig::parse(&text.replace(from, to), "bad.toml").unwrap_err().to_string();
        assert!(err.contains(name), "{err}");
    }
}

fn laserd(args: &[&str]) -> Output {
    let dir = tempfile::tempdir().unwrap();
    Command::new(env!("CARGO_BIN_EXE_laserd")).args(args).current_dir(dir.path()).output().expect("laserd runs")
}

fn cutter() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml").display().to_string()
}

#[test]
fn plan_without_a_planner_cuts_the_nested_sheet_keeping_every_rule_and_says_so() {
    let job = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/nested-sheet.svg").display().to_string();
    let out = laserd(&["plan", &job, "--config", &cutter(), "--time-limit", "2", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["planner"], "ecp", "the sheet's layer pierces: {report}");
    assert_eq!(report["precedence_violations"], 0);
    let out = laserd(&["plan", &job, "--config", &cutter(), "--time-limit", "2"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("planner ecp") && text.contains("precedence_violations 0"), "{text}");
}

#[test]
fn an_order_that_cuts_after_a_part_has_fallen_is_refused_unless_overridden() {
    let dir = tempfile::tempdir().unwrap();
    let job = sheet_svg(dir.path(), 120, 3);
    let job = job.to_str().unwrap();
    let program = dir.path().join("sheet.nc");
    let recording = dir.path().join("sheet.mcap");
    let broken = |out: &Output| -> u64 {
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && !err.contains("panicked"), "refused: {err}");
        let count: u64 = err.split(" precedence violation(s)").next().unwrap().rsplit(' ').next().unwrap().parse().expect("the count");
        assert!(count > 0 && err.contains(" cut after ") && err.contains("--allow-precedence-violations"), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        count
    };
    // plan: reported (the count in the text), not written as a program.
    let out = laserd(&["plan", job, "--config", &cutter(), "--planner", "nearest", "-o", program.to_str().unwrap()]);
    let count = broken(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("precedence_violations {count}")));
    assert!(!program.exists());
    let out = laserd(&["plan", job, "--config", &cutter(), "--planner", "nearest", "-o", program.to_str().unwrap(), "--allow-precedence-violations"]);
    assert!(out.status.success() && program.exists(), "{}", String::from_utf8_lossy(&out.stderr));
    // dry-run: refused before anything is streamed or recorded.
    let out = laserd(&["dry-run", job, "--config", &cutter(), "--planner", "nearest", "--record", recording.to_str().unwrap()]);
    assert_eq!(broken(&out), count);
    assert!(!recording.exists() && out.stdout.is_empty());
    let out = laserd(&["dry-run", job, "--config", &cutter(), "--planner", "nearest", "--record", recording.to_str().unwrap(), "--allow-precedence-violations", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["precedence_violations"], count);
    assert!(report["sim"]["job_time_s"].as_f64().unwrap() > 0.0 && recording.exists());
}

/// `[cutting] objective = "time"`: the search prices air moves by their
/// machine time (axes at once), and the length route is judged beside it by
/// its planned motion, so the plan is never slower than the length plan and
/// keeps every rule; the report names the objective.
#[test]
fn the_time_objective_never_cuts_slower_than_the_length_objective() {
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/cut-parts.dxf");
    let mut machine = flatbed(30.0);
    machine.cutting.time_limit = None;
    let length = run::plan(&sample, &machine, PlannerKind::Auto, None).unwrap();
    machine.cutting.objective = "time".into();
    let time = run::plan(&sample, &machine, PlannerKind::Auto, None).unwrap();
    assert_eq!((length.report.objective.as_str(), time.report.objective.as_str()), ("length", "time"));
    assert_eq!(time.report.precedence_violations, Some(0));
    assert!(time.report.trajectory_time_s <= length.report.trajectory_time_s, "{} s against {} s", time.report.trajectory_time_s, length.report.trajectory_time_s);
    // Turns and heat order fills, not cuts.
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml")).unwrap();
    assert!(text.matches("objective = \"length\"").count() == 1 && !text.contains("[galvo]"));
    let cutting = text.replace("objective = \"length\"", "objective = \"time+heat\"");
    let galvo = format!("{text}\n[galvo]\nobjective = \"turns\"\n");
    for (bad, name) in [(cutting, "cutting.objective"), (galvo, "galvo.objective")] {
        let err = MachineConfig::parse(&bad, "bad.toml").unwrap_err().to_string();
        assert!(err.contains(name) && err.contains("fills only"), "{err}");
    }
}
