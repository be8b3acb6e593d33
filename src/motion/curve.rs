//! Stage-only runs of gentle vertices (flattened curves, rounded corners
//! between straights) as one smooth curve.
//!
//! Turned one vertex at a time (`blend`), the TCP's acceleration returns to 0
//! between vertices, which caps a curve flattened into short legs far below
//! what its curvature allows. Here the direction of travel is smoothed along
//! the arc length instead: at each vertex the direction changes by a pure-jerk
//! S-curve over a window around it (a multiple of its shorter leg), the
//! windows of neighbouring vertices overlapping, so the path turns
//! continuously (a circle gets a nearly constant curvature). The widest
//! windows whose path stays within `corner_tolerance` of the polyline are
//! taken. The speed follows the curve: sampled, each place has a top speed
//! (the feed, and what the curvature and its change leave the axes);
//! stretches of like top speed are sections, each run at most at its cap
//! with jerk-limited ramps (`blend::Profile`) between, so a rounded
//! rectangle runs its sides at the feed and slows only for its corners. On
//! an axis the curve's own (centripetal) acceleration κ·v² adds to the
//! ramp's tangential one at right angles, so a ramp's acceleration steps
//! down as its speed nears what the curve allows. Of several scales of the
//! caps and shares of the ramps, the fastest profile whose every sampled
//! per-axis velocity, acceleration and jerk stays within the limits is
//! taken. The motion is tabulated into short free moves
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
    /// Each inner vertex's window is `factor` times its shorter leg (long
    /// straights between short curved legs keep their own shape), then
    /// narrowed so that neighbouring windows differ by at most twice the leg
    /// between them: their edges stay in the order of the vertices, so the
    /// directions' weights stay positive. The ends keep their direction.
    fn new(points: Vec<Point>, factor: f64) -> Curve {
        let dirs: Vec<Vector2<f64>> = points.windows(2).map(|w| (w[1] - w[0]).normalize()).collect();
        let legs: Vec<f64> = points.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
        let mut at_vertex = vec![0.0];
        for l in &legs {
            at_vertex.push(at_vertex.last().unwrap() + l);
        }
        let n = dirs.len();
        // A vertex that does not turn needs no window (the split ends' midpoints).
        let turns = |i: usize| turns_more_than(dirs[i - 1], dirs[i], 1e-9);
        let mut window: Vec<f64> = (0..=n).map(|i| if i == 0 || i == n || !turns(i) { 0.0 } else { factor * legs[i - 1].min(legs[i]) }).collect();
        for i in 0..n {
            window[i + 1] = window[i + 1].min(window[i] + 2.0 * legs[i]);
        }
        for i in (0..n).rev() {
            window[i] = window[i].min(window[i + 1] + 2.0 * legs[i]);
        }
        let widest = window.iter().cloned().fold(0.0, f64::max);
        Curve { points, dirs, at_vertex, window, widest }
    }

    /// The curve through `points` smoothed over windows of `factor` legs, its
    /// vertices moved so that it passes near the polyline: the smoothing
    /// cuts inside every turn (by ~turn·width/12 per window, the
    /// overlapping windows adding up), which a few rounds of moving each
    /// vertex by the cut left at it undo. The aim at each vertex is an
    /// eighth of the way to its neighbours' midpoint (on a flattened
    /// circle, halfway between the vertices and the chords). The run
    /// enters and leaves along its first and last legs: their outer halves
    /// stay, split off at their midpoints.
    fn compensated(points: &[Point], factor: f64) -> Curve {
        let n = points.len() - 1;
        let half = |a: Point, b: Point| Point::from(0.5 * (a.coords + b.coords));
        let mut start = vec![points[0], half(points[0], points[1])];
        start.extend_from_slice(&points[1..n]);
        start.extend([half(points[n - 1], points[n]), points[n]]);
        // Vertex i of `points` is i + 1 of `start`.
        let aim = |i: usize| points[i] + (half(points[i - 1], points[i + 1]) - points[i]) / 8.0;
        let mut curve = Curve::new(start, factor);
        for _ in 0..4 {
            let mut moved = curve.points.clone();
            for i in 1..n {
                moved[i + 1] -= curve.state(curve.at_vertex[i + 1]).0 - aim(i);
            }
            curve = Curve::new(moved, factor);
        }
        curve
    }

    fn length(&self) -> f64 {
        *self.at_vertex.last().unwrap()
    }

    /// The widest window of a vertex that turns by more than a trace (the
    /// compensation bends a split end's midpoint by a trace).
    fn reach(&self) -> f64 {
        (1..self.dirs.len())
            .filter(|&i| turns_more_than(self.dirs[i - 1], self.dirs[i], 1e-3))
            .map(|i| self.window[i])
            .fold(0.0, f64::max)
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

    /// The curve sampled along its arc length (`SAMPLES_PER_LEG` per leg
    /// and its end): per axis its bend there, and the fastest constant
    /// speed the axes and `speed` allow.
    fn samples(&self, speed: f64, axis: &Limits) -> Vec<Sample> {
        let mut at: Vec<f64> = (0..self.dirs.len())
            .flat_map(|k| (0..SAMPLES_PER_LEG).map(move |q| (k, q)))
            .map(|(k, q)| self.at_vertex[k] + (self.at_vertex[k + 1] - self.at_vertex[k]) * q as f64 / SAMPLES_PER_LEG as f64)
            .collect();
        at.push(self.length());
        at.into_iter()
            .map(|s| {
                let (_, d, d1, d2) = self.state(s);
                // The curve's normal, and the rate its curvature changes at.
                let normal = Vector2::new(-d.y, d.x) / d.norm().max(1e-12);
                let bend = Bend {
                    turning: d1.x.abs().max(d1.y.abs()),
                    turning_change: d2.x.abs().max(d2.y.abs()),
                    curvature: d1.norm(),
                    curvature_change: d2.dot(&normal).abs(),
                };
                let along = axis.velocity / d.x.abs().max(d.y.abs()).max(1e-12);
                let (feed, bent) = (speed.min(along), bend.top_speed(axis));
                Sample { s, feed, bent, bend }
            })
            .collect()
    }
}

