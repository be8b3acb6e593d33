//! On the fly: the stage planned over the whole job, flowing through the scan
//! fields at speed instead of resting in each.
//!
//! Each stage axis is one convex problem (a QP whose rows are banded,
//! solved by `qp`'s interior point method). The unknowns are the control points of a uniform
//! cubic B-spline (step `h` of a few ms). A B-spline's velocity,
//! acceleration and jerk are B-splines of the control points' first, second
//! and third differences over `h`, `h²`, `h³`, so bounding those differences
//! by V, A and J is linear and keeps the limits (exactly so for A and J).
//! The field corridor is linear too: at the ends of the split's windows the
//! spline (a fixed mix of four control points) lies within the TCP's box
//! over the window widened by the usable half field, less how far the spline
//! may bow in between. The first and last three control points are equal:
//! the stage starts and ends at rest.
//!
//! Where no such stage exists (it cannot reach the next field in time), the
//! corridor gives: a slack per sample widens it at a cost, and the largest
//! in each half of a field's time names the field change where the stage
//! falls behind and by how far. The caller slows the TCP there and plans
//! again. A small smoothing term (squared accelerations) picks one stage among
//! the feasible ones.

use super::stage::{windows, SplitSettings, Window};
use super::tcp::TcpPath;
use crate::job::Point;

/// The stage's path: a uniform cubic B-spline per axis, control point `k` at
/// time `t0 + k·h` (before the first and after the last: at rest there).
#[derive(Debug, Clone)]
pub struct Flow {
    /// Before this the stage stands at its first control point (the
    /// approach's moves end before it).
    pub moves_from: f64,
    pub t0: f64,
    pub h: f64,
    pub control: [Vec<f64>; 2],
}

impl Flow {
    pub fn position(&self, t: f64) -> Point {
        Point::new(self.axis(0, t), self.axis(1, t))
    }

    fn axis(&self, i: usize, t: f64) -> f64 {
        spline(&self.control[i], self.h, t - self.t0)
    }

    /// When the stage first moves (the control points' first change, less
    /// the spline's reach).
    pub fn first_motion(&self) -> f64 {
        let first = self.control.iter().map(|c| c.iter().position(|&x| (x - c[0]).abs() > 1e-12).unwrap_or(c.len())).min().unwrap_or(0);
        self.t0 + (first as f64 - 2.0) * self.h
    }

    pub fn start_point(&self) -> Point {
        self.position(self.t0)
    }

    /// When the stage has come to rest (the last three control points are
    /// equal: the spline is still from the second last on).
    pub fn end_time(&self) -> f64 {
        self.t0 + self.h * self.control[0].len().saturating_sub(2) as f64
    }

    pub fn shift(&mut self, dt: f64) {
        self.t0 += dt;
        self.moves_from += dt;
    }

    /// Whether the stage moves at `t`.
    pub fn moving(&self, t: f64) -> bool {
        let u = (t - self.t0) / self.h;
        if u < -1.0 || u > self.control[0].len() as f64 {
            return false;
        }
        let k = u.floor() as isize;
        self.control.iter().any(|c| {
            let at = |j: isize| c[j.clamp(0, c.len() as isize - 1) as usize];
            (k - 1..=k + 2).any(|j| (at(j) - at(k - 1)).abs() > 1e-12)
        })
    }
}

/// Target step between control points (s): fine enough for the stage's
/// jerk ramps (`A/J` is tens of ms), coarse enough for a small problem.
const STEP: f64 = 5.0e-3;
/// Most control points per axis: longer jobs get a coarser spline, up to
/// `COARSEST` times the step; beyond that (or with more than `MOST_SAMPLES`
/// corridor samples) the flow is not planned (the bursts are): the solve's
/// time and memory grow with the problem.
const MOST_STEPS: f64 = 2.0e4;
const COARSEST: f64 = 4.0;
const MOST_SAMPLES: usize = 400_000;
/// Kept between the planned stage and the field's edge (mm): the program's
/// rounding and the solver's tolerance.
const EDGE: f64 = 0.01;
/// Slack below this (mm) is the solver's tolerance, not a shortfall.
const SLACK_TOLERANCE: f64 = 1.0e-3;
/// Weight of the smoothing term (squared acceleration, as a share of the
/// limit, summed) against a millimetre of slack.
const SMOOTH: f64 = 1.0e-4;

