//! Stage-only marks through their vertices at speed (machines without a
//! scanner), planned as Grbl plans junctions but jerk-limited.
//!
//! At each inner vertex the velocity turns from `w·u_in` to `w·u_out` along a
//! jerk-limited S-curve of duration `T`: the two legs overlap there, one
//! ramping down along its line while the next ramps up along its own (as the
//! blended corners of `tcp`), both with the same shape, so the sum changes
//! only by the turn. `T` is the shortest the axes allow for that change; `w`
//! the highest speed whose corner cut stays within `corner_tolerance` and
//! whose turn fits in half of each leg. A sharp corner thus gets a low `w`, a
//! reversal a stop, and the gentle turns of a flattened curve nearly the full
//! speed. Between vertices a leg changes speed along its line (jerk-limited
//! ramps, a cruise); a forward and a backward pass over the vertices make
//! every change fit its leg. A run starts and ends at rest before a pierce;
//! without one it takes over the speed of the laser-off move before it and
//! hands its own to the one after it (the laser switches at the block
//! boundary; the laser-off move, a state-to-state Ruckig move, arrives on the
//! mark's line at the speed Grbl's junction rule gives that corner).

use nalgebra::Vector2;

use super::tcp::{path_limits, Legs, Motion, Run, TcpSettings};
use crate::config::Limits;
use crate::job::Point;

/// A motion along a line as phases of constant jerk: position, speed,
/// acceleration and jerk in closed form at any time.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    /// Each phase's start time and its state there: (t0, s, v, a, jerk).
    phases: Vec<[f64; 5]>,
    /// The speed at the start (a run handed over at speed from a laser-off move).
    start_speed: f64,
    pub length: f64,
    pub duration: f64,
}

impl Profile {
    pub(super) fn new(start_speed: f64) -> Profile {
        Profile { phases: Vec::with_capacity(12), start_speed, length: 0.0, duration: 0.0 }
    }

    /// The state at the end: (s, v, a).
    fn end_state(&self) -> [f64; 3] {
        match self.phases.last() {
            None => [0.0, self.start_speed, 0.0],
            Some(p) => {
                let [s, v, a, _] = eval(p, self.duration);
                [s, v, a]
            }
        }
    }

    /// Appends `duration` seconds at `jerk`.
    pub(super) fn push(&mut self, duration: f64, jerk: f64) {
        if duration <= 0.0 {
            return;
        }
        let [s, v, a] = self.end_state();
        self.phases.push([self.duration, s, v, a, jerk]);
        self.duration += duration;
        self.length = self.end_state()[0];
    }

    /// (distance, speed, acceleration, jerk) `t` seconds in (clamped).
    pub fn at(&self, t: f64) -> [f64; 4] {
        if self.phases.is_empty() {
            return [0.0, self.start_speed, 0.0, 0.0];
        }
        let t = t.clamp(0.0, self.duration);
        let k = self.phases.partition_point(|p| p[0] <= t).saturating_sub(1);
        eval(&self.phases[k], t)
    }

    pub fn breakpoints(&self, out: &mut Vec<f64>) {
        out.extend(self.phases.iter().skip(1).map(|p| p[0]));
    }
}

fn eval(p: &[f64; 5], t: f64) -> [f64; 4] {
    let [t0, s, v, a, j] = *p;
    let x = t - t0;
    [s + v * x + a * x * x / 2.0 + j * x * x * x / 6.0, v + a * x + j * x * x / 2.0, a + j * x, j]
}

/// Jerk and constant-acceleration durations of the time-optimal speed
/// change by `dv` within `lim` (the ramps of `leg::Ramp`).
fn change_phases(dv: f64, lim: &Limits) -> (f64, f64) {
    if dv <= 0.0 {
        return (0.0, 0.0);
    }
    if dv * lim.jerk >= lim.acceleration * lim.acceleration {
        (lim.acceleration / lim.jerk, dv / lim.acceleration - lim.acceleration / lim.jerk)
    } else {
        ((dv / lim.jerk).sqrt(), 0.0)
    }
}

