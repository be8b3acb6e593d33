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

/// A raster engraving as other tools write it (S per pixel, scan lines
/// both ways): each scan line is planned as one geometry, the program
/// gives every pixel its power in the direction the line is marked, and the
/// dry-run keeps every limit.
#[test]
fn a_raster_gcode_keeps_each_scan_lines_power_profile() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::from("G21 G90\nM4 S0\n");
    let mut lines: Vec<Vec<u32>> = Vec::new();
    for row in 0..8 {
        let y = 20.0 + row as f64 * 0.5;
        let xs: Vec<f64> = (0..=12).map(|k| 20.0 + k as f64).collect();
        let xs: Vec<f64> = if row % 2 == 1 { xs.into_iter().rev().collect() } else { xs };
        text += &format!("G0 X{} Y{y}\n", xs[0]);
        let powers: Vec<u32> = (0..12).map(|k| 100 + 50 * ((k * 7 + row * 3) % 9) as u32).collect();
        for (x, s) in xs[1..].iter().zip(&powers) {
            text += &format!("G1 X{x} S{s} F1200\n");
        }
        let mut run = powers.clone();
        run.dedup();
        lines.push(run);
    }
    text += "M5\n";
    std::fs::write(dir.path().join("raster.nc"), text).unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_laserd")).args(args).arg("--config").arg(root.join("config/flatbed-cutter.toml")).arg("raster.nc").current_dir(dir.path()).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    let plan = run(&["plan", "--json", "-o", "program.nc"]);
    assert_eq!(plan["geometries"], 8, "one geometry per scan line: {plan}");
    // The program's powers, cut at every S0 (a jump): one run per scan line
    // (the cutter pierces each at M3 first: not a pixel).
    let program = std::fs::read_to_string(dir.path().join("program.nc")).unwrap();
    let mut marked: Vec<Vec<u32>> = vec![Vec::new()];
    for s in program.lines().filter(|l| !l.contains("M3")).filter_map(|l| l.split('S').nth(1)).map(|w| w.trim_end_matches(|c: char| !c.is_ascii_digit()).split(|c: char| !c.is_ascii_digit()).next().unwrap().parse::<u32>().unwrap()) {
        let current = marked.last_mut().unwrap();
        if s == 0 {
            if !current.is_empty() {
                marked.push(Vec::new());
            }
        } else if current.last() != Some(&s) {
            current.push(s);
        }
    }
    marked.retain(|r| !r.is_empty());
    assert_eq!(marked.len(), 8, "{marked:?}");
    for r in &marked {
        let back: Vec<u32> = r.iter().rev().copied().collect();
        assert!(lines.contains(r) || lines.contains(&back), "{r:?} is no scan line's powers, either way: {lines:?}");
    }
    let dry = run(&["dry-run", "--json"]);
    assert_eq!(dry["sim"]["limit_violations"], 0, "{dry}");
    // The sample raster: a scan line per geometry, within the limits.
    std::fs::copy(root.join("samples/raster-tool.nc"), dir.path().join("raster.nc")).unwrap();
    let sample = run(&["dry-run", "--json"]);
    assert_eq!((sample["geometries"].as_u64(), sample["sim"]["limit_violations"].as_u64()), (Some(39), Some(0)), "{sample}");
}
