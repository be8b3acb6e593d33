//! Motion: turns a `Sequence` into a time-parametrised, jerk-limited
//! `Trajectory` of the stage and scanner axes, inside every configured limit.
//!
//! The tool centre point (TCP) is planned first (`tcp`): marks at their
//! layer's speed along straight legs with blended corners, laser-off moves
//! between them, pierces. Then the stage (`stage`), and the scanner is the
//! difference. Modes:
//! - on-the-fly: marks start and end at speed (the laser-off moves are
//!   time-optimal state-to-state Ruckig moves), corners blended; the stage
//!   moves from field to field while the scanner marks (see `stage`);
//! - step-and-scan (the baseline of vector-by-vector scanner control): every
//!   vector from rest to rest, the stage carrying the scanner to each field
//!   and standing still while it marks;
//! - stage-only: the stage is the TCP (machines without a scanner); marks
//!   run through their vertices at the speed each turn allows (`blend`),
//!   from rest to rest.
//!
//! Before the job's clock starts the machine moves from where it rests to the
//! job's first point (`PieceKind::Approach`); `lower_bound_s`, the idle
//! stroke and the job time all begin there.
//!
//! Where a layer asks for a pierce (`pierce_time` > 0), its marks start at
//! rest: the machine stands still at the entry with the laser on at the
//! pierce power for the pierce time (a `Pierce` piece), then marks.

pub mod blend;
pub mod curve;
pub mod flow;
pub mod leg;
pub mod lift;
pub mod profile;
pub mod qp;
pub mod stage;
pub mod tcp;

use crate::config::{Limits, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{Job, Point};
use crate::mode::Mode;
use crate::plan::Sequence;
pub use profile::rest_to_rest_time;
use stage::{SplitSettings, StagePath};
use tcp::{MarkRequest, PieceKind, Run, TcpBuilder, TcpPath, TcpSettings};

/// Positions of all axes at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisState {
    pub stage: Point,
    pub scanner: Point,
}

impl AxisState {
    pub fn tcp(&self) -> Point {
        Point::from(self.stage.coords + self.scanner.coords)
    }
}

/// The planned motion of the whole job: the TCP and the stage; the scanner is
/// their difference.
#[derive(Debug)]
pub struct Trajectory {
    pub tcp: TcpPath,
    pub stage: StagePath,
    pub start: AxisState,
    /// When the approach ends and the job's clock starts.
    pub job_start: f64,
    pub has_scanner: bool,
    /// On the fly: the share of field changes the stage takes at speed (the
    /// others stop the TCP while the stage catches up); `None` otherwise or
    /// without a field change.
    pub stage_flow: Option<f64>,
    /// The head's Z, on a machine with one (`[head]`).
    pub head: Option<lift::HeadPath>,
}

impl Trajectory {
    pub fn duration(&self) -> f64 {
        self.tcp.duration().max(self.stage.end_time())
    }

    /// The job's machine time (after the approach): the contract's `trajectory_time_s`.
    pub fn job_time(&self) -> f64 {
        self.duration() - self.job_start
    }

    /// The head's height at `t` (0 without a Z axis).
    pub fn z_at(&self, t: f64) -> f64 {
        self.head.as_ref().map_or(0.0, |h| h.z_at(t))
    }

    pub fn state_at(&self, t: f64) -> AxisState {
        let tcp = self.tcp.position(t);
        if !self.has_scanner {
            return AxisState { stage: tcp, scanner: Point::origin() };
        }
        let stage = self.stage.position(&self.tcp, t);
        AxisState { stage, scanner: Point::from(tcp - stage) }
    }
}

/// The marking speed, power and pierce of a path.
fn process_of(job: &Job, machine: &MachineConfig, process: usize, cap: f64) -> (f64, f64, crate::config::Pierce) {
    let p = &job.processes[process];
    (p.speed.min(cap), p.power, machine.pierce(&p.layer))
}

fn check_travel(machine: &MachineConfig, p: Point, source: &str) -> Result<()> {
    let (tx, ty) = (machine.stage.travel_x, machine.stage.travel_y);
    if p.x < -1e-9 || p.y < -1e-9 || p.x > tx + 1e-9 || p.y > ty + 1e-9 {
        return Err(Error::Motion(format!("{source}: stage position ({:.4}, {:.4}) outside the travel 0..{tx} x 0..{ty} mm", p.x, p.y)));
    }
    Ok(())
}

fn check_field(p: Point, half: f64, source: &str) -> Result<()> {
    if p.x.abs() > half + 1e-9 || p.y.abs() > half + 1e-9 {
        return Err(Error::Motion(format!("{source}: scanner position ({:.4}, {:.4}) outside the usable field ±{half} mm", p.x, p.y)));
    }
    Ok(())
}

/// Per-axis limits of the TCP in `mode`, within `motion.limit_margin`; on
/// the fly against a stage moving in bursts (`motion.stage_share`).
fn tcp_settings(machine: &MachineConfig, mode: Mode) -> TcpSettings {
    tcp_settings_against(machine, mode, machine.motion.stage_share)
}

/// The same, on the fly against a stage using `stage_share` of its limits.
fn tcp_settings_against(machine: &MachineConfig, mode: Mode, stage_share: f64) -> TcpSettings {
    let margin = machine.motion.limit_margin;
    let stage = machine.stage_limits().scaled(margin);
    let m = &machine.motion;
    let base = |axis: Limits, mark_speed: f64, blend: bool, skywrite: bool| TcpSettings {
        axis,
        mark_speed,
        blend,
        junctions: false,
        skywrite,
        corner_tolerance: m.corner_tolerance,
        line_tolerance: m.line_tolerance,
    };
    match (mode, machine.scanner.as_ref(), machine.scanner_limits()) {
        (Mode::OnTheFly, Some(sc), Some(lim)) => {
            // The scanner moves the TCP against a stage that may be moving at
            // its burst limits: what is left of the scanner's limits is the TCP's.
            let scanner = lim.scaled(margin);
            let burst = stage.scaled(stage_share);
            let axis = Limits {
                velocity: scanner.velocity - burst.velocity,
                acceleration: scanner.acceleration - burst.acceleration,
                jerk: scanner.jerk - burst.jerk,
            };
            base(axis, sc.mark_speed, true, true)
        }
        (Mode::StepAndScan, Some(sc), Some(lim)) => base(lim.scaled(margin), sc.mark_speed, false, false),
        // Stage-only runs through the vertices at the speed each turn
        // allows (`blend`); marks start and end at rest.
        _ => TcpSettings { junctions: true, ..base(stage, stage.velocity, true, false) },
    }
}

/// Builds the trajectory of `sequence`, starting at rest with the stage at
/// `start` and the scanner centred.
pub fn build(job: &Job, sequence: &Sequence, machine: &MachineConfig, mode: Mode, start: Point) -> Result<Trajectory> {
    mode.check(machine)?;
    let first = sequence.paths().next().map(|p| p.start());
    let mut trajectory = match mode {
        Mode::StageOnly => stage_only(job, sequence, machine, start, first),
        Mode::StepAndScan => step_and_scan(job, sequence, machine, start),
        Mode::OnTheFly => on_the_fly(job, sequence, machine, start, &flow::plan),
    }?;
    // The pieces grew by doubling; the program is generated beside them.
    trajectory.tcp.pieces.shrink_to_fit();
    Ok(trajectory)
}

/// Marks every path of `sequence` with `b`; `before_group` runs before each
/// group's first path (a field change). The marks' runs are planned ahead a
/// chunk at a time (`RUN_CHUNK_POINTS`), so that a job of a million hatch
/// lines never holds all its runs twice (as runs and as pieces). With
/// `keep`, they are kept for the next plan of this sequence (or taken from
/// it, when it holds them from an earlier one).
fn mark_all(
    b: &mut TcpBuilder,
    job: &Job,
    sequence: &Sequence,
    machine: &MachineConfig,
    keep: Option<&mut Option<Vec<Option<Run>>>>,
    before_group: impl FnMut(&mut TcpBuilder, usize) -> Result<()>,
) -> Result<()> {
    mark_all_in_chunks(b, job, sequence, machine, keep, before_group, RUN_CHUNK_POINTS)
}

