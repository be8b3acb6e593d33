//! The tool centre point (TCP) in time: the marks at their layer's speed, the
//! laser-off moves between them, pierces and waits, as a list of pieces.
//!
//! A mark is a run of straight legs (see `leg`). With blending on, each inner
//! corner is turned by overlapping the ramp down of one leg with the ramp up of
//! the next: the TCP cuts the corner by at most `corner_tolerance`, never
//! exceeds the mark speed, and stays inside every axis limit (both checked on
//! the overlap; the overlap is the largest that passes). Collinear joints and
//! the gentle turns of flattened curves overlap fully and keep the speed.
//!
//! With skywriting on, a mark starts and ends at its speed: the laser-off move
//! before it accelerates onto its line and the one after it brakes, each a
//! time-optimal state-to-state Ruckig move (`FreeMove`). Without it (and
//! before a pierce) marks start and end at rest.

use nalgebra::Vector2;

use super::blend::RunEnd;
use super::leg::Leg;
use super::profile::FreeMove;
use crate::config::Limits;
use crate::error::{Error, Result};
use crate::job::Point;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PieceKind {
    /// From where the machine rests to the job's first point, before the job's clock starts.
    Approach,
    /// Laser on at `power` along a geometry.
    Mark { geometry: usize, power: f64 },
    /// Laser off, moving to the next geometry.
    Jump,
    /// Laser on at `power`, standing still at a geometry's entry.
    Pierce { geometry: usize, power: f64 },
    /// Laser off, standing still at a geometry's entry until the plate has
    /// cooled there (the thermal planner's last resort).
    Cool { geometry: usize },
    /// The stage carries the TCP while the scanner holds (a field change of
    /// step-and-scan, or on-the-fly where the stage cannot move in time).
    Carried,
}

#[derive(Debug, Clone)]
pub enum Motion {
    /// Along `dir` (a unit vector) from `from`.
    Leg { from: Point, dir: Vector2<f64>, leg: Leg },
    /// Along `dir` from `from` with a speed that changes (stage-only, `blend`).
    Profile { from: Point, dir: Vector2<f64>, profile: super::blend::Profile },
    Free(FreeMove),
    Still(Point),
}

#[derive(Debug)]
pub struct Piece {
    pub kind: PieceKind,
    /// Index of the sequence group (scan field) the piece belongs to; a
    /// laser-off move belongs to the group it goes to.
    pub group: usize,
    pub start: f64,
    pub duration: f64,
    pub motion: Motion,
}

impl Piece {
    pub fn end_time(&self) -> f64 {
        self.start + self.duration
    }

    /// Position `t` seconds after the piece's start (clamped to the piece).
    pub fn position(&self, t: f64) -> Point {
        match &self.motion {
            Motion::Leg { from, dir, leg } => from + dir * leg.position(t),
            Motion::Profile { from, dir, profile } => from + dir * profile.at(t)[0],
            Motion::Free(m) => m.at(t).0,
            Motion::Still(p) => *p,
        }
    }

    pub fn start_point(&self) -> Point {
        self.position(0.0)
    }

    pub fn end_point(&self) -> Point {
        match &self.motion {
            Motion::Leg { from, dir, leg } => from + dir * leg.length,
            Motion::Profile { from, dir, profile } => from + dir * profile.length,
            Motion::Free(m) => m.to,
            Motion::Still(p) => *p,
        }
    }

    pub fn is_marking(&self) -> bool {
        matches!(self.kind, PieceKind::Mark { .. })
    }

    /// Laser power during the piece (0 = off).
    pub fn power(&self) -> f64 {
        match self.kind {
            PieceKind::Mark { power, .. } | PieceKind::Pierce { power, .. } => power,
            _ => 0.0,
        }
    }

    pub fn geometry(&self) -> Option<usize> {
        match self.kind {
            PieceKind::Mark { geometry, .. } | PieceKind::Pierce { geometry, .. } | PieceKind::Cool { geometry } => Some(geometry),
            _ => None,
        }
    }

    /// Times inside the piece (from its start) where the motion changes character.
    pub fn breakpoints(&self, out: &mut Vec<f64>) {
        match &self.motion {
            Motion::Leg { leg, .. } => leg.breakpoints(out),
            Motion::Profile { profile, .. } => profile.breakpoints(out),
            // A Ruckig move's phases are not exposed: eighths of it, or
            // every 5 ms of a long one (an approach across the table).
            Motion::Free(m) => {
                let n = ((m.duration / 5e-3).ceil() as usize).clamp(8, 256);
                out.extend((1..n).map(|k| m.duration * k as f64 / n as f64));
            }
            Motion::Still(_) => {}
        }
    }

    /// Bounding box of the piece's path: exact for legs and standing still,
    /// sampled for free moves.
    pub fn bounds(&self) -> (Point, Point) {
        let mut lo = self.start_point();
        let mut hi = lo;
        let mut grow = |p: Point| {
            lo = Point::new(lo.x.min(p.x), lo.y.min(p.y));
            hi = Point::new(hi.x.max(p.x), hi.y.max(p.y));
        };
        grow(self.end_point());
        if let Motion::Free(m) = &self.motion {
            for k in 1..FREE_SAMPLES {
                grow(m.at(m.duration * k as f64 / FREE_SAMPLES as f64).0);
            }
        }
        (lo, hi)
    }
}

