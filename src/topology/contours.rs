//! Contours and their elements: each geometry cleaned (repeated vertices
//! dropped, degenerate shapes refused), then cut into elements at its corners
//! and where a common cut begins or ends.

use super::Element;
use crate::error::{Error, Result};
use crate::job::{bounds_of, Geometry, Point};

/// Points closer than this (mm) are one point: repeated vertices are dropped.
const SAME_POINT_MM: f64 = 1e-9;

/// A geometry's points without repeats, checked.
pub(super) struct Shape {
    pub(super) points: Vec<Point>,
    pub(super) closed: bool,
}

impl Shape {
    pub(super) fn segments(&self) -> usize {
        if self.closed {
            self.points.len()
        } else {
            self.points.len() - 1
        }
    }

    pub(super) fn segment(&self, i: usize) -> (Point, Point) {
        (self.points[i], self.points[(i + 1) % self.points.len()])
    }
}

pub(super) fn clean(g: &Geometry) -> Result<Shape> {
    let bad = |why: &str| Err(Error::Plan(format!("{}: {why}", g.source)));
    if g.points.iter().any(|p| !(p.x.is_finite() && p.y.is_finite())) {
        return bad("a coordinate is not a finite number");
    }
    let mut points: Vec<Point> = Vec::with_capacity(g.points.len());
    for &p in &g.points {
        if points.last().is_none_or(|q| (p - q).norm() > SAME_POINT_MM) {
            points.push(p);
        }
    }
    if g.closed {
        while points.len() > 1 && (points[points.len() - 1] - points[0]).norm() <= SAME_POINT_MM {
            points.pop();
        }
        if points.len() < 3 {
            return bad("a closed shape needs at least 3 distinct points");
        }
        let (lo, hi) = bounds_of(points.iter());
        // Relative to its box, so that a thin but real part passes.
        if signed_area(&points).abs() <= 1e-9 * (hi - lo).norm_squared() {
            return bad("a closed shape of no area (degenerate polygon)");
        }
    } else if points.len() < 2 {
        return bad("an open shape needs at least 2 distinct points");
    }
    Ok(Shape { points, closed: g.closed })
}

pub(super) fn signed_area(points: &[Point]) -> f64 {
    let n = points.len();
    0.5 * (0..n).map(|i| cross(points[i].coords, points[(i + 1) % n].coords)).sum::<f64>()
}

pub(super) fn cross(a: nalgebra::Vector2<f64>, b: nalgebra::Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// A shape's polyline with the overlaps' split points added. Vertex j is
/// followed by sub-segment j (to vertex j + 1, cyclically when closed).
pub(super) struct Chain {
    pub(super) points: Vec<Point>,
    pub(super) closed: bool,
    /// Per vertex: it ends an overlap (until [`weld`](super::common_cuts::weld)).
    pub(super) ends_overlap: Vec<bool>,
    /// Per vertex: the welded point it was moved to (set by [`weld`](super::common_cuts::weld)).
    pub(super) weld: Vec<Option<usize>>,
}

impl Chain {
    pub(super) fn new(shape: &Shape, splits: Vec<Vec<f64>>, ends: Vec<bool>, tol: f64) -> Chain {
        let mut points = Vec::with_capacity(shape.points.len());
        let mut ends_overlap = Vec::with_capacity(shape.points.len());
        for (i, mut ts) in splits.into_iter().enumerate() {
            points.push(shape.points[i]);
            ends_overlap.push(ends[i]);
            let (a, b) = shape.segment(i);
            let len = (b - a).norm();
            ts.sort_by(f64::total_cmp);
            let mut last = 0.0;
            for t in ts {
                // The same end found from two sides (or two ends within the
                // tolerance) lands twice; keep one, and no piece shorter than it.
                if (t - last) * len > tol {
                    points.push(a + (b - a) * t);
                    ends_overlap.push(true);
                    last = t;
                }
            }
        }
        if !shape.closed {
            points.push(shape.points[shape.points.len() - 1]);
            ends_overlap.push(ends[shape.points.len() - 1]);
        }
        let weld = vec![None; points.len()];
        Chain { points, closed: shape.closed, ends_overlap, weld }
    }

    pub(super) fn subsegments(&self) -> usize {
        if self.closed {
            self.points.len()
        } else {
            self.points.len() - 1
        }
    }

    pub(super) fn next(&self, j: usize) -> usize {
        (j + 1) % self.points.len()
    }
}

/// What a sub-segment belongs to while elements are made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Label {
    /// A copy of a common cut whose element an earlier shape made.
    Follow(usize),
    /// The shape's own, shared with that later shape or with none.
    Own(Option<usize>),
}