/// `mark_all`, planning runs of about `chunk_points` points at a time.
fn mark_all_in_chunks(
    b: &mut TcpBuilder,
    job: &Job,
    sequence: &Sequence,
    machine: &MachineConfig,
    keep: Option<&mut Option<Vec<Option<Run>>>>,
    mut before_group: impl FnMut(&mut TcpBuilder, usize) -> Result<()>,
    chunk_points: usize,
) -> Result<()> {
    let cap = b.settings.mark_speed;
    let processes: Vec<_> = sequence
        .paths()
        .map(|path| {
            let (speed, power, pierce) = process_of(job, machine, path.process, cap);
            (speed, power, if path.pierce { pierce } else { crate::config::Pierce { time: 0.0, ..pierce } })
        })
        .collect();
    let paths: Vec<&crate::plan::PlannedPath> = sequence.paths().collect();
    let fills: Vec<bool> = paths.iter().map(|p| job.processes[p.process].fill).collect();
    let chains = chains(sequence, &processes, &fills, b.settings.junctions);
    let overscan = |k: usize| fills[k] && machine.overscans(&job.processes[paths[k].process].layer);
    // A pierce or a cooling wait stands still at the run's start: from rest.
    let from_rest = |k: usize| processes[k].2.time > 0.0 || paths[k].cooling_wait > 0.0;
    let requests: Vec<_> = chains.iter().map(|c| MarkRequest { points: &c.points, speed: processes[c.paths[0]].0, pierce: from_rest(c.paths[0]), breaks: &c.breaks, overscan: overscan(c.paths[0]) }).collect();
    match keep.map(|slot| (slot.take(), slot)) {
        Some((Some(all), slot)) => {
            place_runs(b, &chains, &paths, &processes, &requests, Some(&all), drop, &mut before_group, chunk_points)?;
            *slot = Some(all);
        }
        Some((None, slot)) => {
            let mut kept = Vec::with_capacity(chains.len());
            place_runs(b, &chains, &paths, &processes, &requests, None, |runs| kept.extend(runs), &mut before_group, chunk_points)?;
            *slot = Some(kept);
        }
        None => place_runs(b, &chains, &paths, &processes, &requests, None, drop, &mut before_group, chunk_points)?,
    }
    b.stop(sequence.groups.len().saturating_sub(1))
}

/// Points of the runs `mark_all` plans ahead at a time (a hatch line has two).
const RUN_CHUNK_POINTS: usize = 1 << 17;

/// `mark_all`'s marking: each chunk of chains' runs (from `planned`, else
/// planned here and handed to `done` once placed) placed in time by `b`.
#[allow(clippy::too_many_arguments)]
fn place_runs(
    b: &mut TcpBuilder,
    chains: &[Chain],
    paths: &[&crate::plan::PlannedPath],
    processes: &[(f64, f64, crate::config::Pierce)],
    requests: &[MarkRequest],
    planned: Option<&[Option<Run>]>,
    mut done: impl FnMut(Vec<Option<Run>>),
    before_group: &mut impl FnMut(&mut TcpBuilder, usize) -> Result<()>,
    chunk_points: usize,
) -> Result<()> {
    let mut last_group = None;
    let mut lo = 0;
    while lo < chains.len() {
        let mut hi = lo;
        let mut points = 0;
        while hi < chains.len() && (hi == lo || points + chains[hi].points.len() <= chunk_points) {
            points += chains[hi].points.len();
            hi += 1;
        }
        let fresh = match planned {
            Some(_) => None,
            None => Some(b.prepare(requests, lo..hi)?),
        };
        let runs = planned.map_or_else(|| fresh.as_deref().expect("planned above"), |all| &all[lo..hi]);
        for (chain, run) in chains[lo..hi].iter().zip(runs) {
            if last_group != Some(chain.group) {
                before_group(b, chain.group)?;
                last_group = Some(chain.group);
            }
            let marks: Vec<(usize, f64)> = chain.paths.iter().map(|&k| (paths[k].geometry, processes[k].1)).collect();
            let pierce = processes[chain.paths[0]].2;
            b.mark_run(&marks, chain.group, run.as_ref(), paths[chain.paths[0]].cooling_wait, pierce.time, pierce.power)?;
            let at = b.time;
            b.fell.extend(chain.paths.iter().flat_map(|&k| paths[k].falls.iter().map(move |&g| (at, g))));
        }
        if let Some(fresh) = fresh {
            done(fresh);
        }
        lo = hi;
    }
    Ok(())
}

/// Paths marked as one run: each after the first goes on from where the one
/// before ended, straight on, at the same speed, without a pierce, and is
/// of the same geometry (a raster line cut where its power changes) or both
/// are of fills (a fill's line with the laser off across its gaps).
struct Chain {
    group: usize,
    /// Indices of the paths in the sequence.
    paths: Vec<usize>,
    points: Vec<Point>,
    /// Where in `points` each path after the first begins.
    breaks: Vec<usize>,
}

/// The sequence's paths in chains (with `junctions` only: elsewhere each
/// path is a run of its own).
fn chains(sequence: &Sequence, processes: &[(f64, f64, crate::config::Pierce)], fills: &[bool], junctions: bool) -> Vec<Chain> {
    let mut out: Vec<Chain> = Vec::new();
    let mut k = 0;
    let mut previous: Option<&crate::plan::PlannedPath> = None;
    for (g, group) in sequence.groups.iter().enumerate() {
        for path in &group.paths {
            let goes_on = previous.zip(out.last()).filter(|(before, _)| before.points.len() >= 2 && path.points.len() >= 2).is_some_and(|(before, chain)| {
                let n = before.points.len();
                let (a, b) = (before.points[n - 1] - before.points[n - 2], path.points[1] - path.points[0]);
                junctions
                    && chain.group == g
                    && (before.geometry == path.geometry || (fills[k - 1] && fills[k]))
                    && processes[k].2.time == 0.0
                    && path.cooling_wait == 0.0
                    && processes[k].0 == processes[chain.paths[0]].0
                    && before.end() == path.start()
                    && a.dot(&b) > 0.0
                    && a.perp(&b).abs() <= 1e-9 * a.norm() * b.norm()
            });
            match out.last_mut() {
                Some(chain) if goes_on => {
                    chain.breaks.push(chain.points.len() - 1);
                    chain.points.extend_from_slice(&path.points[1..]);
                    chain.paths.push(k);
                }
                _ => out.push(Chain { group: g, paths: vec![k], points: path.points.clone(), breaks: Vec::new() }),
            }
            previous = Some(path);
            k += 1;
        }
    }
    out
}