/// Where the stage falls behind: per field change, by how far.
#[derive(Debug, Clone, PartialEq)]
pub struct Behind {
    /// `(g, f, mm)`: the stage reaches field `g` (a group index) too late,
    /// or leaves the field before it too early, by `mm` at most, the shortfall
    /// being in field `f` (`g` or the one before).
    pub into: Vec<(usize, usize, f64)>,
    /// Short at the start (the stage cannot follow the first field from
    /// rest) and at the end (it cannot stop with the TCP), mm.
    pub start: f64,
    pub end: f64,
}

/// Buffers of the two axes' solves, kept from one plan to the next.
#[derive(Debug, Default)]
pub struct Workspace([std::sync::Mutex<super::qp::Workspace>; 2]);

/// Why there is no flow for a TCP.
#[derive(Debug, Clone, PartialEq)]
pub enum NoFlow {
    /// The stage falls behind there.
    Behind(Behind),
    /// The job is too long to plan this way.
    TooLong,
    /// The solver did not converge (an ill-conditioned problem).
    Unsolved,
}

/// Plans the stage for `tcp`, standing still for `pads.0` before the TCP
/// starts and `pads.1` after it ends (the TCP waits at its ends meanwhile), or
/// names where it cannot keep up.
pub fn plan(tcp: &TcpPath, s: &SplitSettings, pads: (f64, f64), space: &Workspace) -> Result<Flow, NoFlow> {
    let duration = tcp.duration();
    let (pre, post) = pads;
    let span = duration + pre + post;
    let steps = ((span / STEP).ceil()).clamp(2.0, MOST_STEPS) as usize;
    let h = span.max(1e-9) / steps as f64;
    if h > COARSEST * STEP {
        return Err(NoFlow::TooLong);
    }
    // Control point k at time t0 + k·h; the first and last three equal (at
    // rest before -pre and after duration + post).
    let t0 = -pre - h;
    let m = steps + 3;
    let samples = samples(tcp, pads, h, s.half, s.burst.acceleration);
    if samples.len() > MOST_SAMPLES {
        return Err(NoFlow::TooLong);
    }
    let slacks = 2 * groups(tcp);
    let travel = [s.travel.0, s.travel.1];
    let mut control: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut short = vec![0.0f64; slacks];
    // The axes are independent problems: one each on two cores.
    let solved = crate::parallel::tasks(2, crate::parallel::threads().unwrap_or(1), |i| {
        let mut space = space.0[i].lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        solve_axis(&samples, i, t0, h, m, slacks, travel[i], s, &mut space)
    });
    for (c, x) in control.iter_mut().zip(solved) {
        let x = x.ok_or(NoFlow::Unsolved)?;
        for (total, &sigma) in short.iter_mut().zip(&x[m..]) {
            *total = total.max(sigma);
        }
        *c = x[..m].to_vec();
    }
    if short.iter().all(|&x| x <= SLACK_TOLERANCE) {
        let mut flow = Flow { moves_from: 0.0, t0, h, control };
        flow.moves_from = flow.first_motion();
        return Ok(flow);
    }
    let mut behind = Behind { into: Vec::new(), start: 0.0, end: 0.0 };
    let used: Vec<usize> = (0..slacks / 2).filter(|&g| tcp.pieces.iter().any(|p| p.group == g)).collect();
    for (k, &g) in used.iter().enumerate() {
        let (into, out) = (short[2 * g], short[2 * g + 1]);
        if into > SLACK_TOLERANCE {
            if k == 0 {
                behind.start = into;
            } else {
                behind.into.push((g, g, into));
            }
        }
        if out > SLACK_TOLERANCE {
            match used.get(k + 1) {
                Some(&next) => behind.into.push((next, g, out)),
                None => behind.end = out,
            }
        }
    }
    behind.into.sort_by(|a, b| a.0.cmp(&b.0).then(b.2.total_cmp(&a.2)));
    behind.into.dedup_by_key(|x| x.0);
    Err(NoFlow::Behind(behind))
}

