//! A convex QP whose rows each touch at most `BAND` consecutive unknowns,
//! solved by a primal-dual interior point method (Mehrotra's predictor and
//! corrector). Each step's normal equations are banded (half bandwidth
//! `BAND - 1`), so a step costs time linear in the problem: the flow's
//! problems (thousands of unknowns, tens of thousands of rows) solve in a few
//! milliseconds, where a general sparse solver factorises a much larger
//! system each step.
//!
//! minimise ½ xᵀPx + w·Σσ  subject to, per row and each of its sides,
//! aᵣ·x ≤ bᵣ / aᵣ·x ≥ bᵣ (hard) or the same widened by its own slack
//! σ ≥ 0 (soft, priced `w`). A row bounded on both sides is one row: its
//! vector enters the normal equations and the residuals once.
//! Plain arithmetic in a fixed order: the same result on any machine.

/// Consecutive unknowns a row may touch.
pub const BAND: usize = 4;

/// `a·x[first..first + BAND]` bounded above (`sides[0]`: `≤ b`) and/or
/// below (`sides[1]`, kept as `−a·x ≤ b`).
#[derive(Debug, Clone)]
pub struct Row {
    first: usize,
    a: [f64; BAND],
    sides: [Option<Side>; 2],
}

/// One bound of a row (in the `≤` form), hard or widened by a slack.
#[derive(Debug, Clone, Copy)]
struct Side {
    b: f64,
    soft: bool,
}

/// The sign a side's row vector carries (`≤` then `≥`).
const SIGN: [f64; 2] = [1.0, -1.0];

impl Row {
    /// The row `a·x ≤ b` from its terms `(unknown, weight)`, which must lie
    /// within `BAND` consecutive unknowns of `n`; `None` when every weight is
    /// zero (the row says nothing).
    pub fn new(terms: &[(usize, f64)], b: f64, soft: bool, n: usize) -> Option<Row> {
        Row::between(terms, None, Some(b), soft, n)
    }

    /// The row `lo ≤ a·x ≤ hi` (either bound may be absent, not both).
    pub fn between(terms: &[(usize, f64)], lo: Option<f64>, hi: Option<f64>, soft: bool, n: usize) -> Option<Row> {
        let lo_index = terms.iter().filter(|t| t.1 != 0.0).map(|t| t.0).min()?;
        let first = lo_index.min(n.saturating_sub(BAND));
        let mut a = [0.0; BAND];
        for &(j, w) in terms {
            a[j - first] += w;
        }
        let sides = [hi.map(|b| Side { b, soft }), lo.map(|b| Side { b: -b, soft })];
        (a.iter().any(|&w| w != 0.0) && sides.iter().any(Option::is_some)).then_some(Row { first, a, sides })
    }

    fn dot(&self, x: &[f64]) -> f64 {
        self.a.iter().zip(&x[self.first..]).map(|(a, x)| a * x).sum()
    }

    fn add_to(&self, y: &mut [f64], k: f64) {
        for (y, a) in y[self.first..].iter_mut().zip(&self.a) {
            *y += k * a;
        }
    }
}

/// A symmetric banded matrix: `band[i][k]` is entry `(i, i + k + 1 - BAND)`
/// (the lower band, the diagonal last).
#[derive(Debug, Clone)]
pub struct Banded {
    band: Vec<[f64; BAND]>,
}

impl Banded {
    pub fn zeros(n: usize) -> Banded {
        Banded { band: vec![[0.0; BAND]; n] }
    }

    /// Adds `k` to entry `(i, j)` (and `(j, i)`), `|i − j| < BAND`.
    pub fn add(&mut self, i: usize, j: usize, k: f64) {
        let (hi, lo) = (i.max(j), i.min(j));
        self.band[hi][BAND - 1 - (hi - lo)] += k;
    }

    fn mul(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        for (i, row) in self.band.iter().enumerate() {
            for (k, &v) in row.iter().enumerate() {
                let Some(j) = (i + k + 1).checked_sub(BAND) else { continue };
                y[i] += v * x[j];
                if j != i {
                    y[j] += v * x[i];
                }
            }
        }
        y
    }

    pub fn add_row(&mut self, r: &Row, k: f64) {
        for p in 0..BAND {
            let kp = k * r.a[p];
            if kp == 0.0 {
                continue;
            }
            let row = &mut self.band[r.first + p];
            for q in 0..=p {
                row[BAND - 1 - (p - q)] += kp * r.a[q];
            }
        }
    }

