//! Scan-field cover for step-and-scan: groups geometries so that each group fits
//! the scanner's usable field around one stage position, with as few fields as
//! it can.
//!
//! Greedy set cover over candidate field squares, then local improvement:
//! * **Candidates.** A square can slide right and up until a geometry inside
//!   touches its left and its bottom edge without losing any, so squares whose
//!   left edge is some geometry's left bound and whose bottom edge is some
//!   geometry's bottom bound are enough.
//! * **Greedy.** The square holding the most geometries not yet covered is
//!   taken, again and again. The squares of one left edge (a column) are
//!   counted in one sweep over the sorted bottoms and tops of the geometries
//!   in that column, which a window sliding along x keeps up to date; a
//!   column's best square is kept until a field takes one of its geometries.
//! * **Improvement.** A field whose geometries all fit into other fields
//!   (their content's bounds still within one field) is dissolved, smallest
//!   first.
//! * **Centring.** Each field is centred on its content (galvo distortion grows
//!   towards the field's edge), the stage kept inside its travel.

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
    let groups = dissolve_small_fields(greedy_cover(&bounds, size), &bounds, size);
    let mut out = Vec::with_capacity(groups.len());
    for members in groups {
        let (lo, hi) = group_bounds(&bounds, &members);
        let center = centre_within_travel(lo, hi, usable_half, travel)
            .ok_or_else(|| Error::Plan(format!("{}: cannot be reached with the stage inside its travel", job.geometries[members[0]].source)))?;
        out.push(Field { center, members });
    }
    Ok(out)
}

/// The stage position of a field whose content spans `lo`..`hi`: centred on
/// the content, but kept inside the travel (the content still fits, being at
/// most one field wide); `None` when no position in the travel reaches it.
pub fn centre_within_travel(lo: Point, hi: Point, usable_half: f64, travel: (f64, f64)) -> Option<Point> {
    // Content exactly one field wide (to rounding) has one centre: its middle.
    let within = |mid: f64, lo: f64, hi: f64, travel: f64| {
        let (a, b) = ((hi - usable_half).max(0.0), (lo + usable_half).min(travel));
        if a <= b {
            mid.clamp(a, b)
        } else {
            mid
        }
    };
    let c = Point::new(within((lo.x + hi.x) / 2.0, lo.x, hi.x, travel.0), within((lo.y + hi.y) / 2.0, lo.y, hi.y, travel.1));
    let reaches = c.x - usable_half <= lo.x + FIT && c.x + usable_half >= hi.x - FIT && c.y - usable_half <= lo.y + FIT && c.y + usable_half >= hi.y - FIT;
    (reaches && c.x >= 0.0 && c.y >= 0.0 && c.x <= travel.0 && c.y <= travel.1).then_some(c)
}

fn group_bounds(bounds: &[(Point, Point)], members: &[usize]) -> (Point, Point) {
    bounds_of(members.iter().flat_map(|&i| [&bounds[i].0, &bounds[i].1]))
}

/// Slack on "fits": bounds are compared in floating point.
const FIT: f64 = 1e-9;

