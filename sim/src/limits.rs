//! Independent kinematic limit checker over executed knots.
//!
//! The knots describe piecewise-linear motion. Per axis, velocity,
//! acceleration and jerk are the exact divided differences of that sequence:
//! * velocity of a segment: `Δp / Δt`;
//! * acceleration at a knot: `2·f[t0,t1,t2] = (v12 − v01) / ((t2 − t0) / 2)`;
//! * jerk over two knots: `6·f[t0,t1,t2,t3] = 3·(a2 − a1) / (t3 − t0)`.
//!
//! By the Peano kernel theorem these are weighted averages of the true
//! derivative, so exact samples of a trajectory within limits never trip them.
//!
//! Rest: while the machine waits (knots with the same position) it is sampled
//! again one neighbouring block's duration after it stopped and before it
//! starts, so that a stop from speed is seen as the deceleration it is rather
//! than diluted by a long wait. These samples are exact (the machine is still),
//! so the Peano argument holds for them too. The motion is taken to be at rest before the first and after the
//! last knot (two virtual rest knots spaced like the adjacent segment), which
//! is true for a machine and catches a start or end at speed.
//!
//! Knots closer than 1e-9 s are merged; a position jump across them is a
//! violation. A limit that is not a positive finite number disables its check.

use std::collections::VecDeque;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::controller::{AxisConfig, Knot};

#[derive(Debug, Clone, Default, Serialize, Deserialize, JsonSchema, PartialEq)]
pub struct LimitReport {
    pub samples: u64,
    pub violations: u64,
    pub peak_velocity_use: Vec<f64>,
    pub peak_acceleration_use: Vec<f64>,
    pub peak_jerk_use: Vec<f64>,
    /// (min, max) position seen per axis.
    pub peak_position: Vec<(f64, f64)>,
    pub first_violation: Option<String>,
}

const MERGE_DT: f64 = 1e-9;
const REL_TOL: f64 = 1e-9;
const POS_TOL: f64 = 1e-6;

#[derive(Debug, Clone)]
struct Mk {
    t: f64,
    pos: Vec<f64>,
    real: bool,
    /// Problems found on arrival (travel, position jump), reported at evaluation.
    issue: Option<String>,
}

pub struct LimitChecker {
    axes: Vec<AxisConfig>,
    /// Last knot received, and the duration of the last moving segment.
    prev: Option<Knot>,
    prev_dt: f64,
    /// A rest in progress: its first and its latest knot.
    rest: Option<(Knot, Knot)>,
    /// Sliding window of merged knots; evaluation of knot i needs i-3..=i+3.
    win: VecDeque<Mk>,
    next_eval: usize,
    started: bool,
    report: LimitReport,
}

impl LimitChecker {
    pub fn new(axes: &[AxisConfig]) -> Self {
        let n = axes.len();
        LimitChecker {
            axes: axes.to_vec(),
            prev: None,
            prev_dt: 0.0,
            rest: None,
            win: VecDeque::new(),
            next_eval: 0,
            started: false,
            report: LimitReport {
                peak_velocity_use: vec![0.0; n],
                peak_acceleration_use: vec![0.0; n],
                peak_jerk_use: vec![0.0; n],
                peak_position: vec![(f64::INFINITY, f64::NEG_INFINITY); n],
                ..LimitReport::default()
            },
        }
    }

    fn violation(&mut self, msg: String) {
        self.report.violations += 1;
        if self.report.first_violation.is_none() {
            self.report.first_violation = Some(msg);
        }
    }

    /// Takes the next knot. A rest (knots with the same position) is sampled
    /// again at the spacing of the blocks on either side of it: those samples are
    /// exact, since the machine stands still, and they make a stop or a start
    /// show the acceleration it really has, however long the machine waits.
    pub fn push(&mut self, knot: &Knot) {
        self.report.samples += 1;
        if let Some(p) = &self.prev {
            // Knots at the same instant inside a rest (the laser switched while
            // standing still) belong to the rest.
            if knot.pos == p.pos && (knot.t > p.t + MERGE_DT || self.rest.is_some()) {
                let start = self.rest.take().map(|r| r.0).unwrap_or_else(|| p.clone());
                self.rest = Some((start, knot.clone()));
                self.prev = Some(knot.clone());
                return;
            }
        }
        if let Some((start, end)) = self.rest.take() {
            let r = end.t - start.t;
            let before = Knot { t: start.t + self.prev_dt.min(r / 2.0), ..start.clone() };
            let after = Knot { t: end.t - (knot.t - end.t).min(r / 2.0), ..end.clone() };
            self.push_sample(&before);
            if after.t > before.t + MERGE_DT {
                self.push_sample(&after);
            }
            if end.t > after.t + MERGE_DT {
                self.push_sample(&end);
            }
        }
        if let Some(p) = &self.prev {
            if knot.t > p.t {
                self.prev_dt = knot.t - p.t;
            }
        }
        self.prev = Some(knot.clone());
        self.push_sample(knot);
    }

