//! Arc blocks (G2/G3) for stage-only programs: where consecutive straight
//! blocks of a mark lie on one circle and the trajectory runs along them
//! close enough to the constant speed a controller runs an arc at (its
//! place at each instant within the limit, its knots within the axis
//! limits), one arc replaces them.
//!
//! The check is against what the controller will execute, not against the
//! fitted circle: the arc as Grbl reads it from the rounded words (start =
//! the previous block's rounded end, `I J` rounded, end rounded; gcode.c's
//! radius check; mc_arc's angular travel and its chords, whose count comes
//! from `$12`), run at constant speed in the block's time. Every planned
//! position in the block must be within the limit of that arc at the same
//! instant, the chords' sagitta added.
//!
//! An arc's chords are also knots the controller runs straight between, at
//! equal times: their small deviations from the plan are divided by the
//! chord time cubed in the jerk the limit checker sees (8·e/T³ for an error
//! e alternating over chords of T). So an arc is taken only where the knots
//! it makes, with the executed blocks before it and the planned ones after,
//! keep every axis within its velocity, acceleration and jerk limits
//! (`within_limits`, the simulator's divided differences): this also keeps
//! the speed continuous at the joins.
//!
//! Arcs are written in G94 (`F` in mm/min): Grbl 1.1h and grblHAL run a G93
//! arc's segments at `F` × segments mm/min (mc_arc multiplies the inverse
//! time by the count, then drops inverse time), not in 1/F minutes.

use crate::config::Limits;
use crate::job::Point;
use std::f64::consts::{PI, TAU};

/// Grbl's default `$12` (mm): the sagitta of the chords it cuts an arc into.
pub const GRBL_ARC_TOLERANCE: f64 = 0.002;

/// Grbl's `ARC_ANGULAR_TRAVEL_EPSILON`: a smaller travel is a full circle.
const ANGULAR_EPSILON: f64 = 5e-7;

/// Share of each limit the knots of an arc and its neighbours may use: the
/// rest is for the rounding of the other blocks' words (1 %, see
/// `min_block_time`) and Grbl's small-angle chord rotation.
const LIMIT_SHARE: f64 = 0.95;

/// Known knots on either side of a candidate arc: enough for every jerk
/// window (four knots) that holds one of the arc's chord ends.
const CONTEXT_KNOTS: usize = 3;

/// Radii beyond this are left as straight blocks (a large arc's centre
/// offset is a long word, and its chord count large).
const MAX_RADIUS: f64 = 2000.0;

/// The words of an arc block, as written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcWords {
    /// G2 (clockwise with the machine's Y up) or G3.
    pub clockwise: bool,
    /// `I`, `J`: the centre from the block's (rounded) start.
    pub centre_offset: [f64; 2],
    /// `F` in mm/min (G94): the controller's chords in the block's time.
    pub feed: f64,
}

/// Rounded as the program writes a coordinate with `decimals` decimals.
fn rounded(v: f64, decimals: usize) -> f64 {
    let scale = 10f64.powi(decimals as i32);
    (v * scale).round() / scale
}

/// Centre of the circle through three points (None when they are nearly
/// on one line).
fn circumcentre(a: Point, b: Point, c: Point) -> Option<Point> {
    let (b, c) = (b - a, c - a);
    let d = 2.0 * (b.x * c.y - b.y * c.x);
    let scale = b.norm_squared().max(c.norm_squared());
    if d.abs() <= 1e-12 * scale || scale == 0.0 {
        return None;
    }
    let (b2, c2) = (b.norm_squared(), c.norm_squared());
    Some(Point::new(a.x + (c.y * b2 - b.y * c2) / d, a.y + (b.x * c2 - c.x * b2) / d))
}

/// The arc the controller runs from `start` to `end` around `start +
/// offset`: (centre, radius, signed angular travel, chord count), or None
/// where Grbl refuses it (error 33).
fn executed(start: Point, end: Point, offset: [f64; 2], clockwise: bool) -> Option<(Point, f64, f64, usize)> {
    let centre = Point::new(start.x + offset[0], start.y + offset[1]);
    let (r0, r1) = (start - centre, end - centre);
    let radius = r0.norm();
    let radius_error = (r1.norm() - radius).abs();
    if radius <= 0.0 || (radius_error > 0.005 && (radius_error > 0.5 || radius_error > 0.001 * radius)) {
        return None;
    }
    let mut travel = (r0.x * r1.y - r0.y * r1.x).atan2(r0.x * r1.x + r0.y * r1.y);
    if clockwise && travel >= -ANGULAR_EPSILON {
        travel -= TAU;
    } else if !clockwise && travel <= ANGULAR_EPSILON {
        travel += TAU;
    }
    let t = GRBL_ARC_TOLERANCE;
    let segments = ((0.5 * travel * radius).abs() / (t * (2.0 * radius - t)).sqrt()).floor();
    let segments = if segments.is_finite() { segments as usize } else { 0 };
    Some((centre, radius, travel, segments))
}

