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

    /// Solves `LLᵀx = y` in place with `self` the factor.
    fn solve(&self, y: &mut [f64]) {
        let n = y.len();
        for i in 0..n {
            for c in i.saturating_sub(BAND - 1)..i {
                y[i] -= self.band[i][c + BAND - 1 - i] * y[c];
            }
            y[i] *= self.band[i][BAND - 1];
        }
        for i in (0..n).rev() {
            y[i] *= self.band[i][BAND - 1];
            for c in i.saturating_sub(BAND - 1)..i {
                y[c] -= self.band[i][c + BAND - 1 - i] * y[i];
            }
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

/// The iterate, per side `j = 2·row + side`: its slack `s` (b − a·x [+ σ]),
/// dual `lam`, and for a soft side `sigma` and the dual `lam_n` of σ ≥ 0
/// (whose slack is σ itself). Absent sides stay zero.
struct Iterate {
    x: Vec<f64>,
    s: Vec<f64>,
    lam: Vec<f64>,
    sigma: Vec<f64>,
    lam_n: Vec<f64>,
}

/// Minimises `½xᵀPx + w·Σσ` over the rows from `x0`, a point where every
/// hard side holds strictly (soft ones need not). `None` when the method
/// does not converge.
pub fn solve(p: &Banded, rows: &[Row], w: f64, x0: Vec<f64>) -> Option<Solution> {
    let sides = 2 * rows.len();
    let mut it = Iterate { x: x0, s: vec![0.0; sides], lam: vec![0.0; sides], sigma: vec![0.0; sides], lam_n: vec![0.0; sides] };
    let mut count = 0.0;
    for (r, row) in rows.iter().enumerate() {
        let ax = row.dot(&it.x);
        for (k, side) in row.sides.iter().enumerate() {
            let Some(side) = side else { continue };
            let (j, room) = (2 * r + k, side.b - SIGN[k] * ax);
            if side.soft {
                it.sigma[j] = (-room).max(0.0) + 1.0;
                it.s[j] = room + it.sigma[j];
                it.lam[j] = 0.5 * w;
                it.lam_n[j] = 0.5 * w;
                count += 2.0;
            } else {
                if room <= 0.0 {
                    return None;
                }
                it.s[j] = room;
                it.lam[j] = 1.0;
                count += 1.0;
            }
        }
    }
    let mut lin = Linear::new(p, sides);
    let (mut affine, mut step) = (Step::zeros(it.x.len(), sides), Step::zeros(it.x.len(), sides));
    // Steps in a row that barely lowered the complementarity.
    let (mut stalled, mut last_mu) = (0, f64::INFINITY);
    for _ in 0..MOST_STEPS {
        let residuals = lin.linearise(p, rows, w, &it);
        let mu = residuals.gap / count;
        let stalled_result = |it: Iterate| (residuals.primal <= PRIMAL && mu <= GAP_STALLED).then(|| it.solution());
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
        let alpha = lin.step(rows, &it, 0.0, None, &mut affine);
        let mut gap_affine = 0.0;
        for (r, row) in rows.iter().enumerate() {
            for (k, side) in row.sides.iter().enumerate() {
                let Some(side) = side else { continue };
                let j = 2 * r + k;
                gap_affine += (it.s[j] + alpha * affine.ds[j]) * (it.lam[j] + alpha * affine.dl[j]);
                if side.soft {
                    gap_affine += (it.sigma[j] + alpha * affine.dsig[j]) * (it.lam_n[j] + alpha * affine.dln[j]);
                }
            }
        }
        // Corrector: towards a centre chosen by how far the predictor got.
        let centre = (gap_affine / count / mu).powi(3) * mu;
        let alpha = lin.step(rows, &it, centre, Some(&affine), &mut step);
        if !alpha.is_finite() {
            return stalled_result(it);
        }
        let alpha = (0.99 * alpha).min(1.0);
        for (v, dv) in it.x.iter_mut().zip(&step.dx) {
            *v += alpha * dv;
        }
        for j in 0..sides {
            it.s[j] += alpha * step.ds[j];
            it.lam[j] += alpha * step.dl[j];
            it.sigma[j] += alpha * step.dsig[j];
            it.lam_n[j] += alpha * step.dln[j];
        }
    }
    None
}

impl Iterate {
    fn solution(self) -> Solution {
        let slack = self.sigma.chunks_exact(2).map(|s| [s[0], s[1]]).collect();
        Solution { x: self.x, slack }
    }
}

/// A Newton step: unknowns, sides' slacks and duals, σ and its bound's dual.
struct Step {
    dx: Vec<f64>,
    ds: Vec<f64>,
    dl: Vec<f64>,
    dsig: Vec<f64>,
    dln: Vec<f64>,
}

impl Step {
    fn zeros(n: usize, sides: usize) -> Step {
        Step { dx: vec![0.0; n], ds: vec![0.0; sides], dl: vec![0.0; sides], dsig: vec![0.0; sides], dln: vec![0.0; sides] }
    }
}

/// The largest residuals and the complementarity of an iterate.
struct Residuals {
    primal: f64,
    dual: f64,
    gap: f64,
}

/// One iterate's linearisation: its residuals, the normal equations (and
/// their factor) and, per side, what the step's other parts follow from.
struct Linear {
    k: Banded,
    factor: Banded,
    /// Dual residual of the unknowns (`Px + Σ ±λ a`).
    rx: Vec<f64>,
    /// Per side: primal residual, σ's dual residual, `λ/s`, `λₙ/σ`,
    /// `1/λ`, `1/λₙ`, `1/(d + dₙ)`, and the step's `e`, `eₙ` (kept from
    /// the right-hand side for the back substitution).
    rp: Vec<f64>,
    rs: Vec<f64>,
    d: Vec<f64>,
    d_n: Vec<f64>,
    inv_lam: Vec<f64>,
    inv_lam_n: Vec<f64>,
    inv_sum: Vec<f64>,
    e: Vec<f64>,
    e_n: Vec<f64>,
}

impl Linear {
    fn new(p: &Banded, sides: usize) -> Linear {
        let z = || vec![0.0; sides];
        Linear { k: p.clone(), factor: p.clone(), rx: Vec::new(), rp: z(), rs: z(), d: z(), d_n: z(), inv_lam: z(), inv_lam_n: z(), inv_sum: z(), e: z(), e_n: z() }
    }

    /// Residuals of `it` and the normal equations' matrix `P + Σ wⱼ aaᵀ`
    /// (a soft side's weight with its σ eliminated), in one pass over the
    /// rows.
    fn linearise(&mut self, p: &Banded, rows: &[Row], w: f64, it: &Iterate) -> Residuals {
        self.rx = p.mul(&it.x);
        self.k.band.clone_from(&p.band);
        let (mut primal, mut dual, mut gap) = (0.0f64, 0.0f64, 0.0);
        for (r, row) in rows.iter().enumerate() {
            let ax = row.dot(&it.x);
            let (mut net_lam, mut weight) = (0.0, 0.0);
            for (k, side) in row.sides.iter().enumerate() {
                let Some(side) = side else { continue };
                let j = 2 * r + k;
                let (s, lam, sigma, lam_n) = (it.s[j], it.lam[j], it.sigma[j], it.lam_n[j]);
                self.rp[j] = SIGN[k] * ax - sigma + s - side.b;
                primal = primal.max(self.rp[j].abs());
                net_lam += SIGN[k] * lam;
                gap += s * lam + sigma * lam_n;
                self.d[j] = lam / s;
                self.inv_lam[j] = 1.0 / lam;
                if side.soft {
                    self.rs[j] = w - lam - lam_n;
                    dual = dual.max(self.rs[j].abs());
                    self.d_n[j] = lam_n / sigma;
                    self.inv_lam_n[j] = 1.0 / lam_n;
                    self.inv_sum[j] = 1.0 / (self.d[j] + self.d_n[j]);
                    weight += self.d[j] * self.d_n[j] * self.inv_sum[j];
                } else {
                    weight += self.d[j];
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
        for (r, row) in rows.iter().enumerate() {
            let mut net = 0.0;
            for (k, side) in row.sides.iter().enumerate() {
                let Some(side) = side else { continue };
                let j = 2 * r + k;
                let (d, d_n) = (self.d[j], self.d_n[j]);
                let rc = it.s[j] * it.lam[j] + affine.map_or(0.0, |a| a.ds[j] * a.dl[j]) - centre;
                self.e[j] = self.rp[j] - rc * self.inv_lam[j];
                let k_side = if side.soft {
                    let rc_n = it.sigma[j] * it.lam_n[j] + affine.map_or(0.0, |a| a.dsig[j] * a.dln[j]) - centre;
                    self.e_n[j] = -rc_n * self.inv_lam_n[j];
                    d * (d_n * (self.e[j] - self.e_n[j]) + self.rs[j]) * self.inv_sum[j]
                } else {
                    d * self.e[j]
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
        for (r, row) in rows.iter().enumerate() {
            let adx = row.dot(&out.dx);
            for (k, side) in row.sides.iter().enumerate() {
                let Some(side) = side else { continue };
                let j = 2 * r + k;
                let (d, d_n, e) = (self.d[j], self.d_n[j], self.e[j]);
                let adx = SIGN[k] * adx;
                if side.soft {
                    let e_n = self.e_n[j];
                    out.dsig[j] = (d * (adx + e) + d_n * e_n - self.rs[j]) * self.inv_sum[j];
                    out.dln[j] = d_n * (e_n - out.dsig[j]);
                    alpha = longest(longest(alpha, it.sigma[j], out.dsig[j]), it.lam_n[j], out.dln[j]);
                    finite &= out.dsig[j].is_finite() && out.dln[j].is_finite();
                }
                out.dl[j] = d * (adx - out.dsig[j] + e);
                // s·dλ + λ·ds = −rc, with rc = λ·(rp − e).
                out.ds[j] = -(self.rp[j] - e) - it.s[j] * out.dl[j] * self.inv_lam[j];
                alpha = longest(longest(alpha, it.s[j], out.ds[j]), it.lam[j], out.dl[j]);
                finite &= out.dl[j].is_finite() && out.ds[j].is_finite();
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
        let solved = solve(&Banded::zeros(n), &rows, 1.0, vec![-1.0, -1.0]).expect("solved");
        assert!((solved.x[0] - 0.0).abs() < 1e-5 && (solved.x[1] - 1.0).abs() < 1e-5, "{:?}", solved.x);
        assert!((solved.slack[2][1] - 2.0).abs() < 1e-5 && solved.slack[2][0] == 0.0, "{:?}", solved.slack);
        // A hard row that does not hold at the start: refused.
        assert!(solve(&Banded::zeros(n), &rows, 1.0, vec![1.0, 1.0]).is_none());
    }
}
