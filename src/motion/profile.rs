//! One-dimensional jerk-limited rest-to-rest moves, computed by Ruckig.
//!
//! Straight segments are planned along their path length with one degree of
//! freedom and mapped back to the axes: a multi-axis Ruckig move synchronises
//! axes in time and can bow a straight line. Only state-to-state `calculate` is
//! used (intermediate waypoints go through Ruckig's cloud service), and position
//! limits are ours to enforce (the binding ignores them without waypoints).

use nalgebra::Vector2;
use ruckig::{InputParameter, Ruckig, Trajectory};

use crate::config::Limits;
use crate::error::{Error, Result};
use crate::job::Point;

thread_local! {
    /// Ruckig planners for one and two axes, kept per thread: making one was
    /// a tenth of planning a short move, and `calculate` keeps nothing from
    /// one move to the next (its buffers are overwritten).
    static PLANNERS: std::cell::RefCell<[Option<Ruckig>; 2]> = const { std::cell::RefCell::new([None, None]) };
}

/// Ruckig's state-to-state trajectory for `input` (`dofs` 1 or 2) into `trajectory`.
fn calculate(input: &mut InputParameter, trajectory: &mut Trajectory, dofs: usize) -> ruckig::Result {
    PLANNERS.with_borrow_mut(|planners| planners[dofs - 1].get_or_insert_with(|| Ruckig::new_direct_and_offline(dofs)).calculate(input, trajectory))
}

/// s(t) from 0 to `length`, starting and ending at rest.
pub struct Profile {
    trajectory: Option<Trajectory>,
    pub length: f64,
    pub duration: f64,
    time_unit: f64,
    length_unit: f64,
}

impl std::fmt::Debug for Profile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Profile {{ length: {}, duration: {} }}", self.length, self.duration)
    }
}

impl Profile {
    /// Time-optimal rest-to-rest move over `length` within `limits` (path limits).
    pub fn rest_to_rest(length: f64, limits: Limits) -> Result<Profile> {
        if !(length.is_finite() && length >= 0.0) {
            return Err(Error::Motion(format!("invalid move length {length}")));
        }
        let ok = |x: f64| x.is_finite() && x > 0.0;
        if !(ok(limits.velocity) && ok(limits.acceleration) && ok(limits.jerk)) {
            return Err(Error::Motion(format!("invalid limits {limits:?}")));
        }
        if length == 0.0 {
            return Ok(Profile { trajectory: None, length, duration: 0.0, time_unit: 1.0, length_unit: 1.0 });
        }
        // Ruckig fails on badly scaled inputs (a scanner's jerk is 1e11 times
        // its velocity), so plan in units where velocity and acceleration are 1:
        // time in units of v/a, length in units of v²/a.
        let time_unit = limits.velocity / limits.acceleration;
        let length_unit = limits.velocity * time_unit;
        let mut input = InputParameter::new(1);
        input.current_position = vec![0.0];
        input.target_position = vec![length / length_unit];
        input.max_velocity = vec![1.0];
        input.max_acceleration = vec![1.0];
        input.max_jerk = vec![limits.jerk * time_unit * time_unit * time_unit / length_unit];
        let mut trajectory = Trajectory::new_direct(1);
        let result = calculate(&mut input, &mut trajectory, 1);
        if !matches!(result, ruckig::Result::Working | ruckig::Result::Finished) {
            return Err(Error::Motion(format!(
                "Ruckig could not plan a {length} mm move with v={} a={} j={}: {result:?}",
                limits.velocity, limits.acceleration, limits.jerk
            )));
        }
        let duration = trajectory.get_duration() * time_unit;
        Ok(Profile { trajectory: Some(trajectory), length, duration, time_unit, length_unit })
    }

    /// Position along the move at time `t` (clamped to the move).
    pub fn position(&self, t: f64) -> f64 {
        self.state(t).0
    }

    /// (position, velocity, acceleration) at time `t` (clamped to the move).
    pub fn state(&self, t: f64) -> (f64, f64, f64) {
        match &self.trajectory {
            None => (0.0, 0.0, 0.0),
            Some(tr) => {
                if t <= 0.0 {
                    return (0.0, 0.0, 0.0);
                }
                if t >= self.duration {
                    return (self.length, 0.0, 0.0);
                }
                let (p, v, a) = tr.at_time(t / self.time_unit);
                let (l, u) = (self.length_unit, self.time_unit);
                (p[0] * l, v[0] * l / u, a[0] * l / (u * u))
            }
        }
    }
}