/// Samples over a free move where its path is bounded (its bow or overshoot
/// is a fraction of its length, so this many samples find it closely).
pub const FREE_SAMPLES: usize = 12;

/// The TCP's pieces in time order. Two consecutive legs overlap at a blended
/// corner; nothing else overlaps.
#[derive(Debug, Default)]
pub struct TcpPath {
    pub pieces: Vec<Piece>,
    /// Start times of the pieces, for finding the piece at a time (built on
    /// first use: a path is sampled after it is built).
    starts: std::sync::OnceLock<Vec<f64>>,
}

impl TcpPath {
    pub fn duration(&self) -> f64 {
        self.pieces.iter().map(Piece::end_time).fold(0.0, f64::max)
    }

    pub fn new(pieces: Vec<Piece>) -> TcpPath {
        TcpPath { pieces, starts: Default::default() }
    }

    /// Index of the last piece starting at or before `t` (0 before the first).
    pub fn index_at(&self, t: f64) -> usize {
        let starts = self.starts.get_or_init(|| self.pieces.iter().map(|p| p.start).collect());
        debug_assert_eq!(starts.len(), self.pieces.len(), "pieces changed after the path was sampled");
        starts.partition_point(|&s| s <= t).saturating_sub(1)
    }

    /// Position at time `t`.
    pub fn position(&self, t: f64) -> Point {
        let Some(last) = self.pieces.last() else { return Point::origin() };
        if t >= last.end_time() {
            return last.end_point();
        }
        let k = self.index_at(t);
        self.position_from(k, t)
    }

    /// Position at `t`, knowing that the piece running then is one of
    /// `lo..=hi` (a faster search where many nearby times are asked for).
    pub fn position_among(&self, t: f64, lo: usize, hi: usize) -> Point {
        let hi = hi.min(self.pieces.len().saturating_sub(1));
        if lo > hi || t < self.pieces[lo].start || (hi + 1 < self.pieces.len() && t >= self.pieces[hi + 1].start) {
            return self.position(t);
        }
        let k = lo + self.pieces[lo..=hi].partition_point(|p| p.start <= t).saturating_sub(1);
        if k == self.pieces.len() - 1 && t >= self.pieces[k].end_time() {
            return self.pieces[k].end_point();
        }
        self.position_from(k, t)
    }

    /// Position at `t` given the index of the piece running then.
    pub fn position_from(&self, k: usize, t: f64) -> Point {
        let piece = &self.pieces[k];
        let mut p = piece.position(t - piece.start);
        // The leg before, still ramping down at a blended corner, adds what it
        // has not yet covered (negative: it ends at this leg's start).
        if k > 0 {
            let prev = &self.pieces[k - 1];
            if prev.end_time() > t {
                p += prev.position(t - prev.start) - prev.end_point();
            }
        }
        p
    }

    pub fn shift(&mut self, dt: f64) {
        for p in &mut self.pieces {
            p.start += dt;
        }
        self.starts = Default::default();
    }
}

/// How the TCP is planned in a mode.
#[derive(Debug, Clone, Copy)]
pub struct TcpSettings {
    /// Per-axis limits of the TCP.
    pub axis: Limits,
    /// Highest marking speed (the layer's speed is capped by it).
    pub mark_speed: f64,
    /// Blend corners within `corner_tolerance` (else stop at every vertex).
    pub blend: bool,
    /// Run through the vertices at the speed each turn allows (`blend`:
    /// stage-only), rather than by overlapping legs' ramps.
    pub junctions: bool,
    /// Marks start and end at speed; laser-off moves are state-to-state.
    pub skywrite: bool,
    pub corner_tolerance: f64,
    /// Vertices this close to the line through their neighbours are dropped.
    pub line_tolerance: f64,
}

/// A run's motions: (start relative to the run's start, duration, motion).
pub type Legs = Vec<(f64, f64, Motion)>;

/// A planned mark: its legs with their start times relative to the run's
/// start and their durations (consecutive legs may overlap at a corner).
pub struct Run {
    legs: Legs,
    /// The legs where each piece after the first of a run of several marks
    /// begins (a raster line whose power changes); empty for one mark.
    breaks: Vec<usize>,
    duration: f64,
    entry: Point,
    entry_velocity: Vector2<f64>,
    exit: Point,
    exit_velocity: Vector2<f64>,
}

impl Run {
    /// From legs in time order (at least one).
    pub fn new(legs: Legs) -> Run {
        let (_, _, first) = &legs[0];
        let (last_start, last_duration, last) = legs.last().expect("a run has legs");
        let entry_velocity = first.velocity(0.0);
        let exit_velocity = last.velocity(*last_duration);
        let (entry, exit) = (first.start(), last.end());
        let duration = last_start + last_duration;
        Run { legs, breaks: Vec::new(), duration, entry, entry_velocity, exit, exit_velocity }
    }

    fn entry_velocity(&self) -> Vector2<f64> {
        self.entry_velocity
    }

    fn exit_point(&self) -> Point {
        self.exit
    }

    fn exit_velocity(&self) -> Vector2<f64> {
        self.exit_velocity
    }
}

impl Motion {
    /// Velocity `t` seconds into the motion.
    pub fn velocity(&self, t: f64) -> Vector2<f64> {
        match self {
            Motion::Leg { dir, leg, .. } => dir * leg.at(t)[1],
            Motion::Profile { dir, profile, .. } => dir * profile.at(t)[1],
            Motion::Free(m) => m.at(t).1,
            Motion::Still(_) => Vector2::zeros(),
        }
    }