    /// Cholesky factor (`LLᵀ`, `L` in the same banded layout but with
    /// `1/Lᵢᵢ` on the diagonal: the substitutions multiply), each pivot kept
    /// at least `floor` times its diagonal entry (the matrix is positive
    /// semi-definite at worst; rounding may leave a pivot near zero).
    fn cholesky(&mut self, floor: f64) {
        let n = self.band.len();
        for i in 0..n {
            for k in 0..BAND {
                let Some(j) = (i + k + 1).checked_sub(BAND) else { continue };
                let entry = self.band[i][k];
                let mut sum = entry;
                // Σ L[i][c]·L[j][c] over the columns c < j both rows reach.
                for c in i.saturating_sub(BAND - 1)..j {
                    sum -= self.band[i][c + BAND - 1 - i] * self.band[j][c + BAND - 1 - j];
                }
                self.band[i][k] = if j == i { 1.0 / sum.max(floor * entry).max(f64::MIN_POSITIVE).sqrt() } else { sum * self.band[j][BAND - 1] };
            }
        }
    }

    /// Solves `LLᵀx = y` in place with `self` the factor. (Each unknown
    /// depends on the three before (after) it, kept in registers: the
    /// substitutions are a chain of dependent steps.)
    fn solve(&self, y: &mut [f64]) {
        const { assert!(BAND == 4) };
        let (mut y1, mut y2, mut y3) = (0.0, 0.0, 0.0);
        for (v, l) in y.iter_mut().zip(&self.band) {
            *v = (*v - l[0] * y3 - l[1] * y2 - l[2] * y1) * l[3];
            (y3, y2, y1) = (y2, y1, *v);
        }
        // Lᵀ: column c of L below the diagonal is L[c+1][2], L[c+2][1], L[c+3][0].
        let entry = |i: usize, k: usize| self.band.get(i).map_or(0.0, |l| l[k]);
        let (mut x1, mut x2, mut x3) = (0.0, 0.0, 0.0);
        for c in (0..y.len()).rev() {
            y[c] = (y[c] - entry(c + 3, 0) * x3 - entry(c + 2, 1) * x2 - entry(c + 1, 2) * x1) * self.band[c][3];
            (x3, x2, x1) = (x2, x1, y[c]);
        }
    }
}

/// The solution: the unknowns, and per row the slack of each side (`≤`
/// then `≥`; 0 for hard or absent sides).
#[derive(Debug, Clone)]
pub struct Solution {
    pub x: Vec<f64>,
    pub slack: Vec<[f64; 2]>,
}

/// Most steps; a problem not solved by then is reported unsolved.
const MOST_STEPS: usize = 80;
/// Converged: the rows' residual, the optimality residuals and the mean
/// complementarity below these (the rows hold to far below a micrometre; a
/// slack that should be 0 comes out about `GAP / w`: for the flow ~1e-5 mm,
/// far below its shortfall tolerance; 1e-6 gave the same plans, ~5 % slower).
const PRIMAL: f64 = 1.0e-9;
const DUAL: f64 = 1.0e-5;
const GAP: f64 = 1.0e-5;
/// Where the normal equations get too ill-conditioned to step on, a point
/// whose rows hold and whose mean complementarity is below this is taken.
const GAP_STALLED: f64 = 1.0e-5;

/// Per side of a row (or its step): the side's slack `s` (b − a·x [+ σ]),
/// dual `lam`, and for a soft side `sigma` and the dual `lam_n` of σ ≥ 0
/// (whose slack is σ itself). Zero for hard parts and absent sides.
#[derive(Debug, Clone, Copy, Default)]
struct Var {
    s: f64,
    lam: f64,
    sigma: f64,
    lam_n: f64,
}

/// The iterate: the unknowns and, per row, its sides.
struct Iterate {
    x: Vec<f64>,
    v: Vec<[Var; 2]>,
}

/// Per-side buffers a solve works in, kept from one solve to the next (a
/// flow's rounds solve problems of about the same size: fresh memory for
/// each was a sixth of their time, in page faults).
#[derive(Debug, Default)]
pub struct Workspace {
    v: Vec<[Var; 2]>,
    sides: Vec<[SideLinear; 2]>,
    affine: Vec<[Var; 2]>,
    step: Vec<[Var; 2]>,
}

