//! Common cuts: where the boundaries of two closed geometries coincide, found
//! through an R-tree of segment boxes, their ends welded to one point so that
//! both copies meet their neighbours exactly; and the ranks of contours in a
//! grid of parts joined by them.

use std::collections::{HashMap, VecDeque};

use rstar::primitives::{GeomWithData, Rectangle};
use rstar::RTree;

use super::contours::{cross, Chain, Shape};
use super::{Box2, CommonCut};
use crate::job::{bounds_of, Point};

/// Elements on exactly two contours, with the two contours, in element order.
pub fn common_cuts(contours: &[Vec<usize>], element_count: usize) -> Vec<CommonCut> {
    let mut owners: Vec<Vec<usize>> = vec![Vec::new(); element_count];
    for (k, contour) in contours.iter().enumerate() {
        for &e in contour {
            owners[e].push(k);
        }
    }
    owners
        .iter()
        .enumerate()
        .filter(|(_, o)| o.len() == 2)
        .map(|(element, o)| CommonCut { element, contours: (o[0], o[1]) })
        .collect()
}

/// Where segments of two different closed shapes overlap. Returns per shape
/// and segment the parameters (0..1) to split it at, and per shape and
/// vertex whether the vertex ends an overlap; both kinds of point are welded.
#[allow(clippy::type_complexity)]
pub(super) fn find_overlaps(shapes: &[Shape], tol: f64) -> (Vec<Vec<Vec<f64>>>, Vec<Vec<bool>>) {
    let mut splits: Vec<Vec<Vec<f64>>> = shapes.iter().map(|s| vec![Vec::new(); s.segments()]).collect();
    let mut ends: Vec<Vec<bool>> = shapes.iter().map(|s| vec![false; s.points.len()]).collect();
    // Boxes grown by half the tolerance meet when the segments' boxes are
    // within the tolerance; one join of the tree with itself finds them all.
    let half = 0.5 * tol;
    let boxes: Vec<Box2> = shapes
        .iter()
        .enumerate()
        .filter(|(_, s)| s.closed)
        .flat_map(|(g, s)| {
            (0..s.segments()).map(move |i| {
                let (a, b) = s.segment(i);
                let (lo, hi) = bounds_of([a, b].iter());
                let r = Rectangle::from_corners([lo.x - half, lo.y - half], [hi.x + half, hi.y + half]);
                GeomWithData::new(r, (g, i))
            })
        })
        .collect();
    let tree = RTree::bulk_load(boxes);
    for (x, y) in tree.intersection_candidates_with_other_tree(&tree) {
        let ((g, i), (h, j)) = (x.data, y.data);
        if h <= g {
            continue;
        }
        let (s, t) = (shapes[g].segment(i), shapes[h].segment(j));
        if let Some(overlap_ends) = overlap(s, t, tol) {
            for (ps, pt) in overlap_ends {
                mark(&shapes[g], &mut splits[g], &mut ends[g], i, ps, tol);
                mark(&shapes[h], &mut splits[h], &mut ends[h], j, pt, tol);
            }
        }
    }
    (splits, ends)
}

/// Notes an overlap's end at parameter `t` of segment `i`: the vertex it is
/// at (within `tol`), or a split.
fn mark(shape: &Shape, splits: &mut [Vec<f64>], ends: &mut [bool], i: usize, t: f64, tol: f64) {
    let (a, b) = shape.segment(i);
    let len = (b - a).norm();
    if t * len <= tol {
        ends[i] = true;
    } else if (1.0 - t) * len <= tol {
        ends[(i + 1) % shape.points.len()] = true;
    } else {
        splits[i].push(t);
    }
}

/// The overlap of two segments lying on one line within `tol` and sharing
/// more than `tol` of their length: its two ends, each as the parameter on
/// `s` and on `t` (0 at a segment's start, 1 at its end).
fn overlap(s: (Point, Point), t: (Point, Point), tol: f64) -> Option<[(f64, f64); 2]> {
    let len = |seg: (Point, Point)| (seg.1 - seg.0).norm();
    let s_longer = len(s) >= len(t);
    let (long, short) = if s_longer { (s, t) } else { (t, s) };
    let long_len = len(long);
    if len(short) <= tol {
        return None;
    }
    // The shorter one's ends near the longer one's line: collinear.
    let u = (long.1 - long.0) / long_len;
    if cross(u, short.0 - long.0).abs() > tol || cross(u, short.1 - long.0).abs() > tol {
        return None;
    }
    let (p0, p1) = (u.dot(&(short.0 - long.0)), u.dot(&(short.1 - long.0)));
    let (lo, hi) = (p0.min(p1).max(0.0), p0.max(p1).min(long_len));
    if hi - lo <= tol {
        return None;
    }
    let on_short = |along: f64| {
        let x = long.0 + u * along;
        let d = short.1 - short.0;
        ((x - short.0).dot(&d) / d.norm_squared()).clamp(0.0, 1.0)
    };
    let ends = [(lo / long_len, on_short(lo)), (hi / long_len, on_short(hi))];
    Some(ends.map(|(l, sh)| if s_longer { (l, sh) } else { (sh, l) }))
}

