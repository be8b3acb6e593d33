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
        let mut ruckig = Ruckig::new_direct_and_offline(1);
        let mut trajectory = Trajectory::new_direct(1);
        let result = ruckig.calculate(&mut input, &mut trajectory);
        if !matches!(result, ruckig::Result::Working | ruckig::Result::Finished) {
            return Err(Error::Motion(format!(
                "Ruckig could not plan a {length} mm move with v={} a={} j={}: {result:?}",
                limits.velocity, limits.acceleration, limits.jerk
            )));
        }
        let duration = trajectory.get_duration() * time_unit;
        Ok(Profile { trajectory: Some(trajectory), length, duration, time_unit, length_unit })
    }

    /// Standing still for `duration` seconds (a dwell: no motion, length 0).
    pub fn dwell(duration: f64) -> Result<Profile> {
        if !(duration.is_finite() && duration >= 0.0) {
            return Err(Error::Motion(format!("invalid dwell time {duration}")));
        }
        Ok(Profile { trajectory: None, length: 0.0, duration, time_unit: 1.0, length_unit: 1.0 })
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
pub struct FreeMove {
    trajectory: Trajectory,
    pub from: Point,
    pub to: Point,
    pub duration: f64,
    time_unit: f64,
    length_unit: f64,
}

impl std::fmt::Debug for FreeMove {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FreeMove {{ from: {:?}, to: {:?}, duration: {} }}", self.from, self.to, self.duration)
    }
}

impl FreeMove {
    pub fn new(from: Point, v_from: Vector2<f64>, to: Point, v_to: Vector2<f64>, axis: Limits) -> Result<FreeMove> {
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
        let mut ruckig = Ruckig::new_direct_and_offline(2);
        let mut trajectory = Trajectory::new_direct(2);
        let result = ruckig.calculate(&mut input, &mut trajectory);
        if !matches!(result, ruckig::Result::Working | ruckig::Result::Finished) {
            return Err(Error::Motion(format!(
                "Ruckig could not plan the move from {from:?} (v {v_from:?}) to {to:?} (v {v_to:?}) within {axis:?}: {result:?}"
            )));
        }
        let duration = trajectory.get_duration() * time_unit;
        Ok(FreeMove { trajectory, from, to, duration, time_unit, length_unit })
    }

    /// (position, velocity, acceleration) `t` seconds into the move (clamped).
    pub fn at(&self, t: f64) -> (Point, Vector2<f64>, Vector2<f64>) {
        let x = (t.clamp(0.0, self.duration)) / self.time_unit;
        let (p, v, a) = self.trajectory.at_time(x);
        let (l, u) = (self.length_unit, self.time_unit);
        (
            Point::new(self.from.x + p[0] * l, self.from.y + p[1] * l),
            Vector2::new(v[0], v[1]) * (l / u),
            Vector2::new(a[0], a[1]) * (l / (u * u)),
        )
    }
}

/// Duration of the time-optimal rest-to-rest move over `distance`.
pub fn rest_to_rest_time(distance: f64, limits: Limits) -> Result<f64> {
    Ok(Profile::rest_to_rest(distance, limits)?.duration)
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn a_dwell_stands_still_for_its_time() {
        let p = Profile::dwell(0.2).unwrap();
        assert_eq!((p.length, p.duration), (0.0, 0.2));
        assert_eq!(p.state(0.1), (0.0, 0.0, 0.0));
        assert_eq!(p.position(0.3), 0.0);
        assert!(Profile::dwell(-1.0).is_err() && Profile::dwell(f64::NAN).is_err());
    }

    #[test]
    fn zero_length_takes_no_time_and_bad_length_is_an_error() {
        let lim = Limits { velocity: 1.0, acceleration: 1.0, jerk: 1.0 };
        assert_eq!(rest_to_rest_time(0.0, lim).unwrap(), 0.0);
        assert!(Profile::rest_to_rest(f64::NAN, lim).is_err());
    }
}