    fn start(&self) -> Point {
        match self {
            Motion::Leg { from, .. } | Motion::Profile { from, .. } => *from,
            Motion::Free(m) => m.at(0.0).0,
            Motion::Still(p) => *p,
        }
    }

    fn end(&self) -> Point {
        match self {
            Motion::Leg { from, dir, leg } => from + dir * leg.length,
            Motion::Profile { from, dir, profile } => from + dir * profile.length,
            Motion::Free(m) => m.to,
            Motion::Still(p) => *p,
        }
    }
}

/// Drops vertices within `tol` of the straight line between the last kept
/// vertex and the next one (and between them along it): they add legs
/// without changing the mark.
fn simplify(points: &[Point], tol: f64) -> Vec<Point> {
    let mut kept: Vec<Point> = Vec::with_capacity(points.len());
    for (i, &p) in points.iter().enumerate() {
        if let (Some(&a), Some(&b)) = (kept.last(), points.get(i + 1)) {
            let d = b - a;
            let len = d.norm();
            if len > 1e-12 {
                let along = (p - a).dot(&d) / len;
                let off = ((p - a).x * d.y - (p - a).y * d.x).abs() / len;
                if off <= tol && along > 0.0 && along < len {
                    continue;
                }
            }
        }
        if kept.last().is_none_or(|q| (p - q).norm() > 1e-9) {
            kept.push(p);
        }
    }
    kept
}

/// `point_segment_distance` for the tests of the other motion planners.
#[cfg(test)]
pub(super) fn tests_distance(p: Point, a: Point, b: Point) -> f64 {
    point_segment_distance(p, a, b)
}

fn point_segment_distance(p: Point, a: Point, b: Point) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    let f = if l2 > 0.0 { ((p - a).dot(&d) / l2).clamp(0.0, 1.0) } else { 0.0 };
    (p - (a + d * f)).norm()
}

/// The largest overlap of leg `a` (ending at `vertex`) with leg `b` (starting
/// there) that keeps the turn within the corner tolerance, the mark speed and
/// every axis limit; checked at the legs' phase changes and between them.
fn corner_overlap(a: (&Leg, Vector2<f64>), b: (&Leg, Vector2<f64>), vertex: Point, s: &TcpSettings, speed: f64) -> f64 {
    let ((la, ua), (lb, ub)) = (a, b);
    if !(la.ramp_out && lb.ramp_in) {
        return 0.0;
    }
    let max = la.ramp.duration.min(lb.ramp.duration);
    let a_start = vertex - ua * la.length;
    let b_end = vertex + ub * lb.length;
    let slack = 1.0 + 1e-9;
    let mut times = Vec::with_capacity(48);
    let (mut breaks_a, mut breaks_b) = (Vec::new(), Vec::new());
    la.breakpoints(&mut breaks_a);
    lb.breakpoints(&mut breaks_b);
    let mut feasible = |tau: f64| -> bool {
        let t0 = la.duration - tau;
        times.clear();
        times.extend((0..=16).map(|k| tau * k as f64 / 16.0));
        times.extend(breaks_a.iter().map(|x| x - t0).filter(|x| *x > 0.0 && *x < tau));
        times.extend(breaks_b.iter().copied().filter(|x| *x > 0.0 && *x < tau));
        times.sort_by(f64::total_cmp);
        let n = times.len();
        for i in 0..n {
            if i + 1 < n {
                times.push(0.5 * (times[i] + times[i + 1]));
            }
        }
        // From the middle of the grid outwards: a turn too wide for the
        // tolerance shows there first (the same answer, sooner).
        let mid = n / 2;
        let middle_out = std::iter::once(mid).chain((1..=n).flat_map(|j| [mid.checked_sub(j), Some(mid + j).filter(|&k| k < n)]).flatten());
        middle_out.chain(n..times.len()).all(|k| {
            let x = times[k];
            let sa = la.at(t0 + x);
            let sb = lb.at(x);
            let pos = vertex + ua * (sa[0] - la.length) + ub * sb[0];
            let vel = ua * sa[1] + ub * sb[1];
            let acc = ua * sa[2] + ub * sb[2];
            let jerk = ua * sa[3] + ub * sb[3];
            let axis_ok = |v: Vector2<f64>, limit: f64| v.x.abs() <= limit * slack && v.y.abs() <= limit * slack;
            axis_ok(vel, s.axis.velocity)
                && axis_ok(acc, s.axis.acceleration)
                && axis_ok(jerk, s.axis.jerk)
                && vel.norm() <= speed * slack
                && point_segment_distance(pos, a_start, vertex).min(point_segment_distance(pos, vertex, b_end)) <= s.corner_tolerance
        })
    };
    if feasible(max) {
        return max;
    }
    // To a thousandth of the overlap: a finer one gains nothing measurable.
    let (mut good, mut bad) = (0.0, max);
    for _ in 0..14 {
        if bad - good <= 1e-3 * good {
            break;
        }
        let mid = 0.5 * (good + bad);
        if feasible(mid) {
            good = mid;
        } else {
            bad = mid;
        }
    }
    good
}

