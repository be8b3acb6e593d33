//! The plate (seed 000, "removing complexity"): the rectangle the parts are
//! cut from, as the cutting model sees it. A preprocessor ([`lay_out`]):
//!
//! * splits the plate into cells: a grid of straight skeleton cuts no
//!   further apart than `[plate] skeleton_piece`, each placed in a gap
//!   between parts where there is one, and the remnant rectangle (given, or
//!   the largest free one at a corner);
//! * makes each cell minus the parts (polygon booleans, `i_overlay`) into
//!   waste regions, the **faces**: a face's outline runs along the plate's
//!   edge (never cut), along parts (their elements, now common cuts between
//!   part and face: an area enclosed by parts and the edge cannot fall
//!   before what lies in it is cut, seed 000's Figure 1), and along the cell
//!   borders: those pieces are the skeleton and remnant cuts, added to the
//!   job as open geometries;
//! * fixes the faces the clamps touch (the largest one when there is no
//!   clamp) and the remnant (it holds no part): their rules are dropped
//!   (seed 000's Figure 2).
//!
//! The cutting model rebuilds the topology of the parts plus the faces
//! ([`PlateLayout::topology_job`]) and drops the elements on the plate's edge.

use i_overlay::core::fill_rule::FillRule;
use i_overlay::core::overlay_rule::OverlayRule;
use i_overlay::float::single::SingleFloatOverlay;

use super::contours::signed_area;
use super::{Element, Topology, TopologyOptions};
use crate::config::{PlateConfig, RemnantSetting, ScrapCuts};
use crate::error::{Error, Result};
use crate::job::{bounds_of, Geometry, Job, Point};

/// How far a part may reach past the plate's edge (mm): an arc drawn to
/// touch the edge comes in a few µm beyond it once flattened from Bézier
/// curves; far less than any kerf, so it is cut as drawn.
const OFF_PLATE_MM: f64 = 0.1;

/// The most skeleton pieces a plate is cut into: a job file's plate is an
/// upload, and each piece is a polygon operation.
const MAX_CELLS: usize = 10_000;

/// A waste region of the plate: a cell of the skeleton grid (or the
/// remnant) minus the parts.
#[derive(Debug, Clone, PartialEq)]
pub struct Face {
    /// Its outline, counter-clockwise (the parts wholly inside it are its
    /// inner contours, found by containment).
    pub ring: Vec<Point>,
    /// Held by a clamp (or the largest, without clamps), or the remnant: it
    /// never moves, so no rule waits for it to close.
    pub fixed: bool,
    pub remnant: bool,
}

/// What [`lay_out`] made of the plate.
#[derive(Debug, Clone, PartialEq)]
pub struct PlateLayout {
    /// The plate's corners.
    pub lo: Point,
    pub hi: Point,
    /// Geometries of the laid-out job from this index on are the skeleton
    /// and remnant cuts; before it, the job's own.
    pub first_cut: usize,
    pub faces: Vec<Face>,
    pub skeleton_cuts: usize,
    pub remnant_cuts: usize,
    /// The remnant kept, if any (lower-left, upper-right corner).
    pub remnant: Option<(Point, Point)>,
    /// Skeleton and remnant cuts after the parts instead of in their route.
    pub scrap_after: bool,
    tolerance: f64,
}

impl PlateLayout {
    /// The side of the plate a point lies on (within the tolerance): 0 left,
    /// 1 right, 2 bottom, 3 top.
    fn sides(&self, p: Point) -> [bool; 4] {
        let t = self.tolerance;
        [(p.x - self.lo.x).abs() <= t, (p.x - self.hi.x).abs() <= t, (p.y - self.lo.y).abs() <= t, (p.y - self.hi.y).abs() <= t]
    }

    /// A point on the plate's edge: a cut can start there without a pierce.
    pub fn on_edge(&self, p: Point) -> bool {
        self.sides(p).contains(&true)
    }

    /// A polyline lying along one side of the plate: nothing to cut there.
    pub fn along_edge(&self, points: &[Point]) -> bool {
        (0..4).any(|side| points.iter().all(|&p| self.sides(p)[side]))
    }

    /// Whether contour `c` of [`Self::topology_job`]'s topology is a region
    /// no rule binds: a fixed one, or any when the skeleton is cut after the parts.
    pub fn is_fixed(&self, c: usize) -> bool {
        c >= self.first_cut && (self.scrap_after || self.faces[c - self.first_cut].fixed)
    }