fn stage_only(job: &Job, sequence: &Sequence, machine: &MachineConfig, start: Point, first: Option<Point>) -> Result<Trajectory> {
    for path in sequence.paths() {
        for p in &path.points {
            check_travel(machine, *p, &job.geometries[path.geometry].source)?;
        }
    }
    let settings = tcp_settings(machine, Mode::StageOnly);
    // Marks without a pierce are entered and left at speed; where a
    // laser-off move running through a mark's end would leave the travel
    // (near the table's edge), its two ends are planned at rest and the job
    // again (a few rounds; should that not settle, all of it rest to rest).
    // Each round starts from the corners and moves the one before planned
    // (the same keys give the same moves), and lets go of that plan first.
    let plan = |hand_over: bool, rest_at: &[Point], before: Option<TcpBuilder>| -> Result<(TcpBuilder, f64)> {
        let cache = before.map(|b| b.take_cache()).unwrap_or_default();
        let mut b = TcpBuilder::new(settings, start, 0.0).with_cache(cache);
        b.hand_over = hand_over;
        b.rest_at = rest_at.to_vec();
        if let Some(f) = first {
            b.jump(PieceKind::Approach, 0, f, nalgebra::Vector2::zeros())?;
        }
        let job_start = b.time;
        mark_all(&mut b, job, sequence, machine, None, |_, _| Ok(()))?;
        Ok((b, job_start))
    };
    // Lifts over pieces that may have tipped wait at a move's end where the
    // move is short: that end is planned at rest too.
    let lift = lift_settings(machine);
    let lifts = |b: &TcpBuilder| -> Result<(Vec<lift::Window>, Vec<Point>)> {
        let Some(settings) = &lift else { return Ok((Vec::new(), Vec::new())) };
        let fallen: Vec<lift::Fallen> = b.fell.iter().map(|&(at, g)| lift::Fallen { outline: &job.geometries[g].points, at }).collect();
        let windows = lift::windows(&b.path, &fallen, settings, machine.stage.max_velocity);
        let rest = lift::rest_needed(&b.path, &windows, settings)?;
        Ok((windows, rest))
    };
    let mut rest_at = Vec::new();
    let (mut b, mut job_start) = plan(true, &rest_at, None)?;
    let mut outside = moves_leaving_travel(&b.path, machine);
    let (mut windows, mut waits) = lifts(&b)?;
    for _ in 0..TRAVEL_ROUNDS {
        if outside.is_empty() && waits.is_empty() {
            break;
        }
        rest_at.extend(outside.iter().flat_map(|&(from, to)| [from, to]));
        rest_at.extend(waits);
        (b, job_start) = plan(true, &rest_at, Some(b))?;
        outside = moves_leaving_travel(&b.path, machine);
        (windows, waits) = lifts(&b)?;
    }
    if !outside.is_empty() || !waits.is_empty() {
        (b, job_start) = plan(false, &[], Some(b))?;
        (windows, waits) = lifts(&b)?;
        if !waits.is_empty() {
            return Err(Error::Motion(format!("a lift over a piece that may have tipped cannot wait at ({:.3}, {:.3})", waits[0].x, waits[0].y)));
        }
    }
    let (tcp, head) = match &lift {
        Some(settings) => {
            let (tcp, head) = lift::apply(b.path, &windows, settings)?;
            (tcp, Some(head))
        }
        None => (b.path, machine.head.as_ref().map(|_| lift::HeadPath::default())),
    };
    let start_state = AxisState { stage: start, scanner: Point::origin() };
    Ok(Trajectory { tcp, stage: StagePath::FollowsTcp, start: start_state, job_start, has_scanner: machine.scanner.is_some(), stage_flow: None, head })
}

/// What lifting the head takes, where it lifts over pieces that may tip.
fn lift_settings(machine: &MachineConfig) -> Option<lift::LiftSettings> {
    let head = machine.head.as_ref().filter(|h| h.lift_moves && machine.support_grid().is_some())?;
    let limits = machine.head_limits()?.scaled(machine.motion.limit_margin);
    Some(lift::LiftSettings { height: head.lift_height, limits, clearance: head.clearance + machine.program.jump_tolerance })
}

/// Rounds of `stage_only` that bring marks' ends to rest where moves left the travel.
const TRAVEL_ROUNDS: usize = 4;

/// The ends of each moving laser-off piece that leaves the stage's travel
/// (sampled every millisecond: a move running through its ends may swing
/// out, and so may the braking after the job's last mark).
fn moves_leaving_travel(path: &TcpPath, machine: &MachineConfig) -> Vec<(Point, Point)> {
    path.pieces
        .iter()
        .filter(|p| !matches!(p.motion, tcp::Motion::Still(_)) && !p.is_marking())
        .filter(|p| {
            let n = ((p.duration / 1e-3).ceil() as usize).max(8);
            (0..=n).any(|k| check_travel(machine, p.position(p.duration * k as f64 / n as f64), "").is_err())
        })
        .map(|p| (p.position(0.0), p.position(p.duration)))
        .collect()
}

fn step_and_scan(job: &Job, sequence: &Sequence, machine: &MachineConfig, start: Point) -> Result<Trajectory> {
    let half = machine.scanner.as_ref().expect("checked by Mode::check").usable_half_field;
    let stage_limits = machine.stage_limits().scaled(machine.motion.limit_margin);
    let mut centres = Vec::with_capacity(sequence.groups.len());
    for group in &sequence.groups {
        let c = group.field_center.ok_or_else(|| Error::Motion("step-and-scan needs a plan with scan fields".into()))?;
        check_travel(machine, c, "scan field")?;
        for path in &group.paths {
            for p in &path.points {
                check_field(Point::from(p - c), half, &job.geometries[path.geometry].source)?;
            }
        }
        centres.push(c);
    }
    let settings = tcp_settings(machine, Mode::StepAndScan);
    let mut b = TcpBuilder::new(settings, start, 0.0);
    let mut axes: [Vec<stage::AxisMove>; 2] = [Vec::new(), Vec::new()];
    let mut stage_at = start;
    let mut job_start = 0.0;
    let mut first_group = true;
    mark_all(&mut b, job, sequence, machine, None, |b, g| {
        // The stage carries the scanner (holding still) to the field's centre.
        let kind = if first_group { PieceKind::Approach } else { PieceKind::Carried };
        b.stop(g)?;
        let to = b.position + (centres[g] - stage_at);
        b.straight(kind, g, to, stage_limits)?;
        if let Some(piece) = b.path.pieces.last().filter(|p| p.kind == kind) {
            stage_at = stage::carried_moves(piece, &mut axes, stage_at);
        }
        stage_at = centres[g];
        if first_group {
            let entry = sequence.groups[g].paths[0].start();
            b.jump(PieceKind::Approach, g, entry, nalgebra::Vector2::zeros())?;
            job_start = b.time;
            first_group = false;
        }
        Ok(())
    })?;
    let start_state = AxisState { stage: start, scanner: Point::origin() };
    Ok(Trajectory { tcp: b.path, stage: StagePath::Moves { start, axes }, start: start_state, job_start, has_scanner: true, stage_flow: None, head: None })
}

/// Plans the flowing stage for a TCP and its pads: `flow::plan` (a seam for
/// tests).
type FlowPlanner<'a> = &'a dyn Fn(&TcpPath, &SplitSettings, (f64, f64), &flow::Workspace) -> std::result::Result<flow::Flow, flow::NoFlow>;

fn on_the_fly(job: &Job, sequence: &Sequence, machine: &MachineConfig, start: Point, planner: FlowPlanner) -> Result<Trajectory> {
    let sc = machine.scanner.as_ref().expect("checked by Mode::check");
    let settings = tcp_settings(machine, Mode::OnTheFly);
    let margin = machine.motion.limit_margin;
    let stage_limits = machine.stage_limits().scaled(margin);
    let split = SplitSettings {
        half: sc.usable_half_field,
        travel: (machine.stage.travel_x, machine.stage.travel_y),
        burst: stage_limits.scaled(machine.motion.stage_share),
    };
    let Some(first) = sequence.paths().next().map(|p| p.start()) else {
        let start_state = AxisState { stage: start, scanner: Point::origin() };
        return Ok(Trajectory { tcp: TcpPath::default(), stage: StagePath::FollowsTcp, start: start_state, job_start: 0.0, has_scanner: true, stage_flow: None, head: None });
    };
    let groups = sequence.groups.len();
    // Field changes where the stage carries the TCP (no burst fits there).
    let mut carried: Vec<bool> = vec![false; groups];
    let mut at: Option<Vec<Point>> = None;
    let mut cache = tcp::PlanCache::default();
    let mut runs: Option<Vec<Option<Run>>> = None;
    loop {
        let mut b = TcpBuilder::new(settings, first, 0.0).with_cache(std::mem::take(&mut cache));
        let positions = at.clone();
        mark_all(&mut b, job, sequence, machine, Some(&mut runs), |b, g| {
            if let (true, Some(at)) = (carried[g], positions.as_ref()) {
                let prev = (0..g).rev().find(|&k| !sequence.groups[k].paths.is_empty()).expect("a field change has a field before");
                b.stop(g)?;
                let to = b.position + (at[g] - at[prev]);
                b.straight(PieceKind::Carried, g, to, stage_limits)?;
            }
            Ok(())
        })?;
        cache = b.take_cache();
        let tcp = b.path;
        let positions = match &at {
            Some(p) => p.clone(),
            None => {
                let p = stage::stage_positions(&tcp, groups, start, &split)?;
                at = Some(p.clone());
                p
            }
        };
        match stage::split(&tcp, &positions, &split)? {
            Ok(stage_path) => {
                let slowed = carried.iter().filter(|&&c| c).count();
                let mut bursts = with_approach(tcp, stage_path, positions[0], start, first, stage_limits, settings)?;
                bursts.stage_flow = flow_share(sequence, slowed);
                if slowed == 0 {
                    return Ok(bursts);
                }
                // Bursts alone carry the TCP somewhere: the stage planned over
                // the whole job may flow there; the faster of the two.
                // The flowing stage may use all of its limits: the TCP leaves
                // the scanner what that needs (so its marks and moves are
                // planned anew).
                let flow_split = SplitSettings { burst: stage_limits.scaled(FLOW_SHARE), ..split };
                let flow_settings = tcp_settings_against(machine, Mode::OnTheFly, FLOW_SHARE);
                return Ok(match flowing(job, sequence, machine, start, first, &flow_split, flow_settings, planner)? {
                    Some(flow) if flow.job_time() < bursts.job_time() => flow,
                    _ => bursts,
                });
            }
            Err(stage::NoSplit(into)) => {
                for g in into {
                    if carried[g] {
                        return Err(Error::Motion(format!("internal: the change into field {} failed although carried", g + 1)));
                    }
                    tracing::debug!(field = g + 1, "no on-the-fly split at this field change: the stage carries the TCP");
                    carried[g] = true;
                }
            }
        }
    }
}