/// A laser-off move of the two TCP axes from one state (position, velocity,
/// no acceleration) to another, time-optimal within per-axis limits: Ruckig's
/// state-to-state `calculate`, the axes synchronised in time. The path between
/// is free (it may bow or overshoot); callers bound it by sampling.
#[derive(Clone)]
pub struct FreeMove {
    pub from: Point,
    pub to: Point,
    pub duration: f64,
    /// Position, velocity and acceleration at equal steps over the move, from Ruckig, in
    /// between interpolated (quintic Hermite, acceleration matched too):
    /// Ruckig's binding allocates on every evaluation, and a move is
    /// evaluated many times. At a galvo's jerk, steps 25 µs apart keep the
    /// positions within 10 nm of Ruckig's and the acceleration within 6 % of
    /// the limit (measured in the tests; the program takes positions only),
    /// and the ends are Ruckig's exactly. Shared: a million hatch lines'
    /// turn-rounds are a few thousand moves, each cloned into many pieces.
    table: std::sync::Arc<[TableState]>,
}

/// Position, velocity and acceleration at one step of a free move's table.
type TableState = (Point, Vector2<f64>, Vector2<f64>);

/// Time between the entries of a free move's table.
const TABLE_STEP: f64 = 25e-6;

/// The table's step for a move at `jerk`: `TABLE_STEP` at a galvo's jerk
/// (4e11 mm/s³), longer at a lower one with jerk·step³ kept (the
/// interpolation error grows with it), at most 4 ms: a stage's turn-round
/// (overscan) then takes a few hundred entries instead of thousands.
fn table_step(jerk: f64) -> f64 {
    (TABLE_STEP * (4e11 / jerk.max(1.0)).cbrt()).clamp(TABLE_STEP, 4e-3)
}

/// Steps of a free move's table: every `step` seconds, at least 16, at most 8192.
fn table_steps(duration: f64, step: f64) -> usize {
    ((duration / step).ceil() as usize).clamp(16, 8192)
}

impl std::fmt::Debug for FreeMove {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FreeMove {{ from: {:?}, to: {:?}, duration: {} }}", self.from, self.to, self.duration)
    }
}

impl FreeMove {
    /// A move given by its states (position, velocity, acceleration) at
    /// equal steps over `duration` (at least two; a stage-only curve).
    pub fn sampled(duration: f64, table: Vec<(Point, Vector2<f64>, Vector2<f64>)>) -> FreeMove {
        let (from, to) = (table[0].0, table[table.len() - 1].0);
        FreeMove { from, to, duration, table: table.into() }
    }

    pub fn new(from: Point, v_from: Vector2<f64>, to: Point, v_to: Vector2<f64>, axis: Limits) -> Result<FreeMove> {
        Self::tabulated(from, v_from, to, v_to, axis, table_step(axis.jerk))
    }

    fn tabulated(from: Point, v_from: Vector2<f64>, to: Point, v_to: Vector2<f64>, axis: Limits, step: f64) -> Result<FreeMove> {
        let finite = [from.x, from.y, to.x, to.y, v_from.x, v_from.y, v_to.x, v_to.y].iter().all(|x| x.is_finite());
        if !finite {
            return Err(Error::Motion(format!("invalid move from {from:?} to {to:?}")));
        }
        // Units where velocity and acceleration limits are 1, as in
        // `Profile::rest_to_rest`, positions relative to the start.
        let time_unit = axis.velocity / axis.acceleration;
        let length_unit = axis.velocity * time_unit;
        let speed_unit = length_unit / time_unit;
        let d = (to - from) / length_unit;
        let mut input = InputParameter::new(2);
        input.current_position = vec![0.0, 0.0];
        input.current_velocity = vec![v_from.x / speed_unit, v_from.y / speed_unit];
        input.target_position = vec![d.x, d.y];
        input.target_velocity = vec![v_to.x / speed_unit, v_to.y / speed_unit];
        input.max_velocity = vec![1.0, 1.0];
        input.max_acceleration = vec![1.0, 1.0];
        let jerk = axis.jerk * time_unit * time_unit * time_unit / length_unit;
        input.max_jerk = vec![jerk, jerk];
        let mut trajectory = Trajectory::new_direct(2);
        let result = calculate(&mut input, &mut trajectory, 2);
        if !matches!(result, ruckig::Result::Working | ruckig::Result::Finished) {
            return Err(Error::Motion(format!(
                "Ruckig could not plan the move from {from:?} (v {v_from:?}) to {to:?} (v {v_to:?}) within {axis:?}: {result:?}"
            )));
        }
        let duration = trajectory.get_duration() * time_unit;
        let steps = table_steps(duration, step);
        let at = |t: f64| -> AxesState {
            let (p, v, a) = trajectory.at_time(t);
            ([p[0], p[1]], [v[0], v[1]], [a[0], a[1]])
        };
        let table = states_at_steps(trajectory.get_duration(), steps, at)
            .into_iter()
            .map(|(p, v, a)| {
                (
                    Point::new(from.x + p[0] * length_unit, from.y + p[1] * length_unit),
                    Vector2::new(v[0], v[1]) * speed_unit,
                    Vector2::new(a[0], a[1]) * (speed_unit / time_unit),
                )
            })
            .collect();
        Ok(FreeMove { from, to, duration, table })
    }