/// Elements and contours, shape by shape: a shape makes the
/// elements of its own sub-segments and of the common cuts it shares with
/// later shapes, and lists the elements an earlier shape made for the common
/// cuts they share.
pub(super) fn elements(
    chains: &[Chain],
    partners: &[Vec<Option<(usize, usize)>>],
    cos_corner: f64,
) -> (Vec<Element>, Vec<Vec<usize>>) {
    let mut pieces: Vec<Element> = Vec::new();
    let mut contours: Vec<Vec<usize>> = Vec::with_capacity(chains.len());
    let mut element_of: Vec<Vec<usize>> = Vec::with_capacity(chains.len());
    for (g, chain) in chains.iter().enumerate() {
        let m = chain.subsegments();
        let labels: Vec<Label> = (0..m)
            .map(|j| match partners[g][j] {
                Some((h, k)) if h < g => Label::Follow(element_of[h][k]),
                Some((h, _)) => Label::Own(Some(h)),
                None => Label::Own(None),
            })
            .collect();
        // breaks[j]: an element ends at vertex j (sub-segment j starts a new one).
        let n = chain.points.len();
        let mut breaks: Vec<bool> = (0..n)
            .map(|j| {
                if !chain.closed && (j == 0 || j == n - 1) {
                    return true;
                }
                let (before, after) = ((j + m - 1) % m, j % m);
                match (labels[before], labels[after]) {
                    (Label::Own(p), Label::Own(q)) => p != q || corner(chain, j, cos_corner),
                    (x, y) => x != y,
                }
            })
            .collect();
        if chain.closed && breaks.iter().filter(|&&b| b).count() < 2 {
            add_even_breaks(chain, &mut breaks);
        }
        let mut own_element = vec![usize::MAX; m];
        let mut contour = Vec::new();
        let start = if chain.closed { breaks.iter().position(|&b| b).unwrap_or(0) } else { 0 };
        let mut j = start;
        loop {
            let run_start = j;
            loop {
                j = chain.next(j);
                if breaks[j] || j == run_start {
                    break;
                }
            }
            let run: Vec<usize> = (0..).map(|s| (run_start + s) % n).take_while(|&v| v != j).collect();
            let e = match labels[run_start] {
                Label::Follow(e) => e,
                Label::Own(shared_with) => {
                    let mut points: Vec<Point> = run.iter().map(|&v| chain.points[v]).collect();
                    points.push(chain.points[j]);
                    pieces.push(Element { geometry: g, shared_with, points });
                    pieces.len() - 1
                }
            };
            contour.push(e);
            for v in run {
                own_element[v] = e;
            }
            if j == start || (!chain.closed && j == n - 1) {
                break;
            }
        }
        contours.push(contour);
        element_of.push(own_element);
    }
    (pieces, contours)
}

/// The direction turns at vertex j by more than the corner angle.
fn corner(chain: &Chain, j: usize, cos_corner: f64) -> bool {
    let n = chain.points.len();
    let (p, q, r) = (chain.points[(j + n - 1) % n], chain.points[j], chain.points[(j + 1) % n]);
    let (d0, d1) = (q - p, r - q);
    let norms = d0.norm() * d1.norm();
    norms > 0.0 && d0.dot(&d1) < cos_corner * norms
}

/// Breaks a closed chain with fewer than 2 breaks into up to 4 runs of equal
/// length, from its break if it has one.
fn add_even_breaks(chain: &Chain, breaks: &mut [bool]) {
    let n = chain.points.len();
    let start = breaks.iter().position(|&b| b).unwrap_or(0);
    let parts = n.min(4);
    let total: f64 = (0..n).map(|j| (chain.points[chain.next(j)] - chain.points[j]).norm()).sum();
    breaks[start] = true;
    let mut along = 0.0;
    let mut part = 1;
    for s in 0..n - 1 {
        let j = (start + s) % n;
        along += (chain.points[chain.next(j)] - chain.points[j]).norm();
        // Vertex j + 1 ends part `part` once it is past that part's share;
        // leave enough vertices for the parts still to come.
        if part < parts && (along >= total * part as f64 / parts as f64 || n - 1 - s <= parts - part) {
            breaks[chain.next(j)] = true;
            part += 1;
        }
    }
}