fn groups(tcp: &TcpPath) -> usize {
    tcp.pieces.iter().map(|p| p.group + 1).max().unwrap_or(1)
}

/// A time where the stage must be within `[lo, hi]` on each axis, and
/// which shortfall a slack here counts towards (the first or second half of
/// a field's time).
struct Sample {
    t: f64,
    lo: [f64; 2],
    hi: [f64; 2],
    slack: usize,
}

/// The corridor at the ends of the split's windows (no longer than `h`),
/// narrowed by how far the spline may bow between them and by `EDGE`.
fn samples(tcp: &TcpPath, pads: (f64, f64), h: f64, half: f64, a: f64) -> Vec<Sample> {
    let duration = tcp.duration();
    let groups = groups(tcp);
    let mut span = vec![(f64::INFINITY, f64::NEG_INFINITY); groups];
    for p in &tcp.pieces {
        let s = &mut span[p.group];
        *s = (s.0.min(p.start), s.1.max(p.end_time()));
    }
    let first = tcp.pieces.first().map_or(0, |p| p.group);
    let last = tcp.pieces.last().map_or(0, |p| p.group);
    let slack_at = |t: f64| {
        if t <= 0.0 {
            return 2 * first;
        }
        if t >= duration {
            return 2 * last + 1;
        }
        let g = tcp.pieces[tcp.index_at(t)].group;
        2 * g + usize::from(t >= 0.5 * (span[g].0 + span[g].1))
    };
    let mut wins = windows(tcp, h);
    // The pads, the TCP still at its ends: windows of `h` too (the bow
    // allowed between samples grows with the square of the window).
    for (t, p, length) in [(-pads.0, tcp.position(0.0), pads.0), (duration, tcp.position(duration), pads.1)] {
        let parts = (length / h).ceil() as usize;
        for k in 0..parts {
            let (t0, t1) = (t + length * k as f64 / parts as f64, t + length * (k + 1) as f64 / parts as f64);
            wins.push(Window { t0, t1, lo: [p.x, p.y], hi: [p.x, p.y] });
        }
    }
    let mut out: Vec<Sample> = Vec::with_capacity(2 * wins.len());
    for w in &wins {
        let bow = a * (w.t1 - w.t0).powi(2) / 8.0 + EDGE;
        let lo = [w.hi[0] - half + bow, w.hi[1] - half + bow];
        let hi = [w.lo[0] + half - bow, w.lo[1] + half - bow];
        for t in [w.t0, w.t1] {
            out.push(Sample { t, lo, hi, slack: slack_at(t.clamp(0.0, duration)) });
        }
    }
    out.sort_by(|x, y| x.t.total_cmp(&y.t));
    // One sample per time: the windows meeting there both hold.
    let mut merged: Vec<Sample> = Vec::with_capacity(out.len() / 2 + 1);
    for s in out {
        match merged.last_mut() {
            Some(m) if (m.t - s.t).abs() < 1e-12 => {
                for i in 0..2 {
                    m.lo[i] = m.lo[i].max(s.lo[i]);
                    m.hi[i] = m.hi[i].min(s.hi[i]);
                }
            }
            _ => merged.push(s),
        }
    }
    merged
}