    /// Whether an element of that topology is left out of the route: it
    /// lies on the plate's edge, or is a region's own (a skeleton or remnant
    /// cut) when those come after the parts.
    pub fn uncut(&self, e: &Element) -> bool {
        self.along_edge(&e.points) || (self.scrap_after && e.geometry >= self.first_cut)
    }

    /// The job the cutting model's topology is built of: the job's own
    /// geometries (without the skeleton and remnant cuts) and the faces, as
    /// closed geometries, from index `first_cut` on.
    pub fn topology_job(&self, job: &Job, process: usize) -> Job {
        let mut geometries: Vec<Geometry> = job.geometries[..self.first_cut].to_vec();
        geometries.extend(self.faces.iter().enumerate().map(|(k, f)| Geometry {
            points: f.ring.clone(),
            closed: true,
            arcs: Vec::new(), profile: Vec::new(),
            process,
            source: format!("plate: {}", face_name(k, f)),
        }));
        Job { geometries, ..job.clone() }
    }

    /// The same layout for a job made of the geometries `which` of the
    /// laid-out job (in that order): `None` unless the cuts are all there,
    /// last, in their order.
    pub fn select(&self, which: &[usize]) -> Option<PlateLayout> {
        let cuts = which.iter().position(|&g| g >= self.first_cut).unwrap_or(which.len());
        let in_order = which[cuts..].iter().enumerate().all(|(i, &g)| g == self.first_cut + i);
        let all = which.len() - cuts == self.skeleton_cuts + self.remnant_cuts;
        (in_order && all).then(|| PlateLayout { first_cut: cuts, ..self.clone() })
    }
}

fn face_name(k: usize, f: &Face) -> String {
    if f.remnant {
        "remnant".to_string()
    } else {
        format!("waste region {}", k + 1)
    }
}

