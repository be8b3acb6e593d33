//! laserd's own job format: the `Job` as JSON, versioned, with a JSON
//! Schema (`laserd job-schema`). `laserd import F -o job.json` writes what
//! an importer read; a `.json` job file is read back unchanged (coordinates
//! round-trip exactly). What it says is checked as any upload is: its
//! version, every number finite and within range, every process index
//! valid, the import caps.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use std::path::Path;

use crate::config::{MachineConfig, PlateConfig, PASSES, VELOCITY};
use crate::error::{Error, Result};
use super::MAX_COORD_MM;
use crate::job::{ArcSpan, Geometry, Job, Point, Process};

/// The `format` a job file carries.
pub const FORMAT: &str = "laserd-job";

/// The version this build writes and reads.
pub const VERSION: u32 = 1;


/// A job file.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JobFile {
    /// Always "laserd-job".
    pub format: String,
    /// 1.
    pub version: u32,
    /// The file the job was imported from.
    pub source: String,
    /// The layers the geometries use: name, speed (mm/s), power (S), passes.
    pub processes: Vec<Process>,
    pub geometries: Vec<GeometryFile>,
    /// The plate the job is cut from (the fields of the config's `[plate]`);
    /// none: the machine config's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plate: Option<PlateConfig>,
}

/// One polyline in machine mm.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct GeometryFile {
    /// Vertices [x, y] in mm; a closed one does not repeat its first vertex.
    pub points: Vec<[f64; 2]>,
    pub closed: bool,
    /// The circular arcs among the segments: vertices `from` to `to` (the
    /// number of points: back to vertex 0) flatten an arc of `bulge` (tan
    /// of a quarter of its sweep, + counter-clockwise, |bulge| <= 1).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub arcs: Vec<ArcSpan>,
    /// The process of each segment (index into `processes`) where it
    /// changes along the geometry (a raster line's power); absent: `process`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub profile: Vec<usize>,
    /// Index into `processes`.
    pub process: usize,
    /// Where it came from, for messages.
    pub source: String,
}

/// The job as its file, with the plate it is cut from, if any.
pub fn to_file(job: &Job, plate: Option<&PlateConfig>) -> JobFile {
    JobFile {
        plate: plate.cloned(),
        format: FORMAT.into(),
        version: VERSION,
        source: job.source.clone(),
        processes: job.processes.clone(),
        geometries: job
            .geometries
            .iter()
            .map(|g| GeometryFile { points: g.points.iter().map(|p| [p.x, p.y]).collect(), closed: g.closed, arcs: g.arcs.clone(), profile: g.profile.clone(), process: g.process, source: g.source.clone() })
            .collect(),
    }
}

/// The plate a job file names, checked as a config's `[plate]` is (its
/// layer must be the machine's); `None` for other job files and where none
/// is named.
pub fn plate_of(path: &Path, config: &MachineConfig) -> Result<Option<PlateConfig>> {
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        return Ok(None);
    }
    let source = path.display().to_string();
    let bytes = super::read_capped(path, (config.import.max_file_mb * 1e6) as usize)?;
    let file: JobFile = serde_json::from_slice(&bytes).map_err(|e| Error::Import(format!("{source}: not a laserd job file: {e}")))?;
    let Some(plate) = file.plate else { return Ok(None) };
    MachineConfig { plate: Some(plate.clone()), ..config.clone() }.checked(&source)?;
    Ok(Some(plate))
}

/// The JSON Schema of a job file.
pub fn schema() -> String {
    serde_json::to_string_pretty(&schemars::schema_for!(JobFile)).expect("a schema serialises")
}