/// One axis as a convex problem: the control points (and the slacks that
/// widen the corridor, as little as possible) such that the control points'
/// first, second and third differences keep `V·h`, `A·h²`, `J·h³` (then the
/// spline keeps V, A and J), inside the travel, and the spline inside the
/// corridor at every sample. Returns control points then, per slack, the
/// most its samples needed.
#[allow(clippy::too_many_arguments)]
fn solve_axis(samples: &[Sample], i: usize, t0: f64, h: f64, m: usize, slacks: usize, travel: f64, s: &SplitSettings, space: &mut super::qp::Workspace) -> Option<Vec<f64>> {
    use super::qp::{Banded, Row};
    // The unknowns: control points 2..m-3; the first and last three equal
    // (at rest at both ends), so control point k is unknown clamp(k − 2).
    let n = m.checked_sub(4).filter(|&n| n > 0)?;
    let unknown = |k: usize| k.saturating_sub(2).min(n - 1);
    let terms = |k0: usize, weights: &[f64]| -> Vec<(usize, f64)> { weights.iter().enumerate().map(|(j, &w)| (unknown(k0 + j), w)).collect() };
    let mut rows = Vec::new();
    let lim = s.burst;
    // Each difference row scaled to a bound of 1.
    let diffs: [(&[f64], f64); 3] = [(&[-1.0, 1.0], lim.velocity * h), (&[1.0, -2.0, 1.0], lim.acceleration * h * h), (&[-1.0, 3.0, -3.0, 1.0], lim.jerk * h * h * h)];
    for (weights, bound) in diffs {
        let scaled: Vec<f64> = weights.iter().map(|w| w / bound).collect();
        for k in 0..=m - weights.len() {
            rows.extend(Row::between(&terms(k, &scaled), Some(-1.0), Some(1.0), false, n));
        }
    }
    let his: Vec<(f64, f64, usize)> = samples.iter().map(|sm| (sm.t, sm.hi[i], sm.slack)).collect();
    let los: Vec<(f64, f64, usize)> = samples.iter().map(|sm| (sm.t, -sm.lo[i], sm.slack)).collect();
    let (keep_hi, keep_lo) = (binding(&his, lim.velocity, slacks), binding(&los, lim.velocity, slacks));
    // Which slack each soft row widens. The corridor rows in half fields
    // (their slacks priced to match): rows of similar size, fewer steps.
    let unit = s.half.max(1.0);
    let mut widens: Vec<Option<usize>> = vec![None; rows.len()];
    for (k, sm) in samples.iter().enumerate() {
        let basis: Vec<(usize, f64)> = basis(m, h, sm.t - t0).into_iter().map(|(c, w)| (unknown(c), w / unit)).collect();
        let (lo, hi) = (keep_lo[k].then_some(sm.lo[i] / unit), keep_hi[k].then_some(sm.hi[i] / unit));
        rows.extend(Row::between(&basis, lo, hi, true, n));
        widens.resize(rows.len(), Some(sm.slack));
    }
    // Smoothing: the second differences' squares.
    let w = SMOOTH / (lim.acceleration * h * h).powi(2);
    let mut p = Banded::zeros(n);
    for k in 0..m - 2 {
        if let Some(r) = Row::new(&terms(k, &[1.0, -2.0, 1.0]), 0.0, false, n) {
            p.add_row(&r, 2.0 * w);
        }
    }
    // From the stage standing still mid-corridor (every hard row holds).
    let mid = samples.iter().map(|sm| 0.5 * (sm.lo[i] + sm.hi[i])).sum::<f64>() / samples.len().max(1) as f64;
    let start = mid.clamp(0.25 * travel, 0.75 * travel);
    let mut solved = super::qp::solve(&p, &rows, unit, vec![start; n], space)?;
    // The travel rarely binds (the corridor lies within it): its rows only
    // where the stage left it without them.
    if solved.x.iter().any(|&x| !(0.0..=travel).contains(&x)) {
        let corridor = rows.len();
        for k in 0..n {
            rows.extend(Row::between(&[(k, 1.0)], Some(0.0), Some(travel), false, n));
        }
        widens.resize(rows.len(), None);
        solved = super::qp::solve(&p, &rows, unit, vec![start; n], space)?;
        solved.slack.truncate(corridor);
    }
    let mut out: Vec<f64> = (0..m).map(|k| solved.x[unknown(k)]).collect();
    let mut short = vec![0.0f64; slacks];
    for (r, sigma) in solved.slack.iter().enumerate() {
        if let Some(g) = widens[r] {
            short[g] = short[g].max(sigma[0].max(sigma[1]) * unit);
        }
    }
    out.extend(short);
    Some(out)
}