/// Lays the job out on the plate: checks that it lies on it, places the
/// skeleton and remnant cuts and makes the faces (see the module). `cuts`:
/// per geometry, whether its layer cuts through (only those are parts);
/// `process`: the process of the skeleton and remnant cuts. Returns the job
/// with those cuts added, and the layout.
pub fn lay_out(job: &Job, cuts: &[bool], plate: &PlateConfig, process: usize, options: &TopologyOptions) -> Result<(Job, PlateLayout)> {
    let tol = options.common_cut_tolerance_mm;
    let (lo, hi) = (Point::new(plate.x, plate.y), Point::new(plate.x + plate.width, plate.y + plate.height));
    let slack = tol.max(OFF_PLATE_MM);
    for g in &job.geometries {
        let (a, b) = g.bounds();
        if a.x < lo.x - slack || a.y < lo.y - slack || b.x > hi.x + slack || b.y > hi.y + slack {
            return Err(Error::Plan(format!(
                "{}: spans ({:.3}, {:.3})–({:.3}, {:.3}) mm, off the plate ({}, {})–({}, {}) mm ([plate])",
                g.source, a.x, a.y, b.x, b.y, lo.x, lo.y, hi.x, hi.y
            )));
        }
    }
    let topology = Topology::build(job, options)?;
    let n = job.geometries.len();
    // Parts: closed shapes that cut through, not inside another such.
    let inside_a_part = |mut k: usize| {
        while let Some(o) = topology.outer[k] {
            if cuts[o] && job.geometries[o].closed {
                return true;
            }
            k = o;
        }
        false
    };
    let parts: Vec<usize> = (0..n).filter(|&k| job.geometries[k].closed && cuts[k] && !inside_a_part(k)).collect();
    let boxes: Vec<(Point, Point)> = parts.iter().map(|&k| job.geometries[k].bounds()).collect();
    let clear = plate.clearance;
    let grown: Vec<(Point, Point)> = boxes.iter().map(|&(a, b)| (a - vector(clear), b + vector(clear))).collect();
    let remnant = match plate.remnant {
        RemnantSetting::None => None,
        RemnantSetting::Auto => auto_remnant(lo, hi, &grown, plate.remnant_min),
        RemnantSetting::At([x, y, w, h]) => {
            let (a, b) = (Point::new(x, y), Point::new(x + w, y + h));
            if a.x < lo.x - tol || a.y < lo.y - tol || b.x > hi.x + tol || b.y > hi.y + tol {
                return Err(Error::Plan(format!("[plate] remnant: ({x}, {y}) {w} x {h} mm is not on the plate")));
            }
            if let Some(i) = boxes.iter().position(|&(p, q)| p.x < b.x - tol && q.x > a.x + tol && p.y < b.y - tol && q.y > a.y + tol) {
                return Err(Error::Plan(format!("[plate] remnant: ({x}, {y}) {w} x {h} mm overlaps {}", job.geometries[parts[i]].source)));
            }
            Some((a, b))
        }
    };
    let piece = plate.skeleton_piece;
    // Cut positions come at least half a piece apart: the cell count is known before.
    let most = |side: f64| if piece > 0.0 { (2.0 * side / piece).ceil() + 1.0 } else { 1.0 };
    if most(plate.width) * most(plate.height) > MAX_CELLS as f64 {
        return Err(Error::Plan(format!(
            "[plate] skeleton_piece = {piece} mm could cut a {} x {} mm plate into more than {MAX_CELLS} pieces: use larger pieces",
            plate.width, plate.height
        )));
    }
    let xs = cut_positions(lo.x, hi.x, &grown.iter().map(|(a, b)| (a.x, b.x)).collect::<Vec<_>>(), piece);
    let ys = cut_positions(lo.y, hi.y, &grown.iter().map(|(a, b)| (a.y, b.y)).collect::<Vec<_>>(), piece);
    // A part within the tolerance of the edge lies on it: snapped there, it
    // leaves no sliver of waste between (which would pinch the region).
    let snap = |v: f64, lo: f64, hi: f64| if (v - lo).abs() <= tol { lo } else if (v - hi).abs() <= tol { hi } else { v };
    let rings: Vec<Vec<[f64; 2]>> = parts
        .iter()
        .map(|&k| ccw(&job.geometries[k].points).into_iter().map(|[x, y]| [snap(x, lo.x, hi.x), snap(y, lo.y, hi.y)]).collect())
        .collect();
    let remnant_ring = remnant.map(|(a, b)| rect_ring(a, b));
    let mut faces: Vec<Face> = Vec::new();
    let xs_all: Vec<f64> = std::iter::once(lo.x).chain(xs.iter().copied()).chain(std::iter::once(hi.x)).collect();
    let ys_all: Vec<f64> = std::iter::once(lo.y).chain(ys.iter().copied()).chain(std::iter::once(hi.y)).collect();
    for xw in xs_all.windows(2) {
        for yw in ys_all.windows(2) {
            let (a, b) = (Point::new(xw[0], yw[0]), Point::new(xw[1], yw[1]));
            let mut clip: Vec<Vec<[f64; 2]>> = (0..parts.len())
                .filter(|&i| boxes[i].0.x < b.x && boxes[i].1.x > a.x && boxes[i].0.y < b.y && boxes[i].1.y > a.y)
                .map(|i| rings[i].clone())
                .collect();
            clip.extend(remnant_ring.clone());
            let shapes = rect_ring(a, b).overlay_as::<i64>(&clip, OverlayRule::Difference, FillRule::NonZero);
            for shape in shapes {
                let Some(outer) = shape.into_iter().next() else { continue };
                let ring: Vec<Point> = outer.iter().map(|q| Point::new(q[0], q[1])).collect();
                let perimeter: f64 = (0..ring.len()).map(|i| (ring[(i + 1) % ring.len()] - ring[i]).norm()).sum();
                // Slivers thinner than the tolerance (a part within it of a
                // cell border) are no region.
                if signed_area(&ring).abs() > tol * perimeter {
                    faces.push(Face { ring, fixed: false, remnant: false });
                }
            }
        }
    }
    if let Some((a, b)) = remnant {
        faces.push(Face { ring: rect_ring(a, b).iter().map(|q| Point::new(q[0], q[1])).collect(), fixed: false, remnant: true });
    }
    fix_faces(&mut faces, plate);
    let layout = PlateLayout {
        lo,
        hi,
        first_cut: n,
        faces,
        skeleton_cuts: 0,
        remnant_cuts: 0,
        remnant,
        scrap_after: plate.scrap_cuts == ScrapCuts::After,
        tolerance: tol,
    };
    // The cuts: the faces' own elements (not the parts', not on the edge).
    let faces_topology = Topology::build(&layout.topology_job(job, process), options)?;
    let remnant_face = layout.faces.iter().position(|f| f.remnant).map(|k| n + k);
    let mut skeleton = Vec::new();
    let mut remnant_cuts = Vec::new();
    for e in &faces_topology.elements {
        if e.geometry < n || layout.along_edge(&e.points) {
            continue;
        }
        let is_remnant = remnant_face.is_some_and(|r| e.geometries().contains(&r));
        if is_remnant { &mut remnant_cuts } else { &mut skeleton }.push(e.points.clone());
    }
    let mut laid = job.clone();
    let named = |kind: &str, k: usize, points: Vec<Point>| Geometry::polyline(points, false, process, format!("plate: {kind} cut {}", k + 1));
    let (s, r) = (skeleton.len(), remnant_cuts.len());
    laid.geometries.extend(skeleton.into_iter().enumerate().map(|(k, p)| named("skeleton", k, p)));
    laid.geometries.extend(remnant_cuts.into_iter().enumerate().map(|(k, p)| named("remnant", k, p)));
    tracing::info!(faces = layout.faces.len(), skeleton_cuts = s, remnant_cuts = r, "plate laid out");
    Ok((laid, PlateLayout { skeleton_cuts: s, remnant_cuts: r, ..layout }))
}