/// Per-path limits along a straight line in direction `d` from per-axis
/// limits: the axis with the largest share of the motion reaches its limit first.
pub fn path_limits(axis: Limits, d: Vector2<f64>) -> Limits {
    let share = d.x.abs().max(d.y.abs()) / d.norm();
    axis.scaled(1.0 / share)
}

/// The run of legs marking `points` at `speed` (none for fewer than two
/// distinct points); corners already in `corners` are taken from there.
fn plan_run(s: &TcpSettings, corners: &mut Corners, points: &[Point], speed: f64, ramp_in: bool, hand_over: HandOver, breaks: &[usize]) -> Result<Option<Run>> {
    if !(speed.is_finite() && speed > 0.0) {
        return Err(Error::Motion(format!("invalid marking speed {speed}")));
    }
    if points.len() < 2 {
        return Ok(None);
    }
    // Simplified between breaks, which stay vertices: the legs there.
    let mut simple: Vec<Point> = Vec::with_capacity(points.len());
    let mut leg_breaks = Vec::with_capacity(breaks.len());
    let ends: Vec<usize> = breaks.iter().copied().chain([points.len() - 1]).collect();
    let mut from = 0;
    for &to in &ends {
        let part = simplify(&points[from..=to], s.line_tolerance);
        if from > 0 {
            leg_breaks.push(simple.len() - 1);
        }
        let skip = usize::from(!simple.is_empty() && part.first().is_some_and(|p| simple.last().is_some_and(|q| (p - q).norm() <= 1e-9)));
        simple.extend(part.into_iter().skip(skip));
        from = to;
    }
    let points = simple;
    if points.len() < 2 {
        return Ok(None);
    }
    if s.junctions {
        let run = super::blend::plan_run(s, &points, speed, hand_over.entry, hand_over.exit, !breaks.is_empty());
        return Ok(run.map(|r| Run { breaks: leg_breaks, ..r }));
    }
    debug_assert!(breaks.is_empty(), "marks run on through one another only with junctions");
    let n = points.len() - 1;
    let mut legs = Vec::with_capacity(n);
    for i in 0..n {
        let d = points[i + 1] - points[i];
        let length = d.norm();
        let dir = d / length;
        let limits = if s.blend {
            // The same ramps in every direction, so that collinear legs
            // overlap into exactly constant speed; 1/√2 of the axis
            // limits, so that two legs at right angles on the diagonals
            // may overlap with both ramps at full acceleration and jerk.
            Limits { velocity: speed, acceleration: s.axis.acceleration * std::f64::consts::FRAC_1_SQRT_2, jerk: s.axis.jerk * std::f64::consts::FRAC_1_SQRT_2 }
        } else {
            let l = path_limits(s.axis, dir);
            Limits { velocity: l.velocity.min(speed), ..l }
        };
        let first_in = if i == 0 { ramp_in } else { true };
        let last_out = if i == n - 1 { !s.skywrite } else { true };
        let leg = if !first_in && !last_out {
            Leg::constant(length, speed)
        } else {
            Leg::new(length, limits, first_in, last_out)?
        };
        legs.push((points[i], dir, leg, 0.0));
    }
    let mut t = 0.0;
    for i in 0..n {
        legs[i].3 = t;
        let overlap = if s.blend && i + 1 < n {
            let (a, b) = (&legs[i].2, &legs[i + 1].2);
            // Corners of legs at full speed on both sides depend only on
            // the two directions and the ramps: jobs repeat them a lot.
            let key = (a.cruise > 0.0 && b.cruise > 0.0).then(|| {
                let q = |x: f64| (x * 1e9).round() as i64;
                (q(legs[i].1.x), q(legs[i].1.y), q(legs[i + 1].1.x), q(legs[i + 1].1.y), q(a.speed()), q(b.speed()), a.ramp_in, b.ramp_out)
            });
            match key.and_then(|k| corners.get(&k).copied()) {
                Some(o) => o,
                None => {
                    let o = corner_overlap((a, legs[i].1), (b, legs[i + 1].1), points[i + 1], s, speed);
                    if let Some(k) = key {
                        corners.insert(k, o);
                    }
                    o
                }
            }
        } else {
            0.0
        };
        t += legs[i].2.duration - overlap;
    }
    let legs = legs.into_iter().map(|(from, dir, leg, start)| (start, leg.duration, Motion::Leg { from, dir, leg })).collect();
    Ok(Some(Run::new(legs)))
}

/// Builds the TCP's pieces one path at a time.
pub struct TcpBuilder {
    pub settings: TcpSettings,
    pub path: TcpPath,
    pub time: f64,
    pub position: Point,
    pub velocity: Vector2<f64>,
    /// Stage-only (`junctions`): marks without a pierce planned ahead by
    /// `prepare` take the laser-off moves' speed over (set by the caller
    /// where the moves may run at speed through the marks' ends).
    pub hand_over: bool,
    /// Mark ends the hand-over leaves at rest (a laser-off move running
    /// through them at speed would leave the travel, or must wait there for
    /// a lift).
    pub rest_at: Vec<Point>,
    /// When each piece that may tip was cut free: (time, job geometry).
    pub fell: Vec<(f64, usize)>,
    /// Corners and laser-off moves already planned (kept from one plan of a
    /// job to the next with `take_cache`: a replan after a field change the
    /// stage cannot make on the fly changes only that change).
    cache: std::cell::RefCell<PlanCache>,
}