/// Share of the stage's limits (within the margin) the flowing stage uses.
/// The bursts keep `motion.stage_share` as headroom for the rounding of
/// short blocks (at share 1 their programs reached 0.987 of the stage's
/// limits); the flow's program, from one smooth spline, needs far less
/// (≤ 0.983 on the four flowed jobs). SC82C24 at 0.8: 1.345 × the bound; at 1:
/// 1.189 (its scan fields far apart: the stage sets its time).
const FLOW_SHARE: f64 = 1.0;

/// Rounds of planning the flow, slowing where it falls behind, at most.
const FLOW_ROUNDS: usize = 24;
/// A field change where the stage falls behind by `d` mm takes
/// `SLOWING · d / V + SLOWING_FLOOR` longer (V: the stage's burst speed), the
/// first time; after that by a secant step (`flowing`). (0.8: SC82C24 5
/// rounds per build, 1.345 × the bound; 0.7 and 1.2 end in a failed solve
/// there, 0.9 and 1.0 take 4-6 rounds at 1.347-1.350.)
const SLOWING: f64 = 0.8;
const SLOWING_FLOOR: f64 = 2.0e-3;
/// A change whose shortfall kept more than this share after it was slowed
/// is not where the stage is short: its neighbours are slowed instead.
const STUCK: f64 = 0.8;
/// Where the flow's solve fails in a later round, the changes that round
/// slowed take this share of their extra time more (and so on while it
/// fails).
const RETRY_MORE: f64 = 0.5;

/// The share of `sequence`'s field changes not `slowed` (`None` without any).
fn flow_share(sequence: &Sequence, slowed: usize) -> Option<f64> {
    let changes = sequence.groups.iter().filter(|g| !g.paths.is_empty()).count().saturating_sub(1);
    (changes > 0).then(|| (changes - slowed.min(changes)) as f64 / changes as f64)
}

/// On the fly with the stage planned over the whole job (`flow`). Where the
/// stage falls behind, the field change there is slowed (the TCP stops and
/// jumps to the next field's first point time-scaled, taking longer by what
/// the stage is short of), and at the ends the TCP waits; all is planned
/// again (after a round whose solve fails: with that round's slowings
/// grown). `None` when that does not settle it. The marks' runs, corners
/// and moves are planned anew: the flow's TCP settings are not the bursts'.
#[allow(clippy::too_many_arguments)]
fn flowing(
    job: &Job,
    sequence: &Sequence,
    machine: &MachineConfig,
    start: Point,
    first: Point,
    split: &SplitSettings,
    settings: TcpSettings,
    planner: FlowPlanner,
) -> Result<Option<Trajectory>> {
    let (mut runs, mut cache): (Option<Vec<Option<Run>>>, tcp::PlanCache) = (None, tcp::PlanCache::default());
    let groups = sequence.groups.len();
    let first_group = sequence.groups.iter().position(|g| !g.paths.is_empty()).unwrap_or(0);
    let stage_limits = machine.stage_limits().scaled(machine.motion.limit_margin);
    let space = flow::Workspace::default();
    // The TCP with the jumps into the fields `slowed` taking that long, and
    // the flow for it (or where it falls behind). `None`: no flow for this job.
    let mut attempt = |slowed: &[Option<f64>], pads: (f64, f64)| -> Result<Option<(TcpPath, std::result::Result<flow::Flow, flow::NoFlow>)>> {
        let mut b = TcpBuilder::new(settings, first, 0.0).with_cache(std::mem::take(&mut cache));
        let marked = mark_all(&mut b, job, sequence, machine, Some(&mut runs), |b, g| {
            if let Some(took) = slowed[g] {
                let entry = sequence.groups[g].paths[0].start();
                b.jump_slowed(g, entry, took)?;
            }
            Ok(())
        });
        if let Err(e) = marked {
            tracing::debug!("no flowing stage: {e}");
            return Ok(None);
        }
        cache = b.take_cache();
        let tcp = b.path;
        if !stage::dwell_times(&tcp).is_empty() {
            // A pierce or cooling wait dwells (`G4`), which stops the stage: the flow does
            // not plan such stops, the bursts do.
            return Ok(None);
        }
        match planner(&tcp, split, pads, &space) {
            Err(flow::NoFlow::TooLong) => Ok(None),
            planned => Ok(Some((tcp, planned))),
        }
    };
    // Per field: how long the jump into it takes, where slowed; how far the
    // stage fell behind at the change into it last round, and how much longer
    // that change was made for it (then how much a second bought, below).
    let mut slowed: Vec<Option<f64>> = vec![None; groups];
    let mut short: Vec<Option<(f64, f64)>> = vec![None; groups];
    let mut pads = (0.0, 0.0);
    let burst_speed = split.burst.velocity;
    let longer = |mm: f64| SLOWING * mm / burst_speed + SLOWING_FLOOR;
    let next_field = |f: usize| (f + 1..groups).find(|&k| !sequence.groups[k].paths.is_empty());
    let mut found = None;
    // What the last round added: per change slowed, its extra time; pads.
    let (mut added, mut pads_added): (Vec<(usize, f64)>, (f64, f64)) = (Vec::new(), (0.0, 0.0));
    for round in 0..FLOW_ROUNDS {
        let Some((tcp, planned)) = attempt(&slowed, pads)? else { return Ok(None) };
        let behind = match planned {
            Ok(f) => {
                tracing::debug!(round, "the stage flows");
                found = Some((tcp, f));
                break;
            }
            Err(flow::NoFlow::Behind(behind)) => behind,
            Err(_) if added.is_empty() && pads_added == (0.0, 0.0) => return Ok(None),
            Err(_) => {
                // The solve failed (ill-conditioned, seen after some
                // slowings): the last round's slowings grow by half of what
                // it added, and all is planned again.
                tracing::debug!(round, "the flow's solve failed: the last slowings grow");
                for &(k, extra) in &added {
                    let more = RETRY_MORE * extra;
                    slowed[k] = slowed[k].map(|took| took + more);
                    if let Some((_, total)) = short[k].as_mut().filter(|s| s.1 > 0.0) {
                        *total += more;
                    }
                }
                pads = (pads.0 + RETRY_MORE * pads_added.0, pads.1 + RETRY_MORE * pads_added.1);
                continue;
            }
        };
        added.clear();
        pads_added = (0.0, 0.0);
        tracing::debug!(round, changes = behind.into.len(), worst = behind.into.iter().map(|x| x.2).fold(0.0, f64::max), "the stage falls behind");
        if behind.start > 0.0 {
            pads_added.0 = longer(behind.start);
        }
        if behind.end > 0.0 {
            pads_added.1 = longer(behind.end);
        }
        pads = (pads.0 + pads_added.0, pads.1 + pads_added.1);
        let mut now: Vec<Option<(f64, f64)>> = vec![None; groups];
        for (g, f, mm) in behind.into {
            // The jump into `g` takes longer: by the shortfall over what the
            // last slowing of it bought per second (a secant step), or at
            // first over the stage's speed. Where slowing it did not help,
            // both jumps next to the field where the stage is short.
            let stuck = short[g].is_some_and(|(before, _)| mm > STUCK * before);
            let rate = short[g].filter(|&(_, added)| added > 0.0).map(|(before, added)| ((before - mm) / added).min(burst_speed));
            let extra = match rate {
                Some(rate) if !stuck => mm / rate + SLOWING_FLOOR,
                _ => longer(mm),
            };
            let around = [Some(f).filter(|&f| f > first_group), next_field(f)];
            let changes = if stuck { around } else { [Some(g), None] };
            now[g] = Some((mm, if stuck { 0.0 } else { extra }));
            for k in changes.into_iter().flatten() {
                let Some(took) = slowed[k].or_else(|| field_change(&tcp, k)) else { continue };
                tracing::debug!(field = k + 1, mm, took, extra, "the stage cannot flow into this field: the TCP slows for it");
                slowed[k] = Some(took + extra);
                added.push((k, extra));
            }
        }
        short = now;
    }
    let Some((tcp, f)) = found else { return Ok(None) };
    let stage_flow = flow_share(sequence, slowed.iter().filter(|s| s.is_some()).count());
    Ok(Some(with_flow(tcp, f, start, first, first_group, groups, stage_limits, settings, stage_flow)?))
}