    /// The same path taking `took` (at least as long as this move): time
    /// scaled by k = duration/took, velocities by k, accelerations by k².
    /// Ruckig with V·k, A·k², J·k³ plans exactly this, without sampling
    /// the move again.
    pub fn slowed(&self, took: f64) -> FreeMove {
        if took.is_nan() || took <= self.duration || self.duration <= 0.0 {
            return self.clone();
        }
        let k = self.duration / took;
        let table = self.table.iter().map(|&(p, v, a)| (p, v * k, a * (k * k))).collect();
        FreeMove { from: self.from, to: self.to, duration: took, table }
    }

    /// (position, velocity, acceleration) `t` seconds into the move (clamped).
    pub fn at(&self, t: f64) -> (Point, Vector2<f64>, Vector2<f64>) {
        let steps = self.table.len() - 1;
        if self.duration <= 0.0 {
            return (self.table[0].0, self.table[0].1, self.table[0].2);
        }
        let h = self.duration / steps as f64;
        let x = t.clamp(0.0, self.duration) / h;
        let k = (x.floor() as usize).min(steps - 1);
        let s = x - k as f64;
        let ((p0, v0, a0), (p1, v1, a1)) = (self.table[k], self.table[k + 1]);
        // Quintic Hermite on [k, k + 1] in the unit parameter s: position,
        // velocity and acceleration of both ends matched.
        let (m0, m1, c0, c1) = (v0 * h, v1 * h, a0 * (h * h), a1 * (h * h));
        let d = p1 - p0;
        let k3 = d * 10.0 - m0 * 6.0 - m1 * 4.0 - c0 * 1.5 + c1 * 0.5;
        let k4 = d * -15.0 + m0 * 8.0 + m1 * 7.0 + c0 * 1.5 - c1;
        let k5 = d * 6.0 - m0 * 3.0 - m1 * 3.0 - c0 * 0.5 + c1 * 0.5;
        let k2 = c0 * 0.5;
        let (s2, s3, s4) = (s * s, s * s * s, s * s * s * s);
        let pos = p0 + m0 * s + k2 * s2 + k3 * s3 + k4 * s4 + k5 * (s4 * s);
        let vel = (m0 + k2 * (2.0 * s) + k3 * (3.0 * s2) + k4 * (4.0 * s3) + k5 * (5.0 * s4)) / h;
        let acc = (k2 * 2.0 + k3 * (6.0 * s) + k4 * (12.0 * s2) + k5 * (20.0 * s3)) / (h * h);
        (pos, vel, acc)
    }
}

/// Position, velocity and acceleration of two axes.
type AxesState = ([f64; 2], [f64; 2], [f64; 2]);

/// Steps a stretch of a table covers before its inside is filled (below).
const STRETCH: usize = 16;

/// The states `at` gives at `steps + 1` equal steps over `duration`, asking
/// `at` far less often than at every step (Ruckig's binding allocates six
/// vectors per evaluation). Ruckig's moves have piecewise constant jerk, so
/// between phase changes each axis is one cubic in time: where the states
/// at both ends and the middle of a stretch agree with one cubic, the steps
/// inside are read off it; else the stretch is halved.
fn states_at_steps(duration: f64, steps: usize, at: impl Fn(f64) -> AxesState) -> Vec<AxesState> {
    let time = |k: usize| duration * k as f64 / steps as f64;
    let mut states = vec![([0.0; 2], [0.0; 2], [0.0; 2]); steps + 1];
    states[0] = at(time(0));
    let mut k0 = 0;
    while k0 < steps {
        let k1 = (k0 + STRETCH).min(steps);
        states[k1] = at(time(k1));
        fill_stretch(&mut states, k0, k1, &time, &at);
        k0 = k1;
    }
    states
}

