//! The galvo planner on the 12 test cases of seed 003's families
//! (`tests/data/galvo/`, from `../shared/bench/galvo/`): every geometry marked
//! once, inside its field, fields processed one after the other, no more
//! fields than the reference reimplementation's mean, and less idle stroke
//! than the nearest-neighbour baseline.

use std::path::{Path, PathBuf};

use laserd::config::{MachineConfig, DEFAULT_CONFIG_PATH};
use laserd::plan::PlannerKind;
use laserd::run;

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/galvo")
}

/// The shipped machine with the benchmark's 70 x 70 mm usable field.
fn machine() -> MachineConfig {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_CONFIG_PATH)).unwrap();
    assert!(text.contains("usable_half_field = 32.0"));
    MachineConfig::parse(&text.replace("usable_half_field = 32.0", "usable_half_field = 35.0"), "galvo70.toml").unwrap()
}

#[test]
fn every_case_is_covered_once_inside_its_fields_with_no_more_fields_than_the_reference() {
    let machine = machine();
    let reference: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(data().join("reference.json")).unwrap()).unwrap();
    let half = machine.scanner.as_ref().unwrap().usable_half_field;
    let (mut ours, mut theirs) = (0usize, 0.0f64);
    for (case, figures) in reference.as_object().unwrap() {
        let job = data().join(format!("{case}.svg"));
        let hha = run::plan(&job, &machine, PlannerKind::Hha, None).unwrap();
        let nearest = run::plan(&job, &machine, PlannerKind::Nearest, None).unwrap();
        let mut times = vec![0u32; hha.job.geometries.len()];
        for group in &hha.sequence.groups {
            let c = group.field_center.expect("step-and-scan");
            for path in &group.paths {
                times[path.geometry] += 1;
                for p in &path.points {
                    assert!((p.x - c.x).abs() <= half + 1e-6 && (p.y - c.y).abs() <= half + 1e-6, "{case}: geometry {} outside its field", path.geometry);
                }
            }
        }
        for (g, &t) in times.iter().enumerate() {
            assert_eq!(t, hha.job.processes[hha.job.geometries[g].process].passes, "{case}: geometry {g} marked {t} times");
        }
        let fields = hha.report.scan_fields.unwrap();
        let mean = figures["fields"].as_f64().unwrap();
        assert!(fields as f64 <= mean, "{case}: {fields} fields, reference mean {mean}");
        assert!(hha.report.idle_stroke_mm < nearest.report.idle_stroke_mm, "{case}: hha {} vs nearest {}", hha.report.idle_stroke_mm, nearest.report.idle_stroke_mm);
        ours += fields;
        theirs += mean;
    }
    assert!((ours as f64) <= 0.9 * theirs, "{ours} fields in all against the reference's {theirs}");
}
