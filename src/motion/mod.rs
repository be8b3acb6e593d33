//! Motion: turns a `Sequence` into a time-parametrised, jerk-limited `Trajectory`
//! of the stage and scanner axes, inside every configured limit.
//!
//! Modes in this version:
//! - step-and-scan: the stage moves to each scan field and stops; the scanner
//!   jumps and marks inside the field while the stage stands still;
//! - stage-only: the stage does everything (machines without a scanner).
//!
//! Where a layer asks for a pierce (`pierce_time` > 0), every path starts with
//! one: after the jump to its start the machine stands still there with the
//! laser on at the pierce power for the pierce time (a `Pierce` segment, no
//! motion), then the marking moves begin.
//!
//! Every straight segment is a rest-to-rest move (see `profile`), so each axis
//! starts and ends every segment at rest: correct and inside the limits, though
//! slow at polyline corners on the stage. Corner blending and on-the-fly motion
//! come with the on-the-fly issue.

pub mod profile;

use std::str::FromStr;

use crate::config::{Limits, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{Job, Point};
use crate::plan::Sequence;
pub use profile::{rest_to_rest_time, Profile};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    OnTheFly,
    StepAndScan,
    StageOnly,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::OnTheFly => "on-the-fly",
            Mode::StepAndScan => "step-and-scan",
            Mode::StageOnly => "stage-only",
        }
    }

    /// The mode used when none is asked for. The contract's default for scanner
    /// machines is on-the-fly; until that exists, step-and-scan.
    pub fn default_for(machine: &MachineConfig) -> Mode {
        if machine.scanner.is_some() {
            Mode::StepAndScan
        } else {
            Mode::StageOnly
        }
    }

    /// Checks the mode against the machine.
    pub fn check(self, machine: &MachineConfig) -> Result<()> {
        match self {
            Mode::OnTheFly => Err(Error::Motion(
                "--mode on-the-fly is not available in this version (use step-and-scan or stage-only)".into(),
            )),
            Mode::StepAndScan if machine.scanner.is_none() => Err(Error::Motion(
                "--mode step-and-scan needs a [scanner] section in the config".into(),
            )),
            _ => Ok(()),
        }
    }
}

impl FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "on-the-fly" => Ok(Mode::OnTheFly),
            "step-and-scan" => Ok(Mode::StepAndScan),
            "stage-only" => Ok(Mode::StageOnly),
            _ => Err(format!("unknown mode '{s}' (on-the-fly, step-and-scan, stage-only)")),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SegmentKind {
    /// Laser on at `power` along a geometry.
    Mark { geometry: usize, power: f64 },
    /// Laser off, moving to the next geometry.
    Jump,
    /// Laser off, the stage moving to the next scan field.
    StageMove,
    /// Laser on at `power`, nothing moving: the pierce at the entry of a
    /// geometry, before it is marked.
    Pierce { geometry: usize, power: f64 },
}

/// Which axes move in a segment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisGroup {
    Stage,
    Scanner,
}

/// A straight move of one axis group; the other group stands still.
#[derive(Debug)]
pub struct Segment {
    pub kind: SegmentKind,
    pub group: AxisGroup,
    pub start_time: f64,
    pub stage: (Point, Point),
    pub scanner: (Point, Point),
    pub profile: Profile,
}

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

impl Segment {
    pub fn duration(&self) -> f64 {
        self.profile.duration
    }

    /// Axis positions `t` seconds into the segment.
    pub fn state_at(&self, t: f64) -> AxisState {
        let f = if self.profile.length > 0.0 { self.profile.position(t) / self.profile.length } else { 1.0 };
        let lerp = |(a, b): (Point, Point)| Point::from(a.coords + (b - a) * f);
        AxisState { stage: lerp(self.stage), scanner: lerp(self.scanner) }
    }

    pub fn is_marking(&self) -> bool {
        matches!(self.kind, SegmentKind::Mark { .. })
    }

    pub fn is_pierce(&self) -> bool {
        matches!(self.kind, SegmentKind::Pierce { .. })
    }
}

/// The planned motion of the whole job.
#[derive(Debug)]
pub struct Trajectory {
    pub segments: Vec<Segment>,
    pub start: AxisState,
    pub has_scanner: bool,
}

impl Trajectory {
    pub fn duration(&self) -> f64 {
        self.segments.last().map(|s| s.start_time + s.duration()).unwrap_or(0.0)
    }
}

