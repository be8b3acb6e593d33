//! Stage-only runs of gentle vertices (flattened curves) as one smooth curve.
//!
//! Turned one vertex at a time (`blend`), the TCP's acceleration returns to 0
//! between vertices, which caps a curve flattened into short legs far below
//! what its curvature allows. Here the direction of travel is smoothed along
//! the arc length instead: at each vertex the direction changes by a pure-jerk
//! S-curve over a window `W` around it, the windows of neighbouring vertices
//! overlapping, so the path turns continuously (a circle gets a nearly
//! constant curvature). The widest window whose path stays within
//! `corner_tolerance` of the polyline is taken; the speed along it is one
//! jerk-limited profile (`blend::Profile`): entry, ramp, cruise, ramp, exit.
//! On an axis the curve's own (centripetal) acceleration v²·d' adds to the
//! ramp's tangential one, so a ramp's acceleration steps down as its speed
//! nears the cruise, keeping to what the curve leaves at each speed; of
//! several cruises up to what the curvature allows, the fastest profile
//! whose every sampled per-axis acceleration and jerk stays within the
//! limits is taken. The motion is tabulated into short free moves
//! (`FreeMove::sampled`, positions, velocities and accelerations exact at
//! their steps) that the program and the checks read as any other piece.

use nalgebra::Vector2;

use super::blend::Profile;
use super::profile::FreeMove;
use super::tcp::{Legs, Motion, TcpSettings};
use crate::config::Limits;
use crate::job::Point;

/// A vertex turning by more than this (radians) is a corner, not a curve.
const GENTLE_TURN: f64 = 0.35;

/// The polyline with smoothed direction changes, by arc length.
struct Curve {
    points: Vec<Point>,
    dirs: Vec<Vector2<f64>>,
    /// Arc length at each vertex.
    at_vertex: Vec<f64>,
    /// Window of each vertex (0 at the ends).
    window: Vec<f64>,
    widest: f64,
}

/// (position, direction, its first and second derivative) at an arc length.
type CurveState = (Point, Vector2<f64>, Vector2<f64>, Vector2<f64>);

impl Curve {
    fn new(points: Vec<Point>, width: f64) -> Curve {
        let dirs: Vec<Vector2<f64>> = points.windows(2).map(|w| (w[1] - w[0]).normalize()).collect();
        let mut at_vertex = vec![0.0];
        for w in points.windows(2) {
            at_vertex.push(at_vertex.last().unwrap() + (w[1] - w[0]).norm());
        }
        let total = *at_vertex.last().unwrap();
        let n = dirs.len();
        // Windows inside the run (its ends keep their direction), ordered
        // as the vertices so that the directions' weights stay positive.
        let window = (0..=n).map(|i| if i == 0 || i == n { 0.0 } else { width.min(2.0 * at_vertex[i]).min(2.0 * (total - at_vertex[i])) }).collect();
        Curve { points, dirs, at_vertex, window, widest: width }
    }

    /// The curve through `points` smoothed over windows of `width`, its
    /// vertices moved so that it passes near the polyline: the smoothing
    /// cuts inside every turn (by ~turn·width/12 per window, the
    /// overlapping windows adding up), which a few rounds of moving each
    /// vertex by the cut left at it undo. The aim at each vertex is an
    /// eighth of the way to its neighbours' midpoint (on a flattened
    /// circle, halfway between the vertices and the chords). The run
    /// enters and leaves along its first and last legs: their outer halves
    /// stay, split off at their midpoints.
    fn compensated(points: &[Point], width: f64) -> Curve {
        let n = points.len() - 1;
        let half = |a: Point, b: Point| Point::from(0.5 * (a.coords + b.coords));
        let mut start = vec![points[0], half(points[0], points[1])];
        start.extend_from_slice(&points[1..n]);
        start.extend([half(points[n - 1], points[n]), points[n]]);
        // Vertex i of `points` is i + 1 of `start`.
        let aim = |i: usize| points[i] + (half(points[i - 1], points[i + 1]) - points[i]) / 8.0;
        let mut curve = Curve::new(start, width);
        for _ in 0..4 {
            let mut moved = curve.points.clone();
            for i in 1..n {
                moved[i + 1] -= curve.state(curve.at_vertex[i + 1]).0 - aim(i);
            }
            curve = Curve::new(moved, width);
        }
        curve
    }

    fn length(&self) -> f64 {
        *self.at_vertex.last().unwrap()
    }

