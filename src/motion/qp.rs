//! A convex QP whose rows each touch at most `BAND` consecutive unknowns,
//! solved by a primal-dual interior point method (Mehrotra's predictor and
//! corrector). Each step's normal equations are banded (half bandwidth
//! `BAND - 1`), so a step costs time linear in the problem: the flow's
//! problems (thousands of unknowns, tens of thousands of rows) solve in a few
//! milliseconds, where a general sparse solver factorises a much larger
//! system each step.
//!
//! minimise ½ xᵀPx + w·Σσ  subject to  aᵣ·x ≤ bᵣ (hard rows) and
//! aᵣ·x − σᵣ ≤ bᵣ, σᵣ ≥ 0 (soft rows: each has its own slack σᵣ, priced `w`).
//! Plain arithmetic in a fixed order: the same result on any machine.

/// Consecutive unknowns a row may touch.
pub const BAND: usize = 4;

/// `a·x[first..first + BAND] ≤ b` (or `− σ` for a soft row).
#[derive(Debug, Clone)]
pub struct Row {
    first: usize,
    a: [f64; BAND],
    b: f64,
    soft: bool,
}

impl Row {
    /// A row from its terms `(unknown, weight)`, which must lie within
    /// `BAND` consecutive unknowns of `n`; `None` when every weight is zero
    /// (the row says nothing).
    pub fn new(terms: &[(usize, f64)], b: f64, soft: bool, n: usize) -> Option<Row> {
        let lo = terms.iter().filter(|t| t.1 != 0.0).map(|t| t.0).min()?;
        let first = lo.min(n.saturating_sub(BAND));
        let mut a = [0.0; BAND];
        for &(j, w) in terms {
            a[j - first] += w;
        }
        a.iter().any(|&w| w != 0.0).then_some(Row { first, a, b, soft })
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

    /// Cholesky factor (`LLᵀ`, `L` in the same banded layout), each pivot
    /// kept at least `floor` times its diagonal entry (the matrix is positive
    /// semi-definite at worst; rounding may leave a pivot near zero).
    fn cholesky(mut self, floor: f64) -> Banded {
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
                self.band[i][k] = if j == i { sum.max(floor * entry).max(f64::MIN_POSITIVE).sqrt() } else { sum / self.band[j][BAND - 1] };
            }
        }
        self
    }

    /// Solves `LLᵀx = y` with `self` the factor.
    fn solve(&self, mut y: Vec<f64>) -> Vec<f64> {
        let n = y.len();
        for i in 0..n {
            for c in i.saturating_sub(BAND - 1)..i {
                y[i] -= self.band[i][c + BAND - 1 - i] * y[c];
            }
            y[i] /= self.band[i][BAND - 1];
        }
        for i in (0..n).rev() {
            y[i] /= self.band[i][BAND - 1];
            for c in i.saturating_sub(BAND - 1)..i {
                y[c] -= self.band[i][c + BAND - 1 - i] * y[i];
            }
        }
        y
    }
}

