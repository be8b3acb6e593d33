//! A geometry larger than the scanner's usable field (64 x 64 mm on the shipped
//! machine): split at field borders into pieces, each marked inside one field,
//! or, with `[scanner] split_oversize = false`, one clear error naming it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use laserd::config::{MachineConfig, DEFAULT_CONFIG_PATH};
use laserd::import::import_job;
use laserd::plan::PlannerKind;
use laserd::run;

/// A 200 mm line (`id="long"`) and four 5 mm squares.
const JOB: &str = r##"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">
<g fill="none" stroke="#000000" stroke-width="0.1">
  <path id="long" d="M 50 150 L 250 150"/>
  <rect x="60" y="60" width="5" height="5"/>
  <rect x="70" y="62" width="5" height="5"/>
  <rect x="200" y="220" width="5" height="5"/>
  <rect x="140" y="140" width="5" height="5"/>
</g>
</svg>
"##;
const SMALL_PARTS: usize = 4;

fn laserd(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_laserd")).args(args).current_dir(dir).output().expect("laserd runs")
}

fn shipped_config() -> String {
    std::fs::read_to_string(Path::new(DEFAULT_CONFIG_PATH)).unwrap()
}

/// The job in a temporary directory, and a config there with splitting off.
fn setup() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("long-line.svg");
    std::fs::write(&job, JOB).unwrap();
    let text = shipped_config();
    assert!(text.contains("split_oversize = true"), "the shipped config documents the switch");
    let off = dir.path().join("no-split.toml");
    std::fs::write(&off, text.replace("split_oversize = true", "split_oversize = false")).unwrap();
    (dir, job, off)
}

fn json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON object")
}

#[test]
fn the_long_line_is_planned_in_pieces_each_inside_its_field() {
    let (_dir, job, _) = setup();
    let machine = MachineConfig::load(None).unwrap();
    let scanner = machine.scanner.as_ref().unwrap();
    assert!(scanner.split_oversize, "splitting is on by default");
    let half = scanner.usable_half_field;
    // The imported job, before splitting (usvg's single precision makes the
    // line a few nanometres longer than 200 mm).
    let imported = import_job(&job, &machine).unwrap();
    let original = imported.geometries.iter().find(|g| g.source.contains("path 'long'")).unwrap();
    assert!((original.length() - 200.0).abs() < 1e-3 && !original.closed);
    for kind in [PlannerKind::Hha, PlannerKind::Nearest] {
        let planned = run::plan(&job, &machine, kind, None).unwrap();
        // 200 mm in cells of (just under) 64 mm: 4 pieces.
        let pieces: Vec<_> = planned.job.geometries.iter().filter(|g| g.source.contains("path 'long'")).collect();
        assert_eq!(pieces.len(), 4, "{kind:?}: {:?}", pieces.iter().map(|g| &g.source).collect::<Vec<_>>());
        assert!(pieces.iter().all(|g| !g.closed && g.source.contains("piece")));
        let long: f64 = pieces.iter().map(|g| g.length()).sum();
        assert!((long - original.length()).abs() <= 1e-6 * original.length(), "{kind:?}: pieces trace {long} mm of {}", original.length());
        assert_eq!(pieces[0].points[0], original.points[0]);
        assert_eq!(pieces[3].points.last(), original.points.last());
        assert_eq!(planned.report.geometries, SMALL_PARTS + 4);
        assert!((planned.report.mark_length_mm - imported.mark_length()).abs() <= 1e-6 * imported.mark_length(), "{}", planned.report.mark_length_mm);
        // Every geometry marked once, inside the field it is marked from.
        let mut times = vec![0; planned.job.geometries.len()];
        for group in &planned.sequence.groups {
            let c = group.field_center.expect("step-and-scan");
            for path in &group.paths {
                times[path.geometry] += 1;
                for p in &path.points {
                    assert!((p.x - c.x).abs() <= half + 1e-6 && (p.y - c.y).abs() <= half + 1e-6, "{kind:?}: {} outside its field", planned.job.geometries[path.geometry].source);
                }
            }
        }
        assert!(times.iter().all(|&t| t == 1), "{kind:?}: {times:?}");
        assert!(planned.report.scan_fields.unwrap() >= 4);
    }
}

#[test]
fn plan_on_the_command_line_succeeds_with_splitting_on() {
    let (dir, job, _) = setup();
    let report = json(&laserd(&["plan", job.to_str().unwrap(), "--planner", "hha", "--json"], dir.path()));
    assert_eq!(report["planner"], "hha");
    assert_eq!(report["mode"], "on-the-fly");
    assert_eq!(report["geometries"], SMALL_PARTS + 4);
    assert!(report["scan_fields"].as_u64().unwrap() >= 4, "{report}");
}

#[test]
fn dry_run_of_the_pieces_stays_inside_the_machine_limits() {
    let (dir, job, _) = setup();
    let rec = dir.path().join("run.mcap");
    let report = json(&laserd(&["dry-run", job.to_str().unwrap(), "--planner", "hha", "--json", "--record", rec.to_str().unwrap()], dir.path()));
    let sim = &report["sim"];
    assert_eq!(sim["limit_violations"], 0, "{sim}");
    assert_eq!(sim["laser_state_errors"], 0, "{sim}");
    assert!(sim["peak_field_use"].as_f64().unwrap() <= 1.0, "{sim}");
}

#[test]
fn with_splitting_off_the_job_fails_naming_the_geometry() {
    let (dir, job, off) = setup();
    for planner in ["hha", "nearest"] {
        let out = laserd(&["plan", job.to_str().unwrap(), "--planner", planner, "--json", "--config", off.to_str().unwrap()], dir.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{planner}: should fail: {err}");
        assert!(!err.contains("panicked"), "{err}");
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "one line: {err}");
        assert!(lines[0].contains("long-line.svg: path 'long'"), "names the geometry: {err}");
        assert!(lines[0].contains("split_oversize = false"), "says splitting is off: {err}");
        assert!(out.stdout.is_empty());
    }
    // Stage-only needs no split: the same config plans the whole line.
    let report = json(&laserd(&["plan", job.to_str().unwrap(), "--mode", "stage-only", "--json", "--config", off.to_str().unwrap()], dir.path()));
    assert_eq!(report["geometries"], SMALL_PARTS + 1);
}