    fn state(&self, s: f64) -> CurveState {
        let n = self.dirs.len();
        let s = s.clamp(0.0, self.length());
        let k = self.at_vertex[..n].partition_point(|&x| x <= s).saturating_sub(1);
        let mut p = self.points[k] + self.dirs[k] * (s - self.at_vertex[k]);
        let (mut d, mut d1, mut d2) = (self.dirs[k], Vector2::zeros(), Vector2::zeros());
        let reach = 0.5 * self.widest;
        let first = self.at_vertex.partition_point(|&x| x < s - reach).max(1);
        let last = self.at_vertex.partition_point(|&x| x <= s + reach).min(n);
        for i in first..last {
            let w = self.window[i];
            let y = (s - self.at_vertex[i]) / w;
            if w <= 0.0 || y.abs() >= 0.5 {
                continue;
            }
            let turn = self.dirs[i] - self.dirs[i - 1];
            let z = y + 0.5;
            let (shape, slope, bend) = if z <= 0.5 { (2.0 * z * z, 4.0 * z, 4.0) } else { (1.0 - 2.0 * (1.0 - z) * (1.0 - z), 4.0 * (1.0 - z), -4.0) };
            let passed = if y >= 0.0 { 1.0 } else { 0.0 };
            // The integral of (shape - step) from the window's start.
            p += turn * (w * 2.0 / 3.0 * (0.5 - y.abs()).powi(3));
            d += turn * (shape - passed);
            d1 += turn * (slope / w);
            d2 += turn * (bend / (w * w));
        }
        (p, d, d1, d2)
    }

    /// Largest distance of the smoothed path from `polyline` (sampled; its
    /// arc lengths near this curve's own).
    fn deviation(&self, polyline: &[Point]) -> f64 {
        let mut along = vec![0.0];
        for w in polyline.windows(2) {
            along.push(along.last().unwrap() + (w[1] - w[0]).norm());
        }
        let m = polyline.len() - 1;
        let mut worst: f64 = 0.0;
        for k in 0..self.dirs.len() {
            for q in 0..8 {
                let s = self.at_vertex[k] + (self.at_vertex[k + 1] - self.at_vertex[k]) * q as f64 / 8.0;
                let p = self.state(s).0;
                let from = along.partition_point(|&x| x < s - self.widest).saturating_sub(1);
                let to = along.partition_point(|&x| x <= s + self.widest).min(m);
                let off = (from..to)
                    .map(|j| segment_distance(p, polyline[j], polyline[j + 1]))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(off);
            }
        }
        worst
    }

    /// The largest per-axis component of the direction's first and second
    /// derivative along the curve from arc length `from` to `to` (sampled).
    fn bend(&self, from: f64, to: f64) -> Bend {
        let samples = (16.0 * self.dirs.len() as f64 * (to - from) / self.length()).ceil().max(16.0) as usize;
        let mut bend = Bend { turning: 0.0, turning_change: 0.0 };
        for q in 0..=samples {
            let (_, _, d1, d2) = self.state(from + (to - from) * q as f64 / samples as f64);
            bend.turning = bend.turning.max(d1.x.abs()).max(d1.y.abs());
            bend.turning_change = bend.turning_change.max(d2.x.abs()).max(d2.y.abs());
        }
        bend
    }
}

/// Bounds of a curve's direction `d(s)` by arc length: per axis |d'| and |d''|.
struct Bend {
    turning: f64,
    turning_change: f64,
}

impl Bend {
    /// The fastest constant speed the axes allow along the curve: there the
    /// acceleration is d'·v² and the jerk d''·v³.
    fn top_speed(&self, axis: &Limits) -> f64 {
        (axis.acceleration / self.turning).sqrt().min((axis.jerk / self.turning_change).cbrt())
    }

    /// The tangential acceleration and jerk the axes leave at speeds up to
    /// `v`: per axis |d'·v² + d·a| ≤ K1·v² + a and |d''·v³ + 3·d'·v·a + d·j|
    /// ≤ K2·v³ + 3·K1·v·a + j (|d| ≤ 1), a little inside the limits; the
    /// cross term takes at most half the jerk the curve leaves.
    fn tangential(&self, axis: &Limits, v: f64) -> Option<Limits> {
        let jerk_left = axis.jerk - self.turning_change * v.powi(3);
        let cross = 3.0 * self.turning * v;
        let mut acceleration = (0.95 * (axis.acceleration - self.turning * v * v)).min(RAMP_MOST * axis.acceleration);
        if cross > 0.0 {
            acceleration = acceleration.min(0.5 * jerk_left / cross);
        }
        let jerk = (0.95 * (jerk_left - cross * acceleration)).min(RAMP_MOST * axis.jerk);
        // `velocity`: the speed up to which these hold.
        (acceleration > 0.0 && jerk > 0.0).then_some(Limits { velocity: v, acceleration, jerk })
    }
}

