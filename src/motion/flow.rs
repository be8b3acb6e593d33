//! On the fly: the stage planned over the whole job, flowing through the scan
//! fields at speed instead of resting in each.
//!
//! Each stage axis is planned alone on a time grid of step `h` over the TCP's
//! plan. At each grid time the TCP's box over the neighbouring grid times,
//! widened by the usable half field, is the corridor the stage must be in.
//! Three steps, repeated:
//! 1. A string: grid positions inside the corridor (less a margin) that move
//!    at most `V·h` a step, found by a forward pass (the reachable
//!    intervals), a backward pass (those from which the end is reachable)
//!    and a walk towards each interval's middle.
//! 2. Two centred moving averages of the string, `n2` and then `n3` steps
//!    long, are the control points of a uniform cubic B-spline: the stage.
//!    A B-spline's derivatives are B-splines of the control points'
//!    differences, so they stay within those differences over `h`, `h²`,
//!    `h³`; the averages bound them by `V`, `2V/(n2·h)` and
//!    `4V/(n2·n3·h²)`, and `n2`, `n3` are chosen long enough for `A` and `J`.
//!    The limits therefore hold by construction, whatever the corridor.
//! 3. The spline is checked against the TCP on the split's fine windows; where
//!    it leaves the field (the averages cut corners) the margin of step 1 is
//!    raised around that time by the excess, and all is planned again.
//!
//! Where no string exists (the stage cannot reach the next field in time) or
//! the repairs do not converge, the plan names the times (the forward pass
//! goes on from the corridor's edge nearest the reach, so that one plan
//! names every place the stage falls behind): the caller slows the TCP at
//! the field changes there, and plans again. The string is held
//! still over the first and last `n2 + n3` steps, so that the stage starts and
//! ends at rest with the TCP (no motion before the job's clock starts).

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

    pub fn end_time(&self) -> f64 {
        self.t0 + self.h * self.control[0].len().saturating_sub(1) as f64
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

/// Grid step: a millisecond, longer on very long jobs (at most this many steps).
const STEP: f64 = 1.0e-3;
const MOST_STEPS: f64 = 2.0e6;
/// Rounds of raising the margin before the plan gives up.
const REPAIRS: usize = 40;
/// Added to each raise of the margin (mm), so that repairs end.
const REPAIR_SLACK: f64 = 0.02;

/// Plans the stage for `tcp`, or names the times where it cannot keep up.
pub fn plan(tcp: &TcpPath, s: &SplitSettings) -> Result<Flow, Vec<f64>> {
    let duration = tcp.duration();
    let steps = ((duration / STEP).ceil() as usize).clamp(1, MOST_STEPS as usize);
    let h = duration.max(1e-9) / steps as f64;
    let n = steps + 1;
    let (v, a, j) = (s.burst.velocity, s.burst.acceleration, s.burst.jerk);
    let odd = |x: f64| {
        let k = x.ceil().max(1.0) as usize;
        k | 1
    };
    let n2 = odd(2.0 * v / (a * h));
    let n3 = odd(4.0 * v / (n2 as f64 * j * h * h));
    // Before and after the TCP's plan it stands at its first and last point,
    // where the stage may start early and settle late.
    let pad = n2 + n3;
    let total = n + 2 * pad;
    let time = |k: usize| (k as f64 - pad as f64) * h;
    let tcp_at: Vec<Point> = (0..total).map(|k| tcp.position(time(k).clamp(0.0, duration))).collect();
    let mut wins = windows(tcp, super::stage::window_length(tcp));
    for (k, p) in tcp_at.iter().enumerate() {
        if k < pad || k >= pad + n {
            let t = time(k);
            wins.push(Window { t0: t, t1: t + h, lo: [p.x, p.y], hi: [p.x, p.y] });
        }
    }
    let travel = [s.travel.0, s.travel.1];
    let mut control: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut behind = Vec::new();
    for i in 0..2 {
        // The corridor at each grid time.
        let mut lo = vec![0.0; total];
        let mut hi = vec![0.0; total];
        for k in 0..total {
            let (mut l, mut u) = (f64::NEG_INFINITY, f64::INFINITY);
            for p in &tcp_at[k.saturating_sub(1)..=(k + 1).min(total - 1)] {
                l = l.max(p[i] - s.half);
                u = u.min(p[i] + s.half);
            }
            lo[k] = l.max(0.0);
            hi[k] = u.min(travel[i]);
        }
        match plan_axis(&lo, &hi, &wins, i, pad, -(pad as f64) * h, h, v * h, n2, n3, s.half, a) {
            Ok(c) => control[i] = c,
            Err(times) => behind.extend(times),
        }
    }
    if behind.is_empty() {
        // Ends where both axes have come to rest.
        let last = control.iter().map(|c| c.iter().rposition(|&x| (x - c[c.len() - 1]).abs() > 1e-12).map_or(0, |k| k + 3)).max().unwrap_or(0);
        for c in &mut control {
            c.truncate((last + 1).min(c.len()));
        }
        let mut flow = Flow { moves_from: 0.0, t0: -(pad as f64) * h, h, control };
        flow.moves_from = flow.first_motion();
        Ok(flow)
    } else {
        behind.sort_by(f64::total_cmp);
        Err(behind)
    }
}

/// One axis: the control points, or the times where the stage falls behind.
#[allow(clippy::too_many_arguments)]
fn plan_axis(lo: &[f64], hi: &[f64], wins: &[Window], i: usize, pad: usize, t0: f64, h: f64, step: f64, n2: usize, n3: usize, half: f64, a: f64) -> Result<Vec<f64>, Vec<f64>> {
    let n = lo.len();
    let mut margin_lo = vec![0.0; n];
    let mut margin_hi = vec![0.0; n];
    let reach = n2 / 2 + n3 / 2 + 2;
    for _ in 0..REPAIRS {
        let l: Vec<f64> = (0..n).map(|k| lo[k] + margin_lo[k]).collect();
        let u: Vec<f64> = (0..n).map(|k| hi[k] - margin_hi[k]).collect();
        let mut string = string(&l, &u, step).map_err(|short| short.iter().map(|&k| t0 + k as f64 * h).collect::<Vec<_>>())?;
        // Still before and after the TCP (the pads), so that the stage starts
        // and settles as late and as early as the averages allow.
        let (first, last) = (string[pad], string[n - 1 - pad]);
        string[..pad].fill(first);
        string[n - pad..].fill(last);
        let c = average(&average(&string, n2), n3);
        // Spline on each window: its ends, and how far a curve with this
        // acceleration bows between them.
        let mut raise_lo = vec![0.0f64; n];
        let mut raise_hi = vec![0.0f64; n];
        let mut any = false;
        for w in wins {
            let (s0, s1) = (spline(&c, h, w.t0 - t0), spline(&c, h, w.t1 - t0));
            let bow = a * (w.t1 - w.t0).powi(2) / 8.0 + 1e-9;
            let (smin, smax) = (s0.min(s1) - bow, s0.max(s1) + bow);
            let low = w.hi[i] - half - smin;
            let high = smax - (w.lo[i] + half);
            if low <= 0.0 && high <= 0.0 {
                continue;
            }
            any = true;
            let k = ((0.5 * (w.t0 + w.t1) - t0) / h).round().max(0.0) as usize;
            for q in k.saturating_sub(reach)..=(k + reach).min(n - 1) {
                if low > 0.0 {
                    raise_lo[q] = raise_lo[q].max(low + REPAIR_SLACK);
                }
                if high > 0.0 {
                    raise_hi[q] = raise_hi[q].max(high + REPAIR_SLACK);
                }
            }
        }
        if !any {
            return Ok(c);
        }
        for k in 0..n {
            margin_lo[k] += raise_lo[k];
            margin_hi[k] += raise_hi[k];
        }
    }
    // Still outside after every repair: where the margin grew most.
    let worst = (0..n).max_by(|&x, &y| (margin_lo[x] + margin_hi[x]).total_cmp(&(margin_lo[y] + margin_hi[y]))).unwrap_or(0);
    Err(vec![t0 + worst as f64 * h])
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

/// Positions within `[lo, hi]` moving at most `step` from one to the next,
/// each as near its reachable interval's middle as the step allows. `Err`:
/// the grid times no string reaches (the pass goes on from the corridor's
/// edge nearest the reach).
fn string(lo: &[f64], hi: &[f64], step: f64) -> Result<Vec<f64>, Vec<usize>> {
    let n = lo.len();
    let mut f = Vec::with_capacity(n);
    let mut prev: Option<(f64, f64)> = None;
    let mut short = Vec::new();
    for k in 0..n {
        let (mut l, mut u) = (lo[k], hi[k]);
        if let Some((pl, pu)) = prev {
            if lo[k] > pu + step + 1e-12 {
                short.push(k);
                u = lo[k];
            } else if hi[k] < pl - step - 1e-12 {
                short.push(k);
                l = hi[k];
            } else {
                l = l.max(pl - step);
                u = u.min(pu + step);
            }
        }
        let u = u.max(l);
        f.push((l, u));
        prev = Some((l, u));
    }
    if !short.is_empty() {
        return Err(short);
    }
    for k in (0..n.saturating_sub(1)).rev() {
        let (nl, nu) = f[k + 1];
        let (l, u) = f[k];
        let (l2, u2) = (l.max(nl - step), u.min(nu + step));
        f[k] = (l2, u2.max(l2));
    }
    let mut out = Vec::with_capacity(n);
    let mut at = 0.5 * (f[0].0 + f[0].1);
    for (k, &(l, u)) in f.iter().enumerate() {
        let (l, u) = if k == 0 { (l, u) } else { (l.max(at - step), u.min(at + step)) };
        at = (0.5 * (f[k].0 + f[k].1)).clamp(l, u.max(l));
        out.push(at);
    }
    Ok(out)
}

/// Centred moving average over `w` (odd) values; beyond the ends the end values.
fn average(x: &[f64], w: usize) -> Vec<f64> {
    let n = x.len();
    let m = (w / 2) as isize;
    let at = |j: isize| x[j.clamp(0, n as isize - 1) as usize];
    let mut out = Vec::with_capacity(n);
    let mut sum: f64 = (-m..=m).map(at).sum();
    for k in 0..n as isize {
        out.push(sum / w as f64);
        sum += at(k + m + 1) - at(k - m);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averaged_strings_keep_the_differences_the_limits_need() {
        // A string zig-zagging at full step: its averages' differences stay
        // within the bounds that make the spline keep V, A and J.
        let (h, v, a, j) = (1e-3, 400.0, 4000.0, 2.0e5);
        let step = v * h;
        // A triangle wave (300 steps up, 300 down) with still ends, as the
        // flow's strings have.
        let tri = |k: usize| if k % 600 < 300 { (k % 600) as f64 } else { (600 - k % 600) as f64 };
        let x: Vec<f64> = (0..2400).map(|k| if (300..2100).contains(&k) { step * tri(k - 300) } else { 0.0 }).collect();
        let n2 = ((2.0 * v / (a * h)).ceil() as usize) | 1;
        let n3 = ((4.0 * v / (n2 as f64 * j * h * h)).ceil() as usize) | 1;
        let c = average(&average(&x, n2), n3);
        let d1: Vec<f64> = c.windows(2).map(|w| w[1] - w[0]).collect();
        let d2: Vec<f64> = d1.windows(2).map(|w| w[1] - w[0]).collect();
        let d3: Vec<f64> = d2.windows(2).map(|w| w[1] - w[0]).collect();
        let big = |d: &[f64]| d.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(big(&d1) / h <= v * (1.0 + 1e-9), "{}", big(&d1) / h);
        assert!(big(&d2) / (h * h) <= a * (1.0 + 1e-9), "{}", big(&d2) / (h * h));
        assert!(big(&d3) / (h * h * h) <= j * (1.0 + 1e-9), "{}", big(&d3) / (h * h * h));
        assert!(big(&d2) / (h * h) > 0.3 * a, "the test zig-zags hard enough to matter");
    }

    #[test]
    fn a_string_keeps_its_corridor_and_step_or_names_where_it_cannot() {
        let lo = [0.0, 0.0, 2.5, 5.0, 5.0];
        let hi = [1.0, 1.0, 9.0, 9.0, 9.0];
        let s = string(&lo, &hi, 2.0).unwrap();
        for k in 0..5 {
            assert!(s[k] >= lo[k] - 1e-12 && s[k] <= hi[k] + 1e-12);
            if k > 0 {
                assert!((s[k] - s[k - 1]).abs() <= 2.0 + 1e-12);
            }
        }
        // Every place it falls behind, in one pass: short at 2, and from
        // there (2.5) at 3; from there (5) the end is reachable.
        assert_eq!(string(&lo, &hi, 1.0), Err(vec![2, 3]));
        // The same going down.
        let far = [10.0, 10.0, 5.0, 0.0, 0.0];
        assert_eq!(string(&far, &far, 1.0), Err(vec![2, 3]));
        assert_eq!(string(&far, &far, 5.0).map(|s| s.len()), Ok(5));
    }
}
