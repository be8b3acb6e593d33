//! The `sim` figures of a run, derived from what the run recorded: the link
//! traffic, the motion the simulated machine executed (knots) and the planned
//! check points of the program. The dry-run computes them from the same
//! `RunLog` that it records, and `replay` rebuilds the `RunLog` from the file,
//! so both give the same figures.

use laserd_sim::controller::{AxisConfig, Knot};
use laserd_sim::limits::{LimitChecker, LimitReport};
use laserd_sim::wire::Response;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::job::Point;
use crate::program::{tcp_of, CheckPoint, LineKind, Program};
use crate::stream::LinkEvent;

mod collisions;

/// What the figures need to know about the machine.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct RunSetup {
    pub axes: Vec<AxisConfig>,
    pub baud: u32,
    /// Half the usable scanner field, when the machine has a scanner (axes 2, 3).
    pub usable_half_field: Option<f64>,
    /// How far the executed TCP may be from the planned one while marking:
    /// `program.tolerance` and a unit of the last decimal of each axis.
    /// Absent in recordings made before it was recorded: not judged then.
    #[serde(default)]
    pub tcp_tolerance_mm: Option<f64>,
    /// The machine the run had (after command-line overrides such as
    /// `--motion`), so that `replay --to-sim` runs the same machine again.
    /// Absent in recordings made before it was recorded.
    #[serde(default)]
    pub machine: Option<crate::config::MachineConfig>,
    /// Recorded in real time on the controller's side (`laserd sim
    /// --record`): its times are the host's and the sender's, and it numbers
    /// every line the controller received, the sender's own too.
    #[serde(default)]
    pub real_time: bool,
    /// Closed cutting contours smaller than twice the support grid, which
    /// may tip once cut free (`[plate] support_grid`); the head's lift height.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub small_pieces: Vec<Vec<[f64; 2]>>,
    #[serde(default)]
    pub lift_height: f64,
}

/// Per program line: its kind and planned check points (marking lines only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct PlannedLine {
    pub line: usize,
    pub kind: LineKind,
    pub checks: Vec<CheckPoint>,
}

impl PlannedLine {
    pub fn from_program(program: &Program) -> Vec<PlannedLine> {
        program
            .lines
            .iter()
            .enumerate()
            .map(|(i, l)| PlannedLine { line: i + 1, kind: l.kind, checks: l.checks.clone() })
            .collect()
    }
}

#[derive(Debug, Clone, Default)]
pub struct RunLog {
    pub setup: Option<RunSetup>,
    pub planned: Vec<PlannedLine>,
    pub link: Vec<(f64, LinkEvent)>,
    pub knots: Vec<Knot>,
}

/// The contract's `sim` object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct SimFigures {
    pub job_time_s: f64,
    pub limit_violations: u64,
    pub alarms: Vec<u16>,
    pub lines_sent: usize,
    pub bytes_sent: usize,
    /// Bytes sent over the nominal character rate (`baud / 10`) from the
    /// first line sent to the last answer (`stream::link_utilization`).
    pub link_utilization: f64,
    pub planner_starved_s: f64,
    /// `null` when the program has no planned TCP to compare with (a G-code
    /// file run as it is).
    pub max_tcp_deviation_mm: Option<f64>,
    pub peak_field_use: Option<f64>,
    pub peak_stage_use: f64,
    /// Marking blocks executed with the laser off, and non-marking blocks executed
    /// with it on (both must be 0).
    pub laser_state_errors: u64,
    /// First limit violation, for the human summary.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_violation: Option<String>,
    /// Every limit the run broke, each once with its worst value: travel,
    /// scanner field, velocity, acceleration, jerk (per axis), TCP deviation
    /// while marking, laser state. Empty: the run kept every limit.
    #[serde(default)]
    pub limit_breaches: Vec<String>,
    /// The head passing below its lift height, laser off, over a piece cut
    /// free that may have tipped (`collisions.rs`); `null` without a
    /// support grid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collisions: Option<u64>,
}

/// The program line of each line the controller received, in order (the
/// controller counts every line; the sender's own commands, such as `$I` at
/// connect or a resume's preamble, are program line 0). Knots carry the
/// controller's count.
pub fn program_lines(link: &[(f64, LinkEvent)]) -> Vec<usize> {
    link.iter().filter_map(|(_, e)| if let LinkEvent::Sent { line, .. } = e { Some(*line) } else { None }).collect()
}

