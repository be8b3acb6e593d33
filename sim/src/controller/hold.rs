//! A feed hold (and the resume after it) in the `timed` motion model.
//!
//! The timed controller keeps the program's timing, so it stops the way such
//! a controller does: by slowing the program's clock. While a hold brakes,
//! program time runs at a factor `k` of real time that falls from 1 to 0
//! along an S-curve; a resume raises it from 0 to 1 again. The machine stays
//! on the programmed path (through block ends, as far as the braking takes
//! it), and its speed is the programmed one times `k`, so a move at constant
//! speed `v` brakes with `v·k'` and a jerk `v·k''`. The curve's rate and its
//! change are set from the fastest axis speeds queued, for half of each axis'
//! acceleration and jerk limit: a program that leaves the other half free
//! (any constant-speed move) stays within the limits while it stops.
//!
//! A hold that comes less than [`PREPARED_S`] before the running block ends
//! brakes from that end (the block runs out, laser as programmed), else from
//! where it came. While `k` changes, knots come only where a block ends, where the hold
//! began and where the machine stopped: exact samples of the braked motion,
//! spaced no closer around a block's end than the program's own (a sample
//! just beside a corner would make the program's change of direction there
//! look sharper to the limit checker than it is). Reports in between show
//! the position and speed on the ramp.

use super::{Controller, Knot, MotionModel};

/// How far ahead Grbl has its motion cut into step segments (6 segments of
/// 10 ms): a hold acts after them.
const PREPARED_S: f64 = 0.06;

/// A change of the program clock's rate: braking to a stop or ramping up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Ramp {
    /// When it began (s).
    start: f64,
    /// From full speed to a stop (else from rest to full speed).
    pub(super) braking: bool,
    /// Largest rate of change of `k` (1/s) and of that rate (1/s²).
    rate: f64,
    jerk: f64,
}

impl Ramp {
    /// Duration of the jerk-limited change of `k` by 1, and the time spent
    /// at each end changing the rate (the S-curve's two bends).
    fn phases(&self) -> (f64, f64) {
        let bend = (self.rate / self.jerk).min((1.0 / self.jerk).sqrt());
        let peak = self.jerk * bend;
        let middle = ((1.0 - self.jerk * bend * bend) / peak).max(0.0);
        (2.0 * bend + middle, bend)
    }

    /// The S-curve from 0 to 1, `s` seconds in, and its integral.
    fn rise(&self, s: f64) -> (f64, f64) {
        let (total, bend) = self.phases();
        let s = s.clamp(0.0, total);
        let j = self.jerk;
        let peak = j * bend;
        if s <= bend {
            (0.5 * j * s * s, j * s * s * s / 6.0)
        } else if s <= total - bend {
            let d = s - bend;
            let g1 = 0.5 * j * bend * bend;
            (g1 + peak * d, j * bend.powi(3) / 6.0 + g1 * d + 0.5 * peak * d * d)
        } else {
            // Symmetric: g(s) + g(total - s) = 1, so the integral to the end is total/2.
            let r = total - s;
            (1.0 - 0.5 * j * r * r, 0.5 * total - (r - j * r.powi(3) / 6.0))
        }
    }

    /// When `k` stops changing.
    pub(super) fn end(&self) -> f64 {
        self.start + self.phases().0
    }

    /// The clock's rate `k` at `t`.
    fn factor(&self, t: f64) -> f64 {
        let g = self.rise(t - self.start).0;
        if self.braking { 1.0 - g } else { g }
    }

    /// Program seconds run from the ramp's start to `t`.
    fn program_time(&self, t: f64) -> f64 {
        let s = (t - self.start).max(0.0);
        let total = self.phases().0;
        let integral = self.rise(s).1;
        let past = (s - total).max(0.0);
        if self.braking {
            s.min(total) - integral
        } else {
            integral + past
        }
    }
}