/// Distance of the speed change from `v0` to `v1` (either way).
pub(super) fn change_distance(v0: f64, v1: f64, lim: &Limits) -> f64 {
    let (tj, ta) = change_phases((v1 - v0).abs(), lim);
    0.5 * (v0 + v1) * (2.0 * tj + ta)
}

/// Appends the speed change to `to` (from the profile's end speed).
pub(super) fn push_change(p: &mut Profile, to: f64, lim: &Limits) {
    let from = p.end_state()[1];
    // A change of rounding size (a run handed over at speed ends at its
    // legs' speed) would be a phase of a nanosecond: a block the controller
    // cannot time. Below a microsecond's jerk it is left out.
    if (to - from).abs() <= lim.jerk * 1e-12 {
        return;
    }
    let (tj, ta) = change_phases((to - from).abs(), lim);
    let j = if to > from { lim.jerk } else { -lim.jerk };
    p.push(tj, j);
    p.push(ta, 0.0);
    p.push(tj, -j);
}

/// A turn from direction `a` to `b` (unit vectors). The velocity changes
/// by w·(b − a) along a symmetric S-curve: per axis the time-optimal change
/// within the acceleration and jerk (`change_phases`), so a pure-jerk
/// S-curve while the change is small and one with a constant-acceleration
/// middle where the jerk would allow more than the acceleration. The path's
/// shape, and so its corner cut per unit of speed × duration, depends on
/// that split.
struct Turn {
    a: Vector2<f64>,
    b: Vector2<f64>,
    /// The largest per-axis component of b − a.
    share: f64,
    axis: Limits,
    /// Corner cut per unit of speed × duration of the pure-jerk S-curve.
    pure_cut: f64,
}

impl Turn {
    fn new(a: Vector2<f64>, b: Vector2<f64>, axis: &Limits) -> Turn {
        let d = b - a;
        let share = d.x.abs().max(d.y.abs());
        let mut turn = Turn { a, b, share, axis: *axis, pure_cut: 0.0 };
        turn.pure_cut = turn.cut_of_shape(0.5);
        turn
    }

    /// Jerk and constant-acceleration phases of the turn at speed `w`.
    fn phases(&self, w: f64) -> (f64, f64) {
        change_phases(self.share * w, &self.axis)
    }

    fn duration(&self, w: f64) -> f64 {
        let (tj, ta) = self.phases(w);
        2.0 * tj + ta
    }

    /// Where the TCP is during a turn of shape `r` (each jerk phase's share
    /// of the duration) with w = T = 1, against the two legs taken as rays
    /// from the vertex: the largest distance.
    fn cut_of_shape(&self, r: f64) -> f64 {
        let ray = |q: Vector2<f64>, u: Vector2<f64>| {
            let along = q.dot(&u).max(0.0);
            (q - u * along).norm()
        };
        let mut cut: f64 = 0.0;
        for k in 1..16 {
            let t = k as f64 / 16.0;
            let covered = ramp_in_distance(t, r);
            let left = 0.5 - t + covered;
            let q = self.b * covered - self.a * left;
            cut = cut.max(ray(q, -self.a).min(ray(q, self.b)));
        }
        cut
    }

    /// Corner cut and speed × duration of the turn at speed `w`.
    fn extent(&self, w: f64) -> (f64, f64) {
        let (tj, ta) = self.phases(w);
        let duration = 2.0 * tj + ta;
        if duration <= 0.0 {
            return (0.0, 0.0);
        }
        let product = w * duration;
        let cut = if ta > 0.0 { self.cut_of_shape(tj / duration) } else { self.pure_cut };
        (cut * product, product)
    }