/// Greedy set cover: the geometries of each field, in the order taken.
fn greedy_cover(bounds: &[(Point, Point)], size: f64) -> Vec<Vec<usize>> {
    let n = bounds.len();
    // Geometries by left and by right bound: a column of squares (one left
    // edge) holds those with lo.x ≥ x and hi.x ≤ x + S, a window that slides
    // along both lists as x grows.
    let mut by_lo: Vec<usize> = (0..n).collect();
    by_lo.sort_by(|&a, &b| bounds[a].0.x.total_cmp(&bounds[b].0.x));
    let mut by_hi: Vec<usize> = (0..n).collect();
    by_hi.sort_by(|&a, &b| bounds[a].1.x.total_cmp(&bounds[b].1.x));
    let mut covered = vec![false; n];
    let mut fields = Vec::new();
    // Each column's best square (count, bottom) while none of the geometries
    // in it gets covered: a field taken only changes the columns it touches.
    let mut column_best: Vec<Option<(usize, f64)>> = vec![None; n];
    let mut in_window = vec![false; n];
    // The window's bottoms and tops, sorted.
    let (mut lows, mut highs): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    let remove = |v: &mut Vec<f64>, y: f64| {
        let at = v.partition_point(|&w| w < y);
        v.remove(at);
    };
    let insert = |v: &mut Vec<f64>, y: f64| {
        let at = v.partition_point(|&w| w < y);
        v.insert(at, y);
    };
    loop {
        let open: Vec<usize> = by_lo.iter().copied().filter(|&i| !covered[i]).collect();
        if open.is_empty() {
            break;
        }
        let open_by_hi: Vec<usize> = by_hi.iter().copied().filter(|&i| !covered[i]).collect();
        lows.clear();
        highs.clear();
        in_window.iter_mut().for_each(|w| *w = false);
        let mut entering = 0;
        // The square holding most open geometries: (count, left, bottom).
        let mut best = (0usize, 0.0f64, 0.0f64);
        for (k, &i) in open.iter().enumerate() {
            let x = bounds[i].0.x;
            if k > 0 {
                let gone = open[k - 1];
                if in_window[gone] {
                    in_window[gone] = false;
                    remove(&mut lows, bounds[gone].0.y);
                    remove(&mut highs, bounds[gone].1.y);
                }
            }
            while entering < open_by_hi.len() && bounds[open_by_hi[entering]].1.x <= x + size + FIT {
                let j = open_by_hi[entering];
                entering += 1;
                if bounds[j].0.x >= x {
                    in_window[j] = true;
                    insert(&mut lows, bounds[j].0.y);
                    insert(&mut highs, bounds[j].1.y);
                }
            }
            if k > 0 && bounds[open[k - 1]].0.x == x {
                continue;
            }
            if column_best[i].is_none() {
                // In the square at height y lie those with lo.y ≥ y and
                // hi.y ≤ y + S; one no taller than S with lo.y < y has
                // hi.y < y + S, so the count is #(hi.y ≤ y + S) − #(lo.y < y).
                let mut here = (0usize, 0.0f64);
                let mut top = 0;
                for (m, &y) in lows.iter().enumerate() {
                    if m > 0 && lows[m - 1] == y {
                        continue;
                    }
                    while top < highs.len() && highs[top] <= y + size + FIT {
                        top += 1;
                    }
                    if top - m > here.0 {
                        here = (top - m, y);
                    }
                }
                column_best[i] = Some(here);
            }
            let (count, y) = column_best[i].unwrap();
            if count > best.0 {
                best = (count, x, y);
            }
        }
        let (_, x, y) = best;
        let inside: Vec<usize> = open
            .iter()
            .copied()
            .filter(|&i| {
                let (lo, hi) = bounds[i];
                lo.x >= x - FIT && hi.x <= x + size + FIT && lo.y >= y - FIT && hi.y <= y + size + FIT
            })
            .collect();
        if inside.is_empty() {
            // Cannot happen (every geometry fits a square anchored at itself);
            // should rounding say otherwise, the rest get a field each.
            fields.extend(open.into_iter().map(|g| vec![g]));
            break;
        }
        for &g in &inside {
            covered[g] = true;
        }
        // Columns whose squares could hold a covered geometry count again.
        let (from, to) = inside.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &g| (a.min(bounds[g].1.x - size - FIT), b.max(bounds[g].0.x)));
        for &i in &open {
            if bounds[i].0.x >= from && bounds[i].0.x <= to {
                column_best[i] = None;
            }
        }
        fields.push(inside);
    }
    fields
}