/// Samples of the curve's bend per leg (its windows change within a leg).
const SAMPLES_PER_LEG: usize = 8;

struct Sample {
    s: f64,
    /// The fastest constant speed here within the feed and the axes'
    /// velocity, and within what the curvature allows.
    feed: f64,
    bent: f64,
    bend: Bend,
}

impl Sample {
    /// The fastest constant speed here.
    fn cap(&self) -> f64 {
        self.feed.min(self.bent)
    }
}

/// Bounds of a curve's direction `d(s)` by arc length: per axis |d'| and |d''|.
#[derive(Clone, Copy)]
struct Bend {
    turning: f64,
    turning_change: f64,
    /// |d'| and the normal part of d'' (the curvature and its rate of change).
    curvature: f64,
    curvature_change: f64,
}

impl Bend {
    /// The fastest constant speed the axes allow along the curve: there the
    /// acceleration is d'·v² and the jerk d''·v³.
    fn top_speed(&self, axis: &Limits) -> f64 {
        (axis.acceleration / self.turning).sqrt().min((axis.jerk / self.turning_change).cbrt())
    }

    fn max(self, other: Bend) -> Bend {
        Bend {
            turning: self.turning.max(other.turning),
            turning_change: self.turning_change.max(other.turning_change),
            curvature: self.curvature.max(other.curvature),
            curvature_change: self.curvature_change.max(other.curvature_change),
        }
    }

