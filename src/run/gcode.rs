//! A G-code file run as it is (`dry-run FILE.nc --keep-order`): which files
//! are G-code, the check of every line as the controller parses it (errors
//! name the line), and the file streamed into the simulator in virtual time.
//! There is no plan behind such a file, so the figures that compare against
//! one (`trajectory_time_s`, `lower_bound_s`, the TCP deviation from the
//! planned path, the laser state per planned line) are not there.

use std::path::Path;

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::figures::{sim_figures, PlannedLine, RunLog};
use crate::program::{LineKind, Program, ProgramLine};
use crate::record::{Recorder, Recording, TOPIC_JOB, TOPIC_PLAN_LINES, TOPIC_REPORT, TOPIC_SETUP};
use crate::report::GcodeReport;
use crate::stream::{SenderOptions, StreamOutcome};

/// How a job file is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobKind {
    /// Planned into a program.
    Svg,
    /// Planned into a program (ASCII or binary DXF).
    Dxf,
    /// Planned into a program (laserd's own job file).
    Json,
    /// Checked line by line as the controller would, then streamed as it is.
    Gcode,
}

pub use crate::import::gcode::GCODE_EXTENSIONS;

impl JobKind {
    /// The kind the file's name says, if its content agrees: a job file is
    /// taken by what it is, not by what it is called.
    pub fn of(name: &str, bytes: &[u8]) -> Result<JobKind> {
        let ext = Path::new(name).extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        let kind = match ext.as_deref() {
            Some("svg") => JobKind::Svg,
            // Binary DXF is no text; the importer judges the content.
            Some("dxf") if bytes.starts_with(b"AutoCAD Binary DXF") => return Ok(JobKind::Dxf),
            Some("dxf") => JobKind::Dxf,
            Some("json") => JobKind::Json,
            Some(e) if GCODE_EXTENSIONS.contains(&e) => JobKind::Gcode,
            _ => return Err(Error::Import(format!("{name}: not a job file: the name must end in .svg, .dxf, .json or a G-code extension (.{})", GCODE_EXTENSIONS.join(", ."))))
        };
        let text = std::str::from_utf8(bytes).map_err(|e| Error::Import(format!("{name}: not a job file: not UTF-8 text (byte {})", e.valid_up_to())))?;
        if let Some(at) = text.find(|c: char| c.is_control() && !matches!(c, '\n' | '\r' | '\t' | '\x0c')) {
            let line = text[..at].lines().count().max(1);
            return Err(Error::Import(format!("{name}:{line}: not a job file: control character {:#04x}", text.as_bytes()[at])));
        }
        let head = text.trim_start_matches('\u{feff}').trim_start();
        let looks_svg = head.starts_with('<') && text[..text.len().min(64 * 1024)].contains("<svg");
        match (kind, looks_svg) {
            (JobKind::Svg, false) => Err(Error::Import(format!("{name}: not an SVG document (no <svg> element at its start)"))),
            (JobKind::Gcode | JobKind::Dxf | JobKind::Json, true) => Err(Error::Import(format!(
                "{name}: an SVG document named as {}: name it .svg",
                match kind {
                    JobKind::Dxf => "DXF",
                    JobKind::Json => "a job file",
                    _ => "G-code",
                }
            ))),
            _ => Ok(kind),
        }
    }
}

/// Checks a G-code program line by line in the simulator's check mode
/// (`$C`), as the controller would parse it; returns its line count. System
/// commands (`$…`) are not program lines: a file must not change the
/// controller's settings.
pub fn check_gcode(name: &str, text: &str, machine: &MachineConfig) -> Result<usize> {
    use laserd_sim::controller::{Controller, Faults};
    use laserd_sim::wire::{error_message, alarm_message, Response};
    let mut controller = Controller::new(super::sim_config(machine, Faults::default()));
    let mut t = 0.0;
    let mut ask = |controller: &mut Controller, line: &str| -> Option<Response> {
        for b in line.bytes().chain([b'\n']) {
            controller.receive(t, b);
        }
        let mut out = String::new();
        // A check takes no time: a few steps of the clock answer it.
        for _ in 0..100 {
            t += 1e-3;
            controller.advance(t);
            out.push_str(&String::from_utf8_lossy(&controller.take_output()));
            if let Some(answer) = out.lines().map(Response::parse).find(|r| matches!(r, Response::Ok | Response::Error(_) | Response::Alarm(_))) {
                return Some(answer);
            }
        }
        None
    };
    controller.advance(0.0);
    controller.take_output();
    if ask(&mut controller, "$C") != Some(Response::Ok) {
        return Err(Error::Io(format!("{name}: the G-code check could not enter check mode")));
    }
    // Split and capped as the service will stream it.
    let mut lines = 0;
    for (i, raw) in crate::stream::FileLines::new(text.as_bytes(), name).enumerate() {
        let raw = raw?;
        lines += 1;
        let n = i + 1;
        let clean = crate::stream::clean_line(&raw);
        if clean.is_empty() {
            continue;
        }
        let quoted = || format!("`{}`", crate::stream::quote(raw.trim()));
        if clean.len() + 1 > machine.serial.rx_buffer {
            return Err(Error::Import(format!("{name}:{n} {}: {} characters, more than the controller's receive buffer takes ([serial] rx_buffer = {})", quoted(), clean.len(), machine.serial.rx_buffer)));
        }
        if clean.starts_with('$') {
            return Err(Error::Import(format!("{name}:{n} {}: a system command, not a program line (a job must not change the controller's settings)", quoted())));
        }
        match ask(&mut controller, &clean) {
            Some(Response::Ok) => {}
            Some(Response::Error(code)) => return Err(Error::Import(format!("{name}:{n} {}: error:{code} ({})", quoted(), error_message(code)))),
            Some(Response::Alarm(code)) => return Err(Error::Import(format!("{name}:{n} {}: ALARM:{code} ({})", quoted(), alarm_message(code)))),
            _ => return Err(Error::Import(format!("{name}:{n} {}: the check got no answer", quoted()))),
        }
    }
    Ok(lines)
}

