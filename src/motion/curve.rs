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
//! jerk-limited profile (`blend::Profile`) whose cruise is the highest for
//! which every sampled per-axis acceleration and jerk of the motion stays
//! within the limits. The motion is tabulated into short free moves
//! (`FreeMove::sampled`, positions, velocities and accelerations exact at
//! their steps) that the program and the checks read as any other piece.

use nalgebra::Vector2;

use super::blend::{change_distance, push_change, Profile};
use super::profile::FreeMove;
use super::tcp::{Legs, Motion, TcpSettings};
use crate::config::Limits;
use crate::job::Point;

/// A vertex turning by more than this (radians) is a corner, not a curve.
const GENTLE_TURN: f64 = 0.35;

/// The polyline with smoothed direction changes, by arc length.
struct Curve<'a> {
    points: &'a [Point],
    dirs: &'a [Vector2<f64>],
    /// Arc length at each vertex.
    at_vertex: Vec<f64>,
    /// Window of each vertex (0 at the ends).
    window: Vec<f64>,
    widest: f64,
}

/// (position, direction, its first and second derivative) at an arc length.
type CurveState = (Point, Vector2<f64>, Vector2<f64>, Vector2<f64>);

impl<'a> Curve<'a> {
    fn new(points: &'a [Point], dirs: &'a [Vector2<f64>], lengths: &[f64], width: f64) -> Curve<'a> {
        let mut at_vertex = vec![0.0];
        for l in lengths {
            at_vertex.push(at_vertex.last().unwrap() + l);
        }
        let total = *at_vertex.last().unwrap();
        let n = lengths.len();
        // Windows inside the run (its ends keep their direction), ordered
        // as the vertices so that the directions' weights stay positive.
        let window = (0..=n).map(|i| if i == 0 || i == n { 0.0 } else { width.min(2.0 * at_vertex[i]).min(2.0 * (total - at_vertex[i])) }).collect();
        Curve { points, dirs, at_vertex, window, widest: width }
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

    /// Largest distance of the smoothed path from the polyline (sampled).
    fn deviation(&self) -> f64 {
        let n = self.dirs.len();
        let mut worst: f64 = 0.0;
        for k in 0..n {
            for q in 0..8 {
                let s = self.at_vertex[k] + (self.at_vertex[k + 1] - self.at_vertex[k]) * q as f64 / 8.0;
                let p = self.state(s).0;
                let from = self.at_vertex.partition_point(|&x| x < s - self.widest).saturating_sub(1);
                let to = self.at_vertex.partition_point(|&x| x <= s + self.widest).min(n);
                let off = (from..to)
                    .map(|j| segment_distance(p, self.points[j], self.points[j + 1]))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(off);
            }
        }
        worst
    }
}

fn segment_distance(p: Point, a: Point, b: Point) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    let f = if l2 > 0.0 { ((p - a).dot(&d) / l2).clamp(0.0, 1.0) } else { 0.0 };
    (p - (a + d * f)).norm()
}

/// The speed along the curve: from `entry` to `cruise` to `exit`, or none
/// where those changes do not fit its length.
fn speed_profile(length: f64, entry: f64, cruise: f64, exit: f64, tangential: &Limits) -> Option<Profile> {
    let (entry, exit) = (entry.min(cruise), exit.min(cruise));
    let ramps = change_distance(entry, cruise, tangential) + change_distance(cruise, exit, tangential);
    if cruise.is_nan() || cruise <= 0.0 || ramps > length {
        return None;
    }
    let mut p = Profile::new(entry);
    push_change(&mut p, cruise, tangential);
    p.push((length - ramps) / cruise, 0.0);
    push_change(&mut p, exit, tangential);
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
        .map(|f| Curve::new(points, dirs, lengths, f * mean))
        .find(|c| c.deviation() <= 0.95 * s.corner_tolerance)?;
    let top = limits.iter().map(|l| l.velocity).fold(f64::INFINITY, f64::min);
    let tangential = Limits { velocity: top, acceleration: 0.5 * s.axis.acceleration, jerk: 0.5 * s.axis.jerk };
    let fits = |v: f64| speed_profile(curve.length(), entry, v, exit, &tangential).filter(|p| within_limits(&curve, p, &s.axis));
    let best = match fits(top) {
        Some(p) => p,
        None => {
            let (mut lo, mut hi, mut found) = (0.0, top, None);
            for _ in 0..16 {
                let mid = 0.5 * (lo + hi);
                match fits(mid) {
                    Some(p) => {
                        lo = mid;
                        found = Some(p);
                    }
                    None => hi = mid,
                }
            }
            found?
        }
    };
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