fn vector(d: f64) -> nalgebra::Vector2<f64> {
    nalgebra::Vector2::new(d, d)
}

fn rect_ring(a: Point, b: Point) -> Vec<[f64; 2]> {
    vec![[a.x, a.y], [b.x, a.y], [b.x, b.y], [a.x, b.y]]
}

/// A closed polyline counter-clockwise, so that overlapping parts add up
/// under the non-zero rule.
fn ccw(points: &[Point]) -> Vec<[f64; 2]> {
    let mut ring: Vec<[f64; 2]> = points.iter().map(|p| [p.x, p.y]).collect();
    if signed_area(points) < 0.0 {
        ring.reverse();
    }
    ring
}

/// Where to cut across `lo..hi` so that no piece is longer than `piece`:
/// from each cut, the furthest position within `piece` (and at least half
/// of it) outside every blocked interval (the parts with their clearance),
/// else at `piece` (the cut then stops at the parts it meets).
fn cut_positions(lo: f64, hi: f64, blocked: &[(f64, f64)], piece: f64) -> Vec<f64> {
    if piece <= 0.0 {
        return Vec::new();
    }
    let mut b: Vec<(f64, f64)> = blocked.to_vec();
    b.sort_by(|p, q| p.0.total_cmp(&q.0));
    let mut merged: Vec<(f64, f64)> = Vec::new();
    for (s, e) in b {
        match merged.last_mut() {
            Some(last) if s <= last.1 => last.1 = last.1.max(e),
            _ => merged.push((s, e)),
        }
    }
    let free = |x: f64| !merged.iter().any(|&(s, e)| s < x && x < e);
    let mut out = Vec::new();
    let mut x = lo;
    while hi - x > piece {
        let (least, most) = (x + piece / 2.0, x + piece);
        // The candidates: the far end of the range and the blocked
        // intervals' starts within it; the furthest free one.
        let candidates = std::iter::once(most).chain(merged.iter().map(|&(s, _)| s)).filter(|&c| c >= least && c <= most);
        x = candidates.filter(|&c| free(c)).fold(None, |best: Option<f64>, c| Some(best.map_or(c, |b| b.max(c)))).unwrap_or(most);
        out.push(x);
    }
    out
}