    /// The tangential acceleration `a` and jerk `j` the axes leave at
    /// speeds up to `v`, a little inside the limits. Along the curve (unit
    /// tangent T, normal N, curvature κ) the acceleration is κ·v²·N + a·T
    /// and the jerk (κ'·v³ + 3·κ·v·a)·N + (j − κ²·v³)·T; an axis takes of a
    /// vector x·N + y·T at most √(x² + y²). The ramp's own part of the
    /// normal jerk (3·κ·v·a) takes at most half of what the curve leaves.
    fn tangential(&self, axis: &Limits, v: f64) -> Option<Limits> {
        let (k, dk) = (self.curvature, self.curvature_change);
        let (most_a, most_j) = (0.95 * axis.acceleration, 0.95 * axis.jerk);
        let along = k * k * v.powi(3);
        let normal_own = dk * v.powi(3);
        let left = (most_j * most_j - along * along).max(0.0).sqrt();
        let mut acceleration = (most_a * most_a - (k * v * v).powi(2)).max(0.0).sqrt();
        if k * v > 0.0 {
            acceleration = acceleration.min(0.5 * (left - normal_own) / (3.0 * k * v));
        }
        let normal = normal_own + 3.0 * k * v * acceleration;
        let jerk = (most_j * most_j - normal * normal).max(0.0).sqrt() - along;
        // `velocity`: the speed up to which these hold.
        (acceleration > 0.0 && jerk > 0.0).then_some(Limits { velocity: v, acceleration, jerk })
    }
}

/// Whether the direction turns from `a` to `b` (unit vectors) by more than
/// `angle` (radians, small).
fn turns_more_than(a: Vector2<f64>, b: Vector2<f64>, angle: f64) -> bool {
    a.perp(&b).abs() > angle || a.dot(&b) < 0.0
}

fn segment_distance(p: Point, a: Point, b: Point) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    let f = if l2 > 0.0 { ((p - a).dot(&d) / l2).clamp(0.0, 1.0) } else { 0.0 };
    (p - (a + d * f)).norm()
}

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

/// A stretch of the curve whose samples' top speeds lie within `SECTION_SPREAD`
/// of each other: it runs at one cruise at most, its ramps within what its
/// most bent sample leaves.
struct Section {
    length: f64,
    /// The lowest top speed of its samples: of the feed and the axes'
    /// velocity (`feed`), and of the curvature (`bent`).
    feed: f64,
    bent: f64,
    bend: Bend,
}

impl Section {
    fn of(samples: &[&Sample]) -> Section {
        let (first, last) = (samples[0], samples[samples.len() - 1]);
        let lowest = |f: &dyn Fn(&Sample) -> f64| samples.iter().map(|x| f(x)).fold(f64::INFINITY, f64::min);
        Section {
            length: last.s - first.s,
            feed: lowest(&|x| x.feed),
            bent: lowest(&|x| x.bent),
            bend: samples.iter().skip(1).fold(first.bend, |b, x| b.max(x.bend)),
        }
    }

    /// The lowest top speed of its samples.
    fn cap(&self) -> f64 {
        self.feed.min(self.bent)
    }

    fn join(&self, other: &Section) -> Section {
        Section {
            length: self.length + other.length,
            feed: self.feed.min(other.feed),
            bent: self.bent.min(other.bent),
            bend: self.bend.max(other.bend),
        }
    }
}

/// The lowest ratio of top speeds within one section.
const SECTION_SPREAD: f64 = 0.8;