/// Corner overlaps by the directions and speeds of their legs, and free
/// moves by their end states.
#[derive(Default)]
pub struct PlanCache {
    corners: Corners,
    moves: std::collections::HashMap<[i64; 8], FreeMove>,
}

pub type CornerKey = (i64, i64, i64, i64, i64, i64, bool, bool);
type Corners = std::collections::HashMap<CornerKey, f64>;

impl TcpBuilder {
    /// Starting at rest at `position` at time `time`.
    pub fn new(settings: TcpSettings, position: Point, time: f64) -> TcpBuilder {
        TcpBuilder { settings, path: TcpPath::default(), time, position, velocity: Vector2::zeros(), hand_over: false, rest_at: Vec::new(), fell: Vec::new(), cache: Default::default() }
    }

    fn push(&mut self, kind: PieceKind, group: usize, motion: Motion, duration: f64) {
        if duration <= 0.0 {
            return;
        }
        self.path.pieces.push(Piece { kind, group, start: self.time, duration, motion });
    }

    /// A laser-off move from where the TCP is to `to`, arriving with `velocity`.
    pub fn jump(&mut self, kind: PieceKind, group: usize, to: Point, velocity: Vector2<f64>) -> Result<()> {
        if (to - self.position).norm() < 1e-9 && (velocity - self.velocity).norm() < 1e-9 {
            return Ok(());
        }
        let m = self.fastest(to, velocity)?;
        let d = m.duration;
        self.push(kind, group, Motion::Free(m), d);
        self.time += d;
        self.position = to;
        self.velocity = velocity;
        Ok(())
    }

    /// The fastest free move from here to `to`, arriving at `velocity`,
    /// within the settings' limits (cached).
    fn fastest(&self, to: Point, velocity: Vector2<f64>) -> Result<FreeMove> {
        let key = move_key(self.position, self.velocity, to, velocity);
        let cached = self.cache.borrow().moves.get(&key).cloned();
        if let Some(m) = cached {
            return Ok(m);
        }
        let m = FreeMove::new(self.position, self.velocity, to, velocity, self.settings.axis)?;
        self.cache.borrow_mut().moves.insert(key, m.clone());
        Ok(m)
    }

    /// A laser-off move from rest to rest at `to` taking `took` (or as long
    /// as it must): the fastest such move (cached) time-scaled.
    pub fn jump_slowed(&mut self, group: usize, to: Point, took: f64) -> Result<()> {
        self.stop(group)?;
        if (to - self.position).norm() < 1e-9 {
            return Ok(());
        }
        let m = self.fastest(to, Vector2::zeros())?.slowed(took);
        let d = m.duration;
        self.push(PieceKind::Jump, group, Motion::Free(m), d);
        self.time += d;
        self.position = to;
        Ok(())
    }

    /// A straight rest-to-rest move to `to` at `limits` (per axis).
    pub fn straight(&mut self, kind: PieceKind, group: usize, to: Point, axis: Limits) -> Result<()> {
        self.stop(group)?;
        let d = to - self.position;
        let length = d.norm();
        if length < 1e-9 {
            return Ok(());
        }
        let dir = d / length;
        let leg = Leg::new(length, path_limits(axis, dir), true, true)?;
        self.push(kind, group, Motion::Leg { from: self.position, dir, leg }, leg.duration);
        self.time += leg.duration;
        self.position = to;
        Ok(())
    }

    /// Starts from what another builder with the same settings planned.
    pub fn with_cache(mut self, cache: PlanCache) -> TcpBuilder {
        self.cache = std::cell::RefCell::new(cache);
        self
    }

    pub fn take_cache(&self) -> PlanCache {
        self.cache.take()
    }

    /// Comes to rest straight ahead if moving.
    pub fn stop(&mut self, group: usize) -> Result<()> {
        let v = self.velocity.norm();
        if v < 1e-12 {
            return Ok(());
        }
        let dir = self.velocity / v;
        let ramp = super::leg::Ramp::new(v, self.settings.axis.acceleration, self.settings.axis.jerk);
        let leg = Leg { length: ramp.distance, ramp, ramp_in: false, ramp_out: true, cruise: 0.0, duration: ramp.duration };
        self.push(PieceKind::Jump, group, Motion::Leg { from: self.position, dir, leg }, leg.duration);
        self.time += leg.duration;
        self.position += dir * ramp.distance;
        self.velocity = Vector2::zeros();
        Ok(())
    }

    /// Standing still for `duration` (a pierce).
    pub fn still(&mut self, kind: PieceKind, group: usize, duration: f64) {
        let p = self.position;
        self.push(kind, group, Motion::Still(p), duration);
        self.time += duration;
    }

    /// Marks `points` at `speed` with `power` (a pierce of `pierce` seconds at
    /// `pierce_power` first when `pierce` > 0), jumping there first.
    #[allow(clippy::too_many_arguments)]
    pub fn mark(&mut self, geometry: usize, group: usize, points: &[Point], speed: f64, power: f64, pierce: f64, pierce_power: f64) -> Result<()> {
        let request = MarkRequest { points, speed, pierce: pierce > 0.0, breaks: &[], overscan: false };
        let run = self.prepare(std::slice::from_ref(&request), 0..1)?.pop().flatten();
        self.mark_run(&[(geometry, power)], group, run.as_ref(), 0.0, pierce, pierce_power)
    }

