//! DXF import against an independent reader: drawings written by `ezdxf`
//! (PyPI, installed by `.ci/run`) with every entity kind laserd reads, in mm
//! and inch, ASCII and binary; laserd's import must agree with ezdxf's own
//! reading of each file (`tests/data/dxf/cases.py`).

use std::path::{Path, PathBuf};
use std::process::Command;

use laserd::config::MachineConfig;

fn cutter() -> MachineConfig {
    MachineConfig::load(Some(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml"))).unwrap()
}

/// The drawings and ezdxf's reading of them, in a fresh folder.
fn drawings() -> (tempfile::TempDir, serde_json::Value) {
    let dir = tempfile::tempdir().unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/dxf/cases.py");
    let out = Command::new("python3").arg(&script).arg(dir.path()).output().expect("python3 runs");
    assert!(out.status.success(), "cases.py (needs ezdxf, which .ci/run installs): {}", String::from_utf8_lossy(&out.stderr));
    let expected = serde_json::from_str(&std::fs::read_to_string(dir.path().join("expected.json")).unwrap()).unwrap();
    (dir, expected)
}

#[test]
fn every_entity_kind_imports_as_ezdxf_reads_it_in_mm_and_inch_ascii_and_binary() {
    let (dir, expected) = drawings();
    let mut machine = cutter();
    // Lines, arcs, circles and bulges are exact (arcs stay arcs); ellipses
    // and splines are chords, which fall short of the curve by about
    // tolerance / (1.5·radius) of their length and reach its bounds within
    // the tolerance.
    machine.import.tolerance = 1e-4;
    let cases = expected.as_object().unwrap();
    assert_eq!(cases.len(), 4, "mm and inch, ASCII and binary");
    for (name, want) in cases {
        let job = laserd::import::import_job(&dir.path().join(name), &machine).unwrap_or_else(|e| panic!("{name}: {e}"));
        let f = |key: &str| want[key].as_f64().unwrap();
        let pair = |key: &str| [want[key][0].as_f64().unwrap(), want[key][1].as_f64().unwrap()];
        assert_eq!(job.geometries.len() as f64, f("geometries"), "{name}: geometries");
        let length: f64 = job.geometries.iter().map(|g| g.length()).sum();
        let truth = f("length_mm");
        assert!((length - truth).abs() <= truth * 1e-6, "{name}: length {length} mm, ezdxf {truth} mm: {:.2e} relative", (length - truth) / truth);
        let (lo, hi) = job.bounds();
        let (want_lo, want_hi) = (pair("min_mm"), pair("max_mm"));
        let off = [(lo.x, want_lo[0]), (lo.y, want_lo[1]), (hi.x, want_hi[0]), (hi.y, want_hi[1])].iter().fold(0.0f64, |m, (got, want)| m.max((got - want).abs()));
        assert!(off <= 1e-3, "{name}: bounds {lo:?}-{hi:?}, ezdxf {want_lo:?}-{want_hi:?}");
        eprintln!("{name}: {} geometries, length {length:.9} mm against ezdxf's {truth:.9} mm ({:+.2e} relative), bounds within {off:.1e} mm", job.geometries.len(), (length - truth) / truth);
        // The slot's two lines and two arcs are one closed contour.
        let slot: Vec<_> = job.geometries.iter().filter(|g| g.source.contains("(+3 chained)")).collect();
        assert!(slot.len() == 1 && slot[0].closed, "{name}: the slot chained and closed: {:?}", job.geometries.iter().map(|g| &g.source).collect::<Vec<_>>());
        assert!((slot[0].length() - (60.0 + 10.0 * std::f64::consts::PI)).abs() < 1e-9, "{name}: slot length {}", slot[0].length());
    }
}

#[test]
fn dxf_layers_and_colours_choose_the_process() {
    let (dir, _) = drawings();
    let mut machine = cutter();
    let mut mark = machine.layers[0].clone();
    mark.name = "dxf-mark".into();
    mark.dxf_layer = Some("mark".into());
    mark.speed = 123.0;
    machine.layers.push(mark);
    let job = laserd::import::import_job(&dir.path().join("drawing-mm-asc.dxf"), &machine).unwrap();
    let on = |layer: &str| job.geometries.iter().filter(|g| job.processes[g.process].layer == layer).count();
    // The DXF layer MARK holds the open bulged polyline and the 2D polyline.
    assert_eq!(on("dxf-mark"), 2, "{:?}", job.processes);
    assert!(job.processes.iter().any(|p| p.layer == "dxf-mark" && p.speed == 123.0));
    assert_eq!(on("dxf-mark") + on(&machine.default_layer), job.geometries.len(), "the rest on the default layer");
}

#[test]
fn bench_import_reports_each_files_geometries_time_and_the_peak_memory() {
    let (dir, expected) = drawings();
    let out = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["bench", "import", "drawing-mm-asc.dxf", "drawing-inch-bin.dxf", "--repeats", "2", "--json", "--config"])
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml"))
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for case in report["jobs"].as_array().unwrap() {
        let name = case["job"].as_str().unwrap();
        assert_eq!(case["geometries"], expected[name]["geometries"], "{case}");
        assert!(case["import_time_s"].as_f64().unwrap() > 0.0 && case["points"].as_u64().unwrap() > case["geometries"].as_u64().unwrap(), "{case}");
    }
    assert!(report["peak_rss_mb"].as_f64().unwrap() > 1.0, "{report}");
}

/// A box whose header says inch over numbers in mm (as MakerCase writes
/// them): refused naming the flag; with it, planned.
#[test]
fn a_wrong_header_unit_is_refused_naming_the_flag_that_reads_it_right() {
    let dir = tempfile::tempdir().unwrap();
    let line = |(x0, y0): (f64, f64), (x1, y1): (f64, f64)| format!("0\nLINE\n8\n0\n10\n{x0}\n20\n{y0}\n11\n{x1}\n21\n{y1}\n");
    let square = [line((10.0, 10.0), (210.0, 10.0)), line((210.0, 10.0), (210.0, 160.0)), line((210.0, 160.0), (10.0, 160.0)), line((10.0, 160.0), (10.0, 10.0))].concat();
    std::fs::write(dir.path().join("box.dxf"), format!("0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n1\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n{square}0\nENDSEC\n0\nEOF\n")).unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let plan = |extra: &[&str]| Command::new(env!("CARGO_BIN_EXE_laserd")).args(["plan", "box.dxf", "--json", "--config"]).arg(&config).args(extra).current_dir(dir.path()).output().unwrap();
    let refused = plan(&[]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("box.dxf") && err.contains("--units mm"), "{err}");
    let planned = plan(&["--units", "mm"]);
    assert!(planned.status.success(), "{}", String::from_utf8_lossy(&planned.stderr));
    let report: serde_json::Value = serde_json::from_slice(&planned.stdout).unwrap();
    assert_eq!(report["geometries"], 1, "one closed contour: {report}");
}

/// The DXF sample, as a CAD program exports parts (lines and arcs end to
/// end, shared edges, bulged polylines, a block inserted three times), cuts
/// as 27 closed contours within every limit.
#[test]
fn the_dxf_sample_is_27_closed_contours_and_dry_runs_within_the_limits() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let machine = cutter();
    let job = laserd::import::import_job(&root.join("samples/cut-parts.dxf"), &machine).unwrap();
    assert_eq!(job.geometries.len(), 27);
    assert!(job.geometries.iter().all(|g| g.closed), "{:?}", job.geometries.iter().filter(|g| !g.closed).map(|g| &g.source).collect::<Vec<_>>());
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["dry-run", "--json", "--record", "cut-parts.mcap", "--config"])
        .arg(root.join("config/flatbed-cutter.toml"))
        .arg(root.join("samples/cut-parts.dxf"))
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["sim"]["limit_violations"], 0, "{report}");
    assert_eq!(report["precedence_violations"], 0, "{report}");
}