/// Reads a job file's `bytes` (`source` names it in messages).
pub fn import_json(bytes: &[u8], source: &str, config: &MachineConfig) -> Result<Job> {
    let file: JobFile = serde_json::from_slice(bytes).map_err(|e| Error::Import(format!("{source}: not a laserd job file: {e}")))?;
    if file.format != FORMAT || file.version != VERSION {
        return Err(Error::Import(format!("{source}: format {:?} version {}; laserd reads {FORMAT:?} version {VERSION}", file.format, file.version)));
    }
    for (i, p) in file.processes.iter().enumerate() {
        let name = |what: &str| format!("{source}: processes[{i}] ({}).{what}", p.layer);
        VELOCITY.check(&name("speed"), p.speed).map_err(Error::Import)?;
        PASSES.check(&name("passes"), p.passes).map_err(Error::Import)?;
        if !(p.power.is_finite() && (0.0..=config.laser.max_power).contains(&p.power)) {
            return Err(Error::Import(format!("{}: {} is outside 0 to the laser's max_power {}", name("power"), p.power, config.laser.max_power)));
        }
    }
    if file.geometries.len() as u64 > config.import.max_elements {
        return Err(Error::TooLarge(format!("{source}: more than {} geometries ([import] max_elements)", config.import.max_elements)));
    }
    let points: usize = file.geometries.iter().map(|g| g.points.len()).sum();
    if points as u64 > config.import.max_points {
        return Err(Error::TooLarge(format!("{source}: more than {} points ([import] max_points)", config.import.max_points)));
    }
    let mut geometries = Vec::with_capacity(file.geometries.len());
    for (i, g) in file.geometries.into_iter().enumerate() {
        let name = format!("{source}: geometries[{i}]");
        if g.process >= file.processes.len() {
            return Err(Error::Import(format!("{name}: process {} of {}", g.process, file.processes.len())));
        }
        if let Some(p) = g.points.iter().find(|p| p.iter().any(|v| !v.is_finite() || v.abs() > MAX_COORD_MM)) {
            return Err(Error::Import(format!("{name}: point {p:?} is beyond {MAX_COORD_MM} mm")));
        }
        if g.points.len() < 2 {
            return Err(Error::Import(format!("{name}: fewer than two points")));
        }
        let geometry = Geometry { points: g.points.iter().map(|p| Point::new(p[0], p[1])).collect(), closed: g.closed, arcs: g.arcs, profile: g.profile, process: g.process, source: g.source };
        if let Some(wrong) = geometry.arc_error(config.import.tolerance) {
            return Err(Error::Import(format!("{name}: {wrong}")));
        }
        let segments = geometry.segments();
        if !geometry.profile.is_empty() && geometry.profile.len() != segments {
            return Err(Error::Import(format!("{name}: a profile of {} processes for {segments} segments", geometry.profile.len())));
        }
        if let Some(k) = geometry.profile.iter().position(|&p| p >= file.processes.len()) {
            return Err(Error::Import(format!("{name}: profile[{k}]: process {} of {}", geometry.profile[k], file.processes.len())));
        }
        geometries.push(geometry);
    }
    if geometries.is_empty() {
        return Err(Error::Import(format!("{source}: nothing to mark: no geometry")));
    }
    Ok(Job { source: file.source, geometries, processes: file.processes })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_round_trips_exactly_and_bad_files_are_named() {
        let config = crate::import::test_config();
        let job = Job {
            source: "a.svg".into(),
            geometries: vec![Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(0.1, 1.0 / 3.0), Point::new(2.0f64.sqrt(), 7.0)], closed: false, process: 0, source: "a.svg: <path>".into() }],
            processes: vec![Process { layer: "mark".into(), speed: 100.0, power: 200.0, passes: 2, fill: false }],
        };
        let text = serde_json::to_string(&to_file(&job, None)).unwrap();
        let back = import_json(text.as_bytes(), "j.json", &config).unwrap();
        assert_eq!(back.geometries, job.geometries);
        assert_eq!(back.processes, job.processes);
        let bad = |edit: &dyn Fn(&mut serde_json::Value)| {
            let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
            edit(&mut v);
            import_json(v.to_string().as_bytes(), "j.json", &config).unwrap_err().to_string()
        };
        assert!(bad(&|v| v["version"] = 2.into()).contains("version 2"));
        assert!(bad(&|v| v["geometries"][0]["process"] = 3.into()).contains("geometries[0]: process 3 of 1"));
        assert!(bad(&|v| v["geometries"][0]["points"][0][0] = 1e300.into()).contains("geometries[0]: point"));
        assert!(bad(&|v| v["processes"][0]["power"] = 1e9.into()).contains("processes[0] (mark).power"));
        assert!(bad(&|v| v["extra"] = 1.into()).contains("not a laserd job file"));
        assert!(import_json(b"{\"format\": ", "j.json", &config).unwrap_err().to_string().contains("j.json: not a laserd job file"));
    }

    #[test]
    fn arcs_round_trip_and_arcs_that_do_not_match_their_points_are_refused() {
        let config = crate::import::test_config();
        let job = crate::import::gcode::import_gcode("M4 S10 F100\nG0 X10 Y0\nG2 X10 Y0 I-5 J0\nG1 X12\nG3 X14 Y2 I0 J2\nM5\n", "t.nc", &config).unwrap();
        assert_eq!(job.geometries[0].arcs.len(), 3);
        let text = serde_json::to_string(&to_file(&job, None)).unwrap();
        let back = import_json(text.as_bytes(), "j.json", &config).unwrap();
        assert_eq!(back.geometries, job.geometries);
        assert_eq!(back.geometries[0].length(), job.geometries[0].length());
        let bad = |edit: &dyn Fn(&mut serde_json::Value)| {
            let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
            edit(&mut v);
            import_json(v.to_string().as_bytes(), "j.json", &config).unwrap_err().to_string()
        };
        assert!(bad(&|v| v["geometries"][0]["arcs"][0]["bulge"] = 2.0.into()).contains("geometries[0]: arc 0: bulge 2"));
        assert!(bad(&|v| v["geometries"][0]["arcs"][2]["to"] = 100000.into()).contains("geometries[0]: arc 2 (vertices"));
        assert!(bad(&|v| v["geometries"][0]["arcs"][1]["from"] = 0.into()).contains("out of order"));
        // Straight points said to be an arc: the length would lie.
        assert!(bad(&|v| v["geometries"][0]["arcs"][2]["bulge"] = 0.9.into()).contains("off the arc"));
        assert!(bad(&|v| v["geometries"][0]["arcs"][0]["bulge"] = 1.0.into()).contains("arc 0: vertex"));
        assert!(bad(&|v| v["geometries"][0]["points"][25] = v["geometries"][0]["points"][0].clone()).contains("arc 0 ends where it starts"));
    }

    #[test]
    fn a_power_profile_round_trips_and_one_that_does_not_fit_is_refused() {
        let config = crate::import::test_config();
        let job = crate::import::gcode::import_gcode("M4 F600\nG1 X1 S10\nG1 X2 S20\nG1 X3 S10\nM5\n", "t.nc", &config).unwrap();
        assert_eq!(job.geometries[0].profile, vec![0, 1, 0]);
        let text = serde_json::to_string(&to_file(&job, None)).unwrap();
        assert_eq!(import_json(text.as_bytes(), "j.json", &config).unwrap().geometries, job.geometries);
        let bad = |edit: &dyn Fn(&mut serde_json::Value)| {
            let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
            edit(&mut v);
            import_json(v.to_string().as_bytes(), "j.json", &config).unwrap_err().to_string()
        };
        assert!(bad(&|v| v["geometries"][0]["profile"] = serde_json::json!([0, 1])).contains("geometries[0]: a profile of 2 processes for 3 segments"));
        assert!(bad(&|v| v["geometries"][0]["profile"] = serde_json::json!([0, 5, 0])).contains("geometries[0]: profile[1]: process 5 of 2"));
    }
}