/// Whether air assist (coolant: M8 flood, M7 mist) is on when the run ends:
/// the last coolant word sent was M7 or M8, and no M9, program end (M2/M30:
/// Grbl stops coolant there) or reset (the banner: Grbl's reset stops it)
/// came after it. From the link alone, so a recording gives the same.
pub fn air_left_on(link: &[(f64, LinkEvent)]) -> bool {
    let mut on = false;
    for (_, e) in link {
        match e {
            LinkEvent::Sent { text, .. } => {
                let mut clean = laserd_sim::gcode::LineBuilder::default();
                text.bytes().for_each(|b| clean.push(b));
                let Some(line) = clean.finish().filter(|l| !l.starts_with('$')) else { continue };
                for w in laserd_sim::gcode::split_words(&line).unwrap_or_default() {
                    match (w.letter, w.value) {
                        ('M', m) if m == 7.0 || m == 8.0 => on = true,
                        ('M', m) if m == 9.0 || m == 2.0 || m == 30.0 => on = false,
                        _ => {}
                    }
                }
            }
            LinkEvent::Received { text } if matches!(Response::parse(text), Response::Banner(_)) => on = false,
            _ => {}
        }
    }
    on
}

/// Received-line numbers (the controller's count, as knots carry it) of the
/// lines that are a dwell (`G4`).
pub fn dwell_lines(link: &[(f64, LinkEvent)]) -> std::collections::HashSet<u64> {
    link.iter()
        .filter_map(|(_, e)| if let LinkEvent::Sent { text, .. } = e { Some(text) } else { None })
        .zip(1u64..)
        .filter(|(text, _)| {
            let mut clean = laserd_sim::gcode::LineBuilder::default();
            text.bytes().for_each(|b| clean.push(b));
            let words = clean.finish().and_then(|l| laserd_sim::gcode::split_words(&l).ok()).unwrap_or_default();
            words.iter().any(|w| w.letter == 'G' && w.value == 4.0)
        })
        .map(|(_, n)| n)
        .collect()
}

/// The program line a knot's block came from (its received-line count when
/// the link log does not say).
pub fn program_line_of(lines: &[usize], knot: &Knot) -> usize {
    (knot.line as usize).checked_sub(1).and_then(|i| lines.get(i)).copied().unwrap_or(knot.line as usize)
}

/// Executed blocks of program lines: (line, their knots). A block the
/// controller runs in several segments (Grbl's acceleration, cruise and
/// deceleration; an arc's chords) has a knot at each; it runs from the knot
/// before its first segment to the end of its last.
fn executed_blocks<'a>(knots: &'a [Knot], lines: &[usize]) -> Vec<(usize, &'a [Knot])> {
    // (line, first knot, last knot)
    let mut blocks: Vec<(usize, usize, usize)> = Vec::new();
    for (k, w) in knots.windows(2).enumerate().filter(|(_, w)| w[1].t > w[0].t && w[0].pos != w[1].pos) {
        let line = program_line_of(lines, &w[1]);
        match blocks.last_mut() {
            Some((last, _, end)) if *last == line && w[1].line == knots[*end].line && *end == k => *end = k + 1,
            _ => blocks.push((line, k, k + 1)),
        }
    }
    blocks.into_iter().filter(|(line, _, _)| *line > 0).map(|(line, a, b)| (line, &knots[a..=b])).collect()
}

/// Where an executed block is at `fraction` of it: on the straight line
/// from its first knot to its last, by distance, as a straight block runs
/// (at constant velocity in its time); on the knots' polyline by time where
/// the knots leave that line (an arc's chords).
fn executed_at(run: &[Knot], fraction: f64) -> Vec<f64> {
    let (a, b) = (&run[0], &run[run.len() - 1]);
    let along = |x: &[f64], y: &[f64], f: f64| -> Vec<f64> { x.iter().zip(y).map(|(x, y)| x + (y - x) * f).collect() };
    let straight = run[1..run.len() - 1].iter().all(|k| {
        let d: Vec<f64> = b.pos.iter().zip(&a.pos).map(|(b, a)| b - a).collect();
        let len2: f64 = d.iter().map(|v| v * v).sum();
        let s = k.pos.iter().zip(&a.pos).zip(&d).map(|((p, a), d)| (p - a) * d).sum::<f64>() / len2.max(f64::MIN_POSITIVE);
        along(&a.pos, &b.pos, s).iter().zip(&k.pos).all(|(p, q)| (p - q).abs() < 1e-6)
    });
    if straight {
        return along(&a.pos, &b.pos, fraction);
    }
    let t = a.t + fraction * (b.t - a.t);
    let i = run.partition_point(|k| k.t < t).clamp(1, run.len() - 1);
    let (p, q) = (&run[i - 1], &run[i]);
    along(&p.pos, &q.pos, ((t - p.t) / (q.t - p.t)).clamp(0.0, 1.0))
}

