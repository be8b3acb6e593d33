//! Oversize geometries in step-and-scan: a geometry larger than the scanner's
//! usable field cannot be marked from one stage position, so it is cut at
//! field borders into open pieces, each inside one field-sized cell. The
//! planner then treats the pieces like any other geometry: each is marked
//! within one field, one after another, and together they trace exactly the
//! original path (the border crossing points end one piece and start the
//! next). With `[scanner] split_oversize = false` such a job fails instead
//! ([`check_fits`]).

use crate::error::{Error, Result};
use crate::job::{Geometry, Job, Point};

/// Slack on "fits", as in the field cover: bounds are compared in floating point.
const FIT: f64 = 1e-9;

/// Whether a geometry's bounding box fits the usable square of side `size`.
fn fits(g: &Geometry, size: f64) -> bool {
    let (lo, hi) = g.bounds();
    hi.x - lo.x <= size + FIT && hi.y - lo.y <= size + FIT
}

/// `job` with every geometry larger than the usable field (`2 × usable_half`
/// square) replaced, in place, by its pieces; geometries that fit are kept
/// unchanged and in order.
///
/// A geometry is cut by a grid of square cells a hair smaller than the field
/// (so a piece fits despite rounding), anchored at its bounding box's
/// minimum: each segment (with the closing one of a closed geometry) is cut
/// where it crosses a cell border, and a new piece starts wherever the path
/// enters another cell. Pieces are open, keep the process, and are named
/// `<source> piece i/n`. The last and the first piece of a closed geometry
/// are joined when they lie in the same cell (they meet at its first vertex).
pub fn split_at_field_borders(job: &Job, usable_half: f64) -> Job {
    let size = 2.0 * usable_half;
    let mut geometries = Vec::with_capacity(job.geometries.len());
    for g in &job.geometries {
        if fits(g, size) {
            geometries.push(g.clone());
            continue;
        }
        let pieces = pieces(g, size * (1.0 - 1e-9));
        let n = pieces.len();
        geometries.extend(pieces.into_iter().enumerate().map(|(i, (points, from))| {
            // A raster line's pieces keep the processes of the segments they come from.
            let mut profile: Vec<usize> = if g.profile.is_empty() { Vec::new() } else { from.iter().map(|&s| g.profile[s]).collect() };
            let process = profile.first().copied().unwrap_or(g.process);
            if profile.iter().all(|&p| p == process) {
                profile.clear();
            }
            Geometry {
                points,
                closed: false,
                // A piece of a field is marked as points; its arcs are the whole's.
                arcs: Vec::new(),
                profile,
                process,
                source: format!("{} piece {}/{n}", g.source, i + 1),
            }
        }));
    }
    Job { source: job.source.clone(), geometries, processes: job.processes.clone() }
}

/// Fails, naming the first geometry larger than the usable field, when
/// splitting is off.
pub fn check_fits(job: &Job, usable_half: f64) -> Result<()> {
    let size = 2.0 * usable_half;
    match job.geometries.iter().find(|g| !fits(g, size)) {
        None => Ok(()),
        Some(g) => {
            let (lo, hi) = g.bounds();
            Err(Error::Plan(format!(
                "{}: {:.3} x {:.3} mm does not fit the scanner's usable field ({size} x {size} mm) and splitting is off in the config ([scanner] split_oversize = false); turn it on or use --mode stage-only",
                g.source,
                hi.x - lo.x,
                hi.y - lo.y
            )))
        }
    }
}