    /// Plans the runs of `marks[range]` ahead, on all cores (a run does not
    /// depend on where the TCP is; the marks beside the range decide how its
    /// ends are handed over), and puts the laser-off moves from each to the
    /// next into the cache: `mark_run` then only places them in time.
    pub fn prepare(&self, marks: &[MarkRequest], range: std::ops::Range<usize>) -> Result<Vec<Option<Run>>> {
        let settings = self.settings;
        let known = self.cache.borrow().corners.clone();
        // Stage-only: a mark without a pierce is entered and left at speed
        // (the mark before and after it in `marks` is where the TCP comes
        // from and goes to); the job's last mark ends at rest, and so does
        // every end in `rest_at`.
        let at_rest = |p: &Point| self.rest_at.iter().any(|r| (r - p).norm() < 1e-6);
        // Whether mark k's start (or end) may be overscanned: not at rest,
        // and a mark whose other end rests long enough to stop in.
        let axis = settings.axis;
        let at_speed = |k: usize, start: bool| {
            let m = &marks[k];
            let (Some(first), Some(last)) = (m.points.first(), m.points.last()) else { return false };
            let (here, there) = if start { (first, last) } else { (last, first) };
            if !m.overscan || (start && m.pierce) || at_rest(here) {
                return false;
            }
            let v = m.speed.min(axis.velocity);
            let stop = v * v / (2.0 * axis.acceleration) + v * axis.acceleration / axis.jerk;
            !at_rest(there) || m.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum::<f64>() >= stop
        };
        let hand_overs: Vec<HandOver> = range
            .clone()
            .map(|k| {
                if !(self.hand_over && settings.junctions) {
                    return HandOver::default();
                }
                let (first, last) = (marks[k].points.first(), marks[k].points.last());
                let before = k.checked_sub(1).and_then(|j| marks[j].points.last());
                let after = marks.get(k + 1).and_then(|m| m.points.first());
                // An overscanned mark (a hatch line) is entered and left at
                // its speed, the move before or after it turning round
                // outside. A move that goes on ahead (to the next segment of
                // its line) does so only between two ends that both may be
                // at speed, else through the junction as between any marks
                // (it would swing back for a run-up otherwise).
                let head = marks[k].points.get(1).zip(first).map(|(p, f)| p - f);
                let tail = last.zip(marks[k].points.len().checked_sub(2).map(|i| marks[k].points[i])).map(|(l, p)| l - p);
                let ahead = |chord: Vector2<f64>, along: Option<Vector2<f64>>| along.is_some_and(|d| chord.dot(&d) > 0.0);
                let entry = match before.zip(first) {
                    _ if marks[k].pierce || first.is_some_and(&at_rest) => RunEnd::Rest,
                    Some((b, f)) if ahead(f - b, head) => if at_speed(k, true) && at_speed(k - 1, false) { RunEnd::AtSpeed } else { RunEnd::Junction(f - b) },
                    Some(_) | None if at_speed(k, true) => RunEnd::AtSpeed,
                    Some((b, f)) => RunEnd::Junction(f - b),
                    None => RunEnd::Rest,
                };
                let exit = match last.zip(after) {
                    _ if last.is_some_and(&at_rest) => RunEnd::Rest,
                    Some((l, a)) if ahead(a - l, tail) => if at_speed(k, false) && at_speed(k + 1, true) { RunEnd::AtSpeed } else { RunEnd::Junction(a - l) },
                    Some(_) | None if at_speed(k, false) => RunEnd::AtSpeed,
                    Some((l, a)) => RunEnd::Junction(a - l),
                    None => RunEnd::Rest,
                };
                HandOver { entry, exit }
            })
            .collect();
        let indexed: Vec<(&MarkRequest, HandOver)> = marks[range.clone()].iter().zip(hand_overs).collect();
        let parts = crate::parallel::chunks(&indexed, 8, |part| {
            let mut corners = known.clone();
            let runs = part
                .iter()
                .map(|(m, h)| plan_run(&settings, &mut corners, m.points, m.speed, m.pierce || !settings.skywrite, *h, m.breaks))
                .collect::<Result<Vec<_>>>();
            (runs, corners)
        });
        let mut runs = Vec::with_capacity(range.len());
        for (part, corners) in parts {
            runs.extend(part?);
            self.cache.borrow_mut().corners.extend(corners);
        }
        // The laser-off moves between consecutive marks, as `mark_run` will
        // ask for them (unless something else moves the TCP in between).
        let ends: Vec<_> = runs.iter().flatten().map(|r| (r.entry, r.entry_velocity(), r.exit_point(), r.exit_velocity())).collect();
        let axis = settings.axis;
        let wanted: Vec<_> = ends
            .windows(2)
            .map(|w| (w[0].2, w[0].3, w[1].0, w[1].1))
            .filter(|(from, v_from, to, v_to)| (to - from).norm() >= 1e-9 || (v_to - v_from).norm() >= 1e-9)
            .filter(|&(from, v_from, to, v_to)| !self.cache.borrow().moves.contains_key(&move_key(from, v_from, to, v_to)))
            .collect();
        let moves = crate::parallel::map(&wanted, 8, |&(from, v_from, to, v_to)| FreeMove::new(from, v_from, to, v_to, axis));
        for (&(from, v_from, to, v_to), m) in wanted.iter().zip(moves) {
            self.cache.borrow_mut().moves.insert(move_key(from, v_from, to, v_to), m?);
        }
        Ok(runs)
    }