pub fn sim_figures(log: &RunLog) -> SimFigures {
    let setup = log.setup.clone().unwrap_or(RunSetup { axes: vec![], baud: 115_200, usable_half_field: None, tcp_tolerance_mm: None, machine: None, real_time: false, small_pieces: Vec::new(), lift_height: 0.0 });

    let mut checker = LimitChecker::new(&setup.axes);
    for k in &log.knots {
        checker.push(k);
    }
    let limits: LimitReport = checker.finish();

    // The job's clock starts where the approach (from where the machine
    // rested to the job's first point) ends, as the plan's does.
    let lines = program_lines(&log.link);
    let kind_of: std::collections::HashMap<usize, LineKind> = log.planned.iter().map(|p| (p.line, p.kind)).collect();
    let approach_end = log
        .knots
        .iter()
        .filter(|k| kind_of.get(&program_line_of(&lines, k)) == Some(&LineKind::Approach))
        .map(|k| k.t)
        .fold(None, |m: Option<f64>, t| Some(m.map_or(t, |m| m.max(t))));
    let job_time_s = match (log.knots.first(), log.knots.last()) {
        (Some(a), Some(b)) => b.t - approach_end.unwrap_or(a.t),
        _ => 0.0,
    };

    // Waiting with the job unfinished: rest intervals between moving blocks,
    // except dwells (a pierce): the program asked for those. A dwell's time is
    // closed by a knot of its `G4` line.
    let dwells = dwell_lines(&log.link);
    let moving = |w: &[Knot]| w[0].pos != w[1].pos;
    let first_move = log.knots.windows(2).position(moving);
    let last_move = log.knots.windows(2).rposition(moving);
    let mut planner_starved_s = 0.0;
    if let (Some(a), Some(b)) = (first_move, last_move) {
        for w in log.knots[a..=b + 1].windows(2) {
            if !moving(w) && !dwells.contains(&w[1].line) {
                planner_starved_s += w[1].t - w[0].t;
            }
        }
    }

    let mut lines_sent = 0;
    let mut bytes_sent = 0;
    let mut first_sent: Option<f64> = None;
    let mut last_answer: Option<f64> = None;
    let mut alarms = Vec::new();
    for (t, ev) in &log.link {
        match ev {
            LinkEvent::Sent { text, .. } => {
                lines_sent += 1;
                bytes_sent += text.len() + 1;
                first_sent.get_or_insert(*t);
            }
            LinkEvent::Received { text } => match Response::parse(text) {
                Response::Ok | Response::Error(_) => last_answer = Some(*t),
                Response::Alarm(code) => alarms.push(code),
                _ => {}
            },
            LinkEvent::Realtime { .. } => {}
        }
    }
    let link_utilization = match (first_sent, last_answer) {
        (Some(a), Some(b)) => crate::stream::link_utilization(bytes_sent, setup.baud, b - a),
        _ => 0.0,
    };

    // Deviation of the executed TCP from the planned one, at the check points of
    // each marking block; and the laser state of every executed block.
    let planned: std::collections::HashMap<usize, &PlannedLine> = log.planned.iter().map(|p| (p.line, p)).collect();
    let mut max_dev: f64 = 0.0;
    let mut laser_state_errors = 0;
    for (line, run) in executed_blocks(&log.knots, &lines) {
        let Some(p) = planned.get(&line) else { continue };
        let marking = p.kind == LineKind::Mark;
        if marking != (run[run.len() - 1].power > 0.0) {
            laser_state_errors += 1;
        }
        for c in &p.checks {
            let exec = executed_at(run, c.fraction);
            let dev = (tcp_of(&exec) - Point::new(c.tcp[0], c.tcp[1])).norm();
            max_dev = max_dev.max(dev);
        }
    }

    let peak_field_use = setup.usable_half_field.map(|half| {
        log.knots
            .iter()
            .flat_map(|k| k.pos.iter().skip(2).take(2))
            .map(|v| v.abs() / half)
            .fold(0.0, f64::max)
    });
    let stage_axes = 0..setup.axes.len().min(2);
    let peak_stage_use = stage_axes
        .flat_map(|i| {
            [
                limits.peak_velocity_use.get(i).copied().unwrap_or(0.0),
                limits.peak_acceleration_use.get(i).copied().unwrap_or(0.0),
                limits.peak_jerk_use.get(i).copied().unwrap_or(0.0),
            ]
        })
        .fold(0.0, f64::max);

    // Measured only against a plan's check points.
    let max_tcp_deviation_mm = log.planned.iter().any(|p| !p.checks.is_empty()).then_some(max_dev);
    let mut limit_breaches = breaches(&setup, &limits);
    if let Some(allowed) = setup.tcp_tolerance_mm.filter(|allowed| max_dev > *allowed) {
        limit_breaches.push(format!("TCP deviation while marking {max_dev:.4} mm, allowed {allowed:.4} mm (program.tolerance)"));
    }
    if laser_state_errors > 0 {
        limit_breaches.push(format!("laser state: {laser_state_errors} block(s) with the laser on while jumping or off while marking"));
    }
    if air_left_on(&log.link) {
        limit_breaches.push("air assist left on at the end: M7/M8 sent and no M9, program end (M2/M30) or reset after it".into());
    }
    // A violation of no kind above (a position jump in zero time, a malformed knot).
    if limits.violations > 0 && limit_breaches.is_empty() {
        limit_breaches.push(limits.first_violation.clone().unwrap_or_else(|| "a limit".into()));
    }

    SimFigures {
        job_time_s,
        limit_violations: limits.violations,
        alarms,
        lines_sent,
        bytes_sent,
        link_utilization,
        planner_starved_s,
        max_tcp_deviation_mm,
        peak_field_use,
        peak_stage_use,
        laser_state_errors,
        first_violation: limits.first_violation,
        limit_breaches,
        collisions: collisions_of(&setup, &log.knots),
    }
}

