//! The curve CAD programs draw through a SPLINE's fit points when the file
//! gives no control points: a cubic through every fit point, twice
//! continuously differentiable, its parameter the chord length between fit
//! points, its ends either without curvature (the second derivative 0) or,
//! where the file gives both end tangents, leaving along them at unit speed
//! per unit of chord length. This is how AutoCAD and BricsCAD read such a
//! spline (as ezdxf documents it: global interpolation, chord
//! parametrisation, natural knots), written here as the classical cubic
//! spline through its moments, which is the same curve.

use nalgebra::Vector2;

type V = Vector2<f64>;

/// The curve through `fit` (at least two distinct points; repeated ones are
/// dropped), with the end tangents if given, as points within `tolerance`
/// of it; `room` is asked for the number of points first and may refuse.
pub fn flatten<E>(fit: &[(f64, f64)], tangents: Option<((f64, f64), (f64, f64))>, tolerance: f64, mut room: impl FnMut(f64) -> Result<(), E>) -> Result<Vec<(f64, f64)>, E> {
    let mut y: Vec<V> = Vec::with_capacity(fit.len());
    for &(a, b) in fit {
        let p = V::new(a, b);
        if y.last().is_none_or(|q| (p - q).norm() > 1e-12) {
            y.push(p);
        }
    }
    if y.len() < 2 {
        return Ok(y.iter().map(|p| (p.x, p.y)).collect());
    }
    let n = y.len() - 1;
    let h: Vec<f64> = y.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
    let m = moments(&y, &h, tangents.map(|(a, b)| (unit(a), unit(b))));
    // Per span, the chords within the tolerance: the second derivative is
    // linear along a span, so its larger end bounds it (a chord over δ of
    // parameter lies at most |P''|·δ²/8 from the curve).
    let counts: Vec<usize> = (0..n)
        .map(|i| {
            let bend = m[i].norm().max(m[i + 1].norm());
            if bend <= 0.0 { 1 } else { (h[i] / (8.0 * tolerance / bend).sqrt()).ceil().clamp(1.0, 1e7) as usize }
        })
        .collect();
    room(counts.iter().map(|&c| c as f64).sum::<f64>() + 1.0)?;
    let mut out = Vec::with_capacity(counts.iter().sum::<usize>() + 1);
    out.push((y[0].x, y[0].y));
    for i in 0..n {
        for k in 1..=counts[i] {
            let p = if k == counts[i] { y[i + 1] } else { at(&y, &h, &m, i, h[i] * k as f64 / counts[i] as f64) };
            out.push((p.x, p.y));
        }
    }
    Ok(out)
}

fn unit((a, b): (f64, f64)) -> V {
    let v = V::new(a, b);
    v / v.norm()
}

/// The second derivatives at the fit points: natural ends, or clamped to
/// the end tangents (a tridiagonal system, solved by elimination; it is
/// diagonally dominant, so no pivoting is needed).
fn moments(y: &[V], h: &[f64], ends: Option<(V, V)>) -> Vec<V> {
    let n = y.len() - 1;
    let slope = |i: usize| (y[i + 1] - y[i]) / h[i];
    let (mut sub, mut diag, mut sup, mut rhs) = (vec![0.0; n + 1], vec![0.0; n + 1], vec![0.0; n + 1], vec![V::zeros(); n + 1]);
    for i in 1..n {
        sub[i] = h[i - 1];
        diag[i] = 2.0 * (h[i - 1] + h[i]);
        sup[i] = h[i];
        rhs[i] = 6.0 * (slope(i) - slope(i - 1));
    }
    match ends {
        None => {
            diag[0] = 1.0;
            diag[n] = 1.0;
        }
        Some((start, end)) => {
            diag[0] = 2.0 * h[0];
            sup[0] = h[0];
            rhs[0] = 6.0 * (slope(0) - start);
            sub[n] = h[n - 1];
            diag[n] = 2.0 * h[n - 1];
            rhs[n] = 6.0 * (end - slope(n - 1));
        }
    }
    for i in 1..=n {
        let w = sub[i] / diag[i - 1];
        diag[i] -= w * sup[i - 1];
        let before = rhs[i - 1];
        rhs[i] -= before * w;
    }
    let mut m = vec![V::zeros(); n + 1];
    m[n] = rhs[n] / diag[n];
    for i in (0..n).rev() {
        m[i] = (rhs[i] - m[i + 1] * sup[i]) / diag[i];
    }
    m
}

/// The point `s` along span `i` (0 ≤ s ≤ h[i]).
fn at(y: &[V], h: &[f64], m: &[V], i: usize, s: f64) -> V {
    let (a, b) = (h[i] - s, s);
    let hi = h[i];
    m[i] * (a * a * a / (6.0 * hi)) + m[i + 1] * (b * b * b / (6.0 * hi)) + (y[i] / hi - m[i] * (hi / 6.0)) * a + (y[i + 1] / hi - m[i + 1] * (hi / 6.0)) * b
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve(fit: &[(f64, f64)], tangents: Option<((f64, f64), (f64, f64))>, tol: f64) -> Vec<(f64, f64)> {
        flatten(fit, tangents, tol, |_| Ok::<(), ()>(())).unwrap()
    }

    #[test]
    fn the_curve_passes_through_every_fit_point_and_stays_straight_on_a_line() {
        let fit = [(0.0, 0.0), (10.0, 15.0), (25.0, -5.0), (40.0, 10.0), (50.0, 0.0)];
        let pts = curve(&fit, None, 1e-3);
        for f in fit {
            assert!(pts.iter().any(|p| (p.0 - f.0).abs() < 1e-12 && (p.1 - f.1).abs() < 1e-12), "{f:?}");
        }
        assert!(pts.len() > 50, "flattened finely: {}", pts.len());
        let line = curve(&[(0.0, 0.0), (1.0, 2.0), (4.0, 8.0)], None, 1e-6);
        assert!(line.iter().all(|p| (p.1 - 2.0 * p.0).abs() < 1e-9), "{line:?}");
    }

    #[test]
    fn natural_ends_are_straight_and_clamped_ends_leave_along_their_tangents() {
        let fit = [(0.0, 0.0), (10.0, 10.0), (20.0, 0.0)];
        // Natural: the second derivative 0 at the ends (three fit points:
        // the moments solve to 0, -6·Δslope/(4h)·…, 0).
        let y: Vec<V> = fit.iter().map(|&(a, b)| V::new(a, b)).collect();
        let h: Vec<f64> = y.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
        let m = moments(&y, &h, None);
        assert!(m[0].norm() == 0.0 && m[2].norm() == 0.0 && m[1].y < 0.0, "{m:?}");
        // Clamped: leaving straight up, the curve's first chord points up.
        let pts = curve(&fit, Some(((0.0, 1.0), (0.0, -1.0))), 1e-5);
        let (a, b) = (pts[0], pts[1]);
        assert!((b.0 - a.0).abs() < 1e-2 * (b.1 - a.1), "{a:?} {b:?}");
        // The derivative at the start is the unit tangent per unit of chord.
        let mc = moments(&y, &h, Some((V::new(0.0, 1.0), V::new(0.0, -1.0))));
        let d = 1e-7;
        let first = (at(&y, &h, &mc, 0, d) - y[0]) / d;
        assert!((first - V::new(0.0, 1.0)).norm() < 1e-5, "{first:?}");
    }
}