    /// Marks a run planned by `prepare` (nothing for none), jumping to its
    /// start first, standing there `cool` seconds with the laser off when
    /// `cool` > 0, with a pierce of `pierce` seconds at `pierce_power` when
    /// `pierce` > 0 (the run must have been planned from rest for either).
    /// `marks`: the geometry and power of each mark the run goes through
    /// (one, or one per piece of a raster line, as the run's breaks).
    #[allow(clippy::too_many_arguments)]
    pub fn mark_run(&mut self, marks: &[(usize, f64)], group: usize, run: Option<&Run>, cool: f64, pierce: f64, pierce_power: f64) -> Result<()> {
        let Some(run) = run else { return Ok(()) };
        let entry = run.entry;
        self.jump(PieceKind::Jump, group, entry, run.entry_velocity())?;
        if cool > 0.0 {
            self.still(PieceKind::Cool { geometry: marks[0].0 }, group, cool);
        }
        if pierce > 0.0 {
            self.still(PieceKind::Pierce { geometry: marks[0].0, power: pierce_power }, group, pierce);
        }
        let t0 = self.time;
        for (i, (start, duration, motion)) in run.legs.iter().enumerate() {
            let (geometry, power) = marks[run.breaks.partition_point(|&b| b <= i).min(marks.len() - 1)];
            // A stretch at power 0 (across a gap of a fill's line) is a laser-off move.
            let kind = if power > 0.0 { PieceKind::Mark { geometry, power } } else { PieceKind::Jump };
            if *duration > 0.0 {
                self.path.pieces.push(Piece { kind, group, start: t0 + start, duration: *duration, motion: motion.clone() });
            }
        }
        self.time = t0 + run.duration;
        self.position = run.exit_point();
        self.velocity = run.exit_velocity();
        Ok(())
    }
}

/// The chords of the laser-off moves before and after a stage-only run that
/// may take it at speed (none: from or to rest).
#[derive(Clone, Copy, Default)]
struct HandOver {
    entry: RunEnd,
    exit: RunEnd,
}

/// A mark to plan ahead: its points, its speed, and whether it starts with a
/// pierce (from rest).
pub struct MarkRequest<'a> {
    pub points: &'a [Point],
    pub speed: f64,
    pub pierce: bool,
    /// Where in `points` a mark run on into from the one before begins.
    pub breaks: &'a [usize],
    /// Stage-only: entered and left at its speed, the laser-off moves
    /// turning round outside it (a fill's hatch line, `[[layer]] overscan`).
    pub overscan: bool,
}