/// The pieces of `g` on a grid of cells of side `cell` anchored at its
/// bounding box's minimum, in path order, each with the index of the
/// segment of `g` each of its segments lies on.
fn pieces(g: &Geometry, cell: f64) -> Vec<(Vec<Point>, Vec<usize>)> {
    let (lo, _) = g.bounds();
    let n = g.points.len();
    let cell_of = |p: Point| (((p.x - lo.x) / cell).floor() as i64, ((p.y - lo.y) / cell).floor() as i64);
    // Slack for rounding at cell borders; with it a piece still spans at most
    // cell × (1 + 5e-10) < the field.
    let tol = cell * 2.5e-10;
    let inside = |c: (i64, i64), p: Point| {
        let (x0, y0) = (lo.x + c.0 as f64 * cell, lo.y + c.1 as f64 * cell);
        p.x >= x0 - tol && p.x <= x0 + cell + tol && p.y >= y0 - tol && p.y <= y0 + cell + tol
    };
    // Shorter bits (crossings of both grid lines at a cell corner, a hair
    // apart) are not worth a piece of their own.
    let min_len = cell * 1e-12;

    let mut segments: Vec<(Point, Point)> = g.points.windows(2).map(|w| (w[0], w[1])).collect();
    if g.closed && n > 2 {
        segments.push((g.points[n - 1], g.points[0]));
    }
    // Per piece: its cell, its points, the segment of `g` each segment lies on.
    type Piece = ((i64, i64), Vec<Point>, Vec<usize>);
    let mut out: Vec<Piece> = Vec::new();
    for (s, (a, b)) in segments.into_iter().enumerate() {
        let d = b - a;
        let len = d.norm();
        if len == 0.0 {
            continue;
        }
        // Parameters where the segment crosses a vertical or horizontal grid line.
        let mut ts = Vec::new();
        for (a0, d0, l0) in [(a.x, d.x, lo.x), (a.y, d.y, lo.y)] {
            if d0 == 0.0 {
                continue;
            }
            let (from, to) = (a0.min(a0 + d0), a0.max(a0 + d0));
            let (k0, k1) = (((from - l0) / cell).ceil() as i64, ((to - l0) / cell).floor() as i64);
            for k in k0..=k1 {
                let t = (l0 + k as f64 * cell - a0) / d0;
                if t > 0.0 && t < 1.0 {
                    ts.push(t);
                }
            }
        }
        ts.sort_by(f64::total_cmp);
        let mut kept = vec![0.0];
        for &t in &ts {
            if (t - kept[kept.len() - 1]) * len >= min_len && (1.0 - t) * len >= min_len {
                kept.push(t);
            }
        }
        kept.push(1.0);
        let at = |t: f64| if t == 0.0 { a } else if t == 1.0 { b } else { a + d * t };
        for w in kept.windows(2) {
            let (p, q) = (at(w[0]), at(w[1]));
            match out.last_mut() {
                // Along the path in the current cell (or on its border): go on.
                Some((c, piece, from)) if inside(*c, p) && inside(*c, q) && piece[piece.len() - 1] == p => {
                    piece.push(q);
                    from.push(s);
                }
                _ => out.push((cell_of(Point::new((p.x + q.x) / 2.0, (p.y + q.y) / 2.0)), vec![p, q], vec![s])),
            }
        }
    }
    // A closed path's last piece leads into its first: one piece if in the same cell.
    if g.closed && out.len() > 1 && out[0].0 == out[out.len() - 1].0 && out[out.len() - 1].1.last() == out[0].1.first() {
        let (_, mut last, mut from) = out.pop().unwrap();
        last.extend_from_slice(&out[0].1[1..]);
        from.extend_from_slice(&out[0].2);
        out[0].1 = last;
        out[0].2 = from;
    }
    out.into_iter().map(|(_, p, from)| (p, from)).filter(|(p, _)| p.windows(2).any(|w| w[0] != w[1])).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::Process;

    fn geometry(points: &[(f64, f64)], closed: bool, source: &str) -> Geometry {
        Geometry { arcs: Vec::new(), profile: Vec::new(), points: points.iter().map(|&(x, y)| Point::new(x, y)).collect(), closed, process: 0, source: source.into() }
    }

    fn job(geometries: Vec<Geometry>) -> Job {
        Job { source: "t.svg".into(), geometries, processes: vec![Process { layer: "mark".into(), speed: 100.0, power: 1.0, passes: 1, fill: false }] }
    }

    /// Every geometry fits the field; the lengths add up to the original's.
    fn check(original: &Job, split: &Job, half: f64) {
        for g in &split.geometries {
            let (lo, hi) = g.bounds();
            assert!(hi.x - lo.x <= 2.0 * half && hi.y - lo.y <= 2.0 * half, "{}: {:?}..{:?}", g.source, lo, hi);
            assert!(g.length() > 0.0, "{}: zero length", g.source);
        }
        let (a, b) = (original.mark_length(), split.mark_length());
        assert!((a - b).abs() <= 1e-6 * a, "length {a} became {b}");
    }

    #[test]
    fn a_long_line_across_three_cells_is_three_pieces() {
        let original = job(vec![geometry(&[(10.0, 40.0), (160.0, 40.0)], false, "line")]);
        let split = split_at_field_borders(&original, 32.0);
        check(&original, &split, 32.0);
        assert_eq!(split.geometries.len(), 3);
        let lens: Vec<f64> = split.geometries.iter().map(|g| g.length()).collect();
        assert!((lens[0] - 64.0).abs() < 1e-6 && (lens[1] - 64.0).abs() < 1e-6 && (lens[2] - 22.0).abs() < 1e-6, "{lens:?}");
        // In path order, each starting where the previous one ended.
        assert_eq!(split.geometries[0].points[0], Point::new(10.0, 40.0));
        for w in split.geometries.windows(2) {
            assert_eq!(w[0].points.last(), w[1].points.first());
        }
        assert_eq!(split.geometries[2].points.last(), Some(&Point::new(160.0, 40.0)));
        assert_eq!(split.geometries[1].source, "line piece 2/3");
        assert!(split.geometries.iter().all(|g| !g.closed && g.process == 0));
    }

    #[test]
    fn a_big_closed_square_is_split_into_pieces_that_trace_its_perimeter() {
        let original = job(vec![geometry(&[(20.0, 20.0), (220.0, 20.0), (220.0, 220.0), (20.0, 220.0)], true, "square")]);
        let split = split_at_field_borders(&original, 32.0);
        check(&original, &split, 32.0);
        assert!((split.mark_length() - 800.0).abs() < 1e-6);
        // 200 mm per side in 64 mm cells: 4 cells per side; the pieces meeting
        // at the corners share a cell, and the first and last join at the start.
        assert_eq!(split.geometries.len(), 12, "{:?}", split.geometries.iter().map(|g| &g.points).collect::<Vec<_>>());
        for w in split.geometries.windows(2) {
            assert_eq!(w[0].points.last(), w[1].points.first());
        }
        assert_eq!(split.geometries.last().unwrap().points.last(), split.geometries[0].points.first());
    }

    #[test]
    fn a_diagonal_zigzag_is_traced_exactly_in_fitting_pieces() {
        let pts = [(0.0, 0.0), (150.0, 130.0), (10.0, 250.0), (64.0, 64.0), (128.0, 128.0), (300.0, 5.0)];
        let original = job(vec![geometry(&pts, true, "zigzag")]);
        let split = split_at_field_borders(&original, 32.0);
        check(&original, &split, 32.0);
        for w in split.geometries.windows(2) {
            assert_eq!(w[0].points.last(), w[1].points.first());
        }
    }

    #[test]
    fn a_diagonal_through_cell_corners_leaves_no_slivers() {
        let original = job(vec![geometry(&[(0.0, 0.0), (200.0, 200.0)], false, "diagonal")]);
        let split = split_at_field_borders(&original, 32.0);
        check(&original, &split, 32.0);
        // ⌈200 / 64⌉ cells along the diagonal, nothing in the cells beside it.
        assert_eq!(split.geometries.len(), 4, "{:?}", split.geometries.iter().map(|g| &g.points).collect::<Vec<_>>());
    }

    #[test]
    fn a_path_back_into_a_cell_it_left_is_a_new_piece() {
        // A U of 100 x 10 mm: out along the bottom, back along the top.
        let original = job(vec![geometry(&[(0.0, 0.0), (100.0, 0.0), (100.0, 10.0), (0.0, 10.0)], false, "u")]);
        let split = split_at_field_borders(&original, 32.0);
        check(&original, &split, 32.0);
        let g = &split.geometries;
        assert_eq!(g.len(), 3);
        assert_eq!(g[1].points.len(), 4, "the turn is one piece: {:?}", g[1].points);
        assert!(g[0].points.iter().chain(&g[2].points).all(|p| p.x <= 64.0));
    }

    #[test]
    fn random_polylines_are_traced_exactly_in_fitting_pieces() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for case in 0..200 {
            let n = rng.random_range(2..12);
            let pts: Vec<(f64, f64)> = (0..n).map(|_| (rng.random_range(0.0..300.0), rng.random_range(0.0..300.0))).collect();
            let closed = case % 2 == 0;
            let original = job(vec![geometry(&pts, closed, "r")]);
            let half = rng.random_range(5.0..40.0);
            let split = split_at_field_borders(&original, half);
            check(&original, &split, half);
            for w in split.geometries.windows(2) {
                assert_eq!(w[0].points.last(), w[1].points.first(), "case {case}: pieces follow the path");
            }
            let g = &original.geometries[0];
            if !fits(g, 2.0 * half) {
                let first = split.geometries[0].points[0];
                assert!(closed || first == g.points[0], "case {case}");
                assert!(split.geometries.iter().all(|p| !p.closed));
            }
        }
    }

    #[test]
    fn small_geometries_are_unchanged_and_keep_their_place() {
        let small = geometry(&[(0.0, 0.0), (5.0, 0.0), (5.0, 5.0)], true, "small");
        let big = geometry(&[(0.0, 10.0), (100.0, 10.0)], false, "big");
        let other = geometry(&[(50.0, 50.0), (60.0, 52.0)], false, "other");
        let original = job(vec![small.clone(), big, other.clone()]);
        let split = split_at_field_borders(&original, 32.0);
        check(&original, &split, 32.0);
        assert_eq!(split.geometries.len(), 4);
        assert_eq!(split.geometries[0], small);
        assert_eq!(split.geometries[1].source, "big piece 1/2");
        assert_eq!(split.geometries[2].source, "big piece 2/2");
        assert_eq!(split.geometries[3], other);
        let only_small = job(vec![small, other]);
        assert_eq!(split_at_field_borders(&only_small, 32.0).geometries, only_small.geometries);
        assert!(check_fits(&only_small, 32.0).is_ok());
    }

    #[test]
    fn a_geometry_exactly_the_field_size_is_kept() {
        let square = geometry(&[(10.0, 10.0), (74.0, 10.0), (74.0, 74.0), (10.0, 74.0)], true, "exact");
        let original = job(vec![square.clone()]);
        assert_eq!(split_at_field_borders(&original, 32.0).geometries, vec![square]);
        assert!(check_fits(&original, 32.0).is_ok());
        // A hair more is split, into pieces that fit.
        let wider = job(vec![geometry(&[(10.0, 10.0), (74.001, 10.0), (74.001, 74.0), (10.0, 74.0)], true, "wider")]);
        let split = split_at_field_borders(&wider, 32.0);
        check(&wider, &split, 32.0);
        assert!(split.geometries.len() >= 2);
    }

    #[test]
    fn with_splitting_off_the_oversize_geometry_is_named() {
        let original = job(vec![geometry(&[(0.0, 0.0), (5.0, 5.0)], false, "a.svg: <path id=\"ok\">"), geometry(&[(0.0, 10.0), (100.0, 10.0)], false, "a.svg: <path id=\"long\">")]);
        let err = check_fits(&original, 32.0).unwrap_err().to_string();
        assert!(err.contains("<path id=\"long\">") && err.contains("split_oversize = false"), "{err}");
    }

    #[test]
    fn a_raster_line_split_at_field_borders_keeps_each_segments_power() {
        // 100 pixels of 1 mm along x, the power rising every 10: fields of 32 mm.
        let mut line = geometry(&(0..=100).map(|k| (k as f64, 5.0)).collect::<Vec<_>>(), false, "t.nc:3");
        line.profile = (0..100).map(|k| k / 10).collect();
        let mut original = job(vec![line]);
        original.processes = (0..10).map(|k| Process { layer: format!("S{k}"), speed: 100.0, power: k as f64, passes: 1, fill: false }).collect();
        let split = split_at_field_borders(&original, 16.0);
        check(&original, &split, 16.0);
        assert!(split.geometries.len() >= 4 && split.geometries.len() <= 8, "pieces, not a geometry per power: {}", split.geometries.len());
        // Every piece's segment has the power of the pixel it lies on.
        for g in &split.geometries {
            for (i, w) in g.points.windows(2).enumerate() {
                let process = if g.profile.is_empty() { g.process } else { g.profile[i] };
                let pixel = ((w[0].x + w[1].x) / 2.0).floor() as usize;
                assert_eq!(process, pixel / 10, "{}: segment {i} at x = {}", g.source, w[0].x);
            }
        }
    }
}
