//! Straight legs: motion along one line with a jerk-limited speed profile,
//! evaluated in closed form.
//!
//! A leg is `[ramp up from rest] [cruise] [ramp down to rest]`, each ramp
//! optional (a leg may start or end at cruise speed, where a laser-off move
//! hands over or takes over the speed). The ramps are the time-optimal
//! jerk-limited S-curves between rest and the cruise speed, the same ones
//! Ruckig computes for a one-dimensional rest-to-rest move (the tests check
//! the durations agree). They are evaluated here in closed form because the
//! corner blending, the split and the program sample them millions of times;
//! a call through Ruckig's binding allocates three vectors per sample.
//!
//! Two legs overlapping in time add up: while one ramps down along its line
//! the next ramps up along its own, which turns a corner smoothly (see `tcp`).

use crate::config::Limits;
use crate::error::{Error, Result};

/// The time-optimal jerk-limited ramp from rest to speed `v`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    pub speed: f64,
    /// Peak acceleration reached, jerk, jerk-phase and constant-acceleration durations.
    accel: f64,
    jerk: f64,
    tj: f64,
    ta: f64,
    /// Total duration and distance covered.
    pub duration: f64,
    pub distance: f64,
}

impl Ramp {
    pub fn new(speed: f64, acceleration: f64, jerk: f64) -> Ramp {
        if speed <= 0.0 {
            return Ramp { speed: 0.0, accel: 0.0, jerk, tj: 0.0, ta: 0.0, duration: 0.0, distance: 0.0 };
        }
        // The acceleration reaches its limit only when the speed change is
        // large enough for a full jerk phase both ways.
        let (tj, ta, accel) = if speed * jerk >= acceleration * acceleration {
            (acceleration / jerk, speed / acceleration - acceleration / jerk, acceleration)
        } else {
            let tj = (speed / jerk).sqrt();
            (tj, 0.0, jerk * tj)
        };
        let duration = 2.0 * tj + ta;
        // Symmetric: the speed at x and at duration - x add up to `speed`.
        Ramp { speed, accel, jerk, tj, ta, duration, distance: 0.5 * speed * duration }
    }

    /// (distance, speed, acceleration, jerk) `x` seconds into the ramp up.
    pub fn up(&self, x: f64) -> [f64; 4] {
        let (j, tj, ta, a) = (self.jerk, self.tj, self.ta, self.accel);
        if x <= 0.0 {
            return [0.0, 0.0, 0.0, 0.0];
        }
        if x >= self.duration {
            return [self.distance + self.speed * (x - self.duration), self.speed, 0.0, 0.0];
        }
        if x < tj {
            return [j * x * x * x / 6.0, 0.5 * j * x * x, j * x, j];
        }
        // End of the first jerk phase.
        let (s1, v1) = (j * tj * tj * tj / 6.0, 0.5 * j * tj * tj);
        if x < tj + ta {
            let y = x - tj;
            return [s1 + v1 * y + 0.5 * a * y * y, v1 + a * y, a, 0.0];
        }
        // The last jerk phase mirrors the first: measured from the end.
        let y = self.duration - x;
        [self.distance - self.speed * y + j * y * y * y / 6.0, self.speed - 0.5 * j * y * y, j * y, -j]
    }

    /// The ramp down from `speed` to rest, `x` seconds in.
    pub fn down(&self, x: f64) -> [f64; 4] {
        let x = x.clamp(0.0, self.duration);
        let [s, v, a, j] = self.up(x);
        [self.speed * x - s, self.speed - v, -a, -j]
    }
}

/// A straight move of `length` along its line: optional ramp up, cruise,
/// optional ramp down (all times from the leg's start).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leg {
    pub length: f64,
    pub ramp: Ramp,
    pub ramp_in: bool,
    pub ramp_out: bool,
    pub cruise: f64,
    pub duration: f64,
}