/// Whether `path` names a G-code file by its extension.
pub fn is_gcode(path: &Path) -> bool {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    ext.is_some_and(|e| GCODE_EXTENSIONS.contains(&e.as_str()))
}

/// A G-code file read and checked as the service takes one: at most
/// `[import] max_file_mb`, UTF-8 text that is not an SVG document, every
/// line accepted by the controller's parser. The lines as the sender splits
/// them, each of kind `Setup` (nothing is known of what it does).
pub fn read_gcode(path: &Path, machine: &MachineConfig) -> Result<Program> {
    let shown = path.display().to_string();
    let bytes = crate::import::read_capped(path, machine.import.max_file_bytes())?;
    if JobKind::of(&shown, &bytes)? != JobKind::Gcode {
        return Err(Error::Import(format!("{shown}: not a G-code file (.{})", GCODE_EXTENSIONS.join(", ."))));
    }
    let text = String::from_utf8_lossy(&bytes);
    check_gcode(&shown, &text, machine)?;
    let mut lines = Vec::new();
    for line in crate::stream::FileLines::new(text.as_bytes(), &shown) {
        lines.push(ProgramLine { text: line?, kind: LineKind::Setup, geometry: None, plan_time: None, checks: vec![] });
    }
    let axes = super::sim_config(machine, laserd_sim::controller::Faults::default()).axes;
    Ok(Program { lines, axis_letters: axes.iter().map(|a| a.letter).collect(), start: vec![0.0; axes.len()], sources: vec![] })
}

/// How a G-code file ran in the simulator.
pub struct GcodeDryRun {
    pub report: GcodeReport,
    pub outcome: StreamOutcome,
    pub log: RunLog,
}

/// Streams the G-code file at `path` as it is (no planning) into a fresh
/// simulator of `machine` in virtual time, recording the run at `recording`.
/// Its lines are checked first; a line the controller refuses is an error
/// naming it.
pub fn dry_run_gcode(path: &Path, machine: &MachineConfig, recording: &Path) -> Result<GcodeDryRun> {
    let program = read_gcode(path, machine)?;
    let rec = Recording::create(recording)?;
    let recorder = rec.recorder();
    let mut report = GcodeReport {
        job: path.display().to_string(),
        planner: "keep-order".into(),
        motion: machine.simulator.motion,
        junction_deviation_mm: machine.simulator.junction_deviation,
        program_lines: program.lines.len(),
        program_bytes: program.lines.iter().map(|l| l.text.len() + 1).sum(),
        trajectory_time_s: None,
        lower_bound_s: None,
        sim: None,
        recording: Some(recording.display().to_string()),
        config: None,
    };
    recorder.write(TOPIC_JOB, 0.0, &report);
    let streamed = simulate(&program, vec![], machine, Some(&recorder));
    let (outcome, log, recorder, rec) = super::closed_on_error(streamed, recorder, rec)?;
    report.sim = Some(sim_figures(&log));
    recorder.write(TOPIC_REPORT, log.knots.last().map(|k| k.t).unwrap_or(0.0), &report);
    drop(recorder);
    rec.finish()?;
    Ok(GcodeDryRun { report, outcome, log })
}

/// Streams a program laserd did not plan for this run (a G-code file, a
/// plan written as plain `G1 F` moves) into a fresh simulator of `machine`,
/// from the machine origin; `planned` holds its lines' kinds where they are
/// known (the laser state and the approach are judged by them), and no TCP
/// tolerance applies (there is no planned TCP to keep to).
pub fn simulate(program: &Program, planned: Vec<PlannedLine>, machine: &MachineConfig, recorder: Option<&Recorder>) -> Result<(StreamOutcome, RunLog)> {
    let sim = super::sim_config(machine, laserd_sim::controller::Faults::default());
    let setup = crate::figures::RunSetup { tcp_tolerance_mm: None, ..super::run_setup(machine, &sim) };
    if let Some(r) = recorder {
        r.write(TOPIC_SETUP, 0.0, &setup);
        for p in &planned {
            r.write(TOPIC_PLAN_LINES, 0.0, p);
        }
    }
    let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    options.hold_limit = options.hold_limit_for(machine.stop_time_s());
    let (outcome, log) = super::stream_into_simulator(program, sim, machine.serial.baud, &options, recorder)?;
    Ok((outcome, RunLog { setup: Some(setup), planned, ..log }))
}