    /// The highest speed (at most `cap`) whose turn cuts the corner by at
    /// most `tolerance` and takes at most `span` of speed × duration.
    fn speed_for(&self, tolerance: f64, span: f64, cap: f64) -> f64 {
        if self.share <= 0.0 {
            return cap;
        }
        // Pure jerk (closed form) while the change stays below A²/J.
        let product = (tolerance / self.pure_cut.max(1e-12)).min(span);
        let by_jerk = (product / (2.0 * (self.share / self.axis.jerk).sqrt())).powf(2.0 / 3.0);
        let pure_up_to = self.axis.acceleration * self.axis.acceleration / (self.axis.jerk * self.share);
        if by_jerk <= pure_up_to {
            return by_jerk.min(cap);
        }
        if cap <= pure_up_to {
            return cap;
        }
        largest(pure_up_to, cap, &|w| {
            let (cut, product) = self.extent(w);
            cut <= tolerance && product <= span
        })
    }
}

/// Distance covered `t` into a symmetric S-curve ramp from rest to speed 1
/// lasting 1, its jerk phases `r` long each (0.5: pure jerk; the second
/// half mirrors the first).
fn ramp_in_distance(t: f64, r: f64) -> f64 {
    // Peak acceleration of the shape (its jerk: peak / r).
    let peak = 1.0 / (1.0 - r);
    let first = |y: f64| {
        if y <= r {
            peak / r * y * y * y / 6.0
        } else {
            peak * r * r / 6.0 + peak * r / 2.0 * (y - r) + peak * (y - r) * (y - r) / 2.0
        }
    };
    if t <= 0.5 {
        first(t)
    } else {
        let y = 1.0 - t;
        0.5 - y + first(y)
    }
}

/// The speed at which a laser-off move along `chord` (from the vertex, or to
/// it) may hand over to a leg along `leg` (a unit vector) at a run's end: the
/// junction speed of Grbl's rule (a circle `corner_tolerance` deep through
/// the corner at the acceleration of the turn's direction; the laser-off
/// move itself runs free of the corner), at most the speed reached from
/// rest over half the chord: the speeds at both ends of a laser-off move
/// then differ by no more than it can change along its way, so it never
/// swings back for a run-up. 0 without a chord.
fn hand_over_speed(s: &TcpSettings, chord: Vector2<f64>, leg: Vector2<f64>, lim: &Limits) -> f64 {
    let length = chord.norm();
    if length < 1e-9 {
        return 0.0;
    }
    let u = chord / length;
    // Half the angle between the two directions' reversals (Grbl: sin(θ/2)).
    let half = (0.5 * (1.0 + u.dot(&leg))).max(0.0).sqrt();
    let turn = leg - u;
    let junction = if half >= 1.0 - 1e-9 || turn.norm() < 1e-12 {
        f64::INFINITY
    } else {
        let acc = path_limits(s.axis, turn).acceleration;
        (acc * s.corner_tolerance * half / (1.0 - half)).sqrt()
    };
    largest(0.0, junction.min(lim.velocity), &|v| change_distance(0.0, v, lim) <= 0.5 * length)
}

/// The largest speed in `lo..=hi` that `ok` takes (`ok(lo)` holds).
fn largest(lo: f64, hi: f64, ok: &dyn Fn(f64) -> bool) -> f64 {
    bisect(lo, hi, 50, ok)
}