    fn push_sample(&mut self, knot: &Knot) {
        let n = self.axes.len();
        if !knot.t.is_finite() || knot.pos.len() < n || knot.pos.iter().any(|p| !p.is_finite()) {
            self.violation(format!("t={}: malformed knot {:?}", knot.t, knot.pos));
            return;
        }
        let pos = knot.pos[..n].to_vec();
        let mut issue = None;
        for (i, a) in self.axes.iter().enumerate() {
            let pp = &mut self.report.peak_position[i];
            pp.0 = pp.0.min(pos[i]);
            pp.1 = pp.1.max(pos[i]);
            if issue.is_none() && (pos[i] < a.min - POS_TOL || pos[i] > a.max + POS_TOL) {
                issue = Some(format!(
                    "t={:.6} axis {}: position {:.4} outside [{}, {}]",
                    knot.t, a.letter, pos[i], a.min, a.max
                ));
            }
        }
        if let Some(last_t) = self.win.back().map(|k| k.t) {
            if knot.t < last_t - MERGE_DT {
                self.violation(format!("t={:.6}: time goes backwards (previous {last_t:.6})", knot.t));
                return;
            }
        }
        if let Some(last) = self.win.back_mut() {
            if knot.t - last.t <= MERGE_DT {
                let jump = last.pos.iter().zip(&pos).any(|(a, b)| (a - b).abs() > 1e-9);
                if last.issue.is_none() {
                    last.issue = issue.or_else(|| {
                        jump.then(|| format!("t={:.6}: position jumps in zero time", knot.t))
                    });
                }
                last.pos = pos;
                return;
            }
        }
        self.win.push_back(Mk { t: knot.t, pos, real: true, issue });
        if !self.started && self.win.len() == 2 {
            // Rest before the first knot, sampled like the first segment.
            let h = self.win[1].t - self.win[0].t;
            let first = self.win[0].clone();
            for k in 1..=2 {
                self.win.push_front(Mk { t: first.t - k as f64 * h, real: false, issue: None, ..first.clone() });
            }
            self.next_eval = 2;
            self.started = true;
        }
        if self.started {
            while self.next_eval + 3 < self.win.len() {
                self.evaluate(self.next_eval);
                self.next_eval += 1;
                while self.next_eval > 3 {
                    self.win.pop_front();
                    self.next_eval -= 1;
                }
            }
        }
    }

    pub fn finish(mut self) -> LimitReport {
        if let Some((start, end)) = self.rest.take() {
            let r = end.t - start.t;
            self.push_sample(&Knot { t: start.t + self.prev_dt.min(r / 2.0), ..start.clone() });
        }
        if self.started {
            // Rest after the last knot, sampled like the last segment.
            let len = self.win.len();
            let h = self.win[len - 1].t - self.win[len - 2].t;
            let last = self.win[len - 1].clone();
            for k in 1..=2 {
                self.win.push_back(Mk { t: last.t + k as f64 * h, real: false, issue: None, ..last.clone() });
            }
            for i in self.next_eval..self.win.len() {
                if self.win[i].real {
                    self.evaluate(i);
                }
            }
        } else if let Some(only) = self.win.pop_front() {
            if let Some(msg) = only.issue {
                self.violation(msg);
            }
        }
        for pp in &mut self.report.peak_position {
            if pp.0 > pp.1 {
                *pp = (0.0, 0.0);
            }
        }
        self.report
    }

    // Segment k runs from knot k-1 to knot k.
    fn seg_exists(&self, k: usize) -> bool {
        k >= 1 && k < self.win.len()
    }

    fn dt(&self, k: usize) -> f64 {
        self.win[k].t - self.win[k - 1].t
    }


    fn dt_eff(&self, k: usize) -> f64 {
        self.dt(k)
    }

