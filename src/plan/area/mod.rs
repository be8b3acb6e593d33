//! Areas (seed 004): filled shapes marked as hatch lines, in the order an
//! objective prefers.
//!
//! * [`hatch`]: a fill layer's areas become hatch lines (the job's
//!   geometries of its fill process, each one straight segment).
//! * [`ga`]: seed 004's genetic search over routes of segments.
//! * Here: the hatch lines as genes (a segment and the way it is marked), the
//!   plain raster order (line after line across the whole job, what
//!   LightBurn does by default), and the fill planner: stage-only one route
//!   for the job, with a scanner one per field.

pub mod ga;
pub mod grid;
pub mod hatch;

use nalgebra::Vector2;

use super::objective::{Mark, MotionModel, Objective, ObjectiveContext};
use super::stop::{SearchStop, TimeCap};
use super::{PathGroup, PlanContext, PlannedPath, Sequence};
use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::job::{Geometry, Job, Point};
use crate::mode::Mode;
use ga::{GaRun, GaSettings};

/// A hatch line to mark: a straight geometry of a fill process.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub geometry: usize,
    /// Its ends, `from` to `to` the hatch's way.
    pub from: Point,
    pub to: Point,
    /// Whether it may be marked `to` to `from` (a bidirectional fill).
    pub either_way: bool,
    /// Where its line lies across the hatch (the hatch's lines in order).
    pub across: f64,
}

impl Segment {
    /// Its ends in the way it is marked (`reversed`: `to` first).
    pub fn ends(&self, reversed: bool) -> (Point, Point) {
        if reversed {
            (self.to, self.from)
        } else {
            (self.from, self.to)
        }
    }

    pub fn length(&self) -> f64 {
        (self.to - self.from).norm()
    }

    /// The hatch's direction (a unit vector).
    pub fn direction(&self) -> Vector2<f64> {
        (self.to - self.from) / self.length().max(1e-300)
    }
}

/// The hatch lines among `which` (geometries of `job`), in the job's order:
/// the straight open geometries of fill processes (a hatch line, or a whole
/// line of the raster yardstick, `raster_lines`).
pub fn segments(job: &Job, which: &[usize], machine: &MachineConfig) -> Vec<Segment> {
    which
        .iter()
        .filter_map(|&g| {
            let geometry = &job.geometries[g];
            let process = &job.processes[geometry.process];
            if !process.fill || geometry.closed || geometry.points.len() < 2 {
                return None;
            }
            let either_way = machine.layer(&process.layer).is_none_or(|l| l.bidirectional);
            let (from, to) = (geometry.points[0], geometry.points[geometry.points.len() - 1]);
            let d = (to - from).normalize();
            Some(Segment { geometry: g, from, to, either_way, across: d.perp(&from.coords) })
        })
        .collect()
}

/// The raster yardstick's job (`--planner raster`), as LightBurn fills by
/// default: each hatch line whole, from its first segment's start to its
/// last one's end at the fill's speed, the laser off (power 0) across the
/// gaps between its segments.
pub fn raster_lines(job: Job, machine: &MachineConfig) -> Job {
    let all: Vec<usize> = (0..job.geometries.len()).collect();
    let segments = segments(&job, &all, machine);
    if segments.is_empty() {
        return job;
    }
    let off: Vec<usize> = (0..job.processes.len()).map(|p| off_process(&job, p).unwrap_or(p)).collect();
    let Job { source, geometries, processes } = job;
    let is_segment: std::collections::HashSet<usize> = segments.iter().map(|s| s.geometry).collect();
    let mut out: Vec<Geometry> = geometries.iter().enumerate().filter(|(g, _)| !is_segment.contains(g)).map(|(_, g)| g.clone()).collect();
    let mut k = 0;
    while k < segments.len() {
        let first = &geometries[segments[k].geometry];
        let mut line = Geometry { points: vec![segments[k].from, segments[k].to], profile: vec![first.process], ..first.clone() };
        let mut j = k + 1;
        while j < segments.len() && same_line(&segments[j], &segments[k]) && geometries[segments[j].geometry].process == first.process {
            let s = &segments[j];
            if (s.from - line.points[line.points.len() - 1]).norm() > 1e-9 {
                line.profile.push(off[first.process]);
                line.points.push(s.from);
            }
            line.profile.push(first.process);
            line.points.push(s.to);
            j += 1;
        }
        out.push(line);
        k = j;
    }
    Job { source, geometries: out, processes }
}

/// A route over segments: each by its index and whether it is marked reversed.
pub type Order = Vec<(u32, bool)>;

