//! Grbl's look-ahead velocity planner, for the `grbl` motion model.
//!
//! Every block is a straight move with
//! * a nominal speed: the programmed feed (or the G93 block time), capped by
//!   every axis' max rate (`$110`…);
//! * an acceleration along its path: the largest that keeps every axis within
//!   its own limit (`$120`…);
//! * a highest entry speed at its junction with the block before, from the
//!   junction deviation (`$11`): the speed at which a circle of that deviation
//!   through the corner is taken at the junction's acceleration. Never above
//!   either block's nominal speed; zero when the block starts from rest.
//!
//! The queue is planned so the machine can always stop at its end (a reverse
//! pass from rest at the last block), and the executing block is cut into
//! segments of constant speed, at most [`SEGMENT_S`] long while the speed
//! changes, as Grbl's step-segment generator does at 100 Hz. Executed motion is
//! then exactly piecewise linear through the segment ends.

use crate::controller::AxisConfig;

/// Longest segment while accelerating or decelerating (Grbl: 100 per second).
pub const SEGMENT_S: f64 = 0.01;

/// Speeds and distances below these count as zero.
const EPS_SPEED: f64 = 1e-9;
const EPS_DIST: f64 = 1e-9;

/// A block's geometry and the limits its axes put on it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Kinematics {
    /// Euclidean length over all axes (mm).
    pub length: f64,
    /// Direction of travel (unit vector; zero for a zero-length block).
    pub unit: Vec<f64>,
    /// Acceleration along the path (mm/s²).
    pub acceleration: f64,
    /// Highest speed along the path the axes allow (mm/s).
    pub max_speed: f64,
    /// Highest speed at the junction with the block before (mm/s).
    pub max_junction: f64,
}

/// The largest value along `unit` that keeps every axis' share within its own
/// limit (`limit(axis)`); infinite for a zero vector.
fn along(unit: &[f64], axes: &[AxisConfig], limit: impl Fn(&AxisConfig) -> f64) -> f64 {
    unit.iter()
        .zip(axes)
        .filter(|(u, _)| u.abs() > 1e-12)
        .map(|(u, a)| limit(a) / u.abs())
        .fold(f64::INFINITY, f64::min)
}

/// Geometry and axis limits of a move from `start` to `target`. The junction
/// speed is left at zero (a start from rest); see [`junction_speed`].
pub fn kinematics(start: &[f64], target: &[f64], axes: &[AxisConfig]) -> Kinematics {
    let delta: Vec<f64> = target.iter().zip(start).map(|(t, s)| t - s).collect();
    let length = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
    let unit: Vec<f64> = if length > 0.0 { delta.iter().map(|d| d / length).collect() } else { vec![0.0; delta.len()] };
    Kinematics {
        length,
        acceleration: along(&unit, axes, |a| a.max_acceleration),
        max_speed: along(&unit, axes, |a| a.max_velocity),
        unit,
        max_junction: 0.0,
    }
}

/// Highest speed through the corner between a block along `prev` and the next
/// along `next`, for a junction deviation of `deviation` mm: 0 for a reversal,
/// unlimited straight on.
pub fn junction_speed(prev: &[f64], next: &[f64], axes: &[AxisConfig], deviation: f64) -> f64 {
    // cos of the angle between where the machine comes from and where it goes:
    // 1 turns right back, -1 goes straight on.
    let cos: f64 = -prev.iter().zip(next).map(|(a, b)| a * b).sum::<f64>();
    if cos > 0.999_999 {
        return 0.0;
    }
    if cos < -0.999_999 {
        return f64::INFINITY;
    }
    // The corner is taken at the acceleration the axes allow in the direction
    // the velocity changes.
    let change: Vec<f64> = next.iter().zip(prev).map(|(n, p)| n - p).collect();
    let norm = change.iter().map(|c| c * c).sum::<f64>().sqrt();
    let change: Vec<f64> = change.iter().map(|c| c / norm).collect();
    let acceleration = along(&change, axes, |a| a.max_acceleration);
    let sin_half = (0.5 * (1.0 - cos)).sqrt();
    (acceleration * deviation.max(0.0) * sin_half / (1.0 - sin_half)).sqrt()
}