/// The largest value in `lo..=hi` that `ok` takes (`ok(lo)` holds), to
/// 2^-`steps` of the range.
pub(super) fn bisect(lo: f64, hi: f64, steps: usize, ok: &dyn Fn(f64) -> bool) -> f64 {
    if ok(hi) {
        return hi;
    }
    let (mut lo, mut hi) = (lo, hi);
    for _ in 0..steps {
        let mid = 0.5 * (lo + hi);
        if ok(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// How a stage-only run meets the laser-off move before or after it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub enum RunEnd {
    /// At rest.
    #[default]
    Rest,
    /// Through Grbl's junction with the move along this chord (`hand_over_speed`).
    Junction(Vector2<f64>),
    /// At the run's own speed: the laser-off move turns round outside the
    /// mark (a raster engraver's overscan).
    AtSpeed,
}

/// The run marking `points` at `speed` through its vertices (none for fewer
/// than two points), starting and ending as `entry` and `exit` say.
/// With `one_leg_per_segment` its legs are the segments (the run's pieces
/// are told apart by them), never one smooth curve.
pub fn plan_run(s: &TcpSettings, points: &[Point], speed: f64, entry: RunEnd, exit: RunEnd, one_leg_per_segment: bool) -> Option<Run> {
    plan_legs(s, points, speed, entry, exit, !one_leg_per_segment).map(|(legs, _)| Run::new(legs))
}

/// `plan_run`'s legs and duration; with `curves`, a run of gentle vertices
/// becomes one smooth curve where that is faster.
fn plan_legs(s: &TcpSettings, points: &[Point], speed: f64, entry: RunEnd, exit: RunEnd, curves: bool) -> Option<(Legs, f64)> {
    let n = points.len().checked_sub(1).filter(|&n| n > 0)?;
    let lengths: Vec<f64> = points.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
    let dirs: Vec<Vector2<f64>> = points.windows(2).zip(&lengths).map(|(w, l)| (w[1] - w[0]) / *l).collect();
    let limits: Vec<Limits> = dirs
        .iter()
        .map(|d| {
            let l = path_limits(s.axis, *d);
            Limits { velocity: l.velocity.min(speed), ..l }
        })
        .collect();
    // Vertex i joins legs i-1 and i; the ends rest unless handed over.
    let mut turns: Vec<Option<Turn>> = (0..=n).map(|_| None).collect();
    let mut w = vec![0.0; n + 1];
    let end_speed = |end: RunEnd, leg: usize| match end {
        RunEnd::Rest => 0.0,
        RunEnd::Junction(chord) => hand_over_speed(s, chord, dirs[leg], &limits[leg]),
        RunEnd::AtSpeed => limits[leg].velocity,
    };
    w[0] = end_speed(entry, 0);
    w[n] = end_speed(exit, n - 1);
    for i in 1..n {
        let turn = Turn::new(dirs[i - 1], dirs[i], &s.axis);
        let cap = limits[i - 1].velocity.min(limits[i].velocity);
        w[i] = turn.speed_for(s.corner_tolerance, lengths[i - 1].min(lengths[i]), cap);
        turns[i] = Some(turn);
    }
    // Half a turn's length on each leg; leg k fits when its speed change
    // fits between its turns. The turns alone take at most half of each
    // leg, so a leg fits at one speed at both ends, and lowering its
    // faster end towards its slower one only makes room.
    let half = |i: usize, w: f64| turns[i].as_ref().map_or(0.0, |t| 0.5 * w * t.duration(w));
    let fits = |k: usize, a: f64, b: f64| change_distance(a, b, &limits[k]) + half(k, a) + half(k + 1, b) <= lengths[k];
    // Speeds through the vertices, then the legs: their pieces and the run's end.
    let plan_with = |mut w: Vec<f64>| {
        for k in 0..n {
            if w[k + 1] > w[k] {
                w[k + 1] = largest(w[k], w[k + 1], &|b| fits(k, w[k], b));
            }
        }
        for k in (0..n).rev() {
            if w[k] > w[k + 1] {
                w[k] = largest(w[k + 1], w[k], &|a| fits(k, a, w[k + 1]));
            }
        }
        let mut legs = Vec::with_capacity(n);
        let mut start = 0.0;
        for k in 0..n {
            let lim = &limits[k];
            let phases = |i: usize| turns[i].as_ref().map_or((0.0, 0.0), |t| t.phases(w[i]));
            let ((tj_in, ta_in), (tj_out, ta_out)) = (phases(k), phases(k + 1));
            let (t_in, t_out) = (2.0 * tj_in + ta_in, 2.0 * tj_out + ta_out);
            let inner = (lengths[k] - 0.5 * w[k] * t_in - 0.5 * w[k + 1] * t_out).max(0.0);
            // The fastest peak whose ramps fit between the turns.
            let low = w[k].max(w[k + 1]);
            let peak_fits = |v: f64| change_distance(w[k], v, lim) + change_distance(w[k + 1], v, lim) <= inner;
            let peak = largest(low, lim.velocity, &peak_fits);
            // At the run's start, the speed handed over by the laser-off move.
            let mut p = Profile::new(if t_in > 0.0 { 0.0 } else { w[k] });
            if t_in > 0.0 {
                let j = w[k] / (tj_in * (tj_in + ta_in));
                p.push(tj_in, j);
                p.push(ta_in, 0.0);
                p.push(tj_in, -j);
            }
            push_change(&mut p, peak, lim);
            let cruise = inner - change_distance(w[k], peak, lim) - change_distance(w[k + 1], peak, lim);
            if peak > 0.0 && cruise > 0.0 {
                p.push(cruise / peak, 0.0);
            }
            push_change(&mut p, w[k + 1], lim);
            if t_out > 0.0 {
                let j = w[k + 1] / (tj_out * (tj_out + ta_out));
                p.push(tj_out, -j);
                p.push(ta_out, 0.0);
                p.push(tj_out, j);
            }
            let duration = p.duration;
            legs.push((start, duration, Motion::Profile { from: points[k], dir: dirs[k], profile: p }));
            start += duration - t_out;
        }
        // The last vertex has no turn: the run ends with its last leg.
        (legs, start)
    };
    // A turn at a low speed costs more than stopping there (jerk-limited
    // ramps cost the most per unit of speed where they are small): the
    // fastest of turning everywhere, stopping where the turn is slower than
    // half the legs' speed, and stopping everywhere (rest to rest).
    let slow = |i: usize| i > 0 && i < n && w[i] < 0.5 * limits[i - 1].velocity.min(limits[i].velocity);
    let stops = (0..=n).map(|i| if i == 0 || i == n { w[i] } else { 0.0 }).collect();
    let candidates = [w.clone(), (0..=n).map(|i| if slow(i) { 0.0 } else { w[i] }).collect(), stops];
    let (legs, time) = candidates.into_iter().map(plan_with).min_by(|a, b| a.1.total_cmp(&b.1))?;
    // A flattened curve may run faster as one smooth curve than turned
    // vertex by vertex.
    let curve = curves.then(|| super::curve::plan(s, points, &dirs, speed, w[0], w[n])).flatten().filter(|c| c.1 < time);
    Some(curve.unwrap_or((legs, time)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::tcp::{TcpBuilder, TcpPath};

    /// A stage like `config/flatbed-cutter.toml`'s within its margin.
    fn settings() -> TcpSettings {
        TcpSettings {
            axis: Limits { velocity: 490.0, acceleration: 4900.0, jerk: 245_000.0 },
            mark_speed: 490.0,
            blend: true,
            junctions: true,
            skywrite: false,
            corner_tolerance: 0.01,
            line_tolerance: 0.001,
        }
    }

    fn marked(points: &[Point], speed: f64) -> TcpPath {
        let mut b = TcpBuilder::new(settings(), points[0], 0.0);
        b.mark(0, 0, points, speed, 100.0, 0.0, 0.0).unwrap();
        b.stop(0).unwrap();
        b.path
    }

    fn speed_at(path: &TcpPath, t: f64) -> f64 {
        let h = 1e-6;
        (path.position(t + h) - path.position(t - h)).norm() / (2.0 * h)
    }

    /// Samples the path: per-axis velocity and acceleration within the
    /// limits, and never further from the polyline than the corner tolerance.
    fn check(path: &TcpPath, points: &[Point]) {
        let s = settings();
        let dt = 1e-4;
        let n = (path.duration() / dt).ceil() as usize;
        let (mut prev, mut prev_v) = (None, None);
        for k in 0..=n {
            let p = path.position(k as f64 * dt);
            let off = points.windows(2).map(|w| super::super::tcp::tests_distance(p, w[0], w[1])).fold(f64::INFINITY, f64::min);
            assert!(off <= s.corner_tolerance + 1e-9, "{off} mm off the polyline at {p:?}");
            if let Some(q) = prev {
                let v: Vector2<f64> = (p - q) / dt;
                assert!(v.x.abs() <= s.axis.velocity * 1.001 && v.y.abs() <= s.axis.velocity * 1.001, "v {v:?}");
                if let Some(pv) = prev_v {
                    let a: Vector2<f64> = (v - pv) / dt;
                    assert!(a.x.abs() <= s.axis.acceleration * 1.01 && a.y.abs() <= s.axis.acceleration * 1.01, "a {a:?} at {p:?}");
                }
                prev_v = Some(v);
            }
            prev = Some(p);
        }
    }

    /// A closed circle of radius `r` flattened to within `tolerance`.
    fn flattened_circle(centre: Point, r: f64, tolerance: f64) -> Vec<Point> {
        let step = 2.0 * (1.0 - tolerance / r).acos();
        let n = (std::f64::consts::TAU / step).ceil() as usize;
        (0..=n)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                centre + Vector2::new(r * a.cos(), r * a.sin())
            })
            .collect()
    }

    #[test]
    fn a_flattened_circle_runs_through_its_vertices_near_its_speed() {
        // Radius 10 flattened to 0.01 mm: legs of 0.9 mm turning 5 degrees.
        let circle = flattened_circle(Point::new(20.0, 20.0), 10.0, 0.01);
        let n = circle.len() - 1;
        let length: f64 = circle.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        for speed in [50.0, 65.0] {
            let path = marked(&circle, speed);
            let marks: Vec<_> = path.pieces.iter().filter(|p| p.is_marking()).collect();
            let time = marks.last().unwrap().end_time() - marks[0].start;
            assert!(time <= 1.15 * length / speed, "{speed} mm/s: {time} s for {length} mm");
            // Mid-circle, every vertex is passed at nearly the full speed.
            for m in &marks[n / 4..3 * n / 4] {
                let v = speed_at(&path, m.start);
                assert!(v > 0.9 * speed, "{v} mm/s at a vertex of a circle marked at {speed}");
            }
            check(&path, &circle);
        }
    }

    #[test]
    fn a_flattened_circle_at_a_high_feed_runs_near_the_feed_as_one_curve() {
        // Radius 10 finely flattened (to 0.001 mm, legs of 0.28 mm) at 180
        // mm/s: turned vertex by vertex (acceleration back to 0 between
        // them) it ran at most ~55 mm/s; as one curve its centripetal
        // acceleration (3240 mm/s²) and jerk allow the feed.
        let (r, speed): (f64, f64) = (10.0, 180.0);
        let circle = flattened_circle(Point::new(60.0, 60.0), r, 0.001);
        let length: f64 = circle.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let path = marked(&circle, speed);
        let marks: Vec<_> = path.pieces.iter().filter(|p| p.is_marking()).collect();
        let (t0, t1) = (marks[0].start, marks.last().unwrap().end_time());
        let mid = (1..20).map(|k| speed_at(&path, t0 + (t1 - t0) * (0.4 + 0.01 * k as f64))).fold(f64::INFINITY, f64::min);
        assert!(mid > 0.85 * speed, "{mid} mm/s mid-circle");
        // From rest to rest: the ramps at each end add about 0.1 s.
        assert!(t1 - t0 <= 1.5 * length / speed, "{} s for {length} mm", t1 - t0);
        check(&path, &circle);
    }

    #[test]
    fn a_flattened_circle_runs_near_the_speed_its_curvature_allows() {
        // Radius 10 flattened to the corner tolerance (legs of 0.9 mm, as an
        // SVG circle is imported) at a feed far above what the curve
        // allows: mid-circle at nearly √(A·r) = 221 mm/s, where the
        // centripetal acceleration alone takes the axes' limit. The ramps'
        // share used to be fixed at half the acceleration, and the curve's
        // shape cut inside the polyline, so only windows of ~1.5 legs kept
        // to the tolerance (its curvature rippling): ~103 mm/s.
        let r = 10.0;
        let circle = flattened_circle(Point::new(60.0, 60.0), r, 0.01);
        let path = marked(&circle, 490.0);
        let marks: Vec<_> = path.pieces.iter().filter(|p| p.is_marking()).collect();
        let (t0, t1) = (marks[0].start, marks.last().unwrap().end_time());
        let mid = (0..=20).map(|k| speed_at(&path, t0 + (t1 - t0) * (0.4 + 0.01 * k as f64))).fold(f64::INFINITY, f64::min);
        let allowed = (settings().axis.acceleration * r).sqrt();
        assert!(mid >= 0.9 * allowed, "{mid} mm/s mid-circle, the curvature allows {allowed}");
        check(&path, &circle);
    }

    /// A rectangle with corners rounded to `r`, its arcs flattened to 0.01
    /// mm as an SVG `rect` with `rx` is imported, from and to the middle of
    /// its lower side.
    fn rounded_rectangle(w: f64, h: f64, r: f64) -> Vec<Point> {
        let step = 2.0 * (1.0 - 0.01 / r).acos();
        let n = (std::f64::consts::FRAC_PI_2 / step).ceil() as usize;
        let corners = [(w - r, r, -0.5), (w - r, h - r, 0.0), (r, h - r, 0.5), (r, r, 1.0)];
        let mut points = vec![Point::new(20.0 + 0.5 * w, 20.0)];
        for (cx, cy, a0) in corners {
            for k in 0..=n {
                let a = std::f64::consts::PI * (a0 + 0.5 * k as f64 / n as f64);
                points.push(Point::new(20.0 + cx + r * a.cos(), 20.0 + cy + r * a.sin()));
            }
        }
        points.push(points[0]);
        points
    }

    #[test]
    fn a_rounded_rectangle_runs_its_sides_at_the_feed_and_its_corners_near_what_they_allow() {
        // 54 x 40 mm, corners of r = 3 at 200 mm/s. Within the tolerance δ
        // the curvature can grow from the sides into a corner over at most
        // L = √(24·r·δ) (a clothoid's offset), so the jerk allows
        // (J·r·L)^(1/3) ≈ 85 mm/s there. One speed for the whole curve
        // held the sides at that too; turned vertex by vertex, each corner's
        // short legs slowed it further (1.49 s in the simulator).
        let (r, speed) = (3.0, 200.0);
        let rect = rounded_rectangle(54.0, 40.0, r);
        let path = marked(&rect, speed);
        let marks: Vec<_> = path.pieces.iter().filter(|p| p.is_marking()).collect();
        let (t0, t1) = (marks[0].start, marks.last().unwrap().end_time());
        let s = settings();
        let corner = (s.axis.jerk * r * (24.0 * r * s.corner_tolerance).sqrt()).cbrt();
        let speeds: Vec<f64> = (1..1000).map(|k| speed_at(&path, t0 + (t1 - t0) * k as f64 / 1000.0)).collect();
        let fastest = speeds.iter().cloned().fold(0.0, f64::max);
        assert!(fastest >= 0.99 * speed, "{fastest} mm/s at most along the sides");
        let slowest = speeds[50..950].iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(slowest >= 0.75 * corner, "{slowest} mm/s in a corner, {corner} allowed");
        assert!(t1 - t0 <= 1.3, "{} s", t1 - t0);
        check(&path, &rect);
    }

    #[test]
    fn a_run_is_one_curve_only_where_that_is_faster() {
        // Circles flattened to 0.01 mm: at 50 mm/s turned vertex by vertex
        // nearly at the feed, at 180 mm/s faster as one curve.
        let circle = flattened_circle(Point::new(20.0, 20.0), 10.0, 0.01);
        // The legs' end, not their estimate of it.
        let end = |legs: &Legs| legs.iter().map(|(start, duration, _)| start + duration).fold(0.0, f64::max);
        for speed in [50.0, 180.0] {
            let (turned, turned_time) = plan_legs(&settings(), &circle, speed, RunEnd::Rest, RunEnd::Rest, false).unwrap();
            assert!((end(&turned) - turned_time).abs() < 1e-9, "{speed} mm/s: legs end at {} s, estimated {turned_time} s", end(&turned));
            let (chosen, time) = plan_legs(&settings(), &circle, speed, RunEnd::Rest, RunEnd::Rest, true).unwrap();
            assert!((end(&chosen) - time).abs() < 1e-9 && time <= turned_time, "{speed} mm/s: {time} s, turned {turned_time} s");
        }
    }

    #[test]
    fn small_squares_mark_no_slower_than_stopping_at_every_corner() {
        for (side, speed) in [(3.0, 490.0), (3.0, 50.0), (0.5, 490.0), (20.0, 490.0)] {
            let square = [Point::new(10.0, 10.0), Point::new(10.0 + side, 10.0), Point::new(10.0 + side, 10.0 + side), Point::new(10.0, 10.0 + side), Point::new(10.0, 10.0)];
            let through = marked(&square, speed).duration();
            let stopping = TcpSettings { blend: false, junctions: false, ..settings() };
            let mut b = TcpBuilder::new(stopping, square[0], 0.0);
            b.mark(0, 0, &square, speed, 100.0, 0.0, 0.0).unwrap();
            b.stop(0).unwrap();
            let stops = b.path.duration();
            assert!(through <= stops + 1e-9, "side {side} at {speed}: {through} s through the corners, {stops} s stopping");
        }
    }

    #[test]
    fn without_a_jerk_limit_a_right_angle_turns_at_full_acceleration() {
        // A jerk far above what the turn needs: its acceleration has a
        // constant middle (per axis the time-optimal change) instead of a
        // pure-jerk peak, so the corner is nearly a parabola at the axes'
        // acceleration, entered at w = √(8·A·δ) and passed at 0.71·w within
        // the tolerance δ (the pure-jerk turn passed it at 12.1 mm/s here).
        let s = TcpSettings { axis: Limits { jerk: 1e9, ..settings().axis }, ..settings() };
        let square = [Point::new(10.0, 10.0), Point::new(40.0, 10.0), Point::new(40.0, 40.0), Point::new(10.0, 40.0), Point::new(10.0, 10.0)];
        let mut b = TcpBuilder::new(s, square[0], 0.0);
        b.mark(0, 0, &square, 200.0, 100.0, 0.0, 0.0).unwrap();
        b.stop(0).unwrap();
        let path = b.path;
        let parabola = (8.0 * s.axis.acceleration * s.corner_tolerance).sqrt();
        let marks: Vec<_> = path.pieces.iter().filter(|p| p.is_marking()).collect();
        assert_eq!(marks.len(), 4);
        for m in &marks[1..] {
            let slowest = (0..100).map(|k| speed_at(&path, m.start + 1e-4 * k as f64)).fold(f64::INFINITY, f64::min);
            assert!(slowest >= 0.9 * std::f64::consts::FRAC_1_SQRT_2 * parabola, "{slowest} mm/s through a right angle (parabola: {parabola} mm/s at its ends)");
        }
        check(&path, &square);
    }

    #[test]
    fn a_sharp_corner_slows_to_what_the_tolerance_allows() {
        let square = [Point::new(10.0, 10.0), Point::new(40.0, 10.0), Point::new(40.0, 40.0), Point::new(10.0, 40.0), Point::new(10.0, 10.0)];
        let path = marked(&square, 200.0);
        let marks: Vec<_> = path.pieces.iter().filter(|p| p.is_marking()).collect();
        assert_eq!(marks.len(), 4);
        for m in &marks[1..] {
            let v = speed_at(&path, m.start);
            assert!(v < 0.2 * 200.0, "{v} mm/s into a right angle");
        }
        // Along the sides at full speed again.
        assert!(speed_at(&path, 0.5 * (marks[1].start + marks[2].start)) > 0.99 * 200.0);
        check(&path, &square);
        // A reversal stops.
        let back = [Point::new(10.0, 10.0), Point::new(30.0, 10.0), Point::new(20.0, 10.0)];
        let path = marked(&back, 400.0);
        let turn = path.pieces[1].start + 0.5 * (path.pieces[0].end_time() - path.pieces[1].start);
        assert!(speed_at(&path, turn) < 1.0);
        check(&path, &back);
    }
}
