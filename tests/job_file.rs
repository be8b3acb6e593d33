//! laserd's own job file: every importer's output round-trips through it
//! unchanged, through the command line as a user runs it.

use std::path::Path;
use std::process::Command;

#[test]
fn every_sample_round_trips_through_the_job_file_unchanged() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let config = root.join("config/flatbed-cutter.toml");
    let machine = laserd::config::MachineConfig::load(Some(&config)).unwrap();
    for sample in ["samples/nested-sheet.svg", "samples/marking-300.svg", "samples/one-field.svg", "samples/cut-parts.dxf"] {
        let job_file = dir.path().join("job.json");
        let out = Command::new(env!("CARGO_BIN_EXE_laserd")).arg("import").arg(root.join(sample)).arg("--config").arg(&config).arg("-o").arg(&job_file).output().unwrap();
        assert!(out.status.success(), "{sample}: {}", String::from_utf8_lossy(&out.stderr));
        let imported = laserd::import::import_job(&root.join(sample), &machine).unwrap();
        let read_back = laserd::import::import_job(&job_file, &machine).unwrap();
        assert_eq!(read_back.geometries, imported.geometries, "{sample}");
        assert_eq!(read_back.processes, imported.processes, "{sample}");
        assert_eq!(read_back.source, imported.source, "{sample}");
    }
    let schema = Command::new(env!("CARGO_BIN_EXE_laserd")).arg("job-schema").output().unwrap();
    let schema: serde_json::Value = serde_json::from_slice(&schema.stdout).unwrap();
    let required: Vec<&str> = schema["required"].as_array().unwrap().iter().filter_map(|v| v.as_str()).collect();
    for key in ["format", "version", "source", "processes", "geometries"] {
        assert!(required.contains(&key), "{key} in {required:?}");
    }
}

/// A drawing's text is not marked (laserd has no fonts): each text element
/// is named on the warning, with what it says, so it can be converted.
#[test]
fn each_ignored_svg_text_is_named_with_what_it_says() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("box.svg"),
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"100mm\" height=\"100mm\" viewBox=\"0 0 100 100\">\n<path d=\"M 10 10 L 20 20\" stroke=\"black\"/>\n<text id=\"lid\" x=\"5\" y=\"5\">Lid <tspan>A-1</tspan></text>\n<text x=\"5\" y=\"50\">Side</text>\n</svg>",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_laserd")).args(["plan", "box.svg"]).env("XDG_CONFIG_HOME", dir.path()).env_remove("LASERD_CONFIG").current_dir(dir.path()).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("<text id=\"lid\"> (line 3) \"Lid A-1\" ignored"), "{err}");
    assert!(err.contains("<text> at line 4 \"Side\" ignored"), "{err}");
}

/// The G-code sample, as another tool writes it (parts in drawing order):
/// re-planned, with no more idle stroke than the file's own order, and
/// dry-run within every limit.
#[test]
fn another_tools_gcode_re_plans_with_less_idle_stroke_within_the_limits() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let sample = root.join("samples/other-tool.nc");
    // The file's own idle stroke: its G0 moves from the origin, in order.
    let (mut at, mut own) = ((0.0f64, 0.0f64), 0.0);
    for line in std::fs::read_to_string(&sample).unwrap().lines().filter(|l| l.starts_with("G0 X")) {
        let v = |axis: char| line.split_whitespace().find_map(|w| w.strip_prefix(axis)).unwrap().parse::<f64>().unwrap();
        let to = (v('X'), v('Y'));
        if to != (0.0, 0.0) {
            own += ((to.0 - at.0).powi(2) + (to.1 - at.1).powi(2)).sqrt();
        }
        at = to;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["dry-run", "--json", "--record", "x.mcap", "--config"])
        .arg(root.join("config/flatbed-cutter.toml"))
        .arg(&sample)
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["geometries"], 18, "{report}");
    assert_eq!(report["sim"]["limit_violations"], 0, "{report}");
    let idle = report["idle_stroke_mm"].as_f64().unwrap();
    assert!(idle <= own, "re-planned idle stroke {idle} mm, the file's own {own} mm");
}