/// Collisions with pieces that may have tipped, where the run knew of any.
fn collisions_of(setup: &RunSetup, knots: &[Knot]) -> Option<u64> {
    if setup.small_pieces.is_empty() {
        return None;
    }
    let pieces: Vec<Vec<Point>> = setup.small_pieces.iter().map(|o| o.iter().map(|&[x, y]| Point::new(x, y)).collect()).collect();
    let z = setup.axes.iter().position(|a| a.letter == 'Z');
    let tol = setup.tcp_tolerance_mm.unwrap_or(0.02) + 1e-6;
    let machine = setup.machine.as_ref();
    let cover = tol + machine.map_or(0.05, |m| m.import.tolerance + m.motion.corner_tolerance);
    let graze = tol + machine.map_or(0.5, |m| m.program.jump_tolerance);
    Some(collisions::count(knots, &pieces, z, setup.lift_height, cover, tol, graze))
}

/// The axis limits a run broke, each with its worst value: positions outside
/// the travel (stage) or the usable field (scanner), and the peak velocity,
/// acceleration and jerk of each axis over its limit (the limit checker
/// counts a sample over by more than its relative tolerance, 1e-9).
fn breaches(setup: &RunSetup, limits: &LimitReport) -> Vec<String> {
    let mut found = Vec::new();
    for (i, axis) in setup.axes.iter().enumerate() {
        let (lo, hi) = limits.peak_position.get(i).copied().unwrap_or((0.0, 0.0));
        let range = if "XYZ".contains(axis.letter) { "travel" } else { "scanner field" };
        if lo < axis.min - 1e-6 || hi > axis.max + 1e-6 {
            found.push(format!("{range} of {}: {lo:.3} to {hi:.3} mm, limits {} to {} mm", axis.letter, axis.min, axis.max));
        }
        for (what, peaks, limit, unit) in [
            ("velocity", &limits.peak_velocity_use, axis.max_velocity, "mm/s"),
            ("acceleration", &limits.peak_acceleration_use, axis.max_acceleration, "mm/s²"),
            ("jerk", &limits.peak_jerk_use, axis.max_jerk, "mm/s³"),
        ] {
            let used = peaks.get(i).copied().unwrap_or(0.0);
            if used > 1.0 + 1e-9 {
                found.push(format!("{what} of {}: {used:.2} times its limit of {limit} {unit}", axis.letter));
            }
        }
    }
    found
}
