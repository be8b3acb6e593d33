//! Cutting topology from geometry: a [`Job`]'s polylines turned into an
//! End-point Cutting Problem [`Instance`], with what it takes to map a route
//! back to the polylines to mark.
//!
//! * **Contours**: geometry k is contour k, open or closed. An open geometry
//!   can be an inner contour (engraving on a part is done before the part
//!   falls), never an outer one.
//! * **Elements**: each polyline is split at its corners (a turn sharper than
//!   [`TopologyOptions::corner_angle_deg`]) and where a common cut begins or
//!   ends, so a flattened arc stays one element. A closed polyline without two
//!   such breaks (a flattened circle) is split into up to 4 arcs of equal
//!   length, so that it can be entered at more than one place.
//! * **Common cuts**: where the boundaries of two closed geometries coincide
//!   (collinear overlapping segments within
//!   [`TopologyOptions::common_cut_tolerance_mm`], as two parts nested side by
//!   side and each exported whole), the overlap is one element on both
//!   contours, cut once. Segments are split at the ends of partial overlaps,
//!   and the ends of every overlap are welded to one point, so the shared
//!   element and its neighbours on either contour meet exactly (no pierce).
//! * **Inner/outer**: the smallest closed contour that contains another is
//!   its direct outer ([`Instance::inner_outer`] holds direct relations only).
//! * **Levels, ranks and groups** (seed 001, "contour levels, ranks and
//!   groups"): see the fields of [`CuttingModel`].
//!
//! Both searches go through R-trees (segment boxes for common cuts, contour
//! boxes for containment), so a sheet of thousands of contours and a hundred
//! thousand segments builds in well under a second.

use std::collections::{HashMap, VecDeque};

use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};

use super::{Cut, Element, Instance, Metric};
use crate::error::{Error, Result};
use crate::job::{bounds_of, Job, Point};

/// Points closer than this (mm) are one point: repeated vertices are dropped.
const SAME_POINT_MM: f64 = 1e-9;

/// How geometry becomes elements and common cuts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TopologyOptions {
    /// Boundary pieces of two closed geometries within this distance (mm) of
    /// each other, overlapping by more than it, are one common cut. It also
    /// bounds how far a vertex moves when the ends of a common cut are welded.
    pub common_cut_tolerance_mm: f64,
    /// A vertex where the direction turns by more than this (degrees) is a
    /// corner and ends an element; gentler turns (a flattened arc) do not.
    pub corner_angle_deg: f64,
}

impl Default for TopologyOptions {
    fn default() -> Self {
        TopologyOptions { common_cut_tolerance_mm: 0.01, corner_angle_deg: 30.0 }
    }
}

/// The piece of a polyline that one element stands for.
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// The geometry the points belong to; for a common cut the first of its
    /// two geometries (the lower index), whose coordinates it keeps.
    pub geometry: usize,
    /// The other geometry of a common cut.
    pub shared_with: Option<usize>,
    /// The polyline from the element's `a` to its `b` (at least 2 points).
    pub points: Vec<Point>,
}

impl Piece {
    /// The geometries this piece is marked for: one, or two for a common cut.
    fn geometries(&self) -> Vec<usize> {
        std::iter::once(self.geometry).chain(self.shared_with).collect()
    }
}

/// A job as a cutting problem. Contour k is the job's geometry k.
#[derive(Debug, Clone)]
pub struct CuttingModel {
    /// Elements, contours, inner/outer pairs and common cuts; the depot as
    /// given, Euclidean distances, no pierce cost (set `pierce_cost` for the
    /// machine at hand).
    pub instance: Instance,
    /// Per element: the polyline it marks.
    pub pieces: Vec<Piece>,
    /// Per contour: its direct outer contour, the smallest closed contour that
    /// contains it (None on the sheet itself).
    pub outer: Vec<Option<usize>>,
    /// Per contour: its depth in the containment tree. Level 0 has no outer
    /// contour; a level x contour's outer is level x - 1 (a part 0, its holes
    /// 1, a part nested in a hole 2, …).
    pub levels: Vec<usize>,
    /// Per contour: how deep it lies inside a "grid" of contours joined by
    /// common cuts. Rank 0: a contour with an element of its own (not a common
    /// cut), which borders the scrap around the grid, or with no common cut at
    /// all; rank r: the fewest common cuts to cross to reach a rank 0 contour.
    /// A cell in the middle of a 3 × 3 grid is rank 1. The paper's contour
    /// order construction orders the contours of a group from the highest rank
    /// to the lowest, so that common cuts come before the contours around them.
    pub ranks: Vec<usize>,
    /// Per contour: its group, numbered from 0 in contour order. A group is a
    /// set of contours linked by inner/outer relations or common cuts (seed
    /// 001): a part with its holes and the parts nested in them, and every part
    /// sharing a common cut with any of these.
    pub groups: Vec<usize>,
}

impl CuttingModel {
    /// Number of groups.
    pub fn group_count(&self) -> usize {
        self.groups.iter().max().map_or(0, |&g| g + 1)
    }