/// The cache key of a laser-off move: its end states, to the nanometre.
fn move_key(from: Point, v_from: Vector2<f64>, to: Point, v_to: Vector2<f64>) -> [i64; 8] {
    let q = |x: f64| (x * 1e9).round() as i64;
    [from.x, from.y, v_from.x, v_from.y, to.x, to.y, v_to.x, v_to.y].map(q)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(blend: bool, skywrite: bool) -> TcpSettings {
        TcpSettings {
            axis: Limits { velocity: 4500.0, acceleration: 9.8e6, jerk: 3.9e11 },
            mark_speed: 1000.0,
            blend,
            junctions: false,
            skywrite,
            corner_tolerance: 0.01,
            line_tolerance: 0.001,
        }
    }

    fn square(x: f64, y: f64, a: f64) -> Vec<Point> {
        vec![Point::new(x, y), Point::new(x + a, y), Point::new(x + a, y + a), Point::new(x, y + a), Point::new(x, y)]
    }

    /// Samples the path finely and checks continuity, limits and corners.
    fn check(path: &TcpPath, s: &TcpSettings, marks: &[Vec<Point>]) {
        let n = 40_000;
        let d = path.duration();
        let dt = d / n as f64;
        let mut prev: Option<Point> = None;
        let mut prev_v: Option<Vector2<f64>> = None;
        let mut max_dev: f64 = 0.0;
        for k in 0..=n {
            let t = k as f64 * dt;
            let p = path.position(t);
            if let Some(q) = prev {
                let v = (p - q) / dt;
                assert!(v.x.abs() <= s.axis.velocity * 1.001 && v.y.abs() <= s.axis.velocity * 1.001, "t={t}: {v:?}");
                if let Some(pv) = prev_v {
                    let a = (v - pv) / dt;
                    // Within 3 %: second differences at this fine step see
                    // the interpolation of free moves (tabulated every 25 µs)
                    // a little; the limits of the program's blocks are the
                    // simulator's to check.
                    assert!(a.x.abs() <= s.axis.acceleration * 1.03 && a.y.abs() <= s.axis.acceleration * 1.03, "t={t}: {a:?}");
                }
                prev_v = Some(v);
            }
            prev = Some(p);
            let k = path.index_at(t);
            if path.pieces[k].is_marking() {
                let dev = marks
                    .iter()
                    .flat_map(|m| m.windows(2).map(|w| point_segment_distance(p, w[0], w[1])))
                    .fold(f64::INFINITY, f64::min);
                max_dev = max_dev.max(dev);
            }
        }
        assert!(max_dev <= s.corner_tolerance + 1e-9, "marked {max_dev} off the geometry");
    }

    #[test]
    fn blended_squares_stay_within_tolerance_and_limits() {
        for (blend, skywrite) in [(true, true), (true, false), (false, false)] {
            let s = settings(blend, skywrite);
            let mut b = TcpBuilder::new(s, Point::origin(), 0.0);
            let marks = vec![square(1.0, 1.0, 3.0), square(6.0, 2.0, 2.0)];
            for (i, m) in marks.iter().enumerate() {
                b.mark(i, 0, m, 1000.0, 300.0, 0.0, 0.0).unwrap();
            }
            b.stop(0).unwrap();
            check(&b.path, &s, &marks);
            // Marking time: at least length / speed, and blending saves time.
            let marked: f64 = b.path.pieces.iter().filter(|p| p.is_marking()).map(|p| p.duration).sum();
            assert!(marked > 0.0);
        }
    }

    #[test]
    fn marks_planned_ahead_on_all_cores_match_marks_planned_one_by_one() {
        // Enough marks to be shared out over threads, with repeated corners
        // (cached) and circles (not), some pierced.
        let marks: Vec<Vec<Point>> = (0..40)
            .map(|k| {
                let (x, y) = (2.0 + 7.0 * (k % 8) as f64, 2.0 + 7.0 * (k / 8) as f64);
                if k % 3 == 0 {
                    (0..=24).map(|i| Point::new(x + 2.0 * (i as f64 * 0.2618).cos(), y + 2.0 * (i as f64 * 0.2618).sin())).collect()
                } else {
                    square(x, y, 1.0 + 0.1 * k as f64)
                }
            })
            .collect();
        let pierce = |k: usize| if k.is_multiple_of(5) { 0.01 } else { 0.0 };
        let s = settings(true, true);
        let mut one_by_one = TcpBuilder::new(s, Point::origin(), 0.0);
        for (k, m) in marks.iter().enumerate() {
            one_by_one.mark(k, 0, m, 900.0, 300.0, pierce(k), 500.0).unwrap();
        }
        let mut ahead = TcpBuilder::new(s, Point::origin(), 0.0);
        let requests: Vec<_> = marks.iter().enumerate().map(|(k, m)| MarkRequest { points: m, speed: 900.0, pierce: pierce(k) > 0.0, breaks: &[], overscan: false }).collect();
        let runs = ahead.prepare(&requests, 0..requests.len()).unwrap();
        for (k, run) in runs.iter().enumerate() {
            ahead.mark_run(&[(k, 300.0)], 0, run.as_ref(), 0.0, pierce(k), 500.0).unwrap();
        }
        assert_eq!(one_by_one.path.pieces.len(), ahead.path.pieces.len());
        assert!((one_by_one.time - ahead.time).abs() < 1e-12, "{} vs {}", one_by_one.time, ahead.time);
        for k in 0..=1000 {
            let t = one_by_one.time * k as f64 / 1000.0;
            assert!((one_by_one.path.position(t) - ahead.path.position(t)).norm() < 1e-9, "t={t}");
        }
        let bad = MarkRequest { points: &marks[1], speed: f64::NAN, pierce: false, breaks: &[], overscan: false };
        assert!(ahead.prepare(&[bad], 0..1).is_err(), "a NaN speed is refused");
    }

    #[test]
    fn blending_and_skywriting_are_faster_than_stopping() {
        let marks = [square(1.0, 1.0, 3.0), square(6.0, 2.0, 2.0)];
        let time = |blend, skywrite| {
            let mut b = TcpBuilder::new(settings(blend, skywrite), Point::origin(), 0.0);
            for (i, m) in marks.iter().enumerate() {
                b.mark(i, 0, m, 1000.0, 300.0, 0.0, 0.0).unwrap();
            }
            b.stop(0).unwrap();
            b.path.duration()
        };
        let (stop, blend, sky) = (time(false, false), time(true, false), time(true, true));
        assert!(blend < stop && sky < blend, "{stop} {blend} {sky}");
        // 20 mm at 1000 mm/s is 20 ms; the laser-off moves are short.
        assert!(sky < 0.023, "{sky}");
    }

    #[test]
    fn a_flattened_circle_is_marked_at_constant_speed() {
        let s = settings(true, true);
        let n = 72;
        let circle: Vec<Point> = (0..=n)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / n as f64;
                Point::new(10.0 + 5.0 * a.cos(), 10.0 + 5.0 * a.sin())
            })
            .collect();
        let mut b = TcpBuilder::new(s, Point::origin(), 0.0);
        b.mark(0, 0, &circle, 1000.0, 300.0, 0.0, 0.0).unwrap();
        let marks: Vec<&Piece> = b.path.pieces.iter().filter(|p| p.is_marking()).collect();
        let (t0, t1) = (marks[0].start, marks.last().unwrap().end_time());
        let length: f64 = circle.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        // Within 1 % of length / speed: the corners of 5 degrees cost nearly nothing.
        assert!((t1 - t0) < 1.01 * length / 1000.0, "{} vs {}", t1 - t0, length / 1000.0);
        check(&b.path, &s, &[circle]);
    }

    #[test]
    fn simplify_drops_only_collinear_points() {
        let pts = vec![Point::new(0.0, 0.0), Point::new(1.0, 0.0005), Point::new(2.0, 0.0), Point::new(2.0, 1.0)];
        assert_eq!(simplify(&pts, 0.001).len(), 3);
        assert_eq!(simplify(&pts, 0.0001).len(), 4);
    }
}