/// Moves the ends of overlaps, shape by shape, onto the first such point
/// within `tol` of another shape (one point per shape at most), so that the
/// two copies of a common cut have the very same end points. Each welded
/// point gets an id, its vertices [`Chain::weld`].
pub(super) fn weld(chains: &mut [Chain], tol: f64) {
    // A hash grid of `tol` cells: a point's neighbours within `tol` lie in the
    // 3 × 3 cells around its own.
    let cell = |p: Point| ((p.x / tol).floor() as i64, (p.y / tol).floor() as i64);
    let mut grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    // Each welded point, with the shapes and their points moved onto it.
    let mut welded: Vec<(Point, Vec<(usize, Point)>)> = Vec::new();
    for (g, chain) in chains.iter_mut().enumerate() {
        for j in 0..chain.points.len() {
            if !chain.ends_overlap[j] {
                continue;
            }
            let p = chain.points[j];
            let (cx, cy) = cell(p);
            let mut best: Option<(f64, usize)> = None;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for &w in grid.get(&(cx + dx, cy + dy)).into_iter().flatten() {
                        let d = (welded[w].0 - p).norm();
                        // One point per shape, unless the shape itself comes
                        // back to the very point (a region pinched where a
                        // part touches the plate's edge).
                        let own = welded[w].1.iter().any(|&(h, q)| h == g && q != p);
                        if d <= tol * (1.0 + 1e-9) && !own && best.is_none_or(|(bd, _)| d < bd) {
                            best = Some((d, w));
                        }
                    }
                }
            }
            let w = match best {
                Some((_, w)) => w,
                None => {
                    welded.push((p, Vec::new()));
                    grid.entry((cx, cy)).or_default().push(welded.len() - 1);
                    welded.len() - 1
                }
            };
            welded[w].1.push((g, p));
            chain.points[j] = welded[w].0;
            chain.weld[j] = Some(w);
        }
    }
}

/// Per chain and sub-segment: the other copy of it, (chain, sub-segment), if
/// it is a common cut. Two sub-segments are copies when they join the same two
/// welded points; where three shapes coincide the first two are paired.
pub(super) fn match_common_cuts(chains: &[Chain]) -> Vec<Vec<Option<(usize, usize)>>> {
    let mut by_ends: HashMap<(usize, usize), Vec<(usize, usize)>> = HashMap::new();
    for (g, chain) in chains.iter().enumerate() {
        for j in 0..chain.subsegments() {
            if let (Some(a), Some(b)) = (chain.weld[j], chain.weld[chain.next(j)]) {
                by_ends.entry((a.min(b), a.max(b))).or_default().push((g, j));
            }
        }
    }
    let mut partners: Vec<Vec<Option<(usize, usize)>>> = chains.iter().map(|c| vec![None; c.subsegments()]).collect();
    for copies in by_ends.values() {
        let first = copies[0];
        if let Some(&second) = copies.iter().find(|c| c.0 != first.0) {
            partners[first.0][first.1] = Some(second);
            partners[second.0][second.1] = Some(first);
        }
    }
    partners
}

/// Per contour: how deep it lies inside a grid of contours joined by common
/// cuts (see [`Topology::ranks`](super::Topology::ranks)).
pub(super) fn ranks(contours: &[Vec<usize>], element_count: usize, common_cuts: &[CommonCut]) -> Vec<usize> {
    let k = contours.len();
    let mut owners = vec![0u8; element_count];
    for c in contours {
        for &e in c {
            owners[e] = owners[e].saturating_add(1);
        }
    }
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); k];
    for cc in common_cuts {
        neighbours[cc.contours.0].push(cc.contours.1);
        neighbours[cc.contours.1].push(cc.contours.0);
    }
    let mut rank: Vec<Option<usize>> = vec![None; k];
    let mut queue = VecDeque::new();
    for c in 0..k {
        if neighbours[c].is_empty() || contours[c].iter().any(|&e| owners[e] == 1) {
            rank[c] = Some(0);
            queue.push_back(c);
        }
    }
    while let Some(c) = queue.pop_front() {
        let r = rank[c].unwrap_or(0) + 1;
        for &d in &neighbours[c] {
            if rank[d].is_none() {
                rank[d] = Some(r);
                queue.push_back(d);
            }
        }
    }
    // Contours no free edge can be reached from (shapes drawn on top of each
    // other all round): nothing lies outside them, rank 0.
    rank.into_iter().map(|r| r.unwrap_or(0)).collect()
}
