//! Containment: per contour the smallest closed contour around it (candidates
//! from an R-tree of contour boxes, decided by a crossing-number test), and
//! the levels of the tree this makes.

use rstar::primitives::GeomWithData;
use rstar::{RTree, AABB};

use super::contours::signed_area;
use super::{rect, Box2};
use crate::job::{bounds_of, Point};

/// A contour as containment sees it: its vertices, and whether it is closed.
pub(super) type Outline<'a> = (&'a [Point], bool);

/// Per contour: the smallest closed contour containing it.
pub(super) fn containment(chains: &[Outline], tol: f64) -> Vec<Option<usize>> {
    let bounds: Vec<(Point, Point)> = chains.iter().map(|c| bounds_of(c.0.iter())).collect();
    let areas: Vec<f64> = chains.iter().map(|&(points, closed)| if closed { signed_area(points).abs() } else { 0.0 }).collect();
    let tree: RTree<Box2> = RTree::bulk_load(
        chains
            .iter()
            .enumerate()
            .filter(|(_, c)| c.1)
            .map(|(k, _)| GeomWithData::new(rect(bounds[k].0, bounds[k].1), (k, 0)))
            .collect(),
    );
    let holds = |outer: (Point, Point), inner: (Point, Point)| {
        outer.0.x <= inner.0.x + tol
            && outer.0.y <= inner.0.y + tol
            && outer.1.x >= inner.1.x - tol
            && outer.1.y >= inner.1.y - tol
    };
    (0..chains.len())
        .map(|a| {
            let (lo, hi) = bounds[a];
            let mut candidates: Vec<usize> = tree
                .locate_in_envelope_intersecting(AABB::from_corners([lo.x, lo.y], [hi.x, hi.y]))
                .map(|b| b.data.0)
                .filter(|&b| b != a && areas[b] > areas[a] && holds(bounds[b], bounds[a]))
                .collect();
            candidates.sort_by(|&x, &y| areas[x].total_cmp(&areas[y]).then(x.cmp(&y)));
            candidates.into_iter().find(|&b| inside(chains[a], chains[b].0, tol))
        })
        .collect()
}

/// Where a point lies with respect to a closed polygon.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Inside,
    Outside,
    /// Within the tolerance of its boundary: says nothing.
    Boundary,
}

/// Chain `a` lies inside polygon `b`: decided by its first vertex (or segment
/// midpoint) off `b`'s boundary; a chain all on the boundary is not inside.
fn inside((points, closed): Outline, b: &[Point], tol: f64) -> bool {
    let n = points.len();
    let vertices = points.iter().copied();
    let midpoints = (0..if closed { n } else { n - 1 }).map(|j| nalgebra::center(&points[j], &points[(j + 1) % n]));
    vertices.chain(midpoints).map(|p| side(p, b, tol)).find(|&s| s != Side::Boundary) == Some(Side::Inside)
}

/// Crossing-number test (a ray to +x crosses the boundary an odd number of
/// times from inside), with points within `tol` of an edge on the boundary.
pub fn side(p: Point, polygon: &[Point], tol: f64) -> Side {
    let n = polygon.len();
    let mut odd = false;
    for i in 0..n {
        let (a, b) = (polygon[i], polygon[(i + 1) % n]);
        let d = b - a;
        if d.norm_squared() == 0.0 {
            continue;
        }
        let t = ((p - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
        if (a + d * t - p).norm_squared() <= tol * tol {
            return Side::Boundary;
        }
        if (a.y > p.y) != (b.y > p.y) && a.x + (p.y - a.y) / d.y * d.x > p.x {
            odd = !odd;
        }
    }
    if odd {
        Side::Inside
    } else {
        Side::Outside
    }
}

/// Per contour: its depth in the containment tree.
pub(super) fn levels(outer: &[Option<usize>]) -> Vec<usize> {
    let mut level: Vec<Option<usize>> = vec![None; outer.len()];
    for k in 0..outer.len() {
        // Up to the first contour whose level is known (or the top), then down.
        let mut path = vec![k];
        while let Some(o) = outer[*path.last().unwrap()] {
            if level[o].is_some() {
                break;
            }
            path.push(o);
        }
        let top = *path.last().unwrap();
        let first = outer[top].map_or(0, |o| level[o].unwrap_or(0) + 1);
        for (l, &c) in (first..).zip(path.iter().rev()) {
            level[c] = Some(l);
        }
    }
    level.into_iter().map(|l| l.unwrap_or(0)).collect()
}
