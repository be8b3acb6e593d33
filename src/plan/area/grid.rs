//! Seed 004's discretisation of an area: the boundary offset inwards by the
//! tool's (the spot's) radius, an equidistant grid laid over it, the points
//! outside removed. The points are the genes of the seed's own test case
//! (`laserd bench fill`); laser fills use hatch segments (`hatch`).

use i_overlay::core::fill_rule::FillRule;
use i_overlay::float::simplify::SimplifyShape;

use crate::job::{segment_distance, Point};

/// The grid points `spacing` apart (on the machine's grid, rows from the
/// bottom, each from the left) inside the area `contours` enclose (nonzero)
/// and at least `radius` from its boundary.
pub fn points(contours: &[&[Point]], spacing: f64, radius: f64) -> Vec<Point> {
    let raw: Vec<Vec<[f64; 2]>> = contours.iter().filter(|c| c.len() >= 3).map(|c| c.iter().map(|p| [p.x, p.y]).collect()).collect();
    let rings: Vec<Vec<Point>> = raw.simplify_shape(FillRule::NonZero).into_iter().flatten().map(|c| c.into_iter().map(|[x, y]| Point::new(x, y)).collect()).collect();
    if rings.is_empty() {
        return Vec::new();
    }
    let (lo, hi) = crate::job::bounds_of(rings.iter().flatten());
    let edges = || rings.iter().flat_map(|r| (0..r.len()).map(move |i| (r[i], r[(i + 1) % r.len()])));
    // The shapes do not overlap: inside is an odd number of crossings.
    let inside = |p: Point| edges().filter(|(a, b)| (a.y > p.y) != (b.y > p.y) && p.x < a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x)).count() % 2 == 1;
    let clear = |p: Point| edges().all(|(a, b)| segment_distance(p, p, a, b) >= radius);
    let mut out = Vec::new();
    for j in (lo.y / spacing).ceil() as i64..=(hi.y / spacing).floor() as i64 {
        for i in (lo.x / spacing).ceil() as i64..=(hi.x / spacing).floor() as i64 {
            let p = Point::new(i as f64 * spacing, j as f64 * spacing);
            if inside(p) && clear(p) {
                out.push(p);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_lie_inside_clear_of_the_boundary_and_of_holes() {
        let outer = [Point::new(0.0, 0.0), Point::new(10.0, 0.0), Point::new(10.0, 10.0), Point::new(0.0, 10.0)];
        let hole = [Point::new(4.0, 4.0), Point::new(4.0, 6.0), Point::new(6.0, 6.0), Point::new(6.0, 4.0)];
        let got = points(&[&outer, &hole], 1.0, 1.0);
        // 1..=9 both ways (1 from the outline is clear), less the hole's 4..=6.
        assert_eq!(got.len(), 81 - 9);
        assert!(got.iter().all(|p| p.x >= 1.0 && p.x <= 9.0 && !(p.x >= 4.0 && p.x <= 6.0 && p.y >= 4.0 && p.y <= 6.0)));
        assert_eq!(points(&[&outer, &hole], 1.0, 1.5).len(), 49 - 25, "2..=8, less 3..=7");
    }
}