/// Which bounds `x(t) ≤ bound` (samples `(t, bound, slack)`, sorted by
/// time) can bind: one is implied by another of the same slack where
/// `bound' + V·|t − t'| ≤ bound`, since the spline moves at most `V`. Fewer
/// rows, the same solution.
fn binding(bounds: &[(f64, f64, usize)], v: f64, slacks: usize) -> Vec<bool> {
    let mut keep = vec![true; bounds.len()];
    // The tightest bound implied from earlier (then later) samples, per slack.
    let mut best = vec![f64::INFINITY; slacks];
    for (k, &(t, bound, slack)) in bounds.iter().enumerate() {
        if best[slack] + v * t <= bound - TIGHTER {
            keep[k] = false;
        }
        best[slack] = best[slack].min(bound - v * t);
    }
    best.fill(f64::INFINITY);
    for (k, &(t, bound, slack)) in bounds.iter().enumerate().rev() {
        if best[slack] - v * t <= bound - TIGHTER {
            keep[k] = false;
        }
        best[slack] = best[slack].min(bound + v * t);
    }
    keep
}

/// A bound is dropped only where another implies it by this much (mm): the
/// solver's tolerance on the speed rows.
const TIGHTER: f64 = 1.0e-6;

/// The spline's weights on the control points at time `t` (from control
/// point 0), indices clamped to the `m` points as `spline` does.
fn basis(m: usize, h: f64, t: f64) -> Vec<(usize, f64)> {
    let u = (t / h).clamp(0.0, (m - 1) as f64);
    let k = (u.floor() as usize).min(m - 1) as isize;
    let f = u - k as f64;
    let g = 1.0 - f;
    let w = [g * g * g, 3.0 * f * f * f - 6.0 * f * f + 4.0, -3.0 * f * f * f + 3.0 * f * f + 3.0 * f + 1.0, f * f * f];
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(4);
    for (j, wj) in w.iter().enumerate() {
        let c = (k - 1 + j as isize).clamp(0, m as isize - 1) as usize;
        match out.iter_mut().find(|x| x.0 == c) {
            Some(x) => x.1 += wj / 6.0,
            None => out.push((c, wj / 6.0)),
        }
    }
    out
}