    /// A route (cuts of this model's elements) as polylines to mark, each with
    /// its geometry: cuts that go on exactly where the previous one ended, of a
    /// geometry they have in common, are one polyline (no pierce between
    /// them). A common cut is marked for either of its geometries, so it joins
    /// the polyline of whichever of its two contours it continues.
    pub fn polylines(&self, route: &[Cut]) -> Vec<(usize, Vec<Point>)> {
        let mut out: Vec<(usize, Vec<Point>)> = Vec::new();
        // The geometries the current polyline can still be marked for.
        let mut candidates: Vec<usize> = Vec::new();
        for &cut in route {
            let piece = &self.pieces[cut.element];
            let mut points = piece.points.clone();
            if cut.reversed {
                points.reverse();
            }
            let own = piece.geometries();
            let common: Vec<usize> = candidates.iter().copied().filter(|g| own.contains(g)).collect();
            match out.last_mut() {
                Some((geometry, line)) if !common.is_empty() && line.last() == points.first() => {
                    line.extend_from_slice(&points[1..]);
                    *geometry = common[0];
                    candidates = common;
                }
                _ => {
                    out.push((own[0], points));
                    candidates = own;
                }
            }
        }
        out
    }
}

/// Builds the cutting model of `job`, the route starting and ending at `depot`.
/// Pieces keep the geometries' vertices, except that the ends of common cuts
/// may move (by the tolerance at most) onto the first geometry's.
/// Errors (naming the geometry's source) on non-finite coordinates and on
/// degenerate shapes: an open polyline of fewer than 2 distinct points, a
/// closed one of fewer than 3 or of no area.
pub fn build(job: &Job, depot: Point, options: &TopologyOptions) -> Result<CuttingModel> {
    let tol = options.common_cut_tolerance_mm;
    if !(tol.is_finite() && tol > 0.0) {
        return Err(Error::Plan(format!("topology: common_cut_tolerance_mm must be a positive number, not {tol}")));
    }
    let angle = options.corner_angle_deg;
    if !(angle.is_finite() && angle > 0.0 && angle <= 180.0) {
        return Err(Error::Plan(format!("topology: corner_angle_deg must be in (0, 180], not {angle}")));
    }
    let shapes = job.geometries.iter().map(clean).collect::<Result<Vec<_>>>()?;
    let (splits, ends_overlap) = find_overlaps(&shapes, tol);
    let mut chains: Vec<Chain> =
        shapes.iter().zip(splits).zip(ends_overlap).map(|((s, sp), e)| Chain::new(s, sp, e, tol)).collect();
    weld(&mut chains, tol);
    let partners = match_common_cuts(&chains);
    let (pieces, contours) = elements(&chains, &partners, angle.to_radians().cos());

    let outer = containment(&chains, tol);
    let inner_outer: Vec<(usize, usize)> = outer.iter().enumerate().filter_map(|(k, o)| o.map(|o| (k, o))).collect();
    let elements = pieces.iter().map(|p| Element { a: p.points[0], b: p.points[p.points.len() - 1] }).collect();
    let instance = Instance { elements, contours, inner_outer, depot, metric: Metric::Euclidean, pierce_cost: 0.0 };
    let levels = levels(&outer);
    let ranks = ranks(&instance);
    let groups = groups(&instance);
    Ok(CuttingModel { instance, pieces, outer, levels, ranks, groups })
}

/// A geometry's points without repeats, checked.
struct Shape {
    points: Vec<Point>,
    closed: bool,
}

impl Shape {
    fn segments(&self) -> usize {
        if self.closed {
            self.points.len()
        } else {
            self.points.len() - 1
        }
    }

    fn segment(&self, i: usize) -> (Point, Point) {
        (self.points[i], self.points[(i + 1) % self.points.len()])
    }
}