/// Dissolves fields whose geometries all fit into the others, smallest first.
fn dissolve_small_fields(mut fields: Vec<Vec<usize>>, bounds: &[(Point, Point)], size: f64) -> Vec<Vec<usize>> {
    let fits = |lo: Point, hi: Point| hi.x - lo.x <= size + FIT && hi.y - lo.y <= size + FIT;
    let mut order: Vec<usize> = (0..fields.len()).collect();
    order.sort_by_key(|&f| fields[f].len());
    let mut boxes: Vec<Option<(Point, Point)>> = fields.iter().map(|m| Some(group_bounds(bounds, m))).collect();
    for f in order {
        let mut trial = boxes.clone();
        trial[f] = None;
        let mut moves = Vec::new();
        let ok = fields[f].iter().all(|&g| {
            let (lo, hi) = bounds[g];
            // The other field whose box grows least.
            let best = (0..trial.len())
                .filter_map(|k| {
                    let (blo, bhi) = trial[k]?;
                    let (ulo, uhi) = bounds_of([&blo, &bhi, &lo, &hi].into_iter());
                    fits(ulo, uhi).then(|| (k, (uhi.x - ulo.x) * (uhi.y - ulo.y) - (bhi.x - blo.x) * (bhi.y - blo.y), (ulo, uhi)))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match best {
                Some((k, _, grown)) => {
                    trial[k] = Some(grown);
                    moves.push((g, k));
                    true
                }
                None => false,
            }
        });
        if ok {
            boxes = trial;
            for (g, k) in moves {
                fields[k].push(g);
            }
            fields[f].clear();
        }
    }
    fields.into_iter().filter(|m| !m.is_empty()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Geometry, Process};

    fn job(rects: &[(f64, f64, f64, f64)]) -> Job {
        let geometries = rects
            .iter()
            .enumerate()
            .map(|(i, &(x, y, w, h))| Geometry { arcs: Vec::new(), profile: Vec::new(),
                points: vec![Point::new(x, y), Point::new(x + w, y), Point::new(x + w, y + h), Point::new(x, y + h)],
                closed: true,
                process: 0,
                source: format!("r{i}"),
            })
            .collect();
        Job { source: "t".into(), geometries, processes: vec![Process { layer: "mark".into(), speed: 100.0, power: 1.0, passes: 1, fill: false }] }
    }

    fn check_cover(job: &Job, fields: &[Field], half: f64) {
        let mut seen = vec![0; job.geometries.len()];
        for f in fields {
            for &m in &f.members {
                seen[m] += 1;
                for p in &job.geometries[m].points {
                    assert!((p.x - f.center.x).abs() <= half + 1e-9 && (p.y - f.center.y).abs() <= half + 1e-9, "{} outside its field", job.geometries[m].source);
                }
            }
        }
        assert!(seen.iter().all(|&s| s == 1), "each geometry in exactly one field: {seen:?}");
    }

    #[test]
    fn a_row_of_small_parts_takes_the_fewest_fields() {
        // 10 parts of 5 mm every 10 mm along 95 mm: two 50 mm fields hold them
        // (an aligned grid from the first part's corner would too, but one from
        // the bounding box's centre would need three).
        let rects: Vec<_> = (0..10).map(|i| (10.0 + 10.0 * i as f64, 20.0, 5.0, 5.0)).collect();
        let job = job(&rects);
        let fields = cover(&job, 25.0, (300.0, 300.0)).unwrap();
        check_cover(&job, &fields, 25.0);
        assert_eq!(fields.len(), 2);
    }

    #[test]
    fn clusters_get_one_field_each_centred_on_their_content() {
        let mut rects = Vec::new();
        for (cx, cy) in [(50.0, 50.0), (200.0, 60.0), (120.0, 220.0)] {
            for k in 0..5 {
                rects.push((cx + 4.0 * k as f64, cy + 3.0 * k as f64, 2.0, 2.0));
            }
        }
        let job = job(&rects);
        let fields = cover(&job, 35.0, (300.0, 300.0)).unwrap();
        check_cover(&job, &fields, 35.0);
        assert_eq!(fields.len(), 3);
        for f in &fields {
            let (lo, hi) = group_bounds(&job.geometries.iter().map(|g| g.bounds()).collect::<Vec<_>>(), &f.members);
            assert!((f.center.x - (lo.x + hi.x) / 2.0).abs() < 1e-9 && (f.center.y - (lo.y + hi.y) / 2.0).abs() < 1e-9);
        }
    }

    #[test]
    fn random_parts_are_covered_once_and_better_than_one_per_part() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let rects: Vec<_> = (0..400).map(|_| (rng.random_range(0.0..280.0), rng.random_range(0.0..280.0), rng.random_range(0.5..15.0), rng.random_range(0.5..15.0))).collect();
        let job = job(&rects);
        let fields = cover(&job, 35.0, (300.0, 300.0)).unwrap();
        check_cover(&job, &fields, 35.0);
        // A fixed tiling whose squares overlap by the largest part (15 mm)
        // holds every part: steps of 55 mm, 6 x 6 = 36 fields over 295 mm.
        // The cover does better by a fifth at least; no cover beats the
        // area bound (295 / 70)² ≈ 18.
        assert!((18..=28).contains(&fields.len()), "{} fields", fields.len());
    }

    #[test]
    fn a_part_larger_than_the_field_is_named() {
        let job = job(&[(10.0, 10.0, 5.0, 5.0), (20.0, 20.0, 80.0, 5.0)]);
        let err = cover(&job, 35.0, (300.0, 300.0)).unwrap_err().to_string();
        assert!(err.contains("r1") && err.contains("stage-only"), "{err}");
    }
}