/// An on-the-fly trajectory: the approach, then the TCP with the flowing
/// stage, the TCP waiting at its ends for the stage where it needs longer.
#[allow(clippy::too_many_arguments)]
fn with_flow(tcp: TcpPath, f: flow::Flow, start: Point, first: Point, first_group: usize, groups: usize, stage_limits: Limits, settings: TcpSettings, stage_flow: Option<f64>) -> Result<Trajectory> {
    let stage0 = f.start_point();
    let (mut all, approach, job_start) = approach(start, stage0, first, stage_limits, settings)?;
    // Where the stage starts before the TCP, the TCP waits for it at its
    // first point (in the job's time).
    let approach_end = approach.iter().flatten().map(stage::AxisMove::end_time).fold(0.0, f64::max);
    let wait = (approach_end - job_start - f.first_motion()).max(0.0);
    if wait > 0.0 {
        let mut b = TcpBuilder::new(settings, first, job_start);
        b.still(PieceKind::Jump, first_group, wait);
        all.append(&mut b.path.pieces);
    }
    let (mut tcp, mut f) = (tcp, f);
    tcp.shift(job_start + wait);
    f.shift(job_start + wait);
    let tcp_end = tcp.duration();
    all.append(&mut tcp.pieces);
    // And where the stage settles after the TCP's end, the TCP waits at its
    // last point, so that the program runs it.
    if f.end_time() > tcp_end {
        let last = all.last().map_or(first, |p| p.end_point());
        let mut b = TcpBuilder::new(settings, last, tcp_end);
        b.still(PieceKind::Jump, groups.saturating_sub(1), f.end_time() - tcp_end);
        all.append(&mut b.path.pieces);
    }
    let start_state = AxisState { stage: start, scanner: Point::origin() };
    let stage = StagePath::Flow { start, approach, flow: f };
    Ok(Trajectory { tcp: TcpPath::new(all), stage, start: start_state, job_start, has_scanner: true, stage_flow, head: None })
}

/// How long the change into field `g` of `tcp` takes: from the last mark
/// before it to its first mark.
fn field_change(tcp: &TcpPath, g: usize) -> Option<f64> {
    let first = tcp.pieces.iter().position(|p| p.group == g && p.is_marking())?;
    let before = tcp.pieces[..first].iter().rposition(|p| p.is_marking())?;
    Some(tcp.pieces[first].start - tcp.pieces[before].end_time())
}

/// The approach of an on-the-fly job: the stage carries the centred scanner
/// from `start` to `stage0`, then the scanner jumps to the first point. Its
/// TCP pieces, stage moves, and when it ends.
fn approach(start: Point, stage0: Point, first: Point, stage_limits: Limits, settings: TcpSettings) -> Result<(Vec<tcp::Piece>, [Vec<stage::AxisMove>; 2], f64)> {
    let mut b = TcpBuilder::new(settings, start, 0.0);
    b.straight(PieceKind::Approach, 0, stage0, stage_limits)?;
    let mut axes: [Vec<stage::AxisMove>; 2] = [Vec::new(), Vec::new()];
    if let Some(piece) = b.path.pieces.last() {
        stage::carried_moves(piece, &mut axes, start);
    }
    b.jump(PieceKind::Approach, 0, first, nalgebra::Vector2::zeros())?;
    Ok((b.path.pieces, axes, b.time))
}

/// Puts the approach in front of an on-the-fly job; the job's pieces and
/// stage moves follow.
fn with_approach(mut tcp: TcpPath, mut stage_path: StagePath, stage0: Point, start: Point, first: Point, stage_limits: Limits, settings: TcpSettings) -> Result<Trajectory> {
    let (mut pieces, mut axes, job_start) = approach(start, stage0, first, stage_limits, settings)?;
    tcp.shift(job_start);
    stage_path.shift(job_start);
    pieces.append(&mut tcp.pieces);
    if let StagePath::Moves { axes: job_axes, .. } = stage_path {
        for (a, mut moves) in axes.iter_mut().zip(job_axes) {
            a.append(&mut moves);
        }
    }
    let start_state = AxisState { stage: start, scanner: Point::origin() };
    Ok(Trajectory { tcp: TcpPath::new(pieces), stage: StagePath::Moves { start, axes }, start: start_state, job_start, has_scanner: true, stage_flow: None, head: None })
}