/// How many planner blocks each line of `program` takes in the controller:
/// an arc (as written here: G2/G3 first, absolute X Y, I J) as many as the
/// chords Grbl cuts it into, any other line one. The link model needs them:
/// an arc's `ok` comes only once its last chord is queued.
pub fn planner_blocks(program: &super::Program) -> Vec<usize> {
    let mut at = Point::new(program.start.first().copied().unwrap_or(0.0), program.start.get(1).copied().unwrap_or(0.0));
    program
        .lines
        .iter()
        .map(|line| {
            let word = |letter: char| {
                let from = line.text.find(letter)? + 1;
                let rest = &line.text[from..];
                let len = rest.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(rest.len());
                rest[..len].parse::<f64>().ok()
            };
            let end = Point::new(word('X').unwrap_or(at.x), word('Y').unwrap_or(at.y));
            let clockwise = line.text.starts_with("G2G") || line.text.starts_with("G2X") || line.text.starts_with("G2Y");
            let counter = line.text.starts_with("G3G") || line.text.starts_with("G3X") || line.text.starts_with("G3Y");
            let blocks = match (clockwise || counter, word('I'), word('J')) {
                (true, Some(i), Some(j)) => executed(at, end, [i, j], clockwise).map_or(1, |(_, _, _, segments)| segments.max(1)),
                _ => 1,
            };
            at = end;
            blocks
        })
        .collect()
}

/// The knots the controller runs `arc` through from `start` (at `t0`) to
/// `end` (at `t1`), the start excluded: its chord ends at equal times (the
/// timed model; Grbl gives every chord of an arc the same speed).
pub fn chord_knots(start: Point, end: Point, arc: &ArcWords, t0: f64, t1: f64) -> Option<Vec<(f64, Point)>> {
    let (centre, radius, travel, segments) = executed(start, end, arc.centre_offset, arc.clockwise)?;
    let n = segments.max(1);
    let theta0 = (start.y - centre.y).atan2(start.x - centre.x);
    let mut knots: Vec<(f64, Point)> = (1..n)
        .map(|k| {
            let f = k as f64 / n as f64;
            let angle = theta0 + travel * f;
            (t0 + f * (t1 - t0), Point::new(centre.x + radius * angle.cos(), centre.y + radius * angle.sin()))
        })
        .collect();
    knots.push((t1, end));
    Some(knots)
}

/// Whether motion straight from knot to knot (instants, positions) keeps
/// both axes within `LIMIT_SHARE` of `limits`, by the divided differences
/// the simulator's limit checker takes: the velocity of a segment, the
/// acceleration at a knot, the jerk over two knots.
fn within_limits(knots: &[(f64, Point)], limits: Limits) -> bool {
    let axis = |p: Point, k: usize| if k == 0 { p.x } else { p.y };
    (0..2).all(|k| {
        let dt: Vec<f64> = knots.windows(2).map(|w| w[1].0 - w[0].0).collect();
        if dt.iter().any(|&d| d <= 0.0) {
            return false;
        }
        let v: Vec<f64> = knots.windows(2).zip(&dt).map(|(w, d)| (axis(w[1].1, k) - axis(w[0].1, k)) / d).collect();
        let a: Vec<f64> = (0..v.len().saturating_sub(1)).map(|m| (v[m + 1] - v[m]) / (0.5 * (dt[m] + dt[m + 1]))).collect();
        let j = (0..a.len().saturating_sub(1)).map(|m| 3.0 * (a[m + 1] - a[m]) / (dt[m] + dt[m + 1] + dt[m + 2]));
        v.iter().all(|x| x.abs() <= LIMIT_SHARE * limits.velocity)
            && a.iter().all(|x| x.abs() <= LIMIT_SHARE * limits.acceleration)
            && j.into_iter().all(|x| x.abs() <= LIMIT_SHARE * limits.jerk)
    })
}