fn segment_distance(p: Point, a: Point, b: Point) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    let f = if l2 > 0.0 { ((p - a).dot(&d) / l2).clamp(0.0, 1.0) } else { 0.0 };
    (p - (a + d * f)).norm()
}

/// The largest share of the axes' acceleration and jerk a ramp takes, as
/// before the ramps kept to the curve: steeper ramps from rest after a
/// pierce start with blocks the timed controller runs alone and then stands
/// still after (a jerk breach on `samples/marking-300.svg`, flatbed).
const RAMP_MOST: f64 = 0.5;

/// Where a ramp's acceleration steps down: fractions of its speed change.
const RAMP_LEVELS: [f64; 7] = [0.4, 0.6, 0.75, 0.85, 0.92, 0.97, 1.0];

/// The phases (duration, jerk) of a speed change from `from` up to `to`
/// along the curve: the acceleration rises to the level the curve leaves at
/// the first step's speed, holds, and steps down level by level, reaching
/// each level by the speed it is taken at and 0 at `to`. The ramp takes
/// `share` of what the inner part of the curve leaves (its ends, with
/// narrower windows, may leave less). Levels too close for their steps
/// merge into the next (lower) one; a single level too short for a hold
/// peaks lower (pure jerk).
fn ramp(from: f64, to: f64, bend: &Bend, axis: &Limits, share: f64) -> Option<Vec<(f64, f64)>> {
    // A change of rounding size would be phases of nanoseconds (as in
    // `blend::push_change`).
    if to - from <= axis.jerk * 1e-12 {
        return Some(Vec::new());
    }
    let mut levels = RAMP_LEVELS
        .iter()
        .map(|f| {
            let v = from + (to - from) * f;
            bend.tangential(axis, v).map(|l| Limits { acceleration: share * l.acceleration, jerk: share * l.jerk, ..l })
        })
        .collect::<Option<Vec<Limits>>>()?;
    // Each level's hold (s) between its rise (the first) and its step down.
    let holds = |levels: &[Limits]| {
        let mut at = from;
        levels
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let next = levels.get(k + 1).map_or(0.0, |n| n.acceleration);
                let rise = if k == 0 { l.acceleration.powi(2) / (2.0 * l.jerk) } else { 0.0 };
                let step = (l.acceleration.powi(2) - next * next) / (2.0 * l.jerk);
                let hold = (l.velocity - at - rise - step) / l.acceleration;
                at = l.velocity;
                hold
            })
            .collect::<Vec<f64>>()
    };
    while let Some(k) = holds(&levels).iter().position(|&h| h < 0.0) {
        if levels.len() == 1 {
            levels[0].acceleration = ((to - from) * levels[0].jerk).sqrt();
            break;
        }
        levels.remove(k.min(levels.len() - 2));
    }
    let mut phases = vec![(levels[0].acceleration / levels[0].jerk, levels[0].jerk)];
    for (k, (l, hold)) in levels.iter().zip(holds(&levels)).enumerate() {
        let next = levels.get(k + 1).map_or(0.0, |n| n.acceleration);
        phases.push((hold, 0.0));
        phases.push(((l.acceleration - next) / l.jerk, -l.jerk));
    }
    Some(phases)
}

/// The speed along the curve: from `entry` to `cruise` to `exit`, or none
/// where those changes do not fit its length.
fn speed_profile(length: f64, [entry, cruise, exit]: [f64; 3], bend: &Bend, axis: &Limits, share: f64) -> Option<Profile> {
    if cruise.is_nan() || cruise <= 0.0 {
        return None;
    }
    let (entry, exit) = (entry.min(cruise), exit.min(cruise));
    let (up, down) = (ramp(entry, cruise, bend, axis, share)?, ramp(exit, cruise, bend, axis, share)?);
    let distance = |from: f64, phases: &[(f64, f64)]| {
        let mut p = Profile::new(from);
        phases.iter().for_each(|&(d, j)| p.push(d, j));
        p.length
    };
    let ramps = distance(entry, &up) + distance(exit, &down);
    if ramps > length {
        return None;
    }
    let mut p = Profile::new(entry);
    up.iter().for_each(|&(d, j)| p.push(d, j));
    p.push((length - ramps) / cruise, 0.0);
    // The slow-down is the speed-up to the exit backwards in time (same jerks).
    down.iter().rev().for_each(|&(d, j)| p.push(d, j));
    Some(p)
}

/// Per-axis velocity, acceleration and jerk of the motion at time `t`.
fn axis_state(curve: &Curve, speed: &Profile, t: f64) -> (Point, [Vector2<f64>; 3]) {
    let [s, v, a, j] = speed.at(t);
    let (p, d, d1, d2) = curve.state(s);
    let vel = d * v;
    let acc = d1 * (v * v) + d * a;
    let jerk = d2 * (v * v * v) + d1 * (3.0 * v * a) + d * j;
    (p, [vel, acc, jerk])
}