/// `v` emptied and refilled with `len` zeros (its memory kept).
fn zeroed<T: Copy + Default>(mut v: Vec<T>, len: usize) -> Vec<T> {
    v.clear();
    v.resize(len, T::default());
    v
}

/// Minimises `½xᵀPx + w·Σσ` over the rows from `x0`, a point where every
/// hard side holds strictly (soft ones need not), in `space`. `None` when
/// the method does not converge.
pub fn solve(p: &Banded, rows: &[Row], w: f64, x0: Vec<f64>, space: &mut Workspace) -> Option<Solution> {
    let (n, m) = (x0.len(), rows.len());
    let mut it = Iterate { x: x0, v: zeroed(std::mem::take(&mut space.v), m) };
    let mut lin = Linear { k: p.clone(), factor: p.clone(), rx: Vec::new(), sides: zeroed(std::mem::take(&mut space.sides), m) };
    let mut affine = Step { dx: vec![0.0; n], dv: zeroed(std::mem::take(&mut space.affine), m) };
    let mut step = Step { dx: vec![0.0; n], dv: zeroed(std::mem::take(&mut space.step), m) };
    let solved = interior_point(p, rows, w, &mut it, &mut lin, &mut affine, &mut step);
    *space = Workspace { v: it.v, sides: lin.sides, affine: affine.dv, step: step.dv };
    solved
}

fn interior_point(p: &Banded, rows: &[Row], w: f64, it: &mut Iterate, lin: &mut Linear, affine: &mut Step, step: &mut Step) -> Option<Solution> {
    let mut count = 0.0;
    for (row, v) in rows.iter().zip(it.v.iter_mut()) {
        let ax = row.dot(&it.x);
        for (k, (side, v)) in row.sides.iter().zip(v.iter_mut()).enumerate() {
            let Some(side) = side else { continue };
            let room = side.b - SIGN[k] * ax;
            if side.soft {
                let sigma = (-room).max(0.0) + 1.0;
                *v = Var { s: room + sigma, lam: 0.5 * w, sigma, lam_n: 0.5 * w };
                count += 2.0;
            } else {
                if room <= 0.0 {
                    return None;
                }
                *v = Var { s: room, lam: 1.0, sigma: 0.0, lam_n: 0.0 };
                count += 1.0;
            }
        }
    }
    // Steps in a row that barely lowered the complementarity.
    let (mut stalled, mut last_mu) = (0, f64::INFINITY);
    for _ in 0..MOST_STEPS {
        let residuals = lin.linearise(p, rows, w, it);
        let mu = residuals.gap / count;
        let stalled_result = |it: &Iterate| (residuals.primal <= PRIMAL && mu <= GAP_STALLED).then(|| it.solution());
        if residuals.primal <= PRIMAL && residuals.dual <= DUAL && mu <= GAP {
            return Some(it.solution());
        }
        stalled = if mu > 0.9 * last_mu { stalled + 1 } else { 0 };
        last_mu = mu;
        if stalled >= 3 {
            return stalled_result(it);
        }
        lin.factor.band.clone_from(&lin.k.band);
        lin.factor.cholesky(1e-12);
        // Predictor: towards complementarity 0.
        let alpha = lin.step(rows, it, 0.0, None, affine);
        let mut gap_affine = 0.0;
        for ((row, v), dv) in rows.iter().zip(&it.v).zip(&affine.dv) {
            for ((side, v), dv) in row.sides.iter().zip(v).zip(dv) {
                let Some(side) = side else { continue };
                gap_affine += (v.s + alpha * dv.s) * (v.lam + alpha * dv.lam);
                if side.soft {
                    gap_affine += (v.sigma + alpha * dv.sigma) * (v.lam_n + alpha * dv.lam_n);
                }
            }
        }
        // Corrector: towards a centre chosen by how far the predictor got.
        let centre = (gap_affine / count / mu).powi(3) * mu;
        let alpha = lin.step(rows, it, centre, Some(affine), step);
        if !alpha.is_finite() {
            return stalled_result(it);
        }
        let alpha = (0.99 * alpha).min(1.0);
        for (v, dv) in it.x.iter_mut().zip(&step.dx) {
            *v += alpha * dv;
        }
        for (v, dv) in it.v.iter_mut().flatten().zip(step.dv.iter().flatten()) {
            v.s += alpha * dv.s;
            v.lam += alpha * dv.lam;
            v.sigma += alpha * dv.sigma;
            v.lam_n += alpha * dv.lam_n;
        }
    }
    None
}

