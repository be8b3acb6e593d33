//! One-dimensional jerk-limited rest-to-rest moves, computed by Ruckig.
//!
//! Straight segments are planned along their path length with one degree of
//! freedom and mapped back to the axes: a multi-axis Ruckig move synchronises
//! axes in time and can bow a straight line. Only state-to-state `calculate` is
//! used (intermediate waypoints go through Ruckig's cloud service), and position
//! limits are ours to enforce (the binding ignores them without waypoints).

use ruckig::{InputParameter, Ruckig, Trajectory};

use crate::config::Limits;
use crate::error::{Error, Result};

/// s(t) from 0 to `length`, starting and ending at rest.
pub struct Profile {
    trajectory: Option<Trajectory>,
    pub length: f64,
    pub duration: f64,
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
        if length == 0.0 {
            return Ok(Profile { trajectory: None, length, duration: 0.0 });
        }
        let mut input = InputParameter::new(1);
        input.current_position = vec![0.0];
        input.target_position = vec![length];
        input.max_velocity = vec![limits.velocity];
        input.max_acceleration = vec![limits.acceleration];
        input.max_jerk = vec![limits.jerk];
        let mut ruckig = Ruckig::new_direct_and_offline(1);
        let mut trajectory = Trajectory::new_direct(1);
        let result = ruckig.calculate(&mut input, &mut trajectory);
        if !matches!(result, ruckig::Result::Working | ruckig::Result::Finished) {
            return Err(Error::Motion(format!(
                "Ruckig could not plan a {length} mm move with v={} a={} j={}: {result:?}",
                limits.velocity, limits.acceleration, limits.jerk
            )));
        }
        let duration = trajectory.get_duration();
        Ok(Profile { trajectory: Some(trajectory), length, duration })
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
                let (p, v, a) = tr.at_time(t);
                (p[0], v[0], a[0])
            }
        }
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
    fn zero_length_takes_no_time_and_bad_length_is_an_error() {
        let lim = Limits { velocity: 1.0, acceleration: 1.0, jerk: 1.0 };
        assert_eq!(rest_to_rest_time(0.0, lim).unwrap(), 0.0);
        assert!(Profile::rest_to_rest(f64::NAN, lim).is_err());
    }
}
