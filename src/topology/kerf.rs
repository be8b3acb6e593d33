//! Kerf compensation (`[[layer]] kerf`): a closed contour is cut half the
//! kerf into the waste, so that the part comes out the size it was drawn: a
//! part's outline outward, a hole's inward, a part nested in a hole outward
//! again (which is which: the containment levels of the contours that cut).
//! The offset is cavalier_contours': an arc's offset is the concentric arc,
//! so arcs stay arcs; a convex corner goes round on an arc of half the kerf
//! about it, or out to its miter (`kerf_corners = "sharp"`).
//!
//! Nothing is lost silently. A hole the beam cannot enter, or a slot, notch
//! or neck narrower than the kerf (material left where the drawing has none,
//! more than half a kerf deep), is an error naming the contour and the
//! place; so are parts nested closer than the kerf (the cut of one would
//! take material off the other). Contours drawn exactly a kerf apart share
//! their cut (common-line cutting): that is no collision.

use cavalier_contours::core::math::Vector2 as CVec;
use cavalier_contours::polyline::{seg_closest_point, PlineCreation, PlineOffsetOptions, PlineSource, PlineSourceMut, PlineVertex, Polyline};
use rstar::primitives::GeomWithData;
use rstar::{RTree, AABB};

use super::waste::Waste;
use super::{rect, Box2};
use crate::config::KerfCorners;
use crate::error::{Error, Result};
use crate::job::{arc_points, ArcSpan, Geometry, Job, Point};

/// The kerf settings of one process (a layer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KerfLayer {
    /// The cut's width (mm); 0: cut on the line.
    pub kerf: f64,
    pub corners: KerfCorners,
    /// Whether the layer's closed contours cut parts out (they pierce, or
    /// set a kerf): these decide what is a part and what a hole.
    pub cuts: bool,
}

/// A job whose contours were offset by their layer's kerf.
#[derive(Debug, Clone)]
pub struct Kerfed {
    pub job: Job,
    /// Contours offset (closed ones on a layer with a kerf).
    pub offset: usize,
    /// The largest kerf applied (mm); 0 when none was.
    pub kerf_mm: f64,
}

/// Miters longer than this many half-kerfs (corners sharper than about 11°)
/// stay round: the tip would reach far into the waste, and into neighbours.
const MITER_LIMIT: f64 = 10.0;
/// Exactness of the offsets: cavalier_contours computes arcs and lines in
/// closed form, so the offset lies this close to half the kerf.
const EXACT_MM: f64 = 1e-7;

/// `job` with every closed contour of a layer with a kerf offset into the
/// waste by half of it. `layers` is per process; `tolerance` is the import's
/// flattening tolerance (the offset arcs are flattened to it).
pub fn compensate(job: &Job, layers: &[KerfLayer], tolerance: f64) -> Result<Kerfed> {
    let kerf_of = |g: &Geometry| layers.get(g.process).map_or(0.0, |l| l.kerf);
    if !job.geometries.iter().any(|g| g.closed && kerf_of(g) > 0.0) {
        return Ok(Kerfed { job: job.clone(), offset: 0, kerf_mm: 0.0 });
    }
    // Which contours are parts and which holes.
    let cuts: Vec<bool> = layers.iter().map(|l| l.cuts || l.kerf > 0.0).collect();
    let part_levels = super::part_levels(job, &cuts)?;
    let cutting: Vec<usize> = (0..job.geometries.len()).filter(|&k| part_levels[k].is_some()).collect();
    let levels: Vec<usize> = cutting.iter().map(|&k| part_levels[k].unwrap_or(0)).collect();

    let mut out = job.clone();
    let mut kerf_mm = 0.0f64;
    let mut open_skipped = 0;
    let mut offset_geometries = Vec::new();
    for (c, &k) in cutting.iter().enumerate() {
        let g = &job.geometries[k];
        let layer = layers[g.process];
        if layer.kerf <= 0.0 {
            continue;
        }
        if !g.profile.is_empty() {
            tracing::warn!("{}: cut on the drawn line: its power changes along it (a kerf offset would not keep where)", g.source);
            continue;
        }
        let half = layer.kerf / 2.0;
        let path = offset_contour(g, half, levels[c].is_multiple_of(2), layer, &job.processes[g.process].layer)?;
        out.geometries[k] = geometry_of(&path, g, tolerance);
        offset_geometries.push(k);
        kerf_mm = kerf_mm.max(layer.kerf);
    }
    for g in job.geometries.iter().filter(|g| !g.closed && kerf_of(g) > 0.0) {
        open_skipped += 1;
        if open_skipped == 1 {
            tracing::warn!("{}: an open path is cut on the drawn line (it has no side to offset the kerf to)", g.source);
        }
    }
    if open_skipped > 1 {
        tracing::warn!("{}: {open_skipped} open paths on layers with a kerf are cut on the drawn line", job.source);
    }
    check_clearance(job, &out, &cutting, &offset_geometries, layers, tolerance)?;
    Ok(Kerfed { job: out, offset: offset_geometries.len(), kerf_mm })
}