/// The solution: the unknowns, and per row its slack (0 for hard rows).
#[derive(Debug, Clone)]
pub struct Solution {
    pub x: Vec<f64>,
    pub slack: Vec<f64>,
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

/// Minimises `½xᵀPx + w·Σσ` over the rows from `x0`, a point where every
/// hard row holds strictly (soft rows need not). `None` when the method does
/// not converge.
pub fn solve(p: &Banded, rows: &[Row], w: f64, x0: Vec<f64>) -> Option<Solution> {
    let m = rows.len();
    let mut x = x0;
    // Per row: its slack s (b − a·x [+ σ]) and dual λ; per soft row also σ,
    // σ's own bound's slack (= σ) and dual (0 for hard rows).
    let mut s = vec![0.0; m];
    let mut lam = vec![0.0; m];
    let mut sigma = vec![0.0; m];
    let mut lam_n = vec![0.0; m];
    for (r, row) in rows.iter().enumerate() {
        let room = row.b - row.dot(&x);
        if row.soft {
            sigma[r] = (-room).max(0.0) + 1.0;
            s[r] = room + sigma[r];
            lam[r] = 0.5 * w;
            lam_n[r] = 0.5 * w;
        } else {
            if room <= 0.0 {
                return None;
            }
            s[r] = room;
            lam[r] = 1.0;
        }
    }
    let count = (m + rows.iter().filter(|r| r.soft).count()) as f64;
    let worst = |v: &[f64]| v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let (mut rp, mut rs, mut d, mut d_n) = (vec![0.0; m], vec![0.0; m], vec![0.0; m], vec![0.0; m]);
    let (mut rc, mut rc_n) = (vec![0.0; m], vec![0.0; m]);
    let (mut affine, mut step) = (Step::zeros(x.len(), m), Step::zeros(x.len(), m));
    let mut k = p.clone();
    // Steps in a row that barely lowered the complementarity.
    let (mut stalled, mut last_mu) = (0, f64::INFINITY);
    for _ in 0..MOST_STEPS {
        // Residuals: dual (x, σ), primal (rows; σ's bound holds by
        // construction: its slack is σ itself).
        let mut rx = p.mul(&x);
        let mut gap = 0.0;
        for (r, row) in rows.iter().enumerate() {
            row.add_to(&mut rx, lam[r]);
            rp[r] = row.dot(&x) - sigma[r] + s[r] - row.b;
            rs[r] = if row.soft { w - lam[r] - lam_n[r] } else { 0.0 };
            gap += s[r] * lam[r] + sigma[r] * lam_n[r];
        }
        let mu = gap / count;
        let done = |x: Vec<f64>| Some(Solution { x, slack: sigma.clone() });
        if worst(&rp) <= PRIMAL && worst(&rx) <= DUAL && worst(&rs) <= DUAL && mu <= GAP {
            return done(x);
        }
        stalled = if mu > 0.9 * last_mu { stalled + 1 } else { 0 };
        last_mu = mu;
        if stalled >= 3 {
            return (worst(&rp) <= PRIMAL && mu <= GAP_STALLED).then(|| done(x)).flatten();
        }
        // The normal equations' matrix: P + Σ dᵣ aᵣaᵣᵀ (a soft row's weight
        // with its σ eliminated).
        k.band.clone_from(&p.band);
        for (r, row) in rows.iter().enumerate() {
            d[r] = lam[r] / s[r];
            let weight = if row.soft {
                d_n[r] = lam_n[r] / sigma[r];
                d[r] * d_n[r] / (d[r] + d_n[r])
            } else {
                d[r]
            };
            k.add_row(row, weight);
        }
        let factor = k.clone().cholesky(1e-12);
        let newton = Newton { rows, factor: &factor, rx: &rx, rp: &rp, rs: &rs, d: &d, d_n: &d_n, s: &s, lam: &lam, lam_n: &lam_n };
        // Predictor: towards complementarity 0.
        for r in 0..m {
            rc[r] = s[r] * lam[r];
            rc_n[r] = sigma[r] * lam_n[r];
        }
        newton.step(&rc, &rc_n, &mut affine);
        let alpha = affine.longest(&s, &lam, &sigma, &lam_n);
        let mut gap_affine = 0.0;
        for r in 0..m {
            gap_affine += (s[r] + alpha * affine.ds[r]) * (lam[r] + alpha * affine.dl[r]) + (sigma[r] + alpha * affine.dsig[r]) * (lam_n[r] + alpha * affine.dln[r]);
        }
        // Corrector: towards a centre chosen by how far the predictor got.
        let centre = (gap_affine / count / mu).powi(3) * mu;
        for r in 0..m {
            rc[r] = s[r] * lam[r] + affine.ds[r] * affine.dl[r] - centre;
            rc_n[r] = if rows[r].soft { sigma[r] * lam_n[r] + affine.dsig[r] * affine.dln[r] - centre } else { 0.0 };
        }
        newton.step(&rc, &rc_n, &mut step);
        if !step.finite() {
            return (worst(&rp) <= PRIMAL && mu <= GAP_STALLED).then(|| done(x)).flatten();
        }
        let alpha = (0.99 * step.longest(&s, &lam, &sigma, &lam_n)).min(1.0);
        for (v, dv) in x.iter_mut().zip(&step.dx) {
            *v += alpha * dv;
        }
        for r in 0..m {
            s[r] += alpha * step.ds[r];
            lam[r] += alpha * step.dl[r];
            sigma[r] += alpha * step.dsig[r];
            lam_n[r] += alpha * step.dln[r];
        }
    }
    None
}

/// A Newton step: unknowns, rows' slacks and duals, σ and its bound's dual.
struct Step {
    dx: Vec<f64>,
    ds: Vec<f64>,
    dl: Vec<f64>,
    dsig: Vec<f64>,
    dln: Vec<f64>,
}

impl Step {
    fn zeros(n: usize, m: usize) -> Step {
        Step { dx: vec![0.0; n], ds: vec![0.0; m], dl: vec![0.0; m], dsig: vec![0.0; m], dln: vec![0.0; m] }
    }