/// The plain raster: the segments line after line as hatching made them,
/// along each line the hatch's way, a bidirectional hatch's lines turning
/// back one after the other.
pub fn raster(segments: &[Segment]) -> Order {
    let mut order = Vec::with_capacity(segments.len());
    let mut line_start = 0;
    let mut back = false;
    for k in 0..=segments.len() {
        let new_line = k == segments.len() || (k > line_start && !same_line(&segments[k], &segments[line_start]));
        if !new_line {
            continue;
        }
        let line = line_start..k;
        if back && segments[line_start].either_way {
            order.extend(line.rev().map(|i| (i as u32, true)));
        } else {
            order.extend(line.map(|i| (i as u32, false)));
        }
        back = !back;
        line_start = k;
    }
    order
}

/// Whether two segments lie on one hatch line.
fn same_line(a: &Segment, b: &Segment) -> bool {
    (a.across - b.across).abs() <= 1e-6 * (1.0 + a.across.abs()) && a.direction().dot(&b.direction()) > 1.0 - 1e-9
}

/// The process marking fill process `p`'s gaps: the same with the laser
/// off (`hatch` adds one beside each fill).
pub fn off_process(job: &Job, p: usize) -> Option<usize> {
    let fill = &job.processes[p];
    job.processes.iter().position(|q| q.fill && q.power == 0.0 && q.layer == fill.layer && q.speed == fill.speed && q.passes == fill.passes)
}

/// `order` as planned paths (fills never pierce); with `bridges`, a segment
/// that goes on ahead along the line of the one before follows a laser-off
/// path across the gap, which the motion runs through at speed.
pub fn paths(job: &Job, segments: &[Segment], order: &Order, bridges: bool) -> Vec<PlannedPath> {
    let mut out: Vec<PlannedPath> = Vec::with_capacity(order.len());
    for (k, &(i, reversed)) in order.iter().enumerate() {
        let s = &segments[i as usize];
        let g = &job.geometries[s.geometry];
        let mut points = g.points.clone();
        if reversed {
            points.reverse();
        }
        if let (true, Some(&(j, back)), Some(before)) = (bridges, k.checked_sub(1).map(|k| &order[k]), out.last()) {
            let (end, start) = (before.end(), points[0]);
            let way = |a: Point, b: Point| (b - a) / (b - a).norm().max(1e-300);
            let (d, e) = (way(before.start(), end), way(start, points[points.len() - 1]));
            let gap = start - end;
            let goes_on = same_line(s, &segments[j as usize]) && back == reversed && d.dot(&e) > 1.0 - 1e-9 && gap.dot(&d) > 1e-9;
            if let (true, Some(off)) = (goes_on, off_process(job, before.process)) {
                out.push(PlannedPath::new(before.geometry, vec![end, start], off, false));
            }
        }
        out.push(PlannedPath::new(s.geometry, points, g.process, false));
    }
    out
}

/// How the objectives see `segments` marked in `order`.
pub fn marks<'a>(order: &'a [(u32, bool)], forward: &'a [Mark]) -> impl Iterator<Item = Mark> + 'a {
    order.iter().map(|&(i, reversed)| {
        let m = forward[i as usize];
        if reversed {
            Mark { from: m.to, to: m.from, dir_in: -m.dir_out, dir_out: -m.dir_in, ..m }
        } else {
            m
        }
    })
}