/// Cruise speeds tried per curve.
const CRUISES: usize = 48;

/// Shares of what the curve leaves that the ramps take, tried per cruise.
const RAMP_SHARES: [f64; 4] = [1.0, 0.6, 0.35, 0.2];

/// Sample step of the limit check and of the tables (s).
const STEP: f64 = 2.5e-4;

fn within_limits(curve: &Curve, speed: &Profile, axis: &Limits) -> bool {
    let mut times = Vec::new();
    speed.breakpoints(&mut times);
    let n = (speed.duration / STEP).ceil() as usize;
    times.extend((0..=n).map(|k| speed.duration * k as f64 / n.max(1) as f64));
    let inside = |v: Vector2<f64>, limit: f64| v.x.abs() <= limit && v.y.abs() <= limit;
    times.iter().all(|&t| {
        // Either side of a phase change (the jerk steps there).
        [t - 1e-9, t + 1e-9].iter().all(|&t| {
            let (_, [v, a, j]) = axis_state(curve, speed, t);
            inside(v, axis.velocity) && inside(a, axis.acceleration) && inside(j, axis.jerk)
        })
    })
}

/// The run through `points` (its legs' lengths and directions, the layer's
/// `speed` capped per leg in `limits`) as one smooth curve from speed `entry`
/// to speed `exit`, when every inner vertex is gentle: its pieces (start,
/// duration, motion) and its duration.
pub fn plan(s: &TcpSettings, points: &[Point], lengths: &[f64], dirs: &[Vector2<f64>], limits: &[Limits], entry: f64, exit: f64) -> Option<(Legs, f64)> {
    let n = dirs.len();
    if n < 3 || dirs.windows(2).any(|w| w[0].dot(&w[1]).clamp(-1.0, 1.0).acos() > GENTLE_TURN) {
        return None;
    }
    // The widest window that keeps to the tolerance (a little inside it:
    // the deviation is sampled).
    let mean = lengths.iter().sum::<f64>() / n as f64;
    let curve = [8.0, 6.0, 4.0, 3.0, 2.0, 1.5, 1.0]
        .iter()
        .map(|f| Curve::compensated(points, f * mean))
        .find(|c| c.deviation(points) <= 0.95 * s.corner_tolerance)?;
    let top = limits.iter().map(|l| l.velocity).fold(f64::INFINITY, f64::min);
    let (length, reach) = (curve.length(), curve.widest.min(0.5 * curve.length()));
    let bend = curve.bend(reach, length - reach);
    let ceiling = top.min(bend.top_speed(&s.axis));
    // Within a window of its ends, where the windows narrow, the curve
    // bends more sharply than inside: there it starts and ends no faster
    // than it could run at a constant speed (a little below).
    let ends = [curve.bend(0.0, reach), curve.bend(length - reach, length)].map(|b| 0.9 * b.top_speed(&s.axis));
    let (entry, exit) = (entry.min(ends[0]), exit.min(ends[1]));
    // Cruises in steps of 1/CRUISES of the fastest the curvature allows,
    // ramps taking several shares of what it leaves: the fastest profile
    // within the limits (the highest cruise leaves its ramps little
    // acceleration).
    let mut profiles: Vec<Profile> = (0..CRUISES)
        .flat_map(|k| RAMP_SHARES.map(|share| (ceiling * (1.0 - k as f64 / CRUISES as f64), share)))
        .filter_map(|(cruise, share)| speed_profile(length, [entry, cruise, exit], &bend, &s.axis, share))
        .collect();
    profiles.sort_by(|a, b| a.duration.total_cmp(&b.duration));
    let best = profiles.into_iter().find(|p| within_limits(&curve, p, &s.axis))?;
    // Free moves of at most 16 table steps each.
    let total = best.duration;
    let chunks = ((total / (16.0 * STEP)).ceil() as usize).max(1);
    let mut pieces = Vec::with_capacity(chunks);
    for c in 0..chunks {
        let (t0, t1) = (total * c as f64 / chunks as f64, total * (c + 1) as f64 / chunks as f64);
        let table = (0..=16)
            .map(|k| {
                let t = t0 + (t1 - t0) * k as f64 / 16.0;
                let (p, [v, a, _]) = axis_state(&curve, &best, t);
                (p, v, a)
            })
            .collect();
        pieces.push((t0, t1 - t0, Motion::Free(FreeMove::sampled(t1 - t0, table))));
    }
    Some((pieces, total))
}