/// The polyline of a geometry, its arcs as bulges.
fn pline_of(g: &Geometry) -> Polyline {
    let n = g.points.len();
    let mut pline = Polyline::with_capacity(n, g.closed);
    let mut arcs = g.arcs.iter().peekable();
    let mut i = 0;
    while i < n {
        let p = g.points[i];
        match arcs.peek() {
            Some(a) if a.from == i => {
                pline.add(p.x, p.y, a.bulge);
                i = a.to;
                arcs.next();
            }
            _ => {
                pline.add(p.x, p.y, 0.0);
                i += 1;
            }
        }
    }
    pline
}

/// The offset of closed geometry `g` by `half` into its waste (`outward`
/// for a part, inward for a hole), checked: it exists, is one contour, and
/// leaves no drawn feature more than half a kerf uncut.
fn offset_contour(g: &Geometry, half: f64, outward: bool, layer: KerfLayer, name: &str) -> Result<Polyline> {
    let what = |why: String| Error::Plan(format!("{}: with the kerf of {} mm (layer '{name}'), {why}", g.source, layer.kerf));
    let pline = pline_of(g).remove_repeat_pos(1e-9).unwrap_or_else(|| pline_of(g));
    let ccw = pline.area() > 0.0;
    let distance = if outward == ccw { -half } else { half };
    let options = PlineOffsetOptions { handle_self_intersects: true, ..PlineOffsetOptions::new() };
    let mut results = pline.parallel_offset_opt(distance, &options);
    if results.is_empty() {
        return Err(what("a hole smaller than the kerf vanishes".into()));
    }
    let index = SegmentIndex::new(&results);
    // Every drawn point within half a kerf of where the beam's edge runs.
    for (v1, v2) in segments(&pline) {
        for p in probes(v1, v2) {
            let miss = index.distance(&results, p, 2.0 * half + EXACT_MM) - half;
            if miss > half + EXACT_MM {
                return Err(what(format!(
                    "the beam cannot reach ({:.3}, {:.3}): a slot, notch or neck there is narrower than the kerf, or a corner inside the part sharper than 60°",
                    p.x, p.y
                )));
            }
        }
    }
    if results.len() > 1 {
        return Err(what(format!("the hole narrows to less than the kerf: it would be cut as {} holes", results.len())));
    }
    let mut path = results.remove(0);
    if layer.corners == KerfCorners::Sharp {
        path = miter(&path, &pline, half);
        // The arcs' ends now lie on straight sides: one segment each.
        path = path.remove_redundant(1e-9).unwrap_or(path);
    }
    Ok(path)
}

/// The segments of a polyline as vertex pairs (the closing one included).
fn segments(p: &Polyline) -> impl Iterator<Item = (PlineVertex, PlineVertex)> + '_ {
    p.iter_segment_indexes().map(move |(i, j)| (p.at(i), p.at(j)))
}

/// Points along a segment where a drawn feature is looked for: its start,
/// its middle and its quarters (an arc's along the arc).
fn probes(v1: PlineVertex, v2: PlineVertex) -> Vec<Point> {
    let (a, b) = (Point::new(v1.x, v1.y), Point::new(v2.x, v2.y));
    if v1.bulge == 0.0 {
        return [0.0, 0.25, 0.5, 0.75].iter().map(|&t| a + (b - a) * t).collect();
    }
    let (centre, radius, start, sweep) = crate::job::arc_circle(a, b, v1.bulge);
    [0.0, 0.25, 0.5, 0.75]
        .iter()
        .map(|&t| {
            let angle = start + sweep * t;
            centre + nalgebra::Vector2::new(angle.cos(), angle.sin()) * radius
        })
        .collect()
}