impl Leg {
    /// The fastest leg over `length` within `limits` (path velocity,
    /// acceleration and jerk), starting at rest unless `!ramp_in` (then at
    /// cruise speed) and ending at rest unless `!ramp_out`. Where the length is
    /// too short for the ramps at full speed, the cruise speed is lowered.
    pub fn new(length: f64, limits: Limits, ramp_in: bool, ramp_out: bool) -> Result<Leg> {
        let ok = |x: f64| x.is_finite() && x > 0.0;
        if !(length.is_finite() && length >= 0.0) {
            return Err(Error::Motion(format!("invalid move length {length}")));
        }
        if !(ok(limits.velocity) && ok(limits.acceleration) && ok(limits.jerk)) {
            return Err(Error::Motion(format!("invalid limits {limits:?}")));
        }
        let ramps = ramp_in as u8 + ramp_out as u8;
        let ramp_at = |v: f64| Ramp::new(v, limits.acceleration, limits.jerk);
        let mut ramp = ramp_at(limits.velocity);
        if ramps > 0 && f64::from(ramps) * ramp.distance > length {
            // The ramp distance grows with the speed: bisect the fastest that fits.
            let (mut lo, mut hi) = (0.0, limits.velocity);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if f64::from(ramps) * ramp_at(mid).distance <= length {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            ramp = ramp_at(lo);
        }
        if ramp.speed <= 0.0 {
            return Ok(Leg { length, ramp, ramp_in, ramp_out, cruise: 0.0, duration: 0.0 });
        }
        let cruise = ((length - f64::from(ramps) * ramp.distance) / ramp.speed).max(0.0);
        let duration = cruise + f64::from(ramps) * ramp.duration;
        Ok(Leg { length, ramp, ramp_in, ramp_out, cruise, duration })
    }

    /// A leg at constant speed `speed` all along (no ramps).
    pub fn constant(length: f64, speed: f64) -> Leg {
        let ramp = Ramp::new(speed, 1.0, 1.0);
        Leg { length, ramp: Ramp { duration: 0.0, distance: 0.0, ..ramp }, ramp_in: false, ramp_out: false, cruise: length / speed, duration: length / speed }
    }

    pub fn speed(&self) -> f64 {
        self.ramp.speed
    }

    /// Start of the ramp down (seconds into the leg).
    pub fn ramp_out_start(&self) -> f64 {
        if self.ramp_out {
            self.duration - self.ramp.duration
        } else {
            self.duration
        }
    }

    /// (distance, speed, acceleration, jerk) along the leg `t` seconds in
    /// (clamped to the leg: before it at its start, after it at its end).
    pub fn at(&self, t: f64) -> [f64; 4] {
        if t <= 0.0 {
            return [0.0, if self.ramp_in { 0.0 } else { self.speed() }, 0.0, 0.0];
        }
        if t >= self.duration {
            return [self.length, if self.ramp_out { 0.0 } else { self.speed() }, 0.0, 0.0];
        }
        let v = self.speed();
        let r = &self.ramp;
        let (s_in, t_in) = if self.ramp_in { (r.distance, r.duration) } else { (0.0, 0.0) };
        if t < t_in {
            return r.up(t);
        }
        let out = self.ramp_out_start();
        if t < out {
            return [s_in + v * (t - t_in), v, 0.0, 0.0];
        }
        let [s, sv, a, j] = r.down(t - out);
        [s_in + v * self.cruise + s, sv, a, j]
    }

    pub fn position(&self, t: f64) -> f64 {
        self.at(t)[0]
    }

    /// Times inside the leg where its motion changes character (ends of jerk
    /// and acceleration phases, ramps), for sampling.
    pub fn breakpoints(&self, out: &mut Vec<f64>) {
        let r = &self.ramp;
        // Phase ends within a ramp, long phases (a stage's take tens of
        // milliseconds) cut every 5 ms.
        let ramp = |out: &mut Vec<f64>, from: f64| {
            let mut at = 0.0;
            for end in [r.tj, r.tj + r.ta, r.duration] {
                let n = ((end - at) / 5e-3).ceil().max(1.0) as usize;
                out.extend((1..=n).map(|k| from + at + (end - at) * k as f64 / n as f64));
                at = end;
            }
        };
        let mut times = Vec::new();
        if self.ramp_in {
            ramp(&mut times, 0.0);
        }
        if self.ramp_out {
            let s = self.ramp_out_start();
            times.push(s);
            ramp(&mut times, s);
        }
        out.extend(times.into_iter().filter(|&x| x > 0.0 && x < self.duration));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::profile::rest_to_rest_time;

    fn lim(v: f64, a: f64, j: f64) -> Limits {
        Limits { velocity: v, acceleration: a, jerk: j }
    }

    #[test]
    fn rest_to_rest_legs_take_as_long_as_ruckig_says() {
        for (l, limits) in [
            (100.0, lim(500.0, 5000.0, 250_000.0)),
            (3.0, lim(500.0, 5000.0, 250_000.0)),
            (0.01, lim(500.0, 5000.0, 250_000.0)),
            (24.46, lim(5000.0, 1.0e7, 4.0e11)),
            (0.3, lim(1000.0, 1.0e7, 4.0e11)),
            (5.0, lim(1000.0, 1.0e7, 1.0e10)),
        ] {
            let leg = Leg::new(l, limits, true, true).unwrap();
            let ruckig = rest_to_rest_time(l, limits).unwrap();
            assert!((leg.duration - ruckig).abs() <= 1e-6 * ruckig, "{l} {limits:?}: {} vs {ruckig}", leg.duration);
        }
    }

    #[test]
    fn legs_are_continuous_and_within_limits() {
        let limits = lim(1000.0, 1.0e7, 4.0e11);
        for (l, rin, rout) in [(5.0, true, true), (5.0, false, true), (5.0, true, false), (0.05, true, true), (0.05, false, true)] {
            let leg = Leg::new(l, limits, rin, rout).unwrap();
            let n = 4000;
            let dt = leg.duration / n as f64;
            let mut prev = leg.at(0.0);
            assert_eq!(prev[0], 0.0);
            for k in 1..=n {
                let s = leg.at(k as f64 * dt);
                // Speed and acceleration are the derivatives of what they follow.
                assert!((s[0] - prev[0] - 0.5 * (s[1] + prev[1]) * dt).abs() < 1e-6 * l.max(1e-3), "{l} {rin} {rout} at {k}");
                assert!((s[1] - prev[1] - 0.5 * (s[2] + prev[2]) * dt).abs() < 1e-3 * limits.velocity, "{l} {rin} {rout} at {k}");
                assert!(s[1] <= limits.velocity * (1.0 + 1e-12) && s[1] >= -1e-9);
                assert!(s[2].abs() <= limits.acceleration * (1.0 + 1e-12));
                assert!(s[3].abs() <= limits.jerk * (1.0 + 1e-12));
                prev = s;
            }
            assert!((prev[0] - l).abs() < 1e-9, "ends at its length");
            assert_eq!(leg.at(0.0)[1], if rin { 0.0 } else { leg.speed() });
            assert_eq!(leg.at(leg.duration)[1], if rout { 0.0 } else { leg.speed() });
        }
    }

    #[test]
    fn a_ramp_down_mirrors_the_ramp_up() {
        let r = Ramp::new(1000.0, 1.0e7, 4.0e11);
        for k in 0..=20 {
            let x = r.duration * k as f64 / 20.0;
            let up = r.up(x);
            let down = r.down(r.duration - x);
            assert!((up[1] - down[1]).abs() < 1e-9 * 1000.0);
            // Speeds at x and duration - x add up to the full speed.
            assert!((r.up(x)[1] + r.up(r.duration - x)[1] - 1000.0).abs() < 1e-6);
        }
        assert!((r.down(r.duration)[0] - r.distance).abs() < 1e-12);
    }
}