/// Limits along a straight line in direction `d` from per-axis limits: the axis
/// with the largest share of the motion reaches its limit first.
fn path_limits(axis: Limits, d: nalgebra::Vector2<f64>) -> Limits {
    let share = d.x.abs().max(d.y.abs()) / d.norm();
    axis.scaled(1.0 / share)
}

struct Builder<'a> {
    machine: &'a MachineConfig,
    job: &'a Job,
    margin: f64,
    state: AxisState,
    time: f64,
    segments: Vec<Segment>,
}

impl Builder<'_> {
    fn push(&mut self, kind: SegmentKind, group: AxisGroup, to: Point, speed_cap: Option<f64>) -> Result<()> {
        let from = match group {
            AxisGroup::Stage => self.state.stage,
            AxisGroup::Scanner => self.state.scanner,
        };
        let d = to - from;
        let length = d.norm();
        if length < 1e-9 {
            return Ok(());
        }
        let axis = match group {
            AxisGroup::Stage => self.machine.stage_limits(),
            AxisGroup::Scanner => self.machine.scanner_limits().ok_or_else(|| Error::Motion("no scanner configured".into()))?,
        };
        let mut lim = path_limits(axis.scaled(self.margin), d);
        if let Some(cap) = speed_cap {
            lim.velocity = lim.velocity.min(cap);
        }
        let profile = Profile::rest_to_rest(length, lim)?;
        let (stage, scanner) = match group {
            AxisGroup::Stage => ((from, to), (self.state.scanner, self.state.scanner)),
            AxisGroup::Scanner => ((self.state.stage, self.state.stage), (from, to)),
        };
        let duration = profile.duration;
        self.segments.push(Segment { kind, group, start_time: self.time, stage, scanner, profile });
        self.time += duration;
        match group {
            AxisGroup::Stage => self.state.stage = to,
            AxisGroup::Scanner => self.state.scanner = to,
        }
        Ok(())
    }

    /// The pierce of `process`'s layer where the machine stands now, if it has one.
    fn pierce(&mut self, geometry: usize, process: usize, group: AxisGroup) -> Result<()> {
        let pierce = self.machine.pierce(&self.job.processes[process].layer);
        if !pierce.active() {
            return Ok(());
        }
        let (stage, scanner) = (self.state.stage, self.state.scanner);
        let profile = Profile::dwell(pierce.time)?;
        let kind = SegmentKind::Pierce { geometry, power: pierce.power };
        self.segments.push(Segment { kind, group, start_time: self.time, stage: (stage, stage), scanner: (scanner, scanner), profile });
        self.time += pierce.time;
        Ok(())
    }

    fn check_field(&self, p: Point, half: f64, source: &str) -> Result<()> {
        if p.x.abs() > half + 1e-9 || p.y.abs() > half + 1e-9 {
            return Err(Error::Motion(format!(
                "{source}: scanner position ({:.4}, {:.4}) outside the usable field ±{half} mm",
                p.x, p.y
            )));
        }
        Ok(())
    }

    fn check_travel(&self, p: Point, source: &str) -> Result<()> {
        let (tx, ty) = (self.machine.stage.travel_x, self.machine.stage.travel_y);
        if p.x < -1e-9 || p.y < -1e-9 || p.x > tx + 1e-9 || p.y > ty + 1e-9 {
            return Err(Error::Motion(format!(
                "{source}: stage position ({:.4}, {:.4}) outside the travel 0..{tx} x 0..{ty} mm",
                p.x, p.y
            )));
        }
        Ok(())
    }
}

