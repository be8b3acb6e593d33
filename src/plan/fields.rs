//! Scan-field cover for step-and-scan: groups geometries so that each group fits
//! the scanner's usable field around one stage position.
//!
//! Greedy: geometries sorted by position join the open field whose bounds grow
//! least, or open a new one. It is the baseline; the galvo planner replaces it.

use crate::error::{Error, Result};
use crate::job::{bounds_of, Job, Point};

/// A field: the geometries in it and the stage position (centre of their bounds).
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub center: Point,
    pub members: Vec<usize>,
}

pub fn cover(job: &Job, usable_half: f64, travel: (f64, f64)) -> Result<Vec<Field>> {
    let size = 2.0 * usable_half;
    let mut order: Vec<usize> = (0..job.geometries.len()).collect();
    let bounds: Vec<(Point, Point)> = job.geometries.iter().map(|g| g.bounds()).collect();
    for (i, (lo, hi)) in bounds.iter().enumerate() {
        if hi.x - lo.x > size + 1e-9 || hi.y - lo.y > size + 1e-9 {
            return Err(Error::Plan(format!(
                "{}: {:.3} x {:.3} mm does not fit the scanner's usable field ({size} x {size} mm); use --mode stage-only",
                job.geometries[i].source,
                hi.x - lo.x,
                hi.y - lo.y
            )));
        }
    }
    // Row-major by the lower-left corner, in bands one field high, so fields grow
    // along rows instead of scattering.
    order.sort_by(|&a, &b| {
        let band = |i: usize| (bounds[i].0.y / size).floor() as i64;
        band(a).cmp(&band(b)).then(bounds[a].0.x.total_cmp(&bounds[b].0.x))
    });
    let mut fields: Vec<(Point, Point, Vec<usize>)> = Vec::new();
    for i in order {
        let (lo, hi) = bounds[i];
        let mut best: Option<(usize, f64)> = None;
        for (k, (flo, fhi, _)) in fields.iter().enumerate() {
            let (ulo, uhi) = bounds_of([*flo, *fhi, lo, hi].iter());
            if uhi.x - ulo.x <= size && uhi.y - ulo.y <= size {
                let growth = (uhi.x - ulo.x) * (uhi.y - ulo.y) - (fhi.x - flo.x) * (fhi.y - flo.y);
                if best.is_none_or(|(_, g)| growth < g) {
                    best = Some((k, growth));
                }
            }
        }
        match best {
            Some((k, _)) => {
                let f = &mut fields[k];
                let (ulo, uhi) = bounds_of([f.0, f.1, lo, hi].iter());
                f.0 = ulo;
                f.1 = uhi;
                f.2.push(i);
            }
            None => fields.push((lo, hi, vec![i])),
        }
    }
    let mut out = Vec::with_capacity(fields.len());
    for (lo, hi, members) in fields {
        // Centre the field on its content, but keep the stage inside its travel;
        // the content still fits because it is at most one field wide.
        let mut c = Point::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0);
        c.x = c.x.clamp((hi.x - usable_half).max(0.0), (lo.x + usable_half).min(travel.0));
        c.y = c.y.clamp((hi.y - usable_half).max(0.0), (lo.y + usable_half).min(travel.1));
        if c.x < 0.0 || c.y < 0.0 || c.x > travel.0 || c.y > travel.1 {
            return Err(Error::Plan(format!(
                "{}: cannot be reached with the stage inside its travel",
                job.geometries[members[0]].source
            )));
        }
        out.push(Field { center: c, members });
    }
    Ok(out)
}
