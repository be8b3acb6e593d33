//! Arcs (G2/G3) cut into chords as Grbl does (reference §9): the centre from
//! `IJK` or `R`, the error checks, and chord end points from `$12` (Grbl's
//! `mc_arc`).
//! Separate from the parser because it is geometry, not modal state.

use super::{Controller, EPS_POS};

/// An arc of a G-code block: start and end (machine mm), plane (17/18/19),
/// direction, and the `IJK` offsets or the radius `R` (mm).
pub(super) struct ArcInput<'a> {
    pub(super) start: &'a [f64],
    pub(super) end: &'a [f64],
    pub(super) plane: u8,
    pub(super) cw: bool,
    pub(super) ijk: [Option<f64>; 3],
    pub(super) r: Option<f64>,
}

impl Controller {
    /// Chord end points of an arc (reference §9): one per segment Grbl cuts
    /// it into, the last the end point.
    pub(super) fn arc_points(&self, arc: &ArcInput, axes: &[Option<f64>]) -> Result<Vec<Vec<f64>>, u16> {
        let (l0, l1, o0, o1) = match arc.plane {
            17 => ('X', 'Y', 0, 1),
            18 => ('Z', 'X', 2, 0),
            _ => ('Y', 'Z', 1, 2),
        };
        let (Some(a0), Some(a1)) = (self.axis_index(l0), self.axis_index(l1)) else { return Err(20) };
        if axes[a0].is_none() && axes[a1].is_none() {
            return Err(32);
        }
        let (s0, s1) = (arc.start[a0], arc.start[a1]);
        let (x, y) = (arc.end[a0] - s0, arc.end[a1] - s1);
        let (ci, cj) = if let Some(r) = arc.r {
            // Centre from the radius (Grbl's formula; negative R = long way).
            if x.abs() < EPS_POS && y.abs() < EPS_POS {
                return Err(33);
            }
            let h2 = 4.0 * r * r - x * x - y * y;
            if h2 < 0.0 {
                // The radius is too small to reach the end point.
                return Err(34);
            }
            let mut h = -h2.sqrt() / x.hypot(y);
            if !arc.cw {
                h = -h;
            }
            if r < 0.0 {
                h = -h;
            }
            (0.5 * (x - y * h), 0.5 * (y + x * h))
        } else {
            let (i, j) = (arc.ijk[o0], arc.ijk[o1]);
            if i.is_none() && j.is_none() {
                return Err(35);
            }
            (i.unwrap_or(0.0), j.unwrap_or(0.0))
        };
        let (c0, c1) = (s0 + ci, s1 + cj);
        let (r0x, r0y) = (s0 - c0, s1 - c1);
        let (r1x, r1y) = (arc.end[a0] - c0, arc.end[a1] - c1);
        let radius = r0x.hypot(r0y);
        // Grbl's radius check (gcode.c): start and end radii may differ by
        // 0.005 mm, or by up to 0.5 mm where that is within 0.1 % of the radius.
        let radius_error = (r1x.hypot(r1y) - radius).abs();
        if radius.is_nan() || radius <= 0.0 || (radius_error > 0.005 && (radius_error > 0.5 || radius_error > 0.001 * radius)) {
            return Err(33);
        }
        let mut travel = (r0x * r1y - r0y * r1x).atan2(r0x * r1x + r0y * r1y);
        if arc.cw {
            if travel >= -5e-7 {
                travel -= std::f64::consts::TAU;
            }
        } else if travel <= 5e-7 {
            travel += std::f64::consts::TAU;
        }
        // Grbl's mc_arc: as many whole segments as chords of sagitta `$12`
        // fit in the arc (so a segment is at least that long; none: one
        // straight line to the end).
        let tolerance = self.setting(12);
        let segments = (0.5 * travel * radius).abs() / (tolerance * (2.0 * radius - tolerance)).sqrt();
        let segments = if segments.is_finite() { segments.floor() } else { 0.0 };
        if segments > 1e6 {
            return Err(33);
        }
        let segments = segments as usize;
        let mut pts = Vec::with_capacity(segments.max(1));
        if segments > 1 {
            // Each point the radius vector rotated on by a small-angle
            // (third-order) rotation, recomputed exactly every
            // N_ARC_CORRECTION (12) segments, as Grbl does.
            const N_ARC_CORRECTION: usize = 12;
            let step = travel / segments as f64;
            let cos_t = 1.0 - 0.5 * step * step;
            let sin_t = step * (1.0 - step * step / 6.0);
            let (mut rx, mut ry) = (r0x, r0y);
            let mut count = 0;
            for k in 1..segments {
                if count < N_ARC_CORRECTION {
                    (rx, ry) = (rx * cos_t - ry * sin_t, rx * sin_t + ry * cos_t);
                    count += 1;
                } else {
                    let (sin_k, cos_k) = (k as f64 * step).sin_cos();
                    (rx, ry) = (r0x * cos_k - r0y * sin_k, r0x * sin_k + r0y * cos_k);
                    count = 0;
                }
                let f = k as f64 / segments as f64;
                let mut p: Vec<f64> = arc.start.iter().zip(arc.end.iter()).map(|(s, e)| s + (e - s) * f).collect();
                p[a0] = c0 + rx;
                p[a1] = c1 + ry;
                pts.push(p);
            }
        }
        pts.push(arc.end.to_vec());
        Ok(pts)
    }
}