/// What the planner needs of a queued block: its nominal speed now (after
/// overrides) and its kinematics.
#[derive(Debug, Clone, Copy)]
pub struct Planned<'a> {
    pub nominal: f64,
    pub kin: &'a Kinematics,
}

/// The highest speed at which the executing block (nominal `exec_nominal`) may
/// end so that the machine can still take every junction of `queue` and stop
/// at its end (Grbl's reverse pass). 0 for an empty queue.
pub fn exit_speed<'a>(exec_nominal: f64, queue: impl DoubleEndedIterator<Item = Planned<'a>>) -> f64 {
    let mut v: f64 = 0.0;
    let mut from_the_end = queue.rev().peekable();
    while let Some(b) = from_the_end.next() {
        let before = from_the_end.peek().map_or(exec_nominal, |p| p.nominal);
        let max_entry = b.kin.max_junction.min(b.nominal).min(before);
        v = max_entry.min((v * v + 2.0 * b.kin.acceleration * b.kin.length).sqrt());
    }
    v
}

/// One constant-speed stretch of the executing block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub distance: f64,
    pub duration: f64,
    /// Speed of the profile at the segment's end (the next one starts there).
    pub end_speed: f64,
}

/// Where the executing block stands when its next segment is cut.
#[derive(Debug, Clone, Copy)]
pub struct SegmentInput {
    /// Speed now.
    pub speed: f64,
    /// Distance left to the block's end.
    pub remaining: f64,
    /// Nominal speed now (after overrides).
    pub nominal: f64,
    /// Highest speed at the block's end (from [`exit_speed`]).
    pub exit: f64,
    pub acceleration: f64,
    /// A feed hold: decelerate to a stop whatever the plan says.
    pub stopping: bool,
}

/// Distance covered from speed `v` with acceleration `a` (signed) in `t`.
fn covered(v: f64, a: f64, t: f64) -> f64 {
    v * t + 0.5 * a * t * t
}