impl Controller {
    /// The ramp's rate and jerk for what is queued now: half of each axis'
    /// acceleration and jerk over the fastest speed any queued block gives it.
    fn ramp_at(&self, start: f64, braking: bool) -> Ramp {
        let blocks = self.exec.iter().map(|e| &e.block).chain(self.planner.iter());
        let mut speed = vec![0.0f64; self.cfg.axes.len()];
        for b in blocks {
            let v = self.nominal_speed(b);
            for (s, u) in speed.iter_mut().zip(&b.kin.unit) {
                *s = s.max(v * u.abs());
            }
        }
        let (mut rate, mut jerk) = (1e6f64, 1e9f64);
        for (ax, v) in self.cfg.axes.iter().zip(&speed) {
            if *v > 1e-12 {
                rate = rate.min(0.5 * ax.max_acceleration / v);
                if ax.max_jerk.is_finite() && ax.max_jerk > 0.0 {
                    jerk = jerk.min(0.5 * ax.max_jerk / v);
                }
            }
        }
        Ramp { start, braking, rate, jerk }
    }

    /// A hold begins while the timed model moves: the program clock brakes
    /// from the end of the running block if that comes within
    /// [`PREPARED_S`] (as Grbl runs out the step segments it has prepared),
    /// else from now (the block cut here).
    pub(super) fn begin_braking(&mut self) {
        if self.cfg.motion != MotionModel::Timed || !self.moving() || self.ramp.is_some_and(|r| r.braking) {
            return;
        }
        let now = self.now;
        let block_end = self.exec.as_ref().filter(|e| e.end_t - now <= PREPARED_S && e.done >= e.block.kin.length - 1e-9).map(|e| e.end_t);
        if let Some(end) = block_end.filter(|_| self.ramp.is_none()) {
            self.ramp = Some(self.ramp_at(end, true));
            return;
        }
        let mut ramp = self.ramp_at(now, true);
        if let Some(up) = self.ramp.filter(|r| now < r.end()) {
            // Still ramping up after a resume: brake from the rate reached.
            let k = up.factor(now);
            let (mut lo, mut hi) = (0.0, ramp.phases().0);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if ramp.rise(mid).0 < 1.0 - k { lo = mid } else { hi = mid }
            }
            ramp.start = now - lo;
        }
        self.ramp = Some(ramp);
        self.cut_segment_now();
    }

    /// Ends the running segment at the present position (a knot), and cuts
    /// the next one from there as things now stand.
    pub(super) fn cut_segment_now(&mut self) {
        let now = self.now;
        let Some(e) = self.exec.as_mut() else { return };
        if !e.running || now <= e.start_t || now >= e.end_t {
            return;
        }
        let here = super::interpolate(e, now);
        e.done -= super::dist(&here, &e.end_pos);
        e.end_pos = here;
        e.end_t = now;
        self.finish_segment();
    }

    /// `~` after a braked hold: the program clock ramps up again from now.
    pub(super) fn begin_ramp_up(&mut self) {
        if self.ramp.is_some_and(|r| r.braking) {
            self.ramp = Some(self.ramp_at(self.now, false));
        }
    }

    /// A braking hold has brought the machine to rest.
    pub(super) fn braked_to_rest(&self, t: f64) -> bool {
        self.ramp.is_some_and(|r| r.braking && t >= r.end() - 1e-12)
    }

    /// Cuts and starts the next segment of the executing block (timed model):
    /// the rest of the block, at its programmed speed or along the ramp that
    /// runs, or, braking, up to where the machine stops if that comes first.
    /// A braking ramp that has ended leaves the machine at rest inside the block.
    pub(super) fn timed_segment(&mut self, t: f64) {
        if self.ramp.is_some_and(|r| !r.braking && t >= r.end()) {
            self.ramp = None;
        }
        let ramp = self.ramp;
        let stopped = self.braked_to_rest(t);
        let power = if self.hold { 0.0 } else { self.exec.as_ref().map_or(0.0, |e| self.block_power(&e.block)) };
        let Some(e) = self.exec.as_ref() else { return };
        let program_dur = self.block_time(&e.block);
        let Some(e) = self.exec.as_mut() else { return };
        let length = e.block.kin.length;
        let remaining = (length - e.done).max(0.0);
        let speed = if program_dur > 0.0 { length / program_dur } else { f64::INFINITY };
        e.start_t = t;
        e.start_pos = std::mem::take(&mut e.end_pos);
        if stopped {
            e.end_pos = e.start_pos.clone();
            e.end_t = t;
            e.running = false;
            e.speed = 0.0;
            return;
        }
        let (end_t, distance) = match ramp {
            Some(r) if speed.is_finite() => {
                let run = |x: f64| speed * (r.program_time(x) - r.program_time(t));
                // Braking stops at the ramp's end; ramping up, the block ends
                // at the latest its remaining program time after the ramp.
                let until = if r.braking { r.end() } else { r.end().max(t) + remaining / speed };
                if r.braking && run(until) < remaining - 1e-12 {
                    (until, run(until))
                } else {
                    // The block ends inside this segment: find when.
                    let (mut lo, mut hi) = (t, until);
                    for _ in 0..60 {
                        let mid = 0.5 * (lo + hi);
                        if run(mid) < remaining { lo = mid } else { hi = mid }
                    }
                    (hi, remaining)
                }
            }
            // At the programmed speed: the whole block in its own time.
            _ if e.done <= 0.0 => (t + program_dur, remaining),
            _ => (t + remaining / speed, remaining),
        };
        e.done += distance;
        e.end_pos = if length - e.done <= 1e-9 {
            e.done = length;
            e.block.target.clone()
        } else {
            e.origin.iter().zip(&e.block.kin.unit).map(|(o, u)| o + u * e.done).collect()
        };
        e.end_t = end_t;
        e.running = true;
        // M4 scales the laser with the speed reached.
        let reached = if end_t > t && speed.is_finite() && speed > 0.0 { (distance / (end_t - t) / speed).min(1.0) } else { 1.0 };
        e.power = if e.block.dynamic_power { power * reached } else { power };
        e.speed = speed * ramp.map_or(1.0, |r| r.factor(end_t));
    }

    /// Where the machine is and its speed (mm/s) now, on a ramp: the running
    /// segment's knots alone would put it on their straight interpolation.
    pub(super) fn on_ramp(&self) -> Option<(Vec<f64>, f64)> {
        let r = self.ramp?;
        let e = self.exec.as_ref().filter(|e| e.running && e.start_t >= r.start - 1e-12)?;
        let program_dur = self.block_time(&e.block);
        if program_dur <= 0.0 {
            return None;
        }
        let speed = e.block.kin.length / program_dur;
        let t = self.now.clamp(e.start_t, e.end_t);
        let from = e.done - super::dist(&e.start_pos, &e.end_pos);
        let done = (from + speed * (r.program_time(t) - r.program_time(e.start_t))).min(e.done);
        let pos = e.origin.iter().zip(&e.block.kin.unit).map(|(o, u)| o + u * done).collect();
        Some((pos, speed * r.factor(t)))
    }

    /// `~` resumes a hold stopped inside a block: from rest there (a knot
    /// opens the motion), the grbl model on its profile, the timed model on
    /// a ramp.
    pub(super) fn resume_inside_block(&mut self) {
        let Some(e) = self.exec.as_ref() else { return };
        let knot = Knot { t: self.now, pos: e.end_pos.clone(), power: 0.0, line: e.block.line };
        self.push_knot(knot);
        match self.cfg.motion {
            MotionModel::Grbl => self.next_segment(self.now),
            MotionModel::Timed => self.timed_segment(self.now),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_s_curve_is_continuous_and_reaches_its_end() {
        for (rate, jerk) in [(50.0, 1000.0), (5.0, 1000.0), (1e6, 1e9)] {
            let r = Ramp { start: 0.0, braking: true, rate, jerk };
            let (total, _) = r.phases();
            let mut prev = r.rise(0.0);
            let n = 10_000;
            for i in 1..=n {
                let s = total * i as f64 / n as f64;
                let g = r.rise(s);
                // Continuous, rising at most at `rate`, integral consistent.
                assert!((g.0 - prev.0) <= rate * total / n as f64 + 1e-9, "{rate} {jerk} at {s}");
                assert!((g.1 - prev.1 - 0.5 * (g.0 + prev.0) * total / n as f64).abs() < 1e-6, "{rate} {jerk} at {s}");
                prev = g;
            }
            assert!((prev.0 - 1.0).abs() < 1e-9 && (prev.1 - total / 2.0).abs() < 1e-9);
            // Braking runs half the ramp's time of program, then stands.
            assert!((r.program_time(total + 5.0) - total / 2.0).abs() < 1e-9);
            let up = Ramp { braking: false, ..r };
            assert!((up.program_time(total + 5.0) - (total / 2.0 + 5.0)).abs() < 1e-9);
        }
    }
}