    fn vel(&self, k: usize, ax: usize) -> Option<f64> {
        self.seg_exists(k).then(|| (self.win[k].pos[ax] - self.win[k - 1].pos[ax]) / self.dt_eff(k))
    }

    /// Acceleration at knot m (between segments m and m+1).
    fn acc(&self, m: usize, ax: usize) -> Option<f64> {
        let (v0, v1) = (self.vel(m, ax)?, self.vel(m + 1, ax)?);
        Some((v1 - v0) / ((self.dt_eff(m) + self.dt_eff(m + 1)) / 2.0))
    }

    /// Jerk over knots m and m+1 (segments m, m+1, m+2).
    fn jerk(&self, m: usize, ax: usize) -> Option<f64> {
        let (a0, a1) = (self.acc(m, ax)?, self.acc(m + 1, ax)?);
        Some(3.0 * (a1 - a0) / (self.dt_eff(m) + self.dt_eff(m + 1) + self.dt_eff(m + 2)))
    }

    fn evaluate(&mut self, i: usize) {
        let mut msg = self.win[i].issue.take();
        let t = self.win[i].t;
        for ax in 0..self.axes.len() {
            let a = &self.axes[ax];
            let (letter, lv, la, lj) = (a.letter, a.max_velocity, a.max_acceleration, a.max_jerk);
            let checks = [
                ("velocity", self.vel(i, ax), lv, 0),
                ("acceleration", self.acc(i, ax), la, 1),
                ("jerk", i.checked_sub(1).and_then(|m| self.jerk(m, ax)), lj, 2),
                ("jerk", self.jerk(i, ax), lj, 2),
            ];
            for (what, val, limit, kind) in checks {
                let Some(x) = val else { continue };
                if !(limit.is_finite() && limit > 0.0) {
                    continue;
                }
                let used = x.abs() / limit;
                let peak = match kind {
                    0 => &mut self.report.peak_velocity_use[ax],
                    1 => &mut self.report.peak_acceleration_use[ax],
                    _ => &mut self.report.peak_jerk_use[ax],
                };
                *peak = peak.max(used);
                if used > 1.0 + REL_TOL && msg.is_none() {
                    msg = Some(format!("t={t:.6} axis {letter}: {what} {x:.3} exceeds limit {limit:.3}"));
                }
            }
        }
        if let Some(m) = msg {
            self.violation(m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn axes(v: f64, a: f64, j: f64) -> Vec<AxisConfig> {
        ['X', 'Y']
            .iter()
            .map(|&letter| AxisConfig {
                letter,
                min: -1.0,
                max: 500.0,
                max_velocity: v,
                max_acceleration: a,
                max_jerk: j,
            })
            .collect()
    }

    /// Rest-to-rest S-curve with jerk 1000, accel 100, speed 50 (phases of
    /// constant jerk), evaluated exactly. Returns (position at t, total time).
    fn s_curve() -> (impl Fn(f64) -> f64, f64) {
        let phases = [(0.1, 1000.0), (0.4, 0.0), (0.1, -1000.0), (0.5, 0.0), (0.1, -1000.0), (0.4, 0.0), (0.1, 1000.0)];
        let total: f64 = phases.iter().map(|p| p.0).sum();
        let f = move |t: f64| {
            let (mut p, mut v, mut a, mut left) = (0.0, 0.0, 0.0, t);
            for (d, j) in phases {
                let h = left.min(d);
                p += v * h + a * h * h / 2.0 + j * h * h * h / 6.0;
                v += a * h + j * h * h / 2.0;
                a += j * h;
                left -= h;
                if left <= 0.0 {
                    break;
                }
            }
            p
        };
        (f, total)
    }

    /// Samples the S-curve every `h` (plus the exact end), time scaled by
    /// 1/speedup; Y moves at half the X distance.
    fn sampled(h: f64, speedup: f64) -> Vec<Knot> {
        let (f, total) = s_curve();
        let mut ts: Vec<f64> = (0..).map(|k| k as f64 * h).take_while(|t| *t < total - 1e-12).collect();
        ts.push(total);
        ts.iter()
            .map(|&t| {
                let x = f(t);
                Knot { t: t / speedup, pos: vec![x, x / 2.0], power: 0.0, line: 1 }
            })
            .collect()
    }

    fn check(knots: &[Knot], ax: &[AxisConfig]) -> LimitReport {
        let mut c = LimitChecker::new(ax);
        knots.iter().for_each(|k| c.push(k));
        c.finish()
    }

    #[test]
    fn s_curve_within_limits_passes_at_any_spacing() {
        let ax = axes(50.5, 101.0, 1010.0);
        for h in [0.001, 0.01, 0.037, 0.1, 0.25] {
            let r = check(&sampled(h, 1.0), &ax);
            assert_eq!(r.violations, 0, "h={h}: {:?}", r.first_violation);
            assert!(r.peak_velocity_use[0] > 0.5 && r.peak_velocity_use[0] <= 1.0);
            assert!(r.peak_jerk_use[0] <= 1.0);
        }
        // Fine sampling sees nearly the true peaks.
        let r = check(&sampled(0.001, 1.0), &ax);
        assert!(r.peak_jerk_use[0] > 0.95, "{:?}", r.peak_jerk_use);
        assert!(r.peak_acceleration_use[0] > 0.95);
        assert_eq!(r.samples, sampled(0.001, 1.0).len() as u64);
    }

    #[test]
    fn s_curve_ten_percent_faster_fails() {
        let ax = axes(50.5, 101.0, 1010.0);
        for h in [0.001, 0.01, 0.037, 0.1] {
            let r = check(&sampled(h, 1.1), &ax);
            assert!(r.violations > 0, "h={h}");
            assert!(r.first_violation.is_some());
        }
    }

    #[test]
    fn stop_without_deceleration_fails() {
        let ax = axes(50.5, 101.0, 1010.0);
        let (_, total) = s_curve();
        let decel_start = 0.6 + 0.5; // accel phases + cruise
        let mut knots: Vec<Knot> = sampled(0.01, 1.0).into_iter().filter(|k| k.t <= decel_start + 1e-9).collect();
        let last = knots.last().unwrap().clone();
        knots.push(Knot { t: last.t + 0.5, ..last.clone() });
        knots.push(Knot { t: total + 5.0, ..last });
        let r = check(&knots, &ax);
        assert!(r.violations > 0);
        assert!(r.peak_acceleration_use[0] > 1.5, "{:?}", r.peak_acceleration_use);
    }

    #[test]
    fn a_laser_switched_at_the_end_of_a_rest_leaves_the_rest_whole() {
        let ax = axes(50.5, 101.0, 1010.0);
        let k = |t: f64, x: f64, power: f64| Knot { t, pos: vec![x, x / 2.0], power, line: 1 };
        // At rest for 2 s (the laser on, a pierce), then off at 50 mm/s at once:
        // a start without acceleration, whether or not the laser is switched
        // off by a knot at the instant the rest ends.
        let harsh = |switch: bool| {
            let mut v = vec![k(0.0, 0.0, 0.0), k(2.0, 0.0, 500.0)];
            if switch {
                v.push(k(2.0, 0.0, 0.0));
            }
            v.extend([k(2.01, 0.5, 300.0), k(2.02, 1.0, 300.0), k(2.03, 1.5, 300.0)]);
            check(&v, &ax)
        };
        let (plain, switched) = (harsh(false), harsh(true));
        assert!(plain.violations > 0 && plain.peak_acceleration_use[0] > 10.0, "{plain:?}");
        assert_eq!(switched.violations, plain.violations);
        assert_eq!(switched.peak_acceleration_use, plain.peak_acceleration_use);
        assert_eq!(switched.peak_jerk_use, plain.peak_jerk_use);
    }

    #[test]
    fn travel_jump_and_bad_input() {
        let ax = axes(1000.0, 1e6, 1e9);
        let k = |t: f64, x: f64| Knot { t, pos: vec![x, 0.0], power: 0.0, line: 0 };
        let r = check(&[k(0.0, 0.0), k(1.0, 600.0), k(2.0, 600.0)], &ax);
        assert!(r.violations >= 1);
        assert_eq!(r.peak_position[0], (0.0, 600.0));
        let r = check(&[k(0.0, 0.0), k(1.0, 1.0), k(1.0, 2.0), k(2.0, 2.0)], &ax);
        assert!(r.first_violation.unwrap().contains("jumps"));
        let r = check(&[k(0.0, 0.0), Knot { t: f64::NAN, pos: vec![0.0], power: 0.0, line: 0 }], &ax);
        assert_eq!((r.samples, r.violations), (2, 1));
        let r = LimitChecker::new(&ax).finish();
        assert_eq!(r.samples, 0);
        assert_eq!(r.violations, 0);
    }
}