    fn finite(&self) -> bool {
        [&self.dx, &self.ds, &self.dl, &self.dsig, &self.dln].iter().all(|v| v.iter().all(|x| x.is_finite()))
    }

    /// How far along the step every slack and dual stays positive (≤ 1).
    fn longest(&self, s: &[f64], lam: &[f64], sigma: &[f64], lam_n: &[f64]) -> f64 {
        let mut alpha = 1.0f64;
        for (v, dv) in [(s, &self.ds), (lam, &self.dl), (sigma, &self.dsig), (lam_n, &self.dln)] {
            for (&v, &dv) in v.iter().zip(dv.iter()) {
                if dv < 0.0 && v > 0.0 {
                    alpha = alpha.min(-v / dv);
                }
            }
        }
        alpha
    }
}

/// One iterate's linearisation: the factored normal equations and what
/// the step's other parts follow from.
struct Newton<'a> {
    rows: &'a [Row],
    factor: &'a Banded,
    rx: &'a [f64],
    rp: &'a [f64],
    rs: &'a [f64],
    d: &'a [f64],
    d_n: &'a [f64],
    s: &'a [f64],
    lam: &'a [f64],
    lam_n: &'a [f64],
}

impl Newton<'_> {
    /// The step towards complementarity targets `rc` (rows) and `rc_n`
    /// (σ's bounds), into `out`.
    fn step(&self, rc: &[f64], rc_n: &[f64], out: &mut Step) {
        let (d, d_n) = (self.d, self.d_n);
        let mut rhs: Vec<f64> = self.rx.iter().map(|v| -v).collect();
        for (r, row) in self.rows.iter().enumerate() {
            let e = self.rp[r] - rc[r] / self.lam[r];
            let k = if row.soft {
                let e_n = -rc_n[r] / self.lam_n[r];
                d[r] * (d_n[r] * (e - e_n) + self.rs[r]) / (d[r] + d_n[r])
            } else {
                d[r] * e
            };
            row.add_to(&mut rhs, -k);
        }
        out.dx = self.factor.solve(rhs);
        for (r, row) in self.rows.iter().enumerate() {
            let adx = row.dot(&out.dx);
            let e = self.rp[r] - rc[r] / self.lam[r];
            if row.soft {
                let e_n = -rc_n[r] / self.lam_n[r];
                out.dsig[r] = (d[r] * (adx + e) + d_n[r] * e_n - self.rs[r]) / (d[r] + d_n[r]);
                out.dln[r] = d_n[r] * (e_n - out.dsig[r]);
            }
            out.dl[r] = d[r] * (adx - out.dsig[r] + e);
            out.ds[r] = (-rc[r] - self.s[r] * out.dl[r]) / self.lam[r];
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
        let back = k.clone().cholesky(1e-14).solve(y);
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
            Row::new(&[(0, -1.0), (1, 1.0)], 1.0, false, n),
            Row::new(&[(0, 1.0), (1, -1.0)], 1.0, false, n),
            Row::new(&[(0, 1.0)], 0.0, false, n),
            Row::new(&[(1, -1.0)], -3.0, true, n),
        ]
        .into_iter()
        .flatten()
        .collect();
        let solved = solve(&Banded::zeros(n), &rows, 1.0, vec![-1.0, -1.0]).expect("solved");
        assert!((solved.x[0] - 0.0).abs() < 1e-5 && (solved.x[1] - 1.0).abs() < 1e-5, "{:?}", solved.x);
        assert!((solved.slack[3] - 2.0).abs() < 1e-5, "{:?}", solved.slack);
        // A hard row that does not hold at the start: refused.
        assert!(solve(&Banded::zeros(n), &rows, 1.0, vec![1.0, 1.0]).is_none());
    }
}
