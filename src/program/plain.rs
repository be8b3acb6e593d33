//! A plan written as plain G-code, as a simple sender would stream it to a
//! stock Grbl: the planned paths' vertices as `G1` moves at the layer's
//! speed (`F` in mm/min, G94), laser-off moves as `G0`, the same pierces as
//! laserd's programs (`G1M3S<power>F60`, `G4P<time>`, then `M4`), the laser
//! in M4 (or M3) with `S<power>` on marks. Nothing is timed or blended here:
//! the controller's own planner (Grbl's look-ahead, junction deviation `$11`)
//! decides the motion. `bench motion --vs-grbl` times this program against
//! laserd's own on the same path.
//!
//! The TCP only (X Y): on a machine with a scanner this is the same path as
//! a plain XY machine would run it.

use crate::config::{LaserMode, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{Job, Point};
use crate::plan::Sequence;

use super::{format_number, LineKind, Program, ProgramLine};

/// `sequence` as plain `G0`/`G1 F` moves from the machine origin: the first
/// `G0` (to the first path's entry) is the approach, as in laserd's programs.
pub fn plain_program(job: &Job, sequence: &Sequence, machine: &MachineConfig) -> Result<Program> {
    let decimals = machine.program.decimals;
    let xy = |p: Point| -> Result<String> {
        if !(p.x.is_finite() && p.y.is_finite()) {
            return Err(Error::Program(format!("a non-finite vertex ({}, {})", p.x, p.y)));
        }
        Ok(format!("X{}Y{}", format_number(p.x, decimals), format_number(p.y, decimals)))
    };
    let mut lines = Vec::new();
    let mut push = |text: String, kind: LineKind, geometry: Option<usize>| lines.push(ProgramLine { text, kind, geometry, plan_time: None, checks: vec![] });
    let laser_mode = match machine.laser.mode {
        LaserMode::M3 => "M3",
        LaserMode::M4 => "M4",
    };
    push("G21G90G94".into(), LineKind::Setup, None);
    push(format!("{laser_mode}S0"), LineKind::Setup, None);
    // From the machine origin, where laserd's jobs start too.
    let mut at = Point::origin();
    let mut approached = false;
    for path in sequence.paths() {
        let process = &job.processes[path.process];
        let g = Some(path.geometry);
        if path.start() != at {
            let kind = if approached { LineKind::Jump } else { LineKind::Approach };
            push(format!("G0{}", xy(path.start())?), kind, g);
        }
        approached = true;
        let pierce = machine.pierce(&process.layer);
        if pierce.active() {
            push(format!("G1M3S{}F60", format_number(pierce.power, 1)), LineKind::Pierce, g);
            push(format!("G4P{}", format_number(pierce.time, 4)), LineKind::Pierce, g);
            if machine.laser.mode == LaserMode::M4 {
                push("M4".into(), LineKind::Pierce, g);
            }
        }
        let feed = process.speed.min(machine.stage.max_velocity) * 60.0;
        for (k, p) in path.points.iter().skip(1).enumerate() {
            let text = if k == 0 { format!("G1{}S{}F{}", xy(*p)?, format_number(process.power, 1), format_number(feed, 3)) } else { xy(*p)? };
            push(text, LineKind::Mark, g);
        }
        at = path.end();
    }
    for text in ["M5S0", "M2"] {
        push(text.into(), LineKind::End, None);
    }
    Ok(Program { lines, axis_letters: vec!['X', 'Y'], start: vec![0.0, 0.0], sources: job.geometries.iter().map(|g| g.source.clone()).collect() })
}