/// The largest rectangle free of `boxes` at a corner of the plate whose
/// sides are both at least `min`, not the whole plate.
fn auto_remnant(lo: Point, hi: Point, boxes: &[(Point, Point)], min: f64) -> Option<(Point, Point)> {
    if boxes.is_empty() {
        return None;
    }
    let mut best: Option<(f64, (Point, Point))> = None;
    // Each corner mirrored onto the upper right: (sx, sy) flip x and y.
    for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
        let m = |p: Point| Point::new(sx * p.x, sy * p.y);
        let (plo, phi) = bounds_of([m(lo), m(hi)].iter());
        let bs: Vec<(Point, Point)> = boxes.iter().map(|&(a, b)| bounds_of([m(a), m(b)].iter())).collect();
        // Rectangles [a, phi.x] x [floor, phi.y]: for each left side a (the
        // plate's, or a box's right side), the floor is the highest box
        // reaching right of a. Left sides from right to left, the boxes
        // sorted the same way: one sweep.
        let mut by_right: Vec<(f64, f64)> = bs.iter().map(|b| (b.1.x, b.1.y)).collect();
        by_right.sort_by(|p, q| q.0.total_cmp(&p.0));
        let mut lefts: Vec<f64> = std::iter::once(plo.x).chain(by_right.iter().map(|b| b.0)).filter(|&a| a >= plo.x && a < phi.x).collect();
        lefts.sort_by(|p, q| q.total_cmp(p));
        let (mut floor, mut next) = (plo.y, 0);
        for a in lefts {
            while next < by_right.len() && by_right[next].0 > a {
                floor = floor.max(by_right[next].1);
                next += 1;
            }
            let (w, h) = (phi.x - a, phi.y - floor);
            if w >= min && h >= min && w * h > best.map_or(0.0, |b| b.0) {
                let corners = [m(Point::new(a, floor)), m(phi)];
                best = Some((w * h, bounds_of(corners.iter())));
            }
        }
    }
    best.map(|b| b.1)
}

/// The faces a clamp touches are fixed, and the remnant; without clamps,
/// the largest other one (the plate around the parts holds by its weight).
fn fix_faces(faces: &mut [Face], plate: &PlateConfig) {
    // The remnant holds no part and is kept whole: it waits for nothing.
    for f in faces.iter_mut() {
        f.fixed = f.remnant || plate.clamps.iter().any(|c| reaches(Point::new(c.x, c.y), c.radius, &f.ring));
    }
    if plate.clamps.is_empty() {
        let largest = (0..faces.len())
            .filter(|&k| !faces[k].remnant)
            .max_by(|&a, &b| signed_area(&faces[a].ring).abs().total_cmp(&signed_area(&faces[b].ring).abs()).then(b.cmp(&a)));
        if let Some(k) = largest {
            faces[k].fixed = true;
        }
    }
}