/// Cuts the next segment of a trapezoidal profile: accelerate to the nominal
/// speed (or as far as the exit speed allows), cruise, and decelerate to reach
/// the exit speed at the block's end. `None` when the block is done or the
/// machine has come to a stop in a hold.
pub fn next_segment(s: SegmentInput) -> Option<Segment> {
    let a = s.acceleration;
    if s.remaining <= EPS_DIST || !(a.is_finite() && a > 0.0) {
        return None;
    }
    let v = s.speed.max(0.0);
    // Decelerate at `a` for at most one segment, over at most `remaining`.
    let decelerate = |floor: f64| -> Option<Segment> {
        let t_floor = ((v - floor) / a).max(0.0);
        // Time at which the remaining distance is used up, if before the floor.
        let disc = v * v - 2.0 * a * s.remaining;
        // (v - end) / a, written without the cancellation of v - end.
        let end = disc.max(0.0).sqrt();
        let t_end = if disc >= floor * floor { 2.0 * s.remaining / (v + end) } else { f64::INFINITY };
        let t = t_floor.min(t_end).min(SEGMENT_S);
        if t <= 0.0 {
            return None;
        }
        if t >= t_end {
            // The remaining distance carries the rounding of the block's
            // segments (1e-14 mm on a 40 mm block), which the root turns into
            // an end speed of some 1e-6 mm/s above the floor: a step of speed
            // into the next block that reads as acceleration over the limit.
            // A remaining distance that short of braking to the floor only by
            // rounding ends at the floor, and the duration then follows from
            // the distance and the two speeds (an exact ramp, 1e-10 over `a`
            // at most).
            let to_floor = (v * v - floor * floor) / (2.0 * a);
            let end_speed = if s.remaining >= to_floor * (1.0 - 1e-10) - 1e-13 { floor } else { end };
            return Some(Segment { distance: s.remaining, duration: 2.0 * s.remaining / (v + end_speed), end_speed });
        }
        Some(Segment { distance: covered(v, -a, t).min(s.remaining), duration: t, end_speed: (v - a * t).max(0.0) })
    };
    if s.stopping {
        return if v <= EPS_SPEED { None } else { decelerate(0.0) };
    }
    let exit = s.exit.min(s.nominal).max(0.0);
    let braking = if v > exit { (v * v - exit * exit) / (2.0 * a) } else { 0.0 };
    if s.remaining <= braking + EPS_DIST && v > exit + EPS_SPEED {
        return decelerate(exit);
    }
    if v > s.nominal + EPS_SPEED {
        // The nominal speed dropped (a feed override): slow down to it.
        return decelerate(s.nominal);
    }
    // Where accelerating from v meets decelerating to the exit speed.
    let peak = ((v * v + exit * exit + 2.0 * a * s.remaining) / 2.0).sqrt();
    let top = s.nominal.min(peak);
    if top > v + EPS_SPEED {
        let t = ((top - v) / a).min(SEGMENT_S);
        // The exit speed may be more than this block can reach (the reverse
        // pass plans from the queue's end only): then the ramp ends with the
        // block, at the speed it reached there.
        let reached = (v * v + 2.0 * a * s.remaining).sqrt();
        if v + a * t >= reached {
            return Some(Segment { distance: s.remaining, duration: 2.0 * s.remaining / (v + reached), end_speed: reached });
        }
        return Some(Segment { distance: covered(v, a, t), duration: t, end_speed: v + a * t });
    }
    // Cruise to where braking for the exit must begin.
    if v <= EPS_SPEED {
        // Cannot accelerate nor cruise: only reachable with a zero nominal speed.
        return None;
    }
    let cruise = s.remaining - (v * v - exit * exit).max(0.0) / (2.0 * a);
    if cruise <= EPS_DIST {
        return decelerate(exit);
    }
    Some(Segment { distance: cruise, duration: cruise / v, end_speed: v })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn axes() -> Vec<AxisConfig> {
        vec![AxisConfig::new('X'), AxisConfig::new('Y')]
    }

    /// Runs a whole block through `next_segment` from `v0`.
    fn run(remaining: f64, v0: f64, nominal: f64, exit: f64, a: f64) -> (f64, f64, Vec<Segment>) {
        let (mut left, mut v, mut t, mut segs) = (remaining, v0, 0.0, Vec::new());
        while let Some(seg) = next_segment(SegmentInput { speed: v, remaining: left, nominal, exit, acceleration: a, stopping: false }) {
            assert!(seg.duration > 0.0 && seg.distance > 0.0, "{seg:?}");
            left -= seg.distance;
            v = seg.end_speed;
            t += seg.duration;
            segs.push(seg);
            assert!(segs.len() < 100_000);
        }
        assert!(left.abs() < 1e-6, "left {left}");
        (t, v, segs)
    }

    #[test]
    fn trapezoid_from_rest_to_rest_takes_the_textbook_time() {
        // 100 mm at 50 mm/s with 1000 mm/s²: 0.05 s up, 0.05 s down, 1.95 s cruise.
        let (t, v, segs) = run(100.0, 0.0, 50.0, 0.0, 1000.0);
        assert!((t - 2.05).abs() < 1e-9, "{t}");
        assert!(v.abs() < 1e-9, "{v} {:?}", &segs[segs.len() - 3..]);
        assert!(segs.iter().all(|s| s.duration <= SEGMENT_S + 1e-12 || (s.end_speed - 50.0).abs() < 1e-9));
        // A short move never reaches the nominal speed: a triangle.
        let (t, _, _) = run(1.0, 0.0, 50.0, 0.0, 1000.0);
        assert!((t - 2.0 * (1.0f64 / 1000.0).sqrt()).abs() < 1e-9, "{t}");
    }

    #[test]
    fn exit_speed_is_reached_not_exceeded() {
        let (_, v, _) = run(10.0, 0.0, 50.0, 20.0, 1000.0);
        assert!((v - 20.0).abs() < 1e-6, "{v}");
        // Entering faster than the nominal speed (an override dropped): slows down.
        let (_, v, segs) = run(10.0, 80.0, 50.0, 50.0, 1000.0);
        assert!((v - 50.0).abs() < 1e-6 && segs[0].end_speed < 80.0);
    }

    #[test]
    fn hold_decelerates_to_a_stop_within_the_acceleration() {
        let mut v = 50.0;
        let mut travelled = 0.0;
        while let Some(seg) = next_segment(SegmentInput { speed: v, remaining: 100.0, nominal: 50.0, exit: 50.0, acceleration: 1000.0, stopping: true }) {
            assert!((v - seg.end_speed) / seg.duration <= 1000.0 + 1e-6);
            v = seg.end_speed;
            travelled += seg.distance;
        }
        assert!(v < 1e-9);
        assert!((travelled - 50.0 * 50.0 / 2000.0).abs() < 1e-9, "{travelled}");
    }

    #[test]
    fn junctions() {
        let ax = axes();
        assert_eq!(junction_speed(&[1.0, 0.0], &[1.0, 0.0], &ax, 0.01), f64::INFINITY);
        assert_eq!(junction_speed(&[1.0, 0.0], &[-1.0, 0.0], &ax, 0.01), 0.0);
        // A right angle: sin(45°) = 0.7071; v² = a·δ·s/(1-s) with a along the
        // diagonal (both axes share it: 1000·√2).
        let v = junction_speed(&[1.0, 0.0], &[0.0, 1.0], &ax, 0.01);
        let s = 0.5f64.sqrt();
        assert!((v - (1000.0 * 2f64.sqrt() * 0.01 * s / (1.0 - s)).sqrt()).abs() < 1e-9, "{v}");
        // A sharper corner is slower, a larger deviation faster.
        assert!(junction_speed(&[1.0, 0.0], &[-s, s], &ax, 0.01) < v);
        assert!(junction_speed(&[1.0, 0.0], &[0.0, 1.0], &ax, 0.1) > v);
    }

    #[test]
    fn kinematics_respect_every_axis() {
        let mut ax = axes();
        ax[1].max_velocity = 10.0;
        ax[1].max_acceleration = 100.0;
        let k = kinematics(&[0.0, 0.0], &[3.0, 4.0], &ax);
        assert!((k.length - 5.0).abs() < 1e-12);
        // Y carries 0.8 of the motion: its limits bound the path.
        assert!((k.max_speed - 12.5).abs() < 1e-12 && (k.acceleration - 125.0).abs() < 1e-12);
    }

    #[test]
    fn the_reverse_pass_lets_the_queue_stop_at_its_end() {
        let k = Kinematics { length: 1.0, unit: vec![1.0, 0.0], acceleration: 1000.0, max_speed: 100.0, max_junction: f64::INFINITY };
        let q: Vec<Planned> = (0..3).map(|_| Planned { nominal: 100.0, kin: &k }).collect();
        // Three 1 mm blocks: from 0 at the end, sqrt(2·a·3 mm) = 77.5 mm/s before them.
        assert!((exit_speed(100.0, q.iter().copied()) - (2.0f64 * 1000.0 * 3.0).sqrt()).abs() < 1e-9);
        assert_eq!(exit_speed(100.0, std::iter::empty()), 0.0);
        // The executing block's own nominal speed caps its exit.
        assert!((exit_speed(20.0, q.iter().copied()) - 20.0).abs() < 1e-12);
    }
}