impl Iterate {
    fn solution(&self) -> Solution {
        let slack = self.v.iter().map(|v| [v[0].sigma, v[1].sigma]).collect();
        Solution { x: self.x.clone(), slack }
    }
}

/// A Newton step: the unknowns' and the sides' parts.
struct Step {
    dx: Vec<f64>,
    dv: Vec<[Var; 2]>,
}


/// The largest residuals and the complementarity of an iterate.
struct Residuals {
    primal: f64,
    dual: f64,
    gap: f64,
}

/// Per side, what a step follows from: the primal residual, σ's dual
/// residual, `λ/s`, `λₙ/σ`, `1/λ`, `1/λₙ`, `1/(d + dₙ)`, and the step's
/// `e`, `eₙ` (kept from the right-hand side for the back substitution).
#[derive(Debug, Clone, Copy, Default)]
struct SideLinear {
    rp: f64,
    rs: f64,
    d: f64,
    d_n: f64,
    inv_lam: f64,
    inv_lam_n: f64,
    inv_sum: f64,
    e: f64,
    e_n: f64,
}

/// One iterate's linearisation: its residuals, the normal equations (and
/// their factor) and, per side, what the step's other parts follow from.
struct Linear {
    k: Banded,
    factor: Banded,
    /// Dual residual of the unknowns (`Px + Σ ±λ a`).
    rx: Vec<f64>,
    sides: Vec<[SideLinear; 2]>,
}

impl Linear {
    /// Residuals of `it` and the normal equations' matrix `P + Σ wⱼ aaᵀ`
    /// (a soft side's weight with its σ eliminated), in one pass over the
    /// rows.
    fn linearise(&mut self, p: &Banded, rows: &[Row], w: f64, it: &Iterate) -> Residuals {
        self.rx = p.mul(&it.x);
        self.k.band.clone_from(&p.band);
        let (mut primal, mut dual, mut gap) = (0.0f64, 0.0f64, 0.0);
        for ((row, v), l) in rows.iter().zip(&it.v).zip(self.sides.iter_mut()) {
            let ax = row.dot(&it.x);
            let (mut net_lam, mut weight) = (0.0, 0.0);
            for (k, ((side, v), l)) in row.sides.iter().zip(v).zip(l.iter_mut()).enumerate() {
                let Some(side) = side else { continue };
                l.rp = SIGN[k] * ax - v.sigma + v.s - side.b;
                primal = primal.max(l.rp.abs());
                net_lam += SIGN[k] * v.lam;
                gap += v.s * v.lam + v.sigma * v.lam_n;
                l.d = v.lam / v.s;
                l.inv_lam = 1.0 / v.lam;
                if side.soft {
                    l.rs = w - v.lam - v.lam_n;
                    dual = dual.max(l.rs.abs());
                    l.d_n = v.lam_n / v.sigma;
                    l.inv_lam_n = 1.0 / v.lam_n;
                    l.inv_sum = 1.0 / (l.d + l.d_n);
                    weight += l.d * l.d_n * l.inv_sum;
                } else {
                    weight += l.d;
                }
            }
            row.add_to(&mut self.rx, net_lam);
            self.k.add_row(row, weight);
        }
        dual = self.rx.iter().fold(dual, |a, b| a.max(b.abs()));
        Residuals { primal, dual, gap }
    }