/// Tries one arc from `samples[0]` to the last sample (planned instants and
/// TCP positions, the first and last a block's start and end): its words
/// where every sample is within `limit` of the executed arc. The knots the
/// arc makes are the caller's to check (`merge` does).
pub fn fit(samples: &[(f64, Point)], decimals: usize, limit: f64) -> Option<ArcWords> {
    let n = samples.len();
    if n < 4 {
        return None;
    }
    let (t0, t1) = (samples[0].0, samples[n - 1].0);
    let duration = t1 - t0;
    if duration <= 0.0 {
        return None;
    }
    let at_time = |f: f64| samples[samples.partition_point(|s| s.0 < t0 + f * duration).min(n - 1)].1;
    // Three points a third of the time apart: a full circle too has them apart.
    let (a, b, c) = (samples[0].1, at_time(1.0 / 3.0), at_time(2.0 / 3.0));
    let centre = circumcentre(a, b, c)?;
    if (a - centre).norm() > MAX_RADIUS {
        return None;
    }
    // The planned travel: the angle swept sample by sample (each step less than a half turn).
    let mut planned_travel = 0.0;
    for w in samples.windows(2) {
        let (p, q) = (w[0].1 - centre, w[1].1 - centre);
        let step = (p.x * q.y - p.y * q.x).atan2(p.x * q.x + p.y * q.y);
        if step.abs() > 0.5 * PI {
            return None;
        }
        planned_travel += step;
    }
    if planned_travel.abs() > TAU + 1e-9 || planned_travel.abs() < 1e-6 {
        return None;
    }
    let clockwise = planned_travel < 0.0;
    let start = Point::new(rounded(a.x, decimals), rounded(a.y, decimals));
    let last = samples[n - 1].1;
    let end = Point::new(rounded(last.x, decimals), rounded(last.y, decimals));
    let offset = [rounded(centre.x - start.x, decimals), rounded(centre.y - start.y, decimals)];
    let (centre, radius, travel, segments) = executed(start, end, offset, clockwise)?;
    // Rounding may move the end across the start (a circle read as a sliver).
    if (travel - planned_travel).abs() > 1e-3 {
        return None;
    }
    let sagitta = radius * (1.0 - (0.5 * travel.abs() / segments.max(1) as f64).cos());
    if sagitta >= limit {
        return None;
    }
    // The plan may speed up or slow down along the arc as far as the
    // place at each instant stays within the limit (below): the step in
    // speed that the controller's constant-speed chords then meet at the
    // joins is acceleration and jerk in their knots, which `merge` checks.
    let theta0 = (start.y - centre.y).atan2(start.x - centre.x);
    let within = samples.iter().all(|&(t, p)| {
        let angle = theta0 + travel * (t - t0) / duration;
        let on_arc = Point::new(centre.x + radius * angle.cos(), centre.y + radius * angle.sin());
        (p - on_arc).norm() + sagitta <= limit
    });
    if !within {
        return None;
    }
    // Grbl runs every chord at `F`, the last one to the written end (off the
    // circle by the rounding): the block's time is the chords' length over F.
    let mut arc = ArcWords { clockwise, centre_offset: offset, feed: 0.0 };
    let knots = chord_knots(start, end, &arc, 0.0, 1.0)?;
    let chords: f64 = knots.iter().scan(start, |from, &(_, to)| Some((to - std::mem::replace(from, to)).norm())).sum();
    arc.feed = 60.0 * chords / duration;
    Some(arc)
}