/// Builds the trajectory of `sequence`, starting with the stage at `start` and the
/// scanner centred, and ending with the scanner centred again.
pub fn build(job: &Job, sequence: &Sequence, machine: &MachineConfig, mode: Mode, start: Point) -> Result<Trajectory> {
    mode.check(machine)?;
    let start_state = AxisState { stage: start, scanner: Point::origin() };
    let mut b = Builder { machine, job, margin: machine.motion.limit_margin, state: start_state, time: 0.0, segments: Vec::new() };
    match mode {
        Mode::StepAndScan => {
            let scanner = machine.scanner.as_ref().expect("checked by Mode::check");
            let half = scanner.usable_half_field;
            for group in &sequence.groups {
                let center = group
                    .field_center
                    .ok_or_else(|| Error::Motion("step-and-scan needs a plan with scan fields".into()))?;
                b.check_travel(center, "scan field")?;
                if (center - b.state.stage).norm() > 1e-9 {
                    // The scanner stays where it is; only the stage travels.
                    b.push(SegmentKind::StageMove, AxisGroup::Stage, center, None)?;
                }
                for path in &group.paths {
                    let source = &b.job.geometries[path.geometry].source;
                    let process = &b.job.processes[path.process];
                    let local: Vec<Point> = path.points.iter().map(|p| Point::from(p - center)).collect();
                    for p in &local {
                        b.check_field(*p, half, source)?;
                    }
                    b.push(SegmentKind::Jump, AxisGroup::Scanner, local[0], None)?;
                    b.pierce(path.geometry, path.process, AxisGroup::Scanner)?;
                    let cap = process.speed.min(scanner.mark_speed);
                    for p in &local[1..] {
                        let kind = SegmentKind::Mark { geometry: path.geometry, power: process.power };
                        b.push(kind, AxisGroup::Scanner, *p, Some(cap))?;
                    }
                }
            }
            b.push(SegmentKind::Jump, AxisGroup::Scanner, Point::origin(), None)?;
        }
        Mode::StageOnly => {
            for path in sequence.paths() {
                let source = &b.job.geometries[path.geometry].source;
                let process = &b.job.processes[path.process];
                for p in &path.points {
                    b.check_travel(*p, source)?;
                }
                b.push(SegmentKind::Jump, AxisGroup::Stage, path.points[0], None)?;
                b.pierce(path.geometry, path.process, AxisGroup::Stage)?;
                for p in &path.points[1..] {
                    let kind = SegmentKind::Mark { geometry: path.geometry, power: process.power };
                    b.push(kind, AxisGroup::Stage, *p, Some(process.speed))?;
                }
            }
        }
        Mode::OnTheFly => unreachable!("rejected by Mode::check"),
    }
    Ok(Trajectory { segments: b.segments, start: start_state, has_scanner: machine.scanner.is_some() })
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
        t_proc += machine.pierce(&job.processes[path.process].layer).time;
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
        let sq = |x: f64, y: f64| Geometry {
            points: vec![Point::new(x, y), Point::new(x + 5.0, y), Point::new(x + 5.0, y + 5.0), Point::new(x, y + 5.0)],
            closed: true,
            process: 0,
            source: format!("sq {x},{y}"),
        };
        Job {
            source: "t".into(),
            geometries: vec![sq(20.0, 20.0), sq(200.0, 150.0), sq(30.0, 25.0)],
            processes: vec![Process { layer: "mark".into(), speed: 800.0, power: 200.0, passes: 1 }],
        }
    }

    fn check_continuity(tr: &Trajectory) {
        let mut state = tr.start;
        let mut t = 0.0;
        for s in &tr.segments {
            assert!((s.start_time - t).abs() < 1e-9);
            assert!((s.state_at(0.0).tcp() - state.tcp()).norm() < 1e-9);
            state = s.state_at(s.duration());
            t += s.duration();
        }
        assert!((tr.duration() - t).abs() < 1e-9);
    }

    #[test]
    fn step_and_scan_moves_one_group_at_a_time_inside_the_field() {
        let machine = MachineConfig::load(None).unwrap();
        let j = job();
        let ctx = PlanContext { machine: &machine, mode: Mode::StepAndScan, start: Point::origin() };
        let seq = NearestNeighbour.plan(&j, &ctx).unwrap();
        let tr = build(&j, &seq, &machine, Mode::StepAndScan, Point::origin()).unwrap();
        check_continuity(&tr);
        let half = machine.scanner.as_ref().unwrap().usable_half_field;
        let marked: f64 = tr.segments.iter().filter(|s| s.is_marking()).map(|s| s.profile.length).sum();
        assert!((marked - j.mark_length()).abs() < 1e-9);
        for s in &tr.segments {
            match s.group {
                AxisGroup::Stage => assert_eq!(s.scanner.0, s.scanner.1),
                AxisGroup::Scanner => assert_eq!(s.stage.0, s.stage.1),
            }
            if s.is_marking() {
                assert_eq!(s.group, AxisGroup::Scanner);
            }
            for k in 0..=10 {
                let st = s.state_at(s.duration() * k as f64 / 10.0);
                assert!(st.scanner.x.abs() <= half + 1e-9 && st.scanner.y.abs() <= half + 1e-9);
            }
        }
        let last = tr.segments.last().unwrap();
        assert_eq!(last.state_at(last.duration()).scanner, Point::origin());
        let lb = lower_bound(&j, &seq, &machine, Mode::StepAndScan).unwrap();
        assert!(lb > 0.0 && lb <= tr.duration(), "lower bound {lb} vs {}", tr.duration());
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
        for mode in [Mode::StepAndScan, Mode::StageOnly] {
            let mut plain = MachineConfig::load(None).unwrap();
            if mode == Mode::StageOnly {
                plain.scanner = None;
            }
            let machine = piercing(plain.clone(), 0.2, 700.0);
            let j = job();
            let ctx = PlanContext { machine: &machine, mode, start: Point::origin() };
            let seq = NearestNeighbour.plan(&j, &ctx).unwrap();
            let without = build(&j, &seq, &plain, mode, Point::origin()).unwrap();
            let tr = build(&j, &seq, &machine, mode, Point::origin()).unwrap();
            check_continuity(&tr);
            let paths: Vec<_> = seq.paths().collect();
            let pierces: Vec<&Segment> = tr.segments.iter().filter(|s| s.is_pierce()).collect();
            assert_eq!(pierces.len(), paths.len(), "{mode:?}: one pierce per path");
            for (p, path) in pierces.iter().zip(&paths) {
                assert_eq!(p.kind, SegmentKind::Pierce { geometry: path.geometry, power: 700.0 });
                assert!((p.duration() - 0.2).abs() < 1e-12);
                // Standing still over the path's start.
                assert_eq!(p.state_at(0.0), p.state_at(0.2));
                assert!((p.state_at(0.1).tcp() - path.start()).norm() < 1e-9, "{mode:?}");
            }
            // Right after its pierce comes the path's first marking move, from there.
            for (i, s) in tr.segments.iter().enumerate().filter(|(_, s)| s.is_pierce()) {
                let next = &tr.segments[i + 1];
                assert!(next.is_marking(), "{mode:?}: {next:?}");
                assert!((next.state_at(0.0).tcp() - s.state_at(0.0).tcp()).norm() < 1e-12);
            }
            let grown = tr.duration() - without.duration();
            assert!((grown - 0.2 * paths.len() as f64).abs() < 1e-9, "{mode:?}: {grown}");
            let lb = lower_bound(&j, &seq, &machine, mode).unwrap();
            let lb_plain = lower_bound(&j, &seq, &plain, mode).unwrap();
            // T_proc holds every pierce: the bound grows, stays a bound, and
            // is at least the pierces themselves.
            assert!(lb > lb_plain && lb >= 0.2 * paths.len() as f64, "{mode:?}: {lb} vs {lb_plain}");
            assert!(lb <= tr.duration(), "{mode:?}: {lb} vs {}", tr.duration());
        }
        // No pierce time, no pierce segments.
        let machine = piercing(MachineConfig::load(None).unwrap(), 0.0, 700.0);
        let j = job();
        let ctx = PlanContext { machine: &machine, mode: Mode::StepAndScan, start: Point::origin() };
        let seq = NearestNeighbour.plan(&j, &ctx).unwrap();
        let tr = build(&j, &seq, &machine, Mode::StepAndScan, Point::origin()).unwrap();
        assert!(!tr.segments.iter().any(Segment::is_pierce));
    }

    #[test]
    fn stage_only_marks_at_the_layer_speed_and_bound_holds() {
        let mut machine = MachineConfig::load(None).unwrap();
        machine.scanner = None;
        let j = job();
        let ctx = PlanContext { machine: &machine, mode: Mode::StageOnly, start: Point::origin() };
        let seq = NearestNeighbour.plan(&j, &ctx).unwrap();
        let tr = build(&j, &seq, &machine, Mode::StageOnly, Point::origin()).unwrap();
        check_continuity(&tr);
        assert!(tr.segments.iter().all(|s| s.group == AxisGroup::Stage));
        let lb = lower_bound(&j, &seq, &machine, Mode::StageOnly).unwrap();
        assert!(lb <= tr.duration());
        assert!(Mode::StepAndScan.check(&machine).is_err());
    }
}