    /// The step towards complementarity `centre` (with Mehrotra's second
    /// order term from `affine`, if given), into `out`; returns how far
    /// along it every slack and dual stays positive (≤ 1; not finite when
    /// the step is not).
    fn step(&mut self, rows: &[Row], it: &Iterate, centre: f64, affine: Option<&Step>, out: &mut Step) -> f64 {
        let rhs = &mut out.dx;
        for (v, r) in rhs.iter_mut().zip(&self.rx) {
            *v = -r;
        }
        let none = [Var::default(); 2];
        for (r, ((row, v), l)) in rows.iter().zip(&it.v).zip(self.sides.iter_mut()).enumerate() {
            let second = affine.map_or(&none, |a| &a.dv[r]);
            let mut net = 0.0;
            for (k, (((side, v), l), da)) in row.sides.iter().zip(v).zip(l.iter_mut()).zip(second).enumerate() {
                let Some(side) = side else { continue };
                let rc = v.s * v.lam + da.s * da.lam - centre;
                l.e = l.rp - rc * l.inv_lam;
                let k_side = if side.soft {
                    let rc_n = v.sigma * v.lam_n + da.sigma * da.lam_n - centre;
                    l.e_n = -rc_n * l.inv_lam_n;
                    l.d * (l.d_n * (l.e - l.e_n) + l.rs) * l.inv_sum
                } else {
                    l.d * l.e
                };
                net += SIGN[k] * k_side;
            }
            row.add_to(rhs, -net);
        }
        self.factor.solve(&mut out.dx);
        let mut alpha = 1.0f64;
        let mut finite = out.dx.iter().all(|v| v.is_finite());
        // (dividing only where the step would cross zero before `alpha`)
        let longest = |alpha: f64, v: f64, dv: f64| if v + alpha * dv < 0.0 && v > 0.0 { alpha.min(-v / dv) } else { alpha };
        for ((row, v), (l, o)) in rows.iter().zip(&it.v).zip(self.sides.iter().zip(out.dv.iter_mut())) {
            let adx = row.dot(&out.dx);
            for (k, (((side, v), l), o)) in row.sides.iter().zip(v).zip(l).zip(o.iter_mut()).enumerate() {
                let Some(side) = side else { continue };
                let adx = SIGN[k] * adx;
                if side.soft {
                    o.sigma = (l.d * (adx + l.e) + l.d_n * l.e_n - l.rs) * l.inv_sum;
                    o.lam_n = l.d_n * (l.e_n - o.sigma);
                    alpha = longest(longest(alpha, v.sigma, o.sigma), v.lam_n, o.lam_n);
                    finite &= o.sigma.is_finite() && o.lam_n.is_finite();
                }
                o.lam = l.d * (adx - o.sigma + l.e);
                // s·dλ + λ·ds = −rc, with rc = λ·(rp − e).
                o.s = -(l.rp - l.e) - v.s * o.lam * l.inv_lam;
                alpha = longest(longest(alpha, v.s, o.s), v.lam, o.lam);
                finite &= o.lam.is_finite() && o.s.is_finite();
            }
        }
        if finite {
            alpha
        } else {
            f64::NAN
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_banded_factor_solves_the_system() {
        let n = 9;
        let mut k = Banded::zeros(n);
        for i in 0..n {
            k.add(i, i, 4.0 + i as f64);
            for d in 1..BAND {
                if i + d < n {
                    k.add(i + d, i, 0.5 / d as f64);
                }
            }
        }
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.9).cos()).collect();
        let y = k.mul(&x);
        let mut back = y;
        let mut factor = k.clone();
        factor.cholesky(1e-14);
        factor.solve(&mut back);
        for (a, b) in x.iter().zip(&back) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
    }

    #[test]
    fn the_optimum_keeps_the_hard_rows_and_prices_the_soft_ones() {
        // Two unknowns near each other (|x1 − x0| ≤ 1), x0 ≤ 0 hard, x1 ≥ 3
        // soft: the best has x0 = 0, x1 = 1, σ = 2 (cost 2, no quadratic).
        let n = 2;
        let rows: Vec<Row> = [
            Row::between(&[(0, -1.0), (1, 1.0)], Some(-1.0), Some(1.0), false, n),
            Row::new(&[(0, 1.0)], 0.0, false, n),
            Row::between(&[(1, 1.0)], Some(3.0), None, true, n),
        ]
        .into_iter()
        .flatten()
        .collect();
        let mut space = Workspace::default();
        let solved = solve(&Banded::zeros(n), &rows, 1.0, vec![-1.0, -1.0], &mut space).expect("solved");
        assert!((solved.x[0] - 0.0).abs() < 1e-5 && (solved.x[1] - 1.0).abs() < 1e-5, "{:?}", solved.x);
        assert!((solved.slack[2][1] - 2.0).abs() < 1e-5 && solved.slack[2][0] == 0.0, "{:?}", solved.slack);
        // A hard row that does not hold at the start: refused.
        assert!(solve(&Banded::zeros(n), &rows, 1.0, vec![1.0, 1.0], &mut space).is_none());
        // The buffers those solves left give the same optimum again.
        let again = solve(&Banded::zeros(n), &rows, 1.0, vec![-1.0, -1.0], &mut space).expect("solved");
        assert_eq!((again.x, again.slack), (solved.x, solved.slack));
    }
}