/// Fills `states` strictly between `k0` and `k1` (both ends given).
fn fill_stretch(states: &mut [AxesState], k0: usize, k1: usize, time: &impl Fn(usize) -> f64, at: &impl Fn(f64) -> AxesState) {
    if k1 - k0 < 2 {
        return;
    }
    let km = (k0 + k1) / 2;
    states[km] = at(time(km));
    if k1 - k0 == 2 {
        return;
    }
    let (t0, start) = (time(k0), states[k0]);
    let jerk = |d: usize| (states[k1].2[d] - start.2[d]) / (time(k1) - t0);
    let jerk = [jerk(0), jerk(1)];
    if [km, k1].iter().all(|&k| same_state(cubic(start, jerk, time(k) - t0), states[k])) {
        for k in (k0 + 1..k1).filter(|&k| k != km) {
            states[k] = cubic(start, jerk, time(k) - t0);
        }
    } else {
        fill_stretch(states, k0, km, time, at);
        fill_stretch(states, km, k1, time, at);
    }
}

/// The state `t` after `s` with constant `jerk` per axis.
fn cubic(s: AxesState, jerk: [f64; 2], t: f64) -> AxesState {
    let (p, v, a) = s;
    let axis = |d: usize| {
        (
            p[d] + t * (v[d] + t * (a[d] / 2.0 + t * jerk[d] / 6.0)),
            v[d] + t * (a[d] + t * jerk[d] / 2.0),
            a[d] + t * jerk[d],
        )
    };
    let (x, y) = (axis(0), axis(1));
    ([x.0, y.0], [x.1, y.1], [x.2, y.2])
}

/// Equal up to rounding (in Ruckig's units, where the limits are about 1).
fn same_state(a: AxesState, b: AxesState) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-11 * (1.0 + x.abs().max(y.abs()));
    (0..2).all(|d| close(a.0[d], b.0[d]) && close(a.1[d], b.1[d]) && close(a.2[d], b.2[d]))
}