/// The contract's `lower_bound_s` for this sequence: max(T_proc, T_stage).
/// T_proc = marking at full mark speed plus every jump as a time-optimal move with
/// the combined limits of stage and scanner, plus every pierce: the tool centre
/// point must stand still over a path's entry with the laser on for its layer's
/// pierce time whatever the machine, so no schedule avoids that time (while it
/// pierces it neither marks nor jumps). T_stage = the stage's time-optimal move
/// over what the job extends beyond one usable field, per axis.
pub fn lower_bound(job: &Job, sequence: &Sequence, machine: &MachineConfig, mode: Mode) -> Result<f64> {
    let stage = machine.stage_limits();
    let scanner = machine.scanner_limits().filter(|_| mode != Mode::StageOnly);
    let combined = match scanner {
        Some(s) => Limits { velocity: stage.velocity + s.velocity, acceleration: stage.acceleration + s.acceleration, jerk: stage.jerk + s.jerk },
        None => stage,
    };
    let mark_speed_cap = match (&machine.scanner, scanner) {
        (Some(sc), Some(_)) => sc.mark_speed,
        _ => stage.velocity,
    };
    let mut t_proc = 0.0;
    let mut last: Option<Point> = None;
    for path in sequence.paths() {
        let speed = job.processes[path.process].speed.min(mark_speed_cap);
        let length: f64 = path.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        t_proc += length / speed;
        if path.pierce {
            t_proc += machine.pierce(&job.processes[path.process].layer).time;
        }
        t_proc += path.cooling_wait;
        if let Some(l) = last {
            t_proc += rest_to_rest_time((path.start() - l).norm(), combined)?;
        }
        last = Some(path.end());
    }
    let usable = scanner.and(machine.scanner.as_ref()).map(|s| 2.0 * s.usable_half_field).unwrap_or(0.0);
    let (lo, hi) = job.bounds();
    let mut t_stage: f64 = 0.0;
    for extent in [hi.x - lo.x, hi.y - lo.y] {
        t_stage = t_stage.max(rest_to_rest_time((extent - usable).max(0.0), stage)?);
    }
    Ok(t_proc.max(t_stage))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Geometry, Process};
    use crate::plan::{nearest::NearestNeighbour, PlanContext, Planner};

    fn job() -> Job {
        let sq = |x: f64, y: f64| Geometry { arcs: Vec::new(), profile: Vec::new(),
            points: vec![Point::new(x, y), Point::new(x + 5.0, y), Point::new(x + 5.0, y + 5.0), Point::new(x, y + 5.0)],
            closed: true,
            process: 0,
            source: format!("sq {x},{y}"),
        };
        Job {
            source: "t".into(),
            geometries: vec![sq(20.0, 20.0), sq(200.0, 150.0), sq(30.0, 25.0), sq(150.0, 160.0), sq(60.0, 40.0)],
            processes: vec![Process { layer: "mark".into(), speed: 800.0, power: 200.0, passes: 1, fill: false }],
        }
    }

    fn plan(j: &Job, machine: &MachineConfig, mode: Mode) -> (Sequence, Trajectory) {
        let planning = mode.planning_machine(machine);
        let ctx = PlanContext { machine: &planning, mode, start: Point::origin(), plate: None };
        let seq = NearestNeighbour.plan(j, &ctx).unwrap();
        let tr = build(j, &seq, machine, mode, Point::origin()).unwrap();
        (seq, tr)
    }

    /// Samples the trajectory every `dt`: positions continuous, scanner in its
    /// field, stage in its travel, and per-axis velocity and acceleration (as
    /// differences) within the limits. Returns the largest stage speed seen
    /// during marking pieces.
    fn check_sampled(tr: &Trajectory, machine: &MachineConfig, dt: f64) -> f64 {
        let n = (tr.duration() / dt).ceil() as usize;
        let half = machine.scanner.as_ref().map(|s| s.usable_half_field);
        let stage = machine.stage_limits();
        let scanner = machine.scanner_limits();
        let mut prev: Option<AxisState> = None;
        let mut prev_v: Option<(nalgebra::Vector2<f64>, nalgebra::Vector2<f64>)> = None;
        let mut stage_speed_marking: f64 = 0.0;
        for k in 0..=n {
            let t = k as f64 * dt;
            let s = tr.state_at(t);
            if let Some(h) = half.filter(|_| tr.has_scanner) {
                assert!(s.scanner.x.abs() <= h + 1e-6 && s.scanner.y.abs() <= h + 1e-6, "t={t}: scanner {:?}", s.scanner);
            }
            assert!(s.stage.x >= -1e-6 && s.stage.y >= -1e-6 && s.stage.x <= machine.stage.travel_x + 1e-6, "t={t}: stage {:?}", s.stage);
            if let Some(p) = prev {
                let vs = (s.stage - p.stage) / dt;
                let vc = (s.scanner - p.scanner) / dt;
                assert!(vs.x.abs() <= stage.velocity * 1.001 && vs.y.abs() <= stage.velocity * 1.001, "t={t}: stage v {vs:?}");
                if let Some(l) = scanner {
                    assert!(vc.x.abs() <= l.velocity * 1.001 && vc.y.abs() <= l.velocity * 1.001, "t={t}: scanner v {vc:?}");
                }
                if let Some((pvs, pvc)) = prev_v {
                    let (a_s, a_c) = ((vs - pvs) / dt, (vc - pvc) / dt);
                    assert!(a_s.x.abs() <= stage.acceleration * 1.02 && a_s.y.abs() <= stage.acceleration * 1.02, "t={t}: stage a {a_s:?}");
                    if let Some(l) = scanner {
                        assert!(a_c.x.abs() <= l.acceleration * 1.02 && a_c.y.abs() <= l.acceleration * 1.02, "t={t}: scanner a {a_c:?}");
                    }
                }
                if tr.tcp.pieces[tr.tcp.index_at(t)].is_marking() && tr.has_scanner {
                    stage_speed_marking = stage_speed_marking.max(vs.norm());
                }
                prev_v = Some((vs, vc));
            }
            prev = Some(s);
        }
        stage_speed_marking
    }

    /// Time the laser is on along marks: each mark's length at its speed at least.
    fn marked_time(tr: &Trajectory) -> f64 {
        let mut spans: Vec<(f64, f64)> = tr.tcp.pieces.iter().filter(|p| p.is_marking()).map(|p| (p.start, p.end_time())).collect();
        spans.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut total = 0.0;
        let mut until = f64::NEG_INFINITY;
        for (a, b) in spans {
            total += (b - until.max(a)).max(0.0);
            until = until.max(b);
        }
        total
    }

    #[test]
    fn step_and_scan_marks_with_the_stage_standing_still() {
        let machine = MachineConfig::load(None).unwrap();
        let j = job();
        let (seq, tr) = plan(&j, &machine, Mode::StepAndScan);
        assert!(seq.scan_fields().unwrap() >= 2);
        let dt = 2e-5;
        let stage_speed = check_sampled(&tr, &machine, dt);
        assert!(stage_speed < 1e-6, "the stage stands still while the scanner marks: {stage_speed}");
        // The approach ends at the first geometry's start, at rest.
        let first = seq.paths().next().unwrap().start();
        assert!((tr.state_at(tr.job_start).tcp() - first).norm() < 1e-9);
        let marked: f64 = tr.tcp.pieces.iter().filter(|p| p.is_marking()).map(|p| (p.end_point() - p.start_point()).norm()).sum();
        assert!((marked - j.mark_length()).abs() < 1e-6, "{marked} vs {}", j.mark_length());
        let lb = lower_bound(&j, &seq, &machine, Mode::StepAndScan).unwrap();
        assert!(lb > 0.0 && lb <= tr.job_time(), "lower bound {lb} vs {}", tr.job_time());
    }

    /// A row of nested squares 200 mm long: several fields side by side,
    /// more marking than the stage needs to cross them.
    fn row_job() -> Job {
        let mut j = job();
        j.geometries = (0..11)
            .flat_map(|k| {
                (0..8).map(move |n| {
                    let (x, y) = (10.0 + 20.0 * k as f64 + 0.25 * n as f64, 100.0 + 3.0 * (k % 3) as f64 + 0.25 * n as f64);
                    let a = 5.0 - 0.5 * n as f64;
                    Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(x, y), Point::new(x + a, y), Point::new(x + a, y + a), Point::new(x, y + a)], closed: true, process: 0, source: format!("sq {k}.{n}") }
                })
            })
            .collect();
        j
    }

    #[test]
    fn on_the_fly_moves_the_stage_while_marking_and_comes_close_to_the_bound() {
        let machine = MachineConfig::load(None).unwrap();
        let j = row_job();
        let (seq, tr) = plan(&j, &machine, Mode::OnTheFly);
        let stage_speed = check_sampled(&tr, &machine, 2e-5);
        assert!(stage_speed > 10.0, "the stage moves while the scanner marks: {stage_speed}");
        // Every mark at its layer speed: the laser is on for at least length / speed.
        assert!(marked_time(&tr) >= j.mark_length() / 800.0 - 1e-9);
        let (_, step) = plan(&j, &machine, Mode::StepAndScan);
        let lb = lower_bound(&j, &seq, &machine, Mode::OnTheFly).unwrap();
        assert!(tr.job_time() < step.job_time(), "{} vs step-and-scan {}", tr.job_time(), step.job_time());
        assert!(tr.job_time() <= 1.15 * lb, "{} vs bound {lb}", tr.job_time());
    }

    /// Small squares in fields 120 mm apart, zig-zagging over the table:
    /// bursts alone carry the TCP at nearly every change.
    fn far_apart() -> Job {
        let mut j = job();
        j.geometries = (0..8)
            .map(|k| {
                let (x, y) = (20.0 + 30.0 * k as f64, if k % 2 == 0 { 30.0 } else { 150.0 });
                Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(x, y), Point::new(x + 4.0, y), Point::new(x + 4.0, y + 4.0), Point::new(x, y + 4.0)], closed: true, process: 0, source: format!("sq {k}") }
            })
            .collect();
        j
    }

    #[test]
    fn on_the_fly_the_stage_flows_through_fields_far_apart_within_its_limits() {
        let machine = MachineConfig::load(None).unwrap();
        let j = far_apart();
        let (seq, tr) = plan(&j, &machine, Mode::OnTheFly);
        assert!(matches!(tr.stage, StagePath::Flow { .. }), "the flowing stage is the faster here");
        let flow = tr.stage_flow.expect("field changes on the fly");
        assert!((0.0..=1.0).contains(&flow), "{flow}");
        check_sampled(&tr, &machine, 2e-5);
        assert!(marked_time(&tr) >= j.mark_length() / 800.0 - 1e-9);
        let lb = lower_bound(&j, &seq, &machine, Mode::OnTheFly).unwrap();
        assert!(lb <= tr.job_time(), "{lb} vs {}", tr.job_time());
        // The stage's fastest axis while the scanner marks (the flow's time,
        // after the approach): beyond the share the bursts keep as headroom
        // (the flow uses all of the stage's limits, checked above).
        let (dt, mut fastest) = (1e-4, 0.0f64);
        for k in 1..(tr.duration() / dt) as usize {
            let t = k as f64 * dt;
            if tr.tcp.pieces[tr.tcp.index_at(t)].is_marking() {
                let v = (tr.state_at(t).stage - tr.state_at(t - dt).stage) / dt;
                fastest = fastest.max(v.x.abs()).max(v.y.abs());
            }
        }
        let bursts = machine.stage_limits().scaled(machine.motion.limit_margin * machine.motion.stage_share).velocity;
        assert!(fastest > 1.05 * bursts, "the stage at most {fastest} mm/s while marking, the bursts' share {bursts}");
    }

    #[test]
    fn a_round_whose_flow_solve_fails_is_planned_again_with_more_slowing() {
        let machine = MachineConfig::load(None).unwrap();
        let j = far_apart();
        let (seq, _) = plan(&j, &machine, Mode::OnTheFly);
        // (the stage flows here: the test above) The second round's solve
        // fails (as an ill-conditioned one may): the round is planned again
        // with its slowings grown, and the stage still flows, within its
        // limits.
        let calls = std::cell::Cell::new(0);
        let failing = |tcp: &TcpPath, split: &SplitSettings, pads: (f64, f64), space: &flow::Workspace| {
            calls.set(calls.get() + 1);
            if calls.get() == 2 {
                return Err(flow::NoFlow::Unsolved);
            }
            flow::plan(tcp, split, pads, space)
        };
        let tr = on_the_fly(&j, &seq, &machine, Point::origin(), &failing).unwrap();
        assert!(calls.get() > 2, "rounds after the failed one: {}", calls.get());
        assert!(matches!(tr.stage, StagePath::Flow { .. }), "a failed round gives up the flow");
        check_sampled(&tr, &machine, 2e-5);
        assert!(marked_time(&tr) >= j.mark_length() / 800.0 - 1e-9);
        // Failing in the first round (nothing slowed yet to grow): no flow.
        let first_fails = |_: &TcpPath, _: &SplitSettings, _: (f64, f64), _: &flow::Workspace| Err(flow::NoFlow::Unsolved);
        let tr = on_the_fly(&j, &seq, &machine, Point::origin(), &first_fails).unwrap();
        assert!(matches!(tr.stage, StagePath::Moves { .. }), "bursts");
    }

    /// The default machine with a pierce on the `mark` layer.
    fn piercing(mut machine: MachineConfig, time: f64, power: f64) -> MachineConfig {
        let mark = machine.layers.iter_mut().find(|l| l.name == "mark").unwrap();
        mark.pierce_time = Some(time);
        mark.pierce_power = Some(power);
        machine
    }

    #[test]
    fn every_path_starts_with_a_pierce_standing_still_at_its_entry() {
        for mode in [Mode::StepAndScan, Mode::StageOnly, Mode::OnTheFly] {
            let mut plain = MachineConfig::load(None).unwrap();
            if mode == Mode::StageOnly {
                plain.scanner = None;
            }
            let machine = piercing(plain.clone(), 0.2, 700.0);
            let j = job();
            let (seq, tr) = plan(&j, &machine, mode);
            let paths: Vec<_> = seq.paths().collect();
            let pierces: Vec<(usize, &tcp::Piece)> = tr.tcp.pieces.iter().enumerate().filter(|(_, p)| matches!(p.kind, PieceKind::Pierce { .. })).collect();
            assert_eq!(pierces.len(), paths.len(), "{mode:?}: one pierce per path");
            for ((i, p), path) in pierces.iter().zip(&paths) {
                assert_eq!(p.kind, PieceKind::Pierce { geometry: path.geometry, power: 700.0 });
                assert!((p.duration - 0.2).abs() < 1e-12);
                // Standing still over the path's start, then marking from there.
                assert_eq!(tr.tcp.position(p.start + 0.01), tr.tcp.position(p.start + 0.19));
                assert!((tr.tcp.position(p.start + 0.1) - path.start()).norm() < 1e-9, "{mode:?}");
                let next = &tr.tcp.pieces[i + 1];
                assert!(next.is_marking() && (next.start - p.end_time()).abs() < 1e-12, "{mode:?}: {next:?}");
                // The program dwells there (G4), which stops every axis: the
                // stage stands still too.
                if mode != Mode::StageOnly {
                    assert!((0..=20).all(|k| !tr.stage.moving(p.start + p.duration * k as f64 / 20.0)), "{mode:?}: the stage moves during the pierce at {}", p.start);
                }
            }
            check_sampled(&tr, &machine, 5e-5);
            let lb = lower_bound(&j, &seq, &machine, mode).unwrap();
            let lb_plain = lower_bound(&j, &seq, &plain, mode).unwrap();
            // T_proc holds every pierce: the bound grows and stays a bound.
            assert!(lb > lb_plain && lb >= 0.2 * paths.len() as f64, "{mode:?}: {lb} vs {lb_plain}");
            assert!(lb <= tr.job_time(), "{mode:?}: {lb} vs {}", tr.job_time());
        }
        // On the fly with fields side by side: the stage's moves from field
        // to field keep clear of the pierces.
        let machine = piercing(MachineConfig::load(None).unwrap(), 0.05, 700.0);
        let (_, tr) = plan(&row_job(), &machine, Mode::OnTheFly);
        assert!(tr.stage_flow.is_some(), "field changes on the fly");
        for p in tr.tcp.pieces.iter().filter(|p| matches!(p.kind, PieceKind::Pierce { .. })) {
            assert!((0..=20).all(|k| !tr.stage.moving(p.start + p.duration * k as f64 / 20.0)), "the stage moves during the pierce at {}", p.start);
        }
        check_sampled(&tr, &machine, 5e-5);
        // No pierce time, no pierce pieces.
        let machine = piercing(MachineConfig::load(None).unwrap(), 0.0, 700.0);
        let (_, tr) = plan(&job(), &machine, Mode::StepAndScan);
        assert!(!tr.tcp.pieces.iter().any(|p| matches!(p.kind, PieceKind::Pierce { .. })));
    }

    /// A stage-only trajectory of `paths` marked in this order (no scanner).
    fn stage_only_in_order(paths: &[Vec<Point>], machine: &MachineConfig) -> Trajectory {
        let mut j = job();
        j.geometries = paths.iter().enumerate().map(|(k, p)| Geometry { arcs: Vec::new(), profile: Vec::new(), points: p.clone(), closed: false, process: 0, source: format!("path {k}") }).collect();
        let paths = paths.iter().enumerate().map(|(k, p)| crate::plan::PlannedPath::new(k, p.clone(), 0, true)).collect();
        let seq = Sequence { groups: vec![crate::plan::PathGroup { field_center: None, paths }] };
        build(&j, &seq, machine, Mode::StageOnly, Point::origin()).unwrap()
    }

    #[test]
    fn runs_planned_a_few_at_a_time_give_the_trajectory_planned_all_at_once() {
        let mut plain = MachineConfig::load(None).unwrap();
        plain.scanner = None;
        // Dashes along lines and a pierced square: runs at speed, junctions,
        // rests; every chunk edge falls between two of them.
        let mut paths: Vec<Vec<Point>> = (0..9).map(|k| {
            let (x, y) = (20.0 + 15.0 * (k % 3) as f64, 50.0 + 7.0 * (k / 3) as f64);
            vec![Point::new(x, y), Point::new(x + 10.0, y)]
        }).collect();
        paths.push(vec![Point::new(80.0, 80.0), Point::new(90.0, 80.0), Point::new(90.0, 90.0), Point::new(80.0, 90.0), Point::new(80.0, 80.0)]);
        for machine in [plain.clone(), piercing(plain, 0.05, 700.0)] {
            let mut j = job();
            j.geometries = paths.iter().enumerate().map(|(k, p)| Geometry { arcs: Vec::new(), profile: Vec::new(), points: p.clone(), closed: false, process: 0, source: format!("path {k}") }).collect();
            let planned = paths.iter().enumerate().map(|(k, p)| crate::plan::PlannedPath::new(k, p.clone(), 0, true)).collect();
            let seq = Sequence { groups: vec![crate::plan::PathGroup { field_center: None, paths: planned }] };
            let marked = |chunk: usize| {
                let mut b = TcpBuilder::new(tcp_settings(&machine, Mode::StageOnly), Point::origin(), 0.0);
                b.hand_over = true;
                mark_all_in_chunks(&mut b, &j, &seq, &machine, None, |_, _| Ok(()), chunk).unwrap();
                b.path.pieces.iter().map(|p| (format!("{:?}", p.kind), p.start, p.duration, p.position(0.0), p.position(p.duration))).collect::<Vec<_>>()
            };
            let whole = marked(usize::MAX);
            assert!(whole.len() > 2 * paths.len(), "{} pieces", whole.len());
            for chunk in [1, 2, 5] {
                assert_eq!(marked(chunk), whole, "runs of {chunk} points at a time");
            }
        }
    }

    fn speed_at(tr: &Trajectory, t: f64) -> f64 {
        (tr.tcp.position(t + 1e-6) - tr.tcp.position(t - 1e-6)).norm() / 2e-6
    }

    #[test]
    fn stage_only_runs_laser_off_moves_into_marks_without_a_pierce_at_speed() {
        let mut plain = MachineConfig::load(None).unwrap();
        plain.scanner = None;
        // Dashes along a line: Grbl's junction rule takes each G0-G1 corner
        // (here none) at speed, and so does laserd without a pierce.
        let dashes: Vec<Vec<Point>> = (0..6).map(|k| {
            let x = 20.0 + 15.0 * k as f64;
            vec![Point::new(x, 50.0), Point::new(x + 10.0, 50.0)]
        }).collect();
        let tr = stage_only_in_order(&dashes, &plain);
        check_sampled(&tr, &plain, 1e-4);
        let marks: Vec<_> = tr.tcp.pieces.iter().filter(|p| p.is_marking()).collect();
        assert_eq!(marks.len(), dashes.len());
        for (m, dash) in marks.iter().zip(&dashes) {
            // The laser is on exactly along the dash.
            assert!((m.start_point() - dash[0]).norm() < 1e-9 && (m.end_point() - dash[1]).norm() < 1e-9, "{m:?}");
        }
        for m in &marks[1..] {
            assert!(speed_at(&tr, m.start) > 100.0, "entered at {} mm/s", speed_at(&tr, m.start));
        }
        for m in &marks[..marks.len() - 1] {
            assert!(speed_at(&tr, m.end_time()) > 100.0, "left at {} mm/s", speed_at(&tr, m.end_time()));
        }
        // A pierce still stands still: entered and left at rest.
        let pierced = piercing(plain, 0.05, 700.0);
        let tr = stage_only_in_order(&dashes, &pierced);
        for p in tr.tcp.pieces.iter().filter(|p| matches!(p.kind, PieceKind::Pierce { .. })) {
            assert!(speed_at(&tr, p.start) < 1e-6 && speed_at(&tr, p.end_time()) < 1e-6);
        }
    }

    #[test]
    fn a_raster_line_cut_where_its_power_changes_runs_through_at_speed_with_each_pieces_power() {
        let mut plain = MachineConfig::load(None).unwrap();
        plain.scanner = None;
        let mut j = job();
        let line: Vec<Point> = (0..=6).map(|k| Point::new(20.0 + 5.0 * k as f64, 50.0)).collect();
        j.geometries = vec![Geometry { arcs: Vec::new(), profile: vec![0, 1, 1, 2, 0, 1], points: line.clone(), closed: false, process: 0, source: "t.nc:3".into() }];
        let power = |p: f64| crate::job::Process { power: p, ..j.processes[0].clone() };
        j.processes = vec![power(100.0), power(200.0), power(300.0)];
        let path = crate::plan::PlannedPath::new(0, line.clone(), 0, true);
        let seq = crate::plan::split_profiles(Sequence { groups: vec![crate::plan::PathGroup { field_center: None, paths: vec![path] }] }, &j);
        assert_eq!(seq.paths().count(), 5);
        let tr = build(&j, &seq, &plain, Mode::StageOnly, Point::origin()).unwrap();
        check_sampled(&tr, &plain, 1e-4);
        let marks: Vec<_> = tr.tcp.pieces.iter().filter(|p| p.is_marking()).collect();
        let powers: Vec<f64> = marks.iter().map(|m| m.power()).collect();
        assert_eq!(powers, vec![100.0, 200.0, 300.0, 100.0, 200.0], "a leg per piece (straight on inside one), each with its power");
        let ends = [20.0, 25.0, 35.0, 40.0, 45.0, 50.0];
        for (m, w) in marks.iter().zip(ends.windows(2)) {
            assert!((m.start_point().x - w[0]).abs() < 1e-9 && (m.end_point().x - w[1]).abs() < 1e-9, "{m:?}");
        }
        // Through every change of power as through none: one run, no stop.
        let whole = stage_only_in_order(std::slice::from_ref(&line), &plain);
        // (Each leg's ramp starts and ends without acceleration: a little
        // slower than one leg where the line is still speeding up.)
        assert!(tr.job_time() < 1.2 * whole.job_time(), "{} s, the line in one power {} s", tr.job_time(), whole.job_time());
        for m in &marks[1..] {
            let v = speed_at(&tr, m.start);
            assert!(v > 0.5 * speed_at(&whole, m.start), "{v} mm/s at x = {}, in one power {}", m.start_point().x, speed_at(&whole, m.start));
        }
    }

    #[test]
    fn a_stage_only_mark_ending_at_the_travel_edge_is_left_within_the_travel() {
        let mut machine = MachineConfig::load(None).unwrap();
        machine.scanner = None;
        // The first mark ends on the table's edge moving towards it, the next
        // starts beside it: a laser-off move leaving at speed would swing
        // past the edge.
        let paths = vec![vec![Point::new(30.0, 50.0), Point::new(0.0, 50.0)], vec![Point::new(0.0, 53.0), Point::new(30.0, 53.0)]];
        let tr = stage_only_in_order(&paths, &machine);
        check_sampled(&tr, &machine, 2e-5);
    }

    #[test]
    fn near_the_travel_edge_only_the_marks_there_stop() {
        let mut machine = MachineConfig::load(None).unwrap();
        machine.scanner = None;
        // The two marks at the edge of the test above, then dashes away from it.
        let mut paths = vec![vec![Point::new(30.0, 50.0), Point::new(0.0, 50.0)], vec![Point::new(0.0, 53.0), Point::new(30.0, 53.0)]];
        paths.extend((0..4).map(|k| {
            let x = 40.0 + 15.0 * k as f64;
            vec![Point::new(x, 53.0), Point::new(x + 10.0, 53.0)]
        }));
        let tr = stage_only_in_order(&paths, &machine);
        check_sampled(&tr, &machine, 2e-5);
        let marks: Vec<_> = tr.tcp.pieces.iter().filter(|p| p.is_marking()).collect();
        assert_eq!(marks.len(), paths.len());
        assert!(speed_at(&tr, marks[0].end_time()) < 1e-6 && speed_at(&tr, marks[1].start) < 1e-6, "the move at the edge runs from rest to rest");
        for m in &marks[2..] {
            assert!(speed_at(&tr, m.start) > 100.0, "entered at {} mm/s", speed_at(&tr, m.start));
        }
    }

    #[test]
    fn stage_only_marks_at_the_layer_speed_and_bound_holds() {
        let mut machine = MachineConfig::load(None).unwrap();
        machine.scanner = None;
        let j = job();
        let (seq, tr) = plan(&j, &machine, Mode::StageOnly);
        check_sampled(&tr, &machine, 1e-4);
        assert!(marked_time(&tr) >= j.mark_length() / 500.0 - 1e-9, "at most the stage's speed");
        let lb = lower_bound(&j, &seq, &machine, Mode::StageOnly).unwrap();
        assert!(lb <= tr.job_time());
        assert!(Mode::StepAndScan.check(&machine).is_err() && Mode::OnTheFly.check(&machine).is_err());
        assert_eq!(Mode::default_for(&machine), Mode::StageOnly);
    }
}