fn clean(g: &crate::job::Geometry) -> Result<Shape> {
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

fn signed_area(points: &[Point]) -> f64 {
    let n = points.len();
    0.5 * (0..n).map(|i| cross(points[i].coords, points[(i + 1) % n].coords)).sum::<f64>()
}

fn cross(a: nalgebra::Vector2<f64>, b: nalgebra::Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

type Box2 = GeomWithData<Rectangle<[f64; 2]>, (usize, usize)>;

fn rect(lo: Point, hi: Point) -> Rectangle<[f64; 2]> {
    Rectangle::from_corners([lo.x, lo.y], [hi.x, hi.y])
}

/// Where segments of two different closed shapes overlap. Returns per shape
/// and segment the parameters (0..1) to split it at, and per shape and
/// vertex whether the vertex ends an overlap; both kinds of point are welded.
#[allow(clippy::type_complexity)]
fn find_overlaps(shapes: &[Shape], tol: f64) -> (Vec<Vec<Vec<f64>>>, Vec<Vec<bool>>) {
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

/// A shape's polyline with the overlaps' split points added. Vertex j is
/// followed by sub-segment j (to vertex j + 1, cyclically when closed).
struct Chain {
    points: Vec<Point>,
    closed: bool,
    /// Per vertex: it ends an overlap (until [`weld`]).
    ends_overlap: Vec<bool>,
    /// Per vertex: the welded point it was moved to (set by [`weld`]).
    weld: Vec<Option<usize>>,
}

impl Chain {
    fn new(shape: &Shape, splits: Vec<Vec<f64>>, ends: Vec<bool>, tol: f64) -> Chain {
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

    fn subsegments(&self) -> usize {
        if self.closed {
            self.points.len()
        } else {
            self.points.len() - 1
        }
    }

    fn next(&self, j: usize) -> usize {
        (j + 1) % self.points.len()
    }
}

/// Moves the ends of overlaps, shape by shape, onto the first such point
/// within `tol` of another shape (one point per shape at most), so that the
/// two copies of a common cut have the very same end points. Each welded
/// point gets an id, its vertices [`Chain::weld`].
fn weld(chains: &mut [Chain], tol: f64) {
    // A hash grid of `tol` cells: a point's neighbours within `tol` lie in the
    // 3 × 3 cells around its own.
    let cell = |p: Point| ((p.x / tol).floor() as i64, (p.y / tol).floor() as i64);
    let mut grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    let mut welded: Vec<(Point, Vec<usize>)> = Vec::new();
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
                        if d <= tol * (1.0 + 1e-9) && !welded[w].1.contains(&g) && best.is_none_or(|(bd, _)| d < bd) {
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
            welded[w].1.push(g);
            chain.points[j] = welded[w].0;
            chain.weld[j] = Some(w);
        }
    }
}

/// Per chain and sub-segment: the other copy of it, (chain, sub-segment), if
/// it is a common cut. Two sub-segments are copies when they join the same two
/// welded points; where three shapes coincide the first two are paired.
fn match_common_cuts(chains: &[Chain]) -> Vec<Vec<Option<(usize, usize)>>> {
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

/// What a sub-segment belongs to while elements are made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Label {
    /// A copy of a common cut whose element an earlier shape made.
    Follow(usize),
    /// The shape's own, shared with that later shape or with none.
    Own(Option<usize>),
}

/// Elements (as pieces) and contours, shape by shape: a shape makes the
/// elements of its own sub-segments and of the common cuts it shares with
/// later shapes, and lists the elements an earlier shape made for the common
/// cuts they share.
fn elements(
    chains: &[Chain],
    partners: &[Vec<Option<(usize, usize)>>],
    cos_corner: f64,
) -> (Vec<Piece>, Vec<Vec<usize>>) {
    let mut pieces: Vec<Piece> = Vec::new();
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
                    pieces.push(Piece { geometry: g, shared_with, points });
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

/// Per contour: the smallest closed contour containing it.
fn containment(chains: &[Chain], tol: f64) -> Vec<Option<usize>> {
    let bounds: Vec<(Point, Point)> = chains.iter().map(|c| bounds_of(c.points.iter())).collect();
    let areas: Vec<f64> = chains.iter().map(|c| if c.closed { signed_area(&c.points).abs() } else { 0.0 }).collect();
    let tree: RTree<Box2> = RTree::bulk_load(
        chains
            .iter()
            .enumerate()
            .filter(|(_, c)| c.closed)
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
            candidates.into_iter().find(|&b| inside(&chains[a], &chains[b].points, tol))
        })
        .collect()
}

/// Where a point lies with respect to a closed polygon.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Inside,
    Outside,
    /// Within the tolerance of its boundary: says nothing.
    Boundary,
}

/// Chain `a` lies inside polygon `b`: decided by its first vertex (or segment
/// midpoint) off `b`'s boundary; a chain all on the boundary is not inside.
fn inside(a: &Chain, b: &[Point], tol: f64) -> bool {
    let vertices = a.points.iter().copied();
    let midpoints = (0..a.subsegments()).map(|j| nalgebra::center(&a.points[j], &a.points[a.next(j)]));
    vertices.chain(midpoints).map(|p| side(p, b, tol)).find(|&s| s != Side::Boundary) == Some(Side::Inside)
}

/// Crossing-number test (a ray to +x crosses the boundary an odd number of
/// times from inside), with points within `tol` of an edge on the boundary.
fn side(p: Point, polygon: &[Point], tol: f64) -> Side {
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

fn levels(outer: &[Option<usize>]) -> Vec<usize> {
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

fn ranks(inst: &Instance) -> Vec<usize> {
    let k = inst.contours.len();
    let mut owners = vec![0u8; inst.elements.len()];
    for c in &inst.contours {
        for &e in c {
            owners[e] = owners[e].saturating_add(1);
        }
    }
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); k];
    for cc in inst.common_cuts() {
        neighbours[cc.contours.0].push(cc.contours.1);
        neighbours[cc.contours.1].push(cc.contours.0);
    }
    let mut rank: Vec<Option<usize>> = vec![None; k];
    let mut queue = VecDeque::new();
    for c in 0..k {
        if neighbours[c].is_empty() || inst.contours[c].iter().any(|&e| owners[e] == 1) {
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

fn groups(inst: &Instance) -> Vec<usize> {
    let k = inst.contours.len();
    let mut parent: Vec<usize> = (0..k).collect();
    fn root(parent: &mut [usize], mut c: usize) -> usize {
        while parent[c] != c {
            parent[c] = parent[parent[c]];
            c = parent[c];
        }
        c
    }
    let links = inst.inner_outer.iter().copied().chain(inst.common_cuts().into_iter().map(|cc| cc.contours));
    for (a, b) in links {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        parent[ra.max(rb)] = ra.min(rb);
    }
    let mut number: HashMap<usize, usize> = HashMap::new();
    (0..k)
        .map(|c| {
            let r = root(&mut parent, c);
            let next = number.len();
            *number.entry(r).or_insert(next)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;
    use std::time::Instant;

    use super::*;
    use crate::config::MachineConfig;
    use crate::job::{Geometry, Process};
    use crate::plan::ecp::checker;
    use crate::gen::sheet::{self, SheetParams};

    fn p(x: f64, y: f64) -> Point {
        Point::new(x, y)
    }

    fn shape(points: &[(f64, f64)], closed: bool, name: &str) -> Geometry {
        Geometry {
            points: points.iter().map(|&(x, y)| p(x, y)).collect(),
            closed,
            process: 0,
            source: format!("test.svg: {name}"),
        }
    }

    /// A rectangle, counter-clockwise from its lower left corner.
    fn rect(x0: f64, y0: f64, x1: f64, y1: f64, name: &str) -> Geometry {
        shape(&[(x0, y0), (x1, y0), (x1, y1), (x0, y1)], true, name)
    }

    fn job(geometries: Vec<Geometry>) -> Job {
        let process = Process { layer: "cut".into(), speed: 10.0, power: 1000.0, passes: 1 };
        Job { source: "test.svg".into(), geometries, processes: vec![process] }
    }

    fn model_with(geometries: Vec<Geometry>, options: &TopologyOptions) -> CuttingModel {
        let job = job(geometries);
        let model = build(&job, p(0.0, 0.0), options).unwrap();
        check_model(&model, &job, options.common_cut_tolerance_mm);
        model
    }

    fn model(geometries: Vec<Geometry>) -> CuttingModel {
        model_with(geometries, &TopologyOptions::default())
    }

    fn length(points: &[Point]) -> f64 {
        points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }

    fn distance_to_segment(q: Point, a: Point, b: Point) -> f64 {
        let d = b - a;
        let t = ((q - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
        (a + d * t - q).norm()
    }

    /// A contour's elements in its order, each cut the way round the contour
    /// goes; asserts that they form one chain, closed for a closed geometry.
    fn ring(model: &CuttingModel, job: &Job, k: usize) -> Vec<Cut> {
        let inst = &model.instance;
        let c = &inst.contours[k];
        let el = |e: usize| &inst.elements[e];
        let start = match c.len() {
            1 => el(c[0]).a,
            // Where the first element does not meet the second.
            _ if el(c[0]).a == el(c[1]).a || el(c[0]).a == el(c[1]).b => el(c[0]).b,
            _ => el(c[0]).a,
        };
        let mut here = start;
        let cuts = c
            .iter()
            .map(|&e| {
                assert!(el(e).a == here || el(e).b == here, "contour {k}: element {e} does not go on from {here}");
                let reversed = el(e).a != here;
                here = if reversed { el(e).a } else { el(e).b };
                Cut { element: e, reversed }
            })
            .collect();
        if job.geometries[k].closed {
            assert_eq!(here, start, "contour {k} is not closed");
        }
        cuts
    }

    /// What holds for every model: pieces on their geometries, contours as
    /// chains, every element on one or two contours, relations consistent.
    fn check_model(model: &CuttingModel, job: &Job, tol: f64) {
        let inst = &model.instance;
        assert_eq!(inst.contours.len(), job.geometries.len());
        assert_eq!(inst.elements.len(), model.pieces.len());
        let mut owners = vec![Vec::new(); inst.elements.len()];
        for (k, c) in inst.contours.iter().enumerate() {
            for &e in c {
                owners[e].push(k);
            }
        }
        for (e, piece) in model.pieces.iter().enumerate() {
            assert!(piece.points.len() >= 2);
            assert_eq!((inst.elements[e].a, inst.elements[e].b), (piece.points[0], *piece.points.last().unwrap()));
            let mut on: Vec<usize> = piece.geometries();
            on.sort();
            assert_eq!(owners[e], on, "element {e} is on the contours of its piece's geometries");
            // Every point on the geometry's polyline (welding moves by ≤ tol).
            let g = &job.geometries[piece.geometry];
            let n = g.points.len();
            let segs = if g.closed { n } else { n - 1 };
            for &q in &piece.points {
                let d = (0..segs)
                    .map(|i| distance_to_segment(q, g.points[i], g.points[(i + 1) % n]))
                    .fold(f64::INFINITY, f64::min);
                assert!(d <= tol * 1.001, "element {e}: {q} is {d} mm off {}", g.source);
            }
        }
        for k in 0..inst.contours.len() {
            ring(model, job, k);
        }
        // Marked length: the geometries' less the second copies of common cuts.
        let pieces: f64 = model.pieces.iter().map(|pc| length(&pc.points)).sum();
        let shared: f64 = model.pieces.iter().filter(|pc| pc.shared_with.is_some()).map(|pc| length(&pc.points)).sum();
        let drawn: f64 = job.geometries.iter().map(Geometry::length).sum();
        let count = inst.common_cuts().len() as f64;
        assert!((pieces + shared - drawn).abs() <= 1e-6 * drawn + 4.0 * tol * count, "{pieces} + {shared} vs {drawn}");
        for &(i, o) in &inst.inner_outer {
            assert_eq!(model.outer[i], Some(o));
            assert_eq!(model.levels[i], model.levels[o] + 1);
            assert_eq!(model.groups[i], model.groups[o]);
            assert!(job.geometries[o].closed, "an open geometry is never an outer");
        }
        for cc in inst.common_cuts() {
            assert_eq!(model.groups[cc.contours.0], model.groups[cc.contours.1]);
        }
        assert_eq!(model.outer.iter().filter(|o| o.is_some()).count(), inst.inner_outer.len());
    }

    fn common_pairs(inst: &Instance) -> Vec<(usize, usize)> {
        let mut pairs: Vec<(usize, usize)> = inst
            .common_cuts()
            .iter()
            .map(|cc| (cc.contours.0.min(cc.contours.1), cc.contours.0.max(cc.contours.1)))
            .collect();
        pairs.sort();
        pairs
    }

    fn ends_of(inst: &Instance, e: usize) -> BTreeSet<(i64, i64)> {
        let key = |q: Point| ((q.x * 1e6).round() as i64, (q.y * 1e6).round() as i64);
        [key(inst.elements[e].a), key(inst.elements[e].b)].into_iter().collect()
    }

    fn set(points: &[(f64, f64)]) -> BTreeSet<(i64, i64)> {
        points.iter().map(|&(x, y)| ((x * 1e6).round() as i64, (y * 1e6).round() as i64)).collect()
    }

    #[test]
    fn rectangles_side_by_side_share_one_edge() {
        // The right one counter-clockwise (the shared edge runs the other way
        // round in each) and clockwise (the same way in both).
        let clockwise = shape(&[(10.0, 0.0), (10.0, 10.0), (20.0, 10.0), (20.0, 0.0)], true, "b");
        for right in [rect(10.0, 0.0, 20.0, 10.0, "b"), clockwise] {
            let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), right]);
            let inst = &m.instance;
            assert_eq!(inst.elements.len(), 7);
            assert_eq!(inst.contours.iter().map(Vec::len).collect::<Vec<_>>(), vec![4, 4]);
            let cc = inst.common_cuts();
            assert_eq!(cc.len(), 1);
            assert_eq!(cc[0].contours, (0, 1));
            assert_eq!(ends_of(inst, cc[0].element), set(&[(10.0, 0.0), (10.0, 10.0)]));
            assert_eq!(m.pieces[cc[0].element].geometry, 0);
            assert_eq!(m.pieces[cc[0].element].shared_with, Some(1));
            assert!(inst.inner_outer.is_empty());
            assert_eq!((m.levels.clone(), m.ranks.clone(), m.groups.clone()), (vec![0, 0], vec![0, 0], vec![0, 0]));
        }
        // Apart by a gap: two parts, two groups.
        let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(12.0, 0.0, 22.0, 10.0, "b")]);
        assert_eq!((m.instance.elements.len(), m.instance.common_cuts().len(), m.group_count()), (8, 0, 2));
        // Touching at a corner only (collinear edges meeting end to end): no common cut.
        let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 10.0, 20.0, 20.0, "b")]);
        assert_eq!(m.instance.common_cuts().len(), 0);
    }

    #[test]
    fn partly_overlapping_edges_are_split_at_the_overlap() {
        // Shifted up by half: the overlap is x = 10, y 5..10.
        let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 5.0, 20.0, 15.0, "b")]);
        let inst = &m.instance;
        assert_eq!(inst.contours.iter().map(Vec::len).collect::<Vec<_>>(), vec![5, 5]);
        assert_eq!(inst.elements.len(), 9);
        let cc = inst.common_cuts();
        assert_eq!(cc.len(), 1);
        assert_eq!(ends_of(inst, cc[0].element), set(&[(10.0, 5.0), (10.0, 10.0)]));
        // A smaller part against the middle of the edge: it is split in three.
        let m = model(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 2.0, 14.0, 6.0, "b")]);
        let inst = &m.instance;
        assert_eq!(inst.contours.iter().map(Vec::len).collect::<Vec<_>>(), vec![6, 4]);
        let cc = inst.common_cuts();
        assert_eq!(cc.len(), 1);
        assert_eq!(ends_of(inst, cc[0].element), set(&[(10.0, 2.0), (10.0, 6.0)]));
        // Two parts against one long edge: two common cuts, three contours in a group.
        let m = model(vec![
            rect(0.0, 0.0, 10.0, 30.0, "a"),
            rect(10.0, 0.0, 20.0, 10.0, "b"),
            rect(10.0, 10.0, 20.0, 20.0, "c"),
        ]);
        assert_eq!(common_pairs(&m.instance), vec![(0, 1), (0, 2), (1, 2)]);
        assert_eq!(m.groups, vec![0, 0, 0]);
    }

    #[test]
    fn offsets_within_the_tolerance_are_common_cuts_and_beyond_are_not() {
        let a = || rect(0.0, 0.0, 10.0, 10.0, "a");
        let m = model(vec![a(), rect(10.004, 0.003, 20.0, 10.003, "b")]);
        let cc = m.instance.common_cuts();
        assert_eq!(cc.len(), 1);
        // The shared edge keeps the first part's coordinates; the second
        // part's neighbouring edges meet it there (check_model: a chain).
        assert_eq!(ends_of(&m.instance, cc[0].element), set(&[(10.0, 0.0), (10.0, 10.0)]));
        assert_eq!(m.instance.elements.len(), 7);
        let m = model(vec![a(), rect(10.02, 0.0, 20.0, 10.0, "b")]);
        assert_eq!((m.instance.common_cuts().len(), m.instance.elements.len()), (0, 8));
        // A wider tolerance takes it.
        let wide = TopologyOptions { common_cut_tolerance_mm: 0.05, ..TopologyOptions::default() };
        let m = model_with(vec![a(), rect(10.02, 0.0, 20.0, 10.0, "b")], &wide);
        assert_eq!(m.instance.common_cuts().len(), 1);
        // Slightly skewed (within the tolerance over the edge): still one.
        let skew = shape(&[(10.0, 0.0), (20.0, 0.0), (20.0, 10.0), (10.008, 10.0)], true, "b");
        assert_eq!(model(vec![a(), skew]).instance.common_cuts().len(), 1);
    }

    #[test]
    fn part_hole_and_nested_part_have_levels_0_1_2() {
        // Listed inside out, with a part of its own beside them.
        let m = model(vec![
            rect(30.0, 30.0, 70.0, 70.0, "nested part"),
            rect(200.0, 0.0, 300.0, 100.0, "other part"),
            rect(0.0, 0.0, 100.0, 100.0, "part"),
            rect(45.0, 45.0, 55.0, 55.0, "hole of the nested part"),
            rect(20.0, 20.0, 80.0, 80.0, "hole"),
        ]);
        assert_eq!(m.outer, vec![Some(4), None, None, Some(0), Some(2)]);
        assert_eq!(m.levels, vec![2, 0, 0, 3, 1]);
        let pairs: BTreeSet<(usize, usize)> = m.instance.inner_outer.iter().copied().collect();
        assert_eq!(pairs, [(0, 4), (3, 0), (4, 2)].into_iter().collect());
        assert_eq!(m.groups, vec![0, 1, 0, 0, 0]);
        assert_eq!(m.group_count(), 2);
        assert_eq!(m.ranks, vec![0; 5]);
    }

    #[test]
    fn a_grid_ranks_its_middle_cell_higher() {
        // 3 × 3 cells of 10 mm, each drawn whole.
        let mut cells = Vec::new();
        for i in 0..3 {
            for j in 0..3 {
                let (x, y) = (10.0 * j as f64, 10.0 * i as f64);
                cells.push(rect(x, y, x + 10.0, y + 10.0, &format!("cell {i} {j}")));
            }
        }
        let m = model(cells);
        assert_eq!(m.instance.common_cuts().len(), 12);
        assert_eq!(m.instance.elements.len(), 24);
        assert_eq!(m.ranks, vec![0, 0, 0, 0, 1, 0, 0, 0, 0]);
        assert_eq!(m.groups, vec![0; 9]);
    }

    #[test]
    fn flattened_circle_is_a_few_arcs() {
        let circle: Vec<(f64, f64)> =
            (0..360).map(|k| (k as f64).to_radians()).map(|t| (50.0 + 20.0 * t.cos(), 50.0 + 20.0 * t.sin())).collect();
        let m = model(vec![shape(&circle, true, "circle")]);
        let lengths: Vec<f64> = m.pieces.iter().map(|pc| length(&pc.points)).collect();
        assert!((2..=4).contains(&lengths.len()), "{} arcs", lengths.len());
        let total: f64 = lengths.iter().sum();
        for l in &lengths {
            assert!((l - total / lengths.len() as f64).abs() < 0.05 * total, "unequal arcs {lengths:?}");
        }
        // A D: a half circle and its diameter, two corners, two elements.
        let mut d: Vec<(f64, f64)> = (0..=100)
            .map(|k| std::f64::consts::PI * k as f64 / 100.0)
            .map(|t| (20.0 * t.cos(), 20.0 * t.sin()))
            .collect();
        d.push((0.0, 0.0));
        let m = model(vec![shape(&d, true, "D")]);
        let sizes: BTreeSet<usize> = m.pieces.iter().map(|pc| pc.points.len()).collect();
        assert_eq!(sizes, [3, 101].into_iter().collect(), "the arc and the diameter (split at the centre vertex)");
        // A teardrop: one corner; still entered at more than one place.
        let mut drop: Vec<(f64, f64)> =
            (0..=90).map(|k| (45.0 + 3.0 * k as f64).to_radians()).map(|t| (10.0 * t.cos(), 10.0 * t.sin())).collect();
        drop.push((10.0 * 2f64.sqrt(), 0.0));
        let m = model(vec![shape(&drop, true, "drop")]);
        assert!(m.instance.contours[0].len() >= 2);
        // A square stays four lines.
        assert_eq!(model(vec![rect(0.0, 0.0, 1.0, 1.0, "square")]).instance.elements.len(), 4);
    }

    #[test]
    fn open_line_inside_a_part_is_its_inner() {
        let m = model(vec![
            rect(0.0, 0.0, 100.0, 100.0, "part"),
            shape(&[(10.0, 10.0), (50.0, 50.0), (90.0, 10.0)], false, "engraving"),
            shape(&[(200.0, 0.0), (210.0, 0.0)], false, "a line on its own"),
        ]);
        assert_eq!(m.instance.inner_outer, vec![(1, 0)]);
        assert_eq!(m.levels, vec![0, 1, 0]);
        assert_eq!(m.instance.contours[1].len(), 2, "split at its corner");
        assert_eq!(m.pieces[m.instance.contours[1][0]].points, vec![p(10.0, 10.0), p(50.0, 50.0)]);
        // An open line round a part is not its outer.
        let m = model(vec![
            shape(&[(-10.0, 110.0), (-10.0, -10.0), (110.0, -10.0), (110.0, 110.0)], false, "bracket"),
            rect(0.0, 0.0, 100.0, 100.0, "part"),
        ]);
        assert_eq!(m.outer, vec![None, None]);
        // An engraving touching the part's edge from inside is still inside.
        let m = model(vec![rect(0.0, 0.0, 100.0, 100.0, "part"), shape(&[(0.0, 50.0), (50.0, 50.0)], false, "tick")]);
        assert_eq!(m.outer, vec![None, Some(0)]);
    }

    #[test]
    fn bad_geometry_is_an_error_naming_its_source() {
        let options = TopologyOptions::default();
        let cases = [
            (shape(&[(0.0, 0.0), (f64::NAN, 1.0), (1.0, 1.0)], true, "path 'nan'"), "not a finite number"),
            (shape(&[(0.0, 0.0), (f64::INFINITY, 1.0)], false, "path 'inf'"), "not a finite number"),
            (shape(&[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)], true, "path 'flat'"), "no area"),
            (shape(&[(0.0, 0.0), (1.0, 1.0), (0.0, 0.0)], true, "path 'two'"), "at least 3"),
            (shape(&[(1.0, 1.0), (1.0, 1.0)], false, "path 'dot'"), "at least 2"),
        ];
        for (bad, why) in cases {
            let source = bad.source.clone();
            let result = build(&job(vec![rect(0.0, 0.0, 10.0, 10.0, "fine"), bad]), p(0.0, 0.0), &options);
            match result {
                Err(Error::Plan(msg)) => assert!(msg.contains(&source) && msg.contains(why), "{msg}"),
                other => panic!("{source}: {other:?}"),
            }
        }
        for options in [
            TopologyOptions { common_cut_tolerance_mm: 0.0, ..options },
            TopologyOptions { common_cut_tolerance_mm: f64::NAN, ..options },
            TopologyOptions { corner_angle_deg: 0.0, ..options },
        ] {
            assert!(matches!(build(&job(vec![]), p(0.0, 0.0), &options), Err(Error::Plan(_))));
        }
    }

    #[test]
    fn route_polylines_merge_continuing_cuts() {
        let j = job(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 0.0, 20.0, 10.0, "b")]);
        let m = build(&j, p(0.0, 0.0), &TopologyOptions::default()).unwrap();
        let (a, b) = (ring(&m, &j, 0), ring(&m, &j, 1));
        let shared = m.instance.common_cuts()[0].element;
        // The right part first, all round, its common cut (the left part's
        // piece) included; then the rest of the left part, from where the
        // common cut left it.
        let at = a.iter().position(|c| c.element == shared).unwrap();
        let rest_of_a: Vec<Cut> = (1..4).map(|s| a[(at + s) % 4]).collect();
        let route: Vec<Cut> = b.iter().chain(&rest_of_a).copied().collect();
        assert_eq!(checker::check(&m.instance, &route), vec![]);
        let lines = m.polylines(&route);
        assert_eq!(lines.len(), 2);
        assert_eq!((lines[0].0, lines[0].1.len()), (1, 5));
        assert_eq!(lines[0].1[0], lines[0].1[4], "the right part closes");
        assert_eq!((lines[1].0, lines[1].1.len()), (0, 4));
        assert!((length(&lines[0].1) + length(&lines[1].1) - 70.0).abs() < 1e-9);
        // The left part first: one closed polyline; the right part's rest starts
        // where the common cut ended, which is not where the left part ended.
        let at = b.iter().position(|c| c.element == shared).unwrap();
        let route: Vec<Cut> = a.iter().copied().chain((1..4).map(|s| b[(at + s) % 4])).collect();
        let lines = m.polylines(&route);
        assert_eq!(lines.iter().map(|(g, l)| (*g, l.len())).collect::<Vec<_>>(), vec![(0, 5), (1, 4)]);
        // A cut against the direction of the one before: a new polyline.
        let flipped = [a[0], Cut { reversed: !a[1].reversed, ..a[1] }];
        assert_eq!(m.polylines(&flipped).len(), 2);
        // The common cut alone, then the right part's next edge: the polyline
        // is the right part's.
        let at = b.iter().position(|c| c.element == shared).unwrap();
        let lines = m.polylines(&[b[at], b[(at + 1) % 4]]);
        assert_eq!(lines.iter().map(|(g, l)| (*g, l.len())).collect::<Vec<_>>(), vec![(1, 3)]);
    }

    /// Depth of each contour from a generated instance's own `inner_outer`.
    fn depth(inst: &Instance) -> Vec<usize> {
        let mut outer = vec![None; inst.contours.len()];
        for &(i, o) in &inst.inner_outer {
            outer[i] = Some(o);
        }
        levels(&outer)
    }

    #[test]
    fn sheet_svg_round_trip_finds_the_generated_topology() {
        let config = MachineConfig::load(None).unwrap();
        for (target, seed) in [(300, 1), (300, 2), (3000, 1), (12000, 3)] {
            let params = SheetParams::with_target(target);
            let generated = sheet::generate_sheet(&params, seed);
            let gen = &generated.instance;
            let svg = sheet::to_svg(&generated, &params);
            let t0 = Instant::now();
            let job = crate::import::svg::import_svg(&svg, "sheet.svg", &config).unwrap();
            let t1 = Instant::now();
            let options = TopologyOptions::default();
            let m = build(&job, p(0.0, 0.0), &options).unwrap();
            let t2 = Instant::now();
            eprintln!(
                "sheet {target}/{seed}: {} elements, {} contours, {} points imported; import {:.1} ms, topology {:.1} ms",
                gen.elements.len(),
                gen.contours.len(),
                job.geometries.iter().map(|g| g.points.len()).sum::<usize>(),
                (t1 - t0).as_secs_f64() * 1e3,
                (t2 - t1).as_secs_f64() * 1e3
            );
            check_model(&m, &job, options.common_cut_tolerance_mm);
            let inst = &m.instance;
            assert_eq!(job.geometries.len(), gen.contours.len());
            assert!(job.geometries.iter().all(|g| g.closed));
            // The same relations, contour k being geometry k.
            let found: BTreeSet<(usize, usize)> = inst.inner_outer.iter().copied().collect();
            let made: BTreeSet<(usize, usize)> = gen.inner_outer.iter().copied().collect();
            assert_eq!(found, made, "sheet {target}/{seed}: inner/outer pairs");
            assert_eq!(inst.common_cuts().len(), gen.common_cuts().len());
            assert_eq!(common_pairs(inst), common_pairs(gen));
            assert_eq!(m.levels, depth(gen));
            assert_eq!(m.groups, groups(gen));
            // Rank above 0 exactly for cells whose every edge is shared.
            let mut owners = vec![0; gen.elements.len()];
            for c in &gen.contours {
                for &e in c {
                    owners[e] += 1;
                }
            }
            for (k, c) in gen.contours.iter().enumerate() {
                assert_eq!(m.ranks[k] > 0, c.iter().all(|&e| owners[e] == 2), "contour {k}");
                let round = c.iter().all(|&e| generated.arc_centres[e].is_some());
                if round {
                    // Drawn as arcs: every imported point on the circle (the
                    // import flattens within 0.01 mm the cubics an SVG arc
                    // becomes, which are off the circle by up to 0.03 %), and
                    // a 2-arc circle is a disc, not a line there and back.
                    let centre = generated.arc_centres[c[0]].unwrap();
                    let r = (gen.elements[c[0]].a - centre).norm();
                    let g = &job.geometries[k];
                    let off = g.points.iter().map(|q| ((q - centre).norm() - r).abs()).fold(0.0, f64::max);
                    assert!(off < 0.02 + 3e-4 * r, "contour {k} is {off} mm off its circle (r {r})");
                    // Flattening loses at most the perimeter times the tolerance.
                    let (area, pi) = (signed_area(&g.points).abs(), std::f64::consts::PI);
                    assert!((area - pi * r * r).abs() <= 2.0 * pi * r * 0.02, "contour {k}: area {area}, r {r}");
                    assert!((2..=4).contains(&inst.contours[k].len()));
                } else {
                    assert_eq!(inst.contours[k].len(), c.len(), "contour {k}: one element per line");
                }
            }
            if target >= 3000 {
                assert!(m.ranks.iter().any(|&r| r > 0), "a 3-row grid has inner cells");
            }
            // Deepest contours first, each walked round from where its cut
            // common cuts left it: feasible, and one polyline per run of it.
            let mut order: Vec<usize> = (0..inst.contours.len()).collect();
            order.sort_by_key(|&k| std::cmp::Reverse(m.levels[k]));
            let mut done = vec![false; inst.elements.len()];
            let mut route = Vec::new();
            let mut runs = Vec::new();
            for k in order {
                let cuts = ring(&m, &job, k);
                let n = cuts.len();
                let starts: Vec<usize> =
                    (0..n).filter(|&i| !done[cuts[i].element] && done[cuts[(i + n - 1) % n].element]).collect();
                let first = match starts.first() {
                    Some(&i) => i,
                    None if cuts.iter().all(|c| !done[c.element]) => 0,
                    None => continue,
                };
                for _ in 0..starts.len().max(1) {
                    runs.push(k);
                }
                for s in 0..n {
                    let c = cuts[(first + s) % n];
                    if !std::mem::replace(&mut done[c.element], true) {
                        route.push(c);
                    }
                }
            }
            assert_eq!(checker::check(inst, &route), vec![], "sheet {target}/{seed}");
            let lines = m.polylines(&route);
            assert_eq!(lines.iter().map(|(g, _)| *g).collect::<Vec<_>>(), runs);
            let marked: f64 = lines.iter().map(|(_, l)| length(l)).sum();
            let pieces: f64 = m.pieces.iter().map(|pc| length(&pc.points)).sum();
            assert!((marked - pieces).abs() < 1e-6 * pieces);
        }
    }
}
