//! Arcs (G2/G3) cut into chords as Grbl does (reference §9): the centre from
//! `IJK` or `R`, the error checks, and chord end points within 0.002 mm.
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
    /// Chord end points of an arc (reference §9; sagitta <= 0.002 mm).
    pub(super) fn arc_points(&self, arc: &ArcInput, axes: &[Option<f64>]) -> Result<Vec<Vec<f64>>, u16> {
        const TOLERANCE: f64 = 0.002;
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
        let end_radius = r1x.hypot(r1y);
        if radius.is_nan()
            || radius <= 0.0
            || ((end_radius - radius).abs() > 0.005 && (end_radius - radius).abs() > 0.001 * radius)
        {
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
        let max_step = if radius <= TOLERANCE / 2.0 {
            std::f64::consts::PI
        } else {
            (2.0 * (1.0 - TOLERANCE / radius).acos()).min(std::f64::consts::PI)
        };
        let n = (travel.abs() / max_step).ceil().max(1.0);
        if n > 1e6 {
            return Err(33);
        }
        let n = n as usize;
        let theta0 = r0y.atan2(r0x);
        let mut pts = Vec::with_capacity(n);
        for k in 1..n {
            let f = k as f64 / n as f64;
            let th = theta0 + travel * f;
            let mut p: Vec<f64> = arc.start.iter().zip(arc.end.iter()).map(|(s, e)| s + (e - s) * f).collect();
            p[a0] = c0 + radius * th.cos();
            p[a1] = c1 + radius * th.sin();
            pts.push(p);
        }
        pts.push(arc.end.to_vec());
        Ok(pts)
    }
}