/// The segments of some polylines in an R-tree of their boxes.
struct SegmentIndex {
    tree: RTree<Box2>,
}

impl SegmentIndex {
    fn new(plines: &[Polyline]) -> SegmentIndex {
        let boxes = plines
            .iter()
            .enumerate()
            .flat_map(|(k, p)| {
                p.iter_segment_indexes().map(move |(i, j)| {
                    let b = cavalier_contours::polyline::seg_bounding_box(p.at(i), p.at(j));
                    GeomWithData::new(rect(Point::new(b.min_x, b.min_y), Point::new(b.max_x, b.max_y)), (k, i))
                })
            })
            .collect();
        SegmentIndex { tree: RTree::bulk_load(boxes) }
    }

    /// The distance from `p` to the nearest segment, or infinity when none
    /// lies within `beyond`.
    fn distance(&self, plines: &[Polyline], p: Point, beyond: f64) -> f64 {
        let query = AABB::from_corners([p.x - beyond, p.y - beyond], [p.x + beyond, p.y + beyond]);
        self.tree
            .locate_in_envelope_intersecting(query)
            .map(|b| {
                let (k, i) = b.data;
                let line = &plines[k];
                let q = seg_closest_point(line.at(i), line.at(line.next_wrapping_index(i)), CVec::new(p.x, p.y), 1e-12);
                (Point::new(q.x, q.y) - p).norm()
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// `path` with each join arc (an arc of radius `half` about a vertex of
/// `drawn`, tangent to the sides before and after it) replaced by the two
/// sides extended to where they meet.
fn miter(path: &Polyline, drawn: &Polyline, half: f64) -> Polyline {
    let corners: RTree<[f64; 2]> = RTree::bulk_load(drawn.iter_vertexes().map(|v| [v.x, v.y]).collect());
    let n = path.vertex_count();
    let mut out = Polyline::with_capacity(n * 2, true);
    for i in 0..n {
        let (v1, v2) = (path.at(i), path.at(path.next_wrapping_index(i)));
        let prev = path.at(path.prev_wrapping_index(i));
        let next = path.at(path.fwd_wrapping_index(i, 2));
        let mitered = (v1.bulge != 0.0).then(|| join_miter(prev, v1, v2, next, half, &corners)).flatten();
        match mitered {
            Some(m) => {
                out.add(v1.x, v1.y, 0.0);
                out.add(m.x, m.y, 0.0);
            }
            None => out.add_vertex(v1),
        }
    }
    out
}

/// The miter point of join arc `v1`→`v2`, if it is one: radius `half`,
/// centred on a drawn vertex, tangent to the segments on both sides.
fn join_miter(prev: PlineVertex, v1: PlineVertex, v2: PlineVertex, next: PlineVertex, half: f64, corners: &RTree<[f64; 2]>) -> Option<Point> {
    let (a, b) = (Point::new(v1.x, v1.y), Point::new(v2.x, v2.y));
    let (centre, radius, _, sweep) = crate::job::arc_circle(a, b, v1.bulge);
    let corner = corners.nearest_neighbor([centre.x, centre.y])?;
    let tight = 1e-6 * (1.0 + half);
    if (radius - half).abs() > tight || (Point::new(corner[0], corner[1]) - centre).norm() > tight {
        return None;
    }
    let stretch = 1.0 / (sweep / 2.0).cos();
    if !(stretch.is_finite() && stretch > 0.0 && stretch <= MITER_LIMIT) {
        return None;
    }
    // The arc's tangents at its ends, and the sides' directions there.
    let turn = |v: nalgebra::Vector2<f64>| if sweep > 0.0 { nalgebra::Vector2::new(-v.y, v.x) } else { nalgebra::Vector2::new(v.y, -v.x) };
    let (t_in, t_out) = (turn((a - centre).normalize()), turn((b - centre).normalize()));
    let side_end = end_tangent(prev, v1);
    let side_start = start_tangent(v2, next);
    if (side_end - t_in).norm() > 1e-6 || (side_start - t_out).norm() > 1e-6 {
        return None;
    }
    let bisector = ((a - centre) + (b - centre)).normalize();
    Some(centre + bisector * half * stretch)
}

/// Unit tangent of segment `v1`→`v2` at its start.
fn start_tangent(v1: PlineVertex, v2: PlineVertex) -> nalgebra::Vector2<f64> {
    tangent(v1, v2, true)
}

/// Unit tangent of segment `v1`→`v2` at its end.
fn end_tangent(v1: PlineVertex, v2: PlineVertex) -> nalgebra::Vector2<f64> {
    tangent(v1, v2, false)
}

fn tangent(v1: PlineVertex, v2: PlineVertex, at_start: bool) -> nalgebra::Vector2<f64> {
    let (a, b) = (Point::new(v1.x, v1.y), Point::new(v2.x, v2.y));
    if v1.bulge == 0.0 {
        return (b - a).normalize();
    }
    let (centre, _, _, sweep) = crate::job::arc_circle(a, b, v1.bulge);
    let r = if at_start { a - centre } else { b - centre }.normalize();
    if sweep > 0.0 {
        nalgebra::Vector2::new(-r.y, r.x)
    } else {
        nalgebra::Vector2::new(r.y, -r.x)
    }
}

/// The geometry of offset `path` in place of `drawn`: its arcs flattened to
/// `tolerance` and kept as arcs.
fn geometry_of(path: &Polyline, drawn: &Geometry, tolerance: f64) -> Geometry {
    let mut points: Vec<Point> = Vec::with_capacity(path.vertex_count());
    let mut arcs = Vec::new();
    for (v1, v2) in segments(path) {
        let (a, b) = (Point::new(v1.x, v1.y), Point::new(v2.x, v2.y));
        if points.is_empty() {
            points.push(a);
        }
        if v1.bulge == 0.0 {
            points.push(b);
            continue;
        }
        // An arc of more than a half circle goes in two halves (|bulge| ≤ 1).
        let halves = if v1.bulge.abs() > 1.0 {
            let (centre, radius, start, sweep) = crate::job::arc_circle(a, b, v1.bulge);
            let mid = centre + nalgebra::Vector2::new((start + sweep / 2.0).cos(), (start + sweep / 2.0).sin()) * radius;
            let half_bulge = (sweep / 8.0).tan();
            vec![(mid, half_bulge), (b, half_bulge)]
        } else {
            vec![(b, v1.bulge)]
        };
        for (to, bulge) in halves {
            let from = points.len() - 1;
            let start = points[from];
            points.extend(arc_points(start, to, bulge, tolerance));
            arcs.push(ArcSpan { from, to: points.len() - 1, bulge });
        }
    }
    // The closing segment ends on the first vertex, which is not repeated.
    points.pop();
    Geometry { points, closed: true, arcs, profile: Vec::new(), process: drawn.process, source: drawn.source.clone() }
}

/// Parts nested closer than the kerf: an offset contour (`offset`, by
/// geometry) that comes nearer than half its kerf to another drawn contour
/// that cuts (it would cut into it).
fn check_clearance(drawn: &Job, kerfed: &Job, cutting: &[usize], offset: &[usize], layers: &[KerfLayer], tolerance: f64) -> Result<()> {
    let cuts: Vec<bool> = layers.iter().map(|l| l.cuts || l.kerf > 0.0).collect();
    let waste = Waste::new(drawn, &cuts);
    let mut cuts_parts = vec![false; drawn.geometries.len()];
    cutting.iter().for_each(|&k| cuts_parts[k] = true);
    // The chords of a flattened arc lie up to the tolerance off it.
    let slack = tolerance + EXACT_MM;
    for &k in offset {
        let g = &kerfed.geometries[k];
        let reach = layers[g.process].kerf / 2.0 - slack;
        for i in 0..g.segments() {
            let (a, b) = (g.points[i], g.points[(i + 1) % g.points.len()]);
            if let Some((o, _, _, distance)) = waste.near(a, b, reach).find(|&(o, ..)| o != k && cuts_parts[o]) {
                let at = nalgebra::center(&a, &b);
                return Err(Error::Plan(format!(
                    "{} and {}: nested closer than the kerf of {} mm (layer '{}'): the cut of the first passes {distance:.3} mm from the second at ({:.3}, {:.3}); space them by the kerf at least (exactly the kerf to share a cut)",
                    g.source,
                    drawn.geometries[o].source,
                    layers[g.process].kerf,
                    kerfed.processes[g.process].layer,
                    at.x,
                    at.y
                )));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