/// The curve cut into sections. The stretch between two samples belongs to
/// the slower side, so a section's cap holds along all of it. A section
/// shorter than a jerk phase at its cap (the turn-in between a straight and
/// an arc, say) joins its slower neighbour unless it is slower than both:
/// a ramp cut short at its boundaries would restart from no acceleration
/// there.
fn sections(samples: &[&Sample], axis: &Limits) -> Vec<Section> {
    let mut out = Vec::new();
    let (mut from, mut lo, mut hi) = (0, samples[0].cap(), samples[0].cap());
    for j in 1..samples.len() {
        let cap = samples[j].cap();
        if cap.min(lo) >= SECTION_SPREAD * cap.max(hi) {
            (lo, hi) = (lo.min(cap), hi.max(cap));
            continue;
        }
        // Slower ahead: the new section starts at the last sample; faster:
        // this one ends at the next.
        let at = if cap < lo { j - 1 } else { j };
        out.push(Section::of(&samples[from..=at]));
        from = at;
        (lo, hi) = (samples[from..=j].iter().map(|x| x.cap()).fold(f64::INFINITY, f64::min), samples[from..=j].iter().map(|x| x.cap()).fold(0.0, f64::max));
    }
    out.push(Section::of(&samples[from..]));
    out.retain(|x| x.length > 0.0);
    let short = |x: &Section| x.length < x.cap() * axis.acceleration / axis.jerk;
    loop {
        let cap = |i: Option<usize>| i.and_then(|i| out.get(i)).map_or(f64::INFINITY, |x: &Section| x.cap());
        let merge = (0..out.len()).find_map(|i| {
            let (left, right) = (cap(i.checked_sub(1)), cap(Some(i + 1)));
            let into = if left <= right { i.checked_sub(1) } else { Some(i + 1) };
            (short(&out[i]) && out.len() > 1 && out[i].cap() >= left.min(right)).then_some((i, into?))
        });
        let Some((i, into)) = merge else { break };
        let x = out.remove(i);
        let k = if into > i { into - 1 } else { into };
        out[k] = out[k].join(&x);
    }
    out
}

/// Distance of the speed change between `a` and `b` (either way) in a
/// section, if the curve leaves room for it.
fn ramp_distance(a: f64, b: f64, section: &Section, axis: &Limits, share: f64) -> Option<f64> {
    let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
    let phases = ramp(lo, hi, &section.bend, axis, share)?;
    let mut p = Profile::new(lo);
    phases.iter().for_each(|&(d, j)| p.push(d, j));
    Some(p.length)
}

/// The largest value in `lo..=hi` that `ok` takes (`ok(lo)` holds).
fn largest(lo: f64, hi: f64, ok: &dyn Fn(f64) -> bool) -> f64 {
    super::blend::bisect(lo, hi, 30, ok)
}

