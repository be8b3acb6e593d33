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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Geometry, Process};
    use crate::plan::{PathGroup, PlannedPath};

    /// Two cuts: the approach, the pierce as laserd writes it, the vertices
    /// at the layer's feed in mm/min, a `G0` between them.
    #[test]
    fn paths_become_g0_the_pierce_and_g1_at_the_layer_feed() {
        let mut machine = MachineConfig::load(None).unwrap();
        machine.laser.pierce_time = 0.2;
        machine.laser.pierce_power = Some(900.0);
        let square = |x: f64| vec![Point::new(x, 10.0), Point::new(x + 5.0, 10.0), Point::new(x + 5.0, 15.0), Point::new(x, 10.0)];
        let job = Job {
            source: "t".into(),
            geometries: (0..2).map(|k| Geometry { arcs: Vec::new(), profile: Vec::new(), points: square(10.0 * k as f64 + 10.0), closed: false, process: 0, source: format!("g{k}") }).collect(),
            processes: vec![Process { layer: "mark".into(), speed: 50.0, power: 300.0, passes: 1, fill: false }],
        };
        let paths = (0..2).map(|k| PlannedPath::new(k, job.geometries[k].points.clone(), 0, true)).collect();
        let sequence = Sequence { groups: vec![PathGroup { field_center: None, paths }] };
        let program = plain_program(&job, &sequence, &machine).unwrap();
        let text: Vec<(&str, LineKind)> = program.lines.iter().map(|l| (l.text.as_str(), l.kind)).collect();
        let mark = |x: f64| {
            let pierce = [("G1M3S900F60", LineKind::Pierce), ("G4P0.2", LineKind::Pierce), ("M4", LineKind::Pierce)];
            let first = format!("G1X{}Y10S300F3000", x + 5.0);
            (pierce, first)
        };
        let (pierce, first) = mark(10.0);
        let mut expected: Vec<(String, LineKind)> = vec![("G21G90G94".into(), LineKind::Setup), ("M4S0".into(), LineKind::Setup), ("G0X10Y10".into(), LineKind::Approach)];
        expected.extend(pierce.iter().map(|(t, k)| (t.to_string(), *k)));
        expected.extend([(first, LineKind::Mark), ("X15Y15".into(), LineKind::Mark), ("X10Y10".into(), LineKind::Mark), ("G0X20Y10".into(), LineKind::Jump)]);
        let (pierce, first) = mark(20.0);
        expected.extend(pierce.iter().map(|(t, k)| (t.to_string(), *k)));
        expected.extend([(first, LineKind::Mark), ("X25Y15".into(), LineKind::Mark), ("X20Y10".into(), LineKind::Mark), ("M5S0".into(), LineKind::End), ("M2".into(), LineKind::End)]);
        let expected: Vec<(&str, LineKind)> = expected.iter().map(|(t, k)| (t.as_str(), *k)).collect();
        assert_eq!(text, expected);
    }
}