/// A disc of `radius` around `c` meets the polygon `ring`.
fn reaches(c: Point, radius: f64, ring: &[Point]) -> bool {
    let n = ring.len();
    let mut inside = false;
    for i in 0..n {
        let (a, b) = (ring[i], ring[(i + 1) % n]);
        let d = b - a;
        let t = if d.norm_squared() > 0.0 { ((c - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
        if (a + d * t - c).norm() <= radius {
            return true;
        }
        if (a.y > c.y) != (b.y > c.y) && a.x + (c.y - a.y) / d.y * d.x > c.x {
            inside = !inside;
        }
    }
    inside
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::config::ClampConfig;
    use crate::topology::tests::{job, rect};

    /// A plate of `width` x `height` mm at the origin: no skeleton, no
    /// remnant, no clamps.
    pub(crate) fn plate(width: f64, height: f64) -> PlateConfig {
        PlateConfig {
            x: 0.0,
            y: 0.0,
            width,
            height,
            thickness: 2.0,
            skeleton_piece: 0.0,
            remnant: RemnantSetting::None,
            remnant_min: 50.0,
            clearance: 2.0,
            scrap_cuts: ScrapCuts::InRoute,
            layer: None,
            clamps: Vec::new(),
            support_grid: None,
        }
    }

    fn lay(j: &Job, p: &PlateConfig) -> (Job, PlateLayout) {
        lay_out(j, &vec![true; j.geometries.len()], p, 0, &TopologyOptions::default()).unwrap()
    }

    #[test]
    fn cut_positions_use_the_gaps_and_keep_pieces_short() {
        // Parts block 0-45 and 55-140; pieces of at most 100.
        let xs = cut_positions(0.0, 300.0, &[(0.0, 45.0), (55.0, 140.0)], 100.0);
        assert_eq!(xs[0], 55.0, "the gap's far end, the furthest free position within 100");
        assert!(xs.windows(2).all(|w| w[1] - w[0] <= 100.0) && 300.0 - xs[xs.len() - 1] <= 100.0, "{xs:?}");
        assert_eq!(cut_positions(0.0, 300.0, &[], 0.0), Vec::<f64>::new());
        // No gap: at the piece's length, through the part.
        assert_eq!(cut_positions(0.0, 150.0, &[(0.0, 150.0)], 100.0), vec![100.0]);
    }

    #[test]
    fn the_remnant_is_the_largest_free_corner_rectangle() {
        // Parts in the left 100 mm of a 300 x 200 plate: the right 190 mm strip
        // (with 10 mm clearance already in the boxes).
        let boxes = [(Point::new(0.0, 0.0), Point::new(110.0, 200.0))];
        let r = auto_remnant(Point::new(0.0, 0.0), Point::new(300.0, 200.0), &boxes, 50.0).unwrap();
        assert_eq!(r, (Point::new(110.0, 0.0), Point::new(300.0, 200.0)));
        // Too narrow a strip: none.
        assert_eq!(auto_remnant(Point::new(0.0, 0.0), Point::new(300.0, 200.0), &boxes, 200.0), None);
        // A part in the lower-left corner: the strip above it (300 x 150)
        // beats the one beside it (200 x 200).
        let boxes = [(Point::new(0.0, 0.0), Point::new(100.0, 50.0))];
        let r = auto_remnant(Point::new(0.0, 0.0), Point::new(300.0, 200.0), &boxes, 50.0).unwrap();
        assert_eq!(r, (Point::new(0.0, 50.0), Point::new(300.0, 200.0)));
        // A part in the middle of the bottom: a corner rectangle beside it.
        let boxes = [(Point::new(100.0, 0.0), Point::new(150.0, 150.0))];
        let r = auto_remnant(Point::new(0.0, 0.0), Point::new(300.0, 200.0), &boxes, 50.0).unwrap();
        assert_eq!(r, (Point::new(150.0, 0.0), Point::new(300.0, 200.0)));
    }

    #[test]
    fn a_part_on_the_edge_shares_its_outline_with_the_waste_and_its_edge_is_not_cut() {
        // A 40 x 20 part in the plate's lower-left corner, and a free one.
        let j = job(vec![rect(0.0, 0.0, 40.0, 20.0, "corner"), rect(60.0, 60.0, 80.0, 80.0, "free")]);
        let (laid, layout) = lay(&j, &plate(200.0, 100.0));
        assert_eq!(laid.geometries.len(), 2, "no skeleton, no remnant: no cuts");
        assert_eq!(layout.faces.len(), 1);
        assert!(layout.faces[0].fixed, "the only region, the largest");
        let t = Topology::build(&layout.topology_job(&laid, 0), &TopologyOptions::default()).unwrap();
        // The corner part's two inner sides are common cuts with the waste; its
        // two sides on the edge lie along it.
        let corner: Vec<usize> = t.contours[0].clone();
        let on_edge = corner.iter().filter(|&&e| layout.along_edge(&t.elements[e].points)).count();
        let shared = corner.iter().filter(|&&e| t.elements[e].shared_with == Some(2)).count();
        assert_eq!((corner.len(), on_edge, shared), (4, 2, 2));
        assert_eq!(t.outer[1], Some(2), "the free part lies in the waste region");
        assert!(layout.on_edge(Point::new(0.0, 50.0)) && !layout.on_edge(Point::new(1.0, 50.0)));
    }

    #[test]
    fn skeleton_cuts_split_the_waste_and_clamps_fix_what_they_touch() {
        // Four 30 x 30 parts on a 200 x 100 plate, pieces of at most 60 mm.
        let parts: Vec<Geometry> = (0..4).map(|i| rect(10.0 + 50.0 * i as f64, 35.0, 40.0 + 50.0 * i as f64, 65.0, &format!("p{i}"))).collect();
        let j = job(parts);
        let mut p = plate(200.0, 100.0);
        p.skeleton_piece = 60.0;
        p.clamps = vec![ClampConfig { x: 0.0, y: 50.0, radius: 5.0 }];
        let (laid, layout) = lay(&j, &p);
        assert!(layout.skeleton_cuts > 0);
        assert_eq!(laid.geometries.len(), 4 + layout.skeleton_cuts);
        // Every cut lies in the waste, on a grid line, clear of the parts.
        for g in &laid.geometries[4..] {
            assert!(!g.closed && g.source.starts_with("plate: skeleton cut"));
            let (a, b) = g.bounds();
            assert!(a.x == b.x || a.y == b.y, "straight: {:?}", g.points);
            for part in &j.geometries {
                let (pa, pb) = part.bounds();
                let overlaps = a.x < pb.x && b.x > pa.x && a.y < pb.y && b.y > pa.y;
                assert!(!overlaps, "{} crosses {}", g.source, part.source);
            }
        }
        // Pieces at most 60 mm on a side.
        for f in &layout.faces {
            let (a, b) = bounds_of(f.ring.iter());
            assert!(b.x - a.x <= 60.0 + 1e-9 && b.y - a.y <= 60.0 + 1e-9, "{:?}", f.ring);
        }
        // Only the faces at the left edge are clamped.
        assert!(layout.faces.iter().any(|f| f.fixed) && layout.faces.iter().any(|f| !f.fixed));
        for f in layout.faces.iter().filter(|f| f.fixed) {
            assert!(f.ring.iter().any(|q| q.x == 0.0));
        }
    }

    #[test]
    fn a_remnant_is_cut_off_and_a_part_off_the_plate_is_refused() {
        let j = job(vec![rect(5.0, 5.0, 60.0, 95.0, "a")]);
        let mut p = plate(300.0, 100.0);
        p.remnant = RemnantSetting::Auto;
        let (laid, layout) = lay(&j, &p);
        let (a, b) = layout.remnant.unwrap();
        assert_eq!((a.x, a.y, b.x, b.y), (62.0, 0.0, 300.0, 100.0));
        assert_eq!((layout.remnant_cuts, layout.skeleton_cuts), (1, 0), "one straight cut across the plate");
        let cut = &laid.geometries[1];
        assert!(cut.points.iter().all(|q| q.x == 62.0) && cut.length() == 100.0, "{:?}", cut.points);
        let err = lay_out(&job(vec![rect(250.0, 5.0, 310.0, 50.0, "wide")]), &[true], &plate(300.0, 100.0), 0, &TopologyOptions::default()).unwrap_err().to_string();
        assert!(err.contains("wide") && err.contains("off the plate"), "{err}");
        p.remnant = RemnantSetting::At([40.0, 0.0, 100.0, 100.0]);
        let err = lay_out(&j, &[true], &p, 0, &TopologyOptions::default()).unwrap_err().to_string();
        assert!(err.contains("[plate] remnant") && err.contains("overlaps test.svg: a"), "{err}");
    }

    #[test]
    fn a_disc_touching_the_edge_and_a_part_a_rounding_error_off_it_make_no_cuts() {
        // A 64-gon of radius 30 whose lowest vertex is 0.003 mm above the
        // plate's edge (the waste is pinched there), and a rectangle 2 µm off
        // the left edge (as an SVG's f32 coordinates put it).
        let disc: Vec<(f64, f64)> = (0..64)
            .map(|k| {
                let a = -std::f64::consts::FRAC_PI_2 + 2.0 * std::f64::consts::PI * k as f64 / 64.0;
                (100.0 + 30.0 * a.cos(), 30.003 + 30.0 * a.sin())
            })
            .collect();
        let j = job(vec![crate::topology::tests::shape(&disc, true, "disc"), rect(2e-6, 50.0, 40.0, 90.0, "near")]);
        let (laid, layout) = lay(&j, &plate(200.0, 100.0));
        assert_eq!(laid.geometries.len(), 2, "no cut: {:?}", laid.geometries.get(2).map(|g| &g.points));
        let t = Topology::build(&layout.topology_job(&laid, 0), &TopologyOptions::default()).unwrap();
        // Every element of the waste region is the parts' or on the edge.
        for e in t.elements.iter().filter(|e| e.geometry == 2) {
            assert!(layout.along_edge(&e.points), "{:?}", e.points);
        }
        let near_left = t.contours[1].iter().filter(|&&e| layout.along_edge(&t.elements[e].points)).count();
        assert_eq!(near_left, 1, "the side 2 µm off the edge lies on it");
    }

    #[test]
    fn a_skeleton_of_too_many_pieces_is_refused_before_it_is_built() {
        let j = job(vec![rect(5.0, 5.0, 60.0, 95.0, "a")]);
        let mut p = plate(100_000.0, 100_000.0);
        p.skeleton_piece = 10.0;
        let err = lay_out(&j, &[true], &p, 0, &TopologyOptions::default()).unwrap_err().to_string();
        assert!(err.contains("skeleton_piece") && err.contains("10000 pieces"), "{err}");
    }
}