/// The speed along the curve from `entry` to `exit` (both at most what the
/// sections allow): the sections' curvature caps scaled by `scale`, the speeds at their
/// boundaries lowered by a forward and a backward pass until every change
/// fits its section, then in each section a ramp up to the fastest peak that
/// fits, a cruise and a ramp down. Every change starts and ends without
/// acceleration. None where the curve leaves no room for a ramp.
fn speed_along(sections: &[Section], scale: f64, share: f64, entry: f64, exit: f64, axis: &Limits) -> Option<Profile> {
    let k = sections.len();
    let caps: Vec<f64> = sections.iter().map(|x| x.feed.min(scale * x.bent)).collect();
    let mut u: Vec<f64> = (0..=k)
        .map(|i| match i {
            0 => entry.min(caps[0]),
            i if i == k => exit.min(caps[k - 1]),
            i => caps[i - 1].min(caps[i]),
        })
        .collect();
    let fits = |i: usize, a: f64, b: f64| ramp_distance(a, b, &sections[i], axis, share).is_some_and(|d| d <= sections[i].length);
    for i in 0..k {
        if u[i + 1] > u[i] && !fits(i, u[i], u[i + 1]) {
            u[i + 1] = largest(u[i], u[i + 1], &|b| fits(i, u[i], b));
        }
    }
    for i in (0..k).rev() {
        if u[i] > u[i + 1] && !fits(i, u[i], u[i + 1]) {
            u[i] = largest(u[i + 1], u[i], &|a| fits(i, a, u[i + 1]));
        }
    }
    let mut p = Profile::new(u[0]);
    for (i, x) in sections.iter().enumerate() {
        let (a, b) = (u[i], u[i + 1]);
        let both = |v: f64| Some(ramp_distance(a, v, x, axis, share)? + ramp_distance(b, v, x, axis, share)?);
        let peak = largest(a.max(b), caps[i], &|v| both(v).is_some_and(|d| d <= x.length));
        if peak <= 0.0 {
            return None;
        }
        let (up, down) = (ramp(a, peak, &x.bend, axis, share)?, ramp(b, peak, &x.bend, axis, share)?);
        up.iter().for_each(|&(d, j)| p.push(d, j));
        p.push((x.length - both(peak)?).max(0.0) / peak, 0.0);
        // The slow-down is the speed-up to the exit backwards in time (same jerks).
        down.iter().rev().for_each(|&(d, j)| p.push(d, j));
    }
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

/// Scales of the sections' caps tried per curve, fastest first: a cap is
/// the top speed at the samples, which the curve may exceed between them.
const SCALES: [f64; 6] = [1.0, 0.95, 0.88, 0.75, 0.55, 0.35];

/// Shares of what the curve leaves that the ramps take, tried per scale.
const RAMP_SHARES: [f64; 5] = [1.0, 0.85, 0.7, 0.5, 0.25];

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

/// The run through `points` (its legs' directions `dirs`) marked at
/// `speed` as one smooth curve from speed `entry` to speed `exit`, when
/// every inner vertex is gentle: its pieces (start, duration, motion) and
/// its duration. The speed follows the curve: it slows where the curve bends
/// sharply (a rounded corner) and runs fast where it is straight.
pub fn plan(s: &TcpSettings, points: &[Point], dirs: &[Vector2<f64>], speed: f64, entry: f64, exit: f64) -> Option<(Legs, f64)> {
    let n = dirs.len();
    if n < 3 || dirs.windows(2).any(|w| w[0].dot(&w[1]).clamp(-1.0, 1.0).acos() > GENTLE_TURN) {
        return None;
    }
    // The widest windows that keep to the tolerance (a little inside it:
    // the deviation is sampled).
    let curve = [8.0, 6.0, 4.0, 3.0, 2.0, 1.5, 1.0]
        .iter()
        .map(|&f| Curve::compensated(points, f))
        .find(|c| c.deviation(points) <= 0.95 * s.corner_tolerance)?;
    // Two ways to cut it into sections: all of it, or its inner part (the
    // first and last sections reaching over the ends). Within a window of
    // its ends, where the windows narrow, the curve bends more sharply than
    // inside (a circle's curvature grows in from the straight ends): the
    // inner cut lets a ramp from rest run through there on the inner
    // sections' bend, starting and ending no faster than the ends could run
    // at a constant speed (a little below); the limit check has the last word.
    let samples = curve.samples(speed, &s.axis);
    let (length, reach) = (curve.length(), curve.reach().min(0.5 * curve.length()));
    let end_cap = |inside: &dyn Fn(f64) -> bool| 0.9 * samples.iter().filter(|x| inside(x.s)).map(|x| x.cap()).fold(f64::INFINITY, f64::min);
    let ends = (entry.min(end_cap(&|x| x <= reach)), exit.min(end_cap(&|x| x >= length - reach)));
    let inner: Vec<&Sample> = samples.iter().filter(|x| x.s >= reach && x.s <= length - reach).collect();
    let mut cuts = vec![(sections(&samples.iter().collect::<Vec<_>>(), &s.axis), (entry, exit))];
    if inner.len() >= 2 {
        let mut sections = sections(&inner, &s.axis);
        if let (Some(first), Some(x)) = (inner.first(), sections.first_mut()) {
            x.length += first.s;
        }
        if let (Some(last), Some(x)) = (inner.last(), sections.last_mut()) {
            x.length += length - last.s;
        }
        cuts.push((sections, ends));
    }
    // The fastest profile within the limits.
    let mut profiles: Vec<Profile> = cuts
        .iter()
        .filter(|(sections, _)| !sections.is_empty())
        .flat_map(|(sections, (entry, exit))| {
            SCALES.iter().flat_map(move |&scale| RAMP_SHARES.iter().filter_map(move |&share| speed_along(sections, scale, share, *entry, *exit, &s.axis)))
        })
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