/// Where straight blocks with ends `times` (the first the span's start)
/// merge into arcs: (end index into `times`, arc) per block, in order; an
/// arc covers at least two straight blocks and begins at `times[first_arc]`
/// or later. `position(t)` is the planned TCP; `limits` the axes' (see the
/// module's doc on the knots an arc makes).
pub fn merge(times: &[f64], decimals: usize, limit: f64, limits: Limits, first_arc: usize, position: impl Fn(f64) -> Point) -> Vec<(usize, Option<ArcWords>)> {
    let mut out = Vec::new();
    let last = times.len().saturating_sub(1);
    if last == 0 {
        return out;
    }
    // Where a straight block ends: the rounded words the program writes.
    let written = |t: f64| {
        let p = position(t);
        (t, Point::new(rounded(p.x, decimals), rounded(p.y, decimals)))
    };
    // The planned TCP at the block ends from `a` to `b` and eighths of each block between.
    let samples_of = |a: usize, b: usize| {
        let mut out = vec![(times[a], position(times[a]))];
        for w in times[a..=b].windows(2) {
            out.extend((1..=8).map(|q| w[0] + (w[1] - w[0]) * q as f64 / 8.0).map(|t| (t, position(t))));
        }
        out
    };
    // The knots the program makes so far (the blocks before the span: the
    // plan, sampled at the candidate arc's chord time).
    let mut executed = vec![written(times[0])];
    let mut i = 0;
    while i < last {
        let try_to = |j: usize| -> Option<(ArcWords, Vec<(f64, Point)>)> {
            let arc = fit(&samples_of(i, j), decimals, limit)?;
            let (start, end) = (written(times[i]), written(times[j]));
            let chords = chord_knots(start.1, end.1, &arc, start.0, end.0)?;
            let chord_time = chords[0].0 - start.0;
            let known = executed.len().min(CONTEXT_KNOTS);
            let mut knots: Vec<(f64, Point)> = (known..CONTEXT_KNOTS).rev().map(|k| written(times[0] - (k + 1 - known) as f64 * chord_time)).collect();
            knots.extend_from_slice(&executed[executed.len() - known..]);
            knots.extend_from_slice(&chords);
            knots.extend((1..CONTEXT_KNOTS).map(|k| written(if j + k <= last { times[j + k] } else { times[last] + (j + k - last) as f64 * chord_time })));
            within_limits(&knots, limits).then_some((arc, chords))
        };
        // Galloping, then bisecting, over the block ends the arc reaches.
        let (mut good, mut bad, mut step) = (None, last + 1, 2);
        loop {
            if i < first_arc {
                break;
            }
            let j = i + step;
            if j > last {
                if good.as_ref().is_none_or(|(g, _)| *g < last) {
                    if let Some(arc) = try_to(last) {
                        good = Some((last, arc));
                    } else {
                        bad = last;
                    }
                }
                break;
            }
            match try_to(j) {
                Some(arc) => good = Some((j, arc)),
                None => {
                    bad = j;
                    break;
                }
            }
            step *= 2;
        }
        let mut lo = good.as_ref().map_or(i + 1, |(g, _)| *g);
        while bad <= last && bad - lo > 1 {
            let mid = (lo + bad) / 2;
            match try_to(mid) {
                Some(arc) => {
                    good = Some((mid, arc));
                    lo = mid;
                }
                None => bad = mid,
            }
        }
        match good {
            Some((j, (arc, chords))) if j >= i + 2 => {
                out.push((j, Some(arc)));
                executed.extend(chords);
                i = j;
            }
            _ => {
                out.push((i + 1, None));
                executed.push(written(times[i + 1]));
                i += 1;
            }
        }
        // Only the last few knots are context for the next arc.
        if executed.len() > 4 * CONTEXT_KNOTS {
            executed.drain(..executed.len() - CONTEXT_KNOTS);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Planned samples of a run around (cx, cy) at radius `r` from angle
    /// `from` by `travel` (radians, signed) in `duration` s at constant speed.
    fn circle(cx: f64, cy: f64, r: f64, from: f64, travel: f64, duration: f64, n: usize) -> Vec<(f64, Point)> {
        (0..=n)
            .map(|k| {
                let f = k as f64 / n as f64;
                let a = from + travel * f;
                (f * duration, Point::new(cx + r * a.cos(), cy + r * a.sin()))
            })
            .collect()
    }

    #[test]
    fn points_on_a_circle_become_one_arc_with_the_machines_y_up() {
        // A quarter, counter-clockwise (Y up): G3, centre offset from the start.
        let quarter = circle(100.0, 50.0, 10.0, 0.0, 0.5 * PI, 0.4, 40);
        let arc = fit(&quarter, 5, 0.009).expect("a quarter circle is an arc");
        assert!(!arc.clockwise);
        assert_eq!(arc.centre_offset, [-10.0, 0.0]);
        // F: the chords' length in the time, near the arc length (15.71 mm in 0.4 s).
        assert!((arc.feed - 60.0 * 15.70796 / 0.4).abs() < 0.01 * arc.feed, "{}", arc.feed);
        // The same the other way round: G2.
        let cw = circle(100.0, 50.0, 10.0, 0.0, -0.5 * PI, 0.4, 40);
        assert!(fit(&cw, 5, 0.009).expect("an arc").clockwise);
    }

    #[test]
    fn half_and_full_circles_are_arcs() {
        let half = fit(&circle(0.0, 0.0, 5.0, 0.3, PI, 1.0, 64), 5, 0.009).expect("a half circle");
        assert!(!half.clockwise);
        let full = fit(&circle(20.0, 20.0, 5.0, 1.0, -TAU, 1.0, 128), 5, 0.009).expect("a full circle");
        assert!(full.clockwise);
        assert!((full.feed - 60.0 * TAU * 5.0).abs() < 0.01 * full.feed);
        // More than a turn is not one arc.
        assert!(fit(&circle(20.0, 20.0, 5.0, 1.0, TAU + 0.5, 1.0, 140), 5, 0.009).is_none());
    }

    #[test]
    fn a_polyline_that_is_no_arc_or_runs_at_another_pace_stays_lines() {
        // A right-angle corner: no circle within 0.01 mm.
        let corner: Vec<(f64, Point)> = (0..=20)
            .map(|k| {
                let p = if k <= 10 { Point::new(k as f64, 0.0) } else { Point::new(10.0, (k - 10) as f64) };
                (k as f64 * 0.1, p)
            })
            .collect();
        assert!(fit(&corner, 5, 0.009).is_none());
        // On the circle, but stopping half-way (slow, then fast): the
        // controller's constant speed is not the plan's timing.
        let mut uneven = circle(0.0, 0.0, 10.0, 0.0, PI, 1.0, 60);
        for (k, s) in uneven.iter_mut().enumerate() {
            let f = k as f64 / 60.0;
            s.0 = if f <= 0.5 { 1.5 * f } else { 0.75 + 0.5 * (f - 0.5) };
        }
        assert!(fit(&uneven, 5, 0.009).is_none());
    }

    #[test]
    fn a_run_speeding_up_along_a_circle_within_the_limit_is_one_arc() {
        // 0.2 rad of a circle of 10 mm in 10 ms, the speed rising by 1.5 %
        // (300 mm/s²): the constant-speed arc is off the plan's place by
        // a·T²/8 = 0.0038 mm at its middle, with its chords' 0.002 mm sagitta
        // within 0.009 mm.
        let (r, duration) = (10.0, 0.01);
        let ramp = |accel: f64| -> Vec<(f64, Point)> {
            let v0 = 0.2 * r / duration - 0.5 * accel * duration;
            (0..=40)
                .map(|k| {
                    let t = k as f64 / 40.0 * duration;
                    let a = (v0 * t + 0.5 * accel * t * t) / r;
                    (t, Point::new(50.0 + r * a.cos(), 50.0 + r * a.sin()))
                })
                .collect()
        };
        let arc = fit(&ramp(300.0), 5, 0.009).expect("a run speeding up within the limit is an arc");
        assert!(!arc.clockwise);
        // F: the mean speed (200 mm/s), what the block's time asks for.
        assert!((arc.feed - 60.0 * 200.0).abs() < 0.01 * arc.feed, "{}", arc.feed);
        // Ten times the acceleration is 0.038 mm off: lines.
        assert!(fit(&ramp(3000.0), 5, 0.009).is_none());
    }

    #[test]
    fn an_arc_takes_as_many_planner_blocks_as_grbl_cuts_it_into() {
        let line = |text: &str| super::super::ProgramLine { text: text.into(), kind: super::super::LineKind::Mark, geometry: None, plan_time: None, checks: vec![] };
        let program = super::super::Program {
            lines: vec![line("G1X1Y0F60"), line("G3G94X0Y1I-1J0F60"), line("G93G1X5F60"), line("G2G94X5Y2I0J0.5F60")],
            axis_letters: vec!['X', 'Y'],
            start: vec![0.0, 0.0],
            sources: vec![],
        };
        // A quarter of radius 1: floor(0.785 / 0.0632) = 12 chords; a half
        // of radius 0.5: floor(0.785 / 0.0447) = 17.
        assert_eq!(planner_blocks(&program), vec![1, 12, 1, 17]);
    }

    #[test]
    fn merging_keeps_lines_off_the_circle_and_an_arc_on_it() {
        // A straight run of 4 blocks, then a half circle of 16 blocks.
        let times: Vec<f64> = (0..=20).map(|k| k as f64 * 0.1).collect();
        let at = |t: f64| {
            if t <= 0.4 {
                Point::new(-10.0, -40.0 + 100.0 * t)
            } else {
                let a = PI - PI * (t - 0.4) / 1.6;
                Point::new(10.0 * a.cos(), 10.0 * a.sin())
            }
        };
        // Limits this plan keeps (its speed steps from 100 to 20 mm/s at the join).
        let limits = Limits { velocity: 1e3, acceleration: 1e5, jerk: 1e9 };
        let merged = merge(&times, 5, 0.009, limits, 0, at);
        let arcs: Vec<_> = merged.iter().filter(|(_, a)| a.is_some()).collect();
        assert_eq!(arcs.len(), 1, "{merged:?}");
        assert_eq!(arcs[0].0, 20, "the arc ends at the last block");
        assert!(arcs[0].1.unwrap().clockwise);
        assert_eq!(merged.len(), 5, "4 lines and an arc: {merged:?}");
    }
}