/// `objective` over the marks `route` yields, gathered in a buffer kept
/// per thread: the GA prices pieces of routes millions of times.
pub fn price(route: impl Iterator<Item = Mark>, objective: &dyn Objective, ctx: &ObjectiveContext) -> f64 {
    thread_local! {
        static BUFFER: std::cell::RefCell<Vec<Mark>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    BUFFER.with(|buffer| match buffer.try_borrow_mut() {
        Ok(mut marks) => {
            marks.clear();
            marks.extend(route);
            let cost = objective.cost(&marks, ctx);
            // A whole route of a large fill is priced now and then: not kept.
            if marks.capacity() > 1 << 16 {
                *marks = Vec::new();
            }
            cost
        }
        Err(_) => objective.cost(&route.collect::<Vec<_>>(), ctx),
    })
}

/// Each segment as a mark the hatch's way: at its layer's speed (within
/// what the machine marks at), entered and left at speed where its layer
/// overscans (stage-only) or the scanner skywrites (on the fly).
pub fn forward_marks(job: &Job, segments: &[Segment], machine: &MachineConfig, mode: Mode) -> Vec<Mark> {
    let (cap, skywrite) = match scanner_in(machine, mode) {
        None => (machine.stage_limits().scaled(machine.motion.limit_margin).velocity, None),
        Some(s) => (s.mark_speed, Some(mode == Mode::OnTheFly)),
    };
    segments
        .iter()
        .map(|s| {
            let process = &job.processes[job.geometries[s.geometry].process];
            let overscan = skywrite.unwrap_or_else(|| machine.overscans(&process.layer));
            Mark::straight(s.from, s.to, process.speed.min(cap), overscan)
        })
        .collect()
}

/// The scanner that marks in `mode` (none stage-only).
fn scanner_in(machine: &MachineConfig, mode: Mode) -> Option<&crate::config::ScannerConfig> {
    machine.scanner.as_ref().filter(|_| mode != Mode::StageOnly)
}

/// What the objectives need of the machine in `mode`: the TCP's limits (the
/// stage's, or the scanner's).
pub fn objective_context(machine: &MachineConfig, mode: Mode) -> ObjectiveContext {
    let scanner = machine.scanner_limits().filter(|_| scanner_in(machine, mode).is_some());
    let (axis, bridges) = (scanner.unwrap_or_else(|| machine.stage_limits()), scanner.is_none());
    ObjectiveContext { motion: MotionModel { axis: axis.scaled(machine.motion.limit_margin), bridges }, heat_radius: machine.fill.heat_radius, cooling_time: machine.fill.cooling_time }
}

/// The fill planner: seed 004's genetic search under `objective` from
/// `start`, the plain raster among its first routes.
pub fn plan_fill(job: &Job, segments: &[Segment], machine: &MachineConfig, mode: Mode, start: Point, objective: &dyn Objective) -> (Order, GaRun) {
    let forward = forward_marks(job, segments, machine, mode);
    let ctx = objective_context(machine, mode);
    let cost = |order: &[(u32, bool)]| price(marks(order, &forward), objective, &ctx);
    let settings = GaSettings { population: machine.fill.population, stall: machine.fill.stall_generations, seed: machine.galvo.seed, local: objective.is_local(), ..GaSettings::default() };
    let cap = TimeCap::after(machine.galvo.time_limit.map(std::time::Duration::from_secs_f64));
    let starts = |order: &[(u32, bool)]| ctx.motion.timeline(&marks(order, &forward).collect::<Vec<_>>()).0;
    let timed = objective.horizon(&ctx).map(|horizon| ga::Timed { horizon, starts: &starts });
    ga::evolve(segments, start, &cost, timed.as_ref(), vec![raster(segments)], &settings, &cap)
}

/// How the hatch lines of fills are ordered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FillOrder {
    /// By the fill planner under the config's objective.
    Planned,
    /// As a plain raster, line after line (`--planner raster`).
    Raster,
}

/// The fills `fills` (job geometries: hatch lines) planned from `start`:
/// stage-only as one group; with a scanner field by field (the fields
/// covering them, in nearest-neighbour order), each field's lines ordered
/// alone. Also why the searches stopped.
pub fn plan_fills(job: &Job, fills: &[usize], ctx: &PlanContext, order: FillOrder) -> Result<(Sequence, SearchStop)> {
    let machine = ctx.machine;
    let objective = super::objective::parse(&machine.fill.objective).map_err(|e| Error::Config(format!("fill.objective: {e}")))?;
    let scanner = scanner_in(machine, ctx.mode);
    let plan = |members: &[usize], start: Point| -> (Vec<PlannedPath>, SearchStop) {
        let segments = segments(job, members, machine);
        let (route, stop) = match order {
            FillOrder::Raster => (raster(&segments), SearchStop::Budget),
            FillOrder::Planned => {
                let (route, run) = plan_fill(job, &segments, machine, ctx.mode, start, objective.as_ref());
                (route, run.stopped_by)
            }
        };
        (paths(job, &segments, &route, scanner.is_none()), stop)
    };
    let Some(scanner) = scanner else {
        let (paths, stop) = plan(fills, ctx.start);
        return Ok((Sequence { groups: vec![PathGroup { field_center: None, paths }] }, stop));
    };
    let part = Job { source: job.source.clone(), geometries: fills.iter().map(|&g| job.geometries[g].clone()).collect(), processes: job.processes.clone() };
    let travel = (machine.stage.travel_x, machine.stage.travel_y);
    let mut fields = super::fields::cover(&part, scanner.usable_half_field, travel)?;
    let mut groups = Vec::with_capacity(fields.len());
    let mut stop = SearchStop::Budget;
    let mut at = ctx.start;
    while !fields.is_empty() {
        let next = (0..fields.len()).min_by(|&a, &b| (fields[a].center - at).norm().total_cmp(&(fields[b].center - at).norm())).expect("fields left");
        let field = fields.swap_remove(next);
        let members: Vec<usize> = field.members.iter().map(|&m| fills[m]).collect();
        let (paths, stopped) = plan(&members, at);
        stop = stop.and(stopped);
        at = paths.last().map_or(at, |p| p.end());
        groups.push(PathGroup { field_center: Some(field.center), paths });
    }
    Ok((Sequence { groups }, stop))
}