/// Duration of the time-optimal rest-to-rest move over `distance`.
pub fn rest_to_rest_time(distance: f64, limits: Limits) -> Result<f64> {
    Ok(Profile::rest_to_rest(distance, limits)?.duration)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slowed_move_is_the_move_planned_within_time_scaled_limits() {
        let axis = Limits { velocity: 2000.0, acceleration: 1.0e6, jerk: 1.0e9 };
        let (from, to) = (Point::new(1.0, 2.0), Point::new(31.0, -12.0));
        let fast = FreeMove::new(from, Vector2::zeros(), to, Vector2::zeros(), axis).unwrap();
        let took = 2.5 * fast.duration;
        let slow = fast.slowed(took);
        let k = fast.duration / took;
        let scaled = Limits { velocity: axis.velocity * k, acceleration: axis.acceleration * k * k, jerk: axis.jerk * k * k * k };
        let planned = FreeMove::new(from, Vector2::zeros(), to, Vector2::zeros(), scaled).unwrap();
        assert!((slow.duration - took).abs() < 1e-12 && (planned.duration - took).abs() < 1e-9 * took, "{} {} {}", slow.duration, planned.duration, took);
        for j in 0..=1000 {
            let t = took * j as f64 / 1000.0;
            let ((p, v, a), (q, w, b)) = (slow.at(t), planned.at(t));
            assert!((p - q).norm() < 1e-6, "position at {t}: {p:?} vs {q:?}");
            assert!((v - w).norm() < 1e-4 * scaled.velocity, "velocity at {t}: {v:?} vs {w:?}");
            assert!((a - b).norm() < 0.07 * scaled.acceleration, "acceleration at {t}: {a:?} vs {b:?}");
        }
        // Never faster than the move itself.
        assert_eq!(fast.slowed(0.5 * fast.duration).duration, fast.duration);
    }

    #[test]
    fn rest_to_rest_respects_limits_and_ends_at_rest() {
        let lim = Limits { velocity: 500.0, acceleration: 5000.0, jerk: 250_000.0 };
        let p = Profile::rest_to_rest(100.0, lim).unwrap();
        // Lower bound: at least the cruise time, and slower than a bang-bang move.
        assert!(p.duration > 100.0 / 500.0);
        let mut prev_a = 0.0;
        let dt = p.duration / 2000.0;
        for k in 0..=2000 {
            let (s, v, a) = p.state(k as f64 * dt);
            assert!((-1e-9..=100.0 + 1e-9).contains(&s));
            assert!(v.abs() <= 500.0 * (1.0 + 1e-9));
            assert!(a.abs() <= 5000.0 * (1.0 + 1e-9));
            if k > 0 {
                assert!(((a - prev_a) / dt).abs() <= 250_000.0 * 1.01);
            }
            prev_a = a;
        }
        assert_eq!(p.position(p.duration + 1.0), 100.0);
    }

    #[test]
    fn scanner_scale_limits_plan_and_hold() {
        // A galvo: jerk 1e11 times its velocity; Ruckig fails on this unscaled.
        let lim = Limits { velocity: 5000.0, acceleration: 1.0e7, jerk: 4.0e11 };
        let p = Profile::rest_to_rest(24.46, lim).unwrap();
        assert!(p.duration > 24.46 / 5000.0 && p.duration < 0.01);
        let (s, v, a) = p.state(p.duration / 2.0);
        assert!((s - 12.23).abs() < 1e-6, "symmetric move is half way at half time: {s}");
        assert!(v <= 5000.0 * (1.0 + 1e-9) && a.abs() <= 1.0e7 * (1.0 + 1e-9));
    }

    #[test]
    fn a_free_move_table_follows_ruckig_closely() {
        use nalgebra::Vector2;
        // A jump at scanner limits (the largest jerk, so the largest error)
        // against a table a hundred times finer (as good as Ruckig itself here).
        for (axis, to, v0, v1) in [
            (Limits { velocity: 4500.0, acceleration: 9.8e6, jerk: 3.9e11 }, Point::new(13.0, 2.0), Vector2::new(1000.0, 0.0), Vector2::new(0.0, -1000.0)),
        ] {
            let from = Point::new(10.0, 5.0);
            let m = FreeMove::new(from, v0, to, v1, axis).unwrap();
            let fine = FreeMove::tabulated(from, v0, to, v1, axis, TABLE_STEP / 100.0).unwrap();
            let (mut dp, mut da): (f64, f64) = (0.0, 0.0);
            for k in 0..=10_000 {
                let t = m.duration * k as f64 / 10_000.0;
                let ((p, _, a), (q, _, b)) = (m.at(t), fine.at(t));
                dp = dp.max((p - q).norm());
                da = da.max((a - b).x.abs().max((a - b).y.abs()) / axis.acceleration);
            }
            eprintln!("{axis:?}: position {dp:e} mm, acceleration {da:e} of the limit");
            assert!(dp < 2e-5, "{axis:?}: {dp} mm off");
            assert!(da < 0.1, "{axis:?}: acceleration {da} of the limit off");
        }
    }

    #[test]
    fn a_free_move_ends_in_its_target_state_and_keeps_to_the_limits() {
        use nalgebra::Vector2;
        let axis = Limits { velocity: 4500.0, acceleration: 9.8e6, jerk: 3.9e11 };
        let (from, to) = (Point::new(10.0, 5.0), Point::new(13.0, 2.0));
        let (v0, v1) = (Vector2::new(1000.0, 0.0), Vector2::new(0.0, -1000.0));
        let m = FreeMove::new(from, v0, to, v1, axis).unwrap();
        assert!(m.duration > 0.0 && m.duration < 0.003, "{}", m.duration);
        let (p, v, _) = m.at(0.0);
        assert!((p - from).norm() < 1e-12 && (v - v0).norm() < 1e-6);
        let (p, v, _) = m.at(m.duration);
        assert!((p - to).norm() < 1e-12 && (v - v1).norm() < 1e-6);
        // Velocity is the derivative of position, and within the axis limits.
        let n = 2000;
        let dt = m.duration / n as f64;
        for k in 1..n {
            let t = k as f64 * dt;
            let (a, b) = (m.at(t - 0.5 * dt).0, m.at(t + 0.5 * dt).0);
            let (_, v, acc) = m.at(t);
            assert!(((b - a) / dt - v).norm() < 1e-3 * 4500.0, "t={t}");
            assert!(v.x.abs() <= 4500.0 * 1.001 && v.y.abs() <= 4500.0 * 1.001);
            // The interpolant's second derivative approximates Ruckig's
            // piecewise-linear acceleration.
            assert!(acc.x.abs() <= 9.8e6 * 1.1 && acc.y.abs() <= 9.8e6 * 1.1, "t={t}: {acc:?}");
        }
    }

    /// Ruckig's states of a two-axis move in its own units (as `FreeMove`
    /// plans them), and its duration.
    fn ruckig_move(d: [f64; 2], v0: [f64; 2], v1: [f64; 2], jerk: f64) -> (Trajectory, f64) {
        let mut input = InputParameter::new(2);
        input.current_position = vec![0.0, 0.0];
        input.current_velocity = v0.to_vec();
        input.target_position = d.to_vec();
        input.target_velocity = v1.to_vec();
        input.max_velocity = vec![1.0, 1.0];
        input.max_acceleration = vec![1.0, 1.0];
        input.max_jerk = vec![jerk, jerk];
        let mut trajectory = Trajectory::new_direct(2);
        let result = Ruckig::new_direct_and_offline(2).calculate(&mut input, &mut trajectory);
        assert!(matches!(result, ruckig::Result::Working | ruckig::Result::Finished), "{d:?} {v0:?} {v1:?} {jerk}: {result:?}");
        let duration = trajectory.get_duration();
        (trajectory, duration)
    }

    #[test]
    fn a_table_read_off_cubics_agrees_with_ruckig_at_every_step() {
        // Random moves (a fixed xorshift sequence): every step of the table
        // against Ruckig's own evaluation there.
        let mut seed: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut uniform = |lo: f64, hi: f64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            lo + (hi - lo) * (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut asked, mut steps_all) = (0usize, 0usize);
        for case in 0..300 {
            let d = [uniform(-40.0, 40.0), uniform(-40.0, 40.0)];
            let v0 = [uniform(-0.9, 0.9), uniform(-0.9, 0.9)];
            let v1 = if case % 3 == 0 { [0.0, 0.0] } else { [uniform(-0.9, 0.9), uniform(-0.9, 0.9)] };
            let jerk = [0.5, 2.0, 20.0, 400.0][case % 4];
            let (trajectory, duration) = ruckig_move(d, v0, v1, jerk);
            let steps = table_steps(duration, duration / uniform(16.0, 3000.0));
            let calls = std::cell::Cell::new(0usize);
            let at = |t: f64| {
                calls.set(calls.get() + 1);
                let (p, v, a) = trajectory.at_time(t);
                ([p[0], p[1]], [v[0], v[1]], [a[0], a[1]])
            };
            let table = states_at_steps(duration, steps, at);
            assert_eq!(table.len(), steps + 1);
            for (k, state) in table.iter().enumerate() {
                let (p, v, a) = trajectory.at_time(duration * k as f64 / steps as f64);
                for d in 0..2 {
                    let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * (1.0 + y.abs());
                    assert!(
                        close(state.0[d], p[d]) && close(state.1[d], v[d]) && close(state.2[d], a[d]),
                        "case {case}, step {k} of {steps}, axis {d}: {state:?} vs Ruckig {p:?} {v:?} {a:?}"
                    );
                }
            }
            asked += calls.get();
            steps_all += steps + 1;
        }
        // And Ruckig was asked for far fewer states than the tables hold.
        assert!(asked * 3 < steps_all, "asked {asked} of {steps_all} states");
    }

    #[test]
    fn a_phase_change_between_the_checked_states_is_found() {
        // One axis with jerk +1 until 0.3 and −1 after (a cubic either side),
        // the other still: a stretch of 16 steps over [0, 1] has its ends and
        // middle on no single cubic, so it is halved until the change is
        // between two steps.
        let switch = 0.3;
        let at = |t: f64| -> AxesState {
            let before = |t: f64| (t * t * t / 6.0, t * t / 2.0, t);
            let (p, v, a) = if t <= switch {
                before(t)
            } else {
                let (p0, v0, a0) = before(switch);
                let s = t - switch;
                (p0 + s * (v0 + s * (a0 / 2.0 - s / 6.0)), v0 + s * (a0 - s / 2.0), a0 - s)
            };
            ([p, 0.0], [v, 0.0], [a, 0.0])
        };
        let table = states_at_steps(1.0, 16, at);
        for (k, state) in table.iter().enumerate() {
            let exact = at(k as f64 / 16.0);
            assert!(same_state(*state, exact), "step {k}: {state:?} vs {exact:?}");
        }
    }

    #[test]
    fn zero_length_takes_no_time_and_bad_length_is_an_error() {
        let lim = Limits { velocity: 1.0, acceleration: 1.0, jerk: 1.0 };
        assert_eq!(rest_to_rest_time(0.0, lim).unwrap(), 0.0);
        assert!(Profile::rest_to_rest(f64::NAN, lim).is_err());
    }
}