/// The spline of control points `c` (step `h`, from time 0) at `t`.
fn spline(c: &[f64], h: f64, t: f64) -> f64 {
    let n = c.len();
    if n == 0 {
        return 0.0;
    }
    let u = (t / h).clamp(0.0, (n - 1) as f64);
    let k = (u.floor() as usize).min(n - 1);
    let f = u - k as f64;
    let at = |j: isize| c[j.clamp(0, n as isize - 1) as usize];
    let k = k as isize;
    let g = 1.0 - f;
    (g * g * g * at(k - 1) + (3.0 * f * f * f - 6.0 * f * f + 4.0) * at(k) + (-3.0 * f * f * f + 3.0 * f * f + 3.0 * f + 1.0) * at(k + 1) + f * f * f * at(k + 2)) / 6.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Limits;

    /// The field corridor of a TCP that marks moving at `drift` mm/s until
    /// `switch`, then `to` mm further along the axis (both axes alike).
    fn corridor(drift: f64, switch: f64, to: f64, end: f64, half: f64) -> Vec<Sample> {
        (0..=(end / 1e-3) as usize)
            .map(|k| {
                let t = k as f64 * 1e-3;
                let (tcp, slack) = if t < switch { (100.0 + drift * t, 1) } else { (100.0 + drift * t + to, 2) };
                Sample { t, lo: [tcp - half; 2], hi: [tcp + half; 2], slack }
            })
            .collect()
    }

    fn settings() -> SplitSettings {
        SplitSettings { half: 32.0, travel: (300.0, 300.0), burst: Limits { velocity: 400.0, acceleration: 4000.0, jerk: 2.0e5 } }
    }

    #[test]
    fn the_stage_keeps_its_limits_and_corridor_or_names_the_shortfall() {
        let s = settings();
        let (h, end) = (5e-3, 1.0);
        let steps = (end / h) as usize;
        let m = steps + 3;
        let t0 = -h;
        // The TCP drifting 60 mm/s, fields 50 mm apart (they overlap): the
        // stage can follow, and must move by at least 46 mm.
        let samples = corridor(60.0, 0.5, 50.0, end, s.half);
        let x = solve_axis(&samples, 0, t0, h, m, 4, s.travel.0, &s, &mut Default::default()).unwrap();
        let c = &x[..m];
        assert!(x[m..].iter().all(|&sigma| sigma <= SLACK_TOLERANCE), "feasible: no slack {:?}", &x[m..]);
        let diffs = |d: &[f64]| d.windows(2).map(|w| w[1] - w[0]).collect::<Vec<f64>>();
        let (d1, d2, d3) = (diffs(c), diffs(&diffs(c)), diffs(&diffs(&diffs(c))));
        let big = |d: &[f64]| d.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let tol = 1.0 + 1e-6;
        assert!(big(&d1) <= s.burst.velocity * h * tol, "V {}", big(&d1) / h);
        assert!(big(&d2) <= s.burst.acceleration * h * h * tol, "A {}", big(&d2) / (h * h));
        assert!(big(&d3) <= s.burst.jerk * h * h * h * tol, "J {}", big(&d3) / (h * h * h));
        // It moves far, within the field of the TCP at every sample, from
        // rest to rest.
        assert!(spline(c, h, end - t0) - spline(c, h, 0.0 - t0) >= 46.0 - 1e-6);
        for sm in &samples {
            let p = spline(c, h, sm.t - t0);
            assert!(p >= sm.lo[0] - 1e-6 && p <= sm.hi[0] + 1e-6, "t={}: {p} outside {}..{}", sm.t, sm.lo[0], sm.hi[0]);
        }
        assert!((c[0] - c[2]).abs() < 1e-6 && (c[m - 1] - c[m - 3]).abs() < 1e-6, "at rest at both ends");
        // 200 mm at once: the fields are 136 mm apart, which the slacks on
        // both sides of the change bridge, and no more.
        let samples = corridor(0.0, 0.5, 200.0, end, s.half);
        let x = solve_axis(&samples, 0, t0, h, m, 4, s.travel.0, &s, &mut Default::default()).unwrap();
        let short = x[m + 1] + x[m + 2];
        // (less what the stage moves between two samples, at most V·1 ms)
        assert!((136.0 - 0.4 - 1e-6..=136.0 + 1e-6).contains(&short), "{:?}", &x[m..]);
        assert!(x[m] <= SLACK_TOLERANCE && x[m + 3] <= SLACK_TOLERANCE, "nowhere else: {:?}", &x[m..]);
    }

    #[test]
    fn a_bound_is_dropped_only_where_a_tighter_one_nearby_implies_it() {
        // V = 100 mm/s: within 1 ms the spline moves at most 0.1 mm.
        let bounds = [(0.0, 5.0, 0), (0.001, 5.2, 0), (0.001, 1.0, 1), (0.002, 5.15, 0), (0.003, 4.95, 0)];
        let keep = binding(&bounds, 100.0, 2);
        // 5.2 ≥ 5 + 0.1; 5.15 ≥ 4.95 + 0.1; the other slack's bound stands alone.
        assert_eq!(keep, [true, false, true, false, true]);
    }

    #[test]
    fn the_basis_sums_to_one_and_matches_the_spline() {
        let c: Vec<f64> = (0..12).map(|k| (k as f64 * 0.7).sin() * 10.0).collect();
        for k in 0..=110 {
            let t = k as f64 * 0.1 * 2e-3;
            let b = basis(c.len(), 2e-3, t);
            assert!((b.iter().map(|x| x.1).sum::<f64>() - 1.0).abs() < 1e-12);
            let v: f64 = b.iter().map(|&(j, w)| w * c[j]).sum();
            assert!((v - spline(&c, 2e-3, t)).abs() < 1e-9, "t={t}");
        }
    }
}
