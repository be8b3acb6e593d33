//! Topology: what a [`Job`]'s geometry is made of, as every later stage sees
//! it. Built once from a job ([`Topology::build`]); the cutting planner makes
//! its End-point Cutting Problem of it, and the plate model, lead-ins, kerf,
//! bridges and the thermal model are to build on it.
//!
//! * **Contours**: geometry k is contour k, open or closed. An open geometry
//!   can be an inner contour (engraving on a part is done before the part
//!   falls), never an outer one.
//! * **Elements** ([`contours`]): each polyline is split at its corners (a
//!   turn sharper than [`TopologyOptions::corner_angle_deg`]) and where a
//!   common cut begins or ends, so a flattened arc stays one element. A closed
//!   polyline without two such breaks (a flattened circle) is split into up to
//!   4 arcs of equal length, so that it can be entered at more than one place.
//! * **Common cuts** ([`common_cuts`]): where the boundaries of two closed
//!   geometries coincide (collinear overlapping segments within
//!   [`TopologyOptions::common_cut_tolerance_mm`], as two parts nested side by
//!   side and each exported whole), the overlap is one element on both
//!   contours, cut once. Segments are split at the ends of partial overlaps,
//!   and the ends of every overlap are welded to one point, so the shared
//!   element and its neighbours on either contour meet exactly.
//! * **Containment tree** ([`containment`]): the smallest closed contour that
//!   contains another is its direct outer ([`Topology::outer`]).
//! * **Levels, ranks and groups** (seed 001, "contour levels, ranks and
//!   groups"): see the fields of [`Topology`].
//!
//! Both searches go through R-trees (segment boxes for common cuts, contour
//! boxes for containment), so a sheet of thousands of contours and a hundred
//! thousand segments builds in well under a second.

mod common_cuts;
pub mod kerf;
mod containment;
mod contours;
pub mod plate;
pub mod waste;
#[cfg(test)]
pub(crate) mod tests;

use std::collections::HashMap;

use rstar::primitives::{GeomWithData, Rectangle};

use crate::error::{Error, Result};
use crate::job::{Job, Point};
pub use common_cuts::common_cuts;
pub use containment::{side, Side};

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

/// One element: the piece of a polyline between two breaks (corners, ends of
/// common cuts), cut in one go in either direction.
#[derive(Debug, Clone, PartialEq)]
pub struct Element {
    /// The geometry the points belong to; for a common cut the first of its
    /// two geometries (the lower index), whose coordinates it keeps.
    pub geometry: usize,
    /// The other geometry of a common cut.
    pub shared_with: Option<usize>,
    /// The polyline from the element's start to its end (at least 2 points).
    pub points: Vec<Point>,
}

impl Element {
    pub fn start(&self) -> Point {
        self.points[0]
    }

    pub fn end(&self) -> Point {
        self.points[self.points.len() - 1]
    }

    /// The geometries this element is marked for: one, or two for a common cut.
    pub fn geometries(&self) -> Vec<usize> {
        std::iter::once(self.geometry).chain(self.shared_with).collect()
    }
}

/// An element shared by two contours.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommonCut {
    pub element: usize,
    pub contours: (usize, usize),
}

/// A job's geometry as contours of elements, with the relations between
/// contours. Contour k is the job's geometry k.
#[derive(Debug, Clone)]
pub struct Topology {
    pub elements: Vec<Element>,
    /// Per contour: its elements in order along it. An element on two
    /// contours is a common cut.
    pub contours: Vec<Vec<usize>>,
    /// The elements on two contours, in element order.
    pub common_cuts: Vec<CommonCut>,
    /// Per contour: its direct outer contour, the smallest closed contour that
    /// contains it (None on the sheet itself): the containment tree.
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

impl Topology {
    /// The topology of `job`. Elements keep the geometries' vertices, except
    /// that the ends of common cuts may move (by the tolerance at most) onto
    /// the first geometry's.
    /// Errors (naming the geometry's source) on non-finite coordinates and on
    /// degenerate shapes: an open polyline of fewer than 2 distinct points, a
    /// closed one of fewer than 3 or of no area.
    pub fn build(job: &Job, options: &TopologyOptions) -> Result<Topology> {
        let tol = options.common_cut_tolerance_mm;
        if !(tol.is_finite() && tol > 0.0) {
            return Err(Error::Plan(format!("topology: common_cut_tolerance_mm must be a positive number, not {tol}")));
        }
        let angle = options.corner_angle_deg;
        if !(angle.is_finite() && angle > 0.0 && angle <= 180.0) {
            return Err(Error::Plan(format!("topology: corner_angle_deg must be in (0, 180], not {angle}")));
        }
        let shapes = job.geometries.iter().map(contours::clean).collect::<Result<Vec<_>>>()?;
        let (splits, ends_overlap) = common_cuts::find_overlaps(&shapes, tol);
        let mut chains: Vec<contours::Chain> = shapes
            .iter()
            .zip(splits)
            .zip(ends_overlap)
            .map(|((s, sp), e)| contours::Chain::new(s, sp, e, tol))
            .collect();
        common_cuts::weld(&mut chains, tol);
        let partners = common_cuts::match_common_cuts(&chains);
        let (elements, contours) = contours::elements(&chains, &partners, angle.to_radians().cos());
        let shared = common_cuts::common_cuts(&contours, elements.len());
        let outlines: Vec<containment::Outline> = chains.iter().map(|c| (c.points.as_slice(), c.closed)).collect();
        let outer = containment::containment(&outlines, tol);
        let levels = containment::levels(&outer);
        let ranks = common_cuts::ranks(&contours, elements.len(), &shared);
        let groups = groups(contours.len(), &inner_outer(&outer), &shared);
        Ok(Topology { elements, contours, common_cuts: shared, outer, levels, ranks, groups })
    }

    /// Every (inner, outer) pair of the containment tree, by inner contour.
    pub fn inner_outer(&self) -> Vec<(usize, usize)> {
        inner_outer(&self.outer)
    }

    /// Number of groups.
    pub fn group_count(&self) -> usize {
        self.groups.iter().max().map_or(0, |&g| g + 1)
    }
}

/// Per geometry of `job`: its level among the closed contours that cut parts
/// out (`cuts`, per process) — a part's outline even, a hole odd — or `None`
/// for the others (open paths, engraved outlines). Errors as
/// [`Topology::build`] does on a degenerate contour.
pub fn part_levels(job: &Job, cuts: &[bool]) -> Result<Vec<Option<usize>>> {
    let cutting: Vec<usize> = (0..job.geometries.len()).filter(|&k| job.geometries[k].closed && cuts.get(job.geometries[k].process).copied().unwrap_or(false)).collect();
    let shapes = cutting.iter().map(|&k| contours::clean(&job.geometries[k])).collect::<Result<Vec<_>>>()?;
    let outlines: Vec<containment::Outline> = shapes.iter().map(|s| (s.points.as_slice(), true)).collect();
    let levels = containment::levels(&containment::containment(&outlines, 1e-7));
    let mut out = vec![None; job.geometries.len()];
    for (c, &k) in cutting.iter().enumerate() {
        out[k] = Some(levels[c]);
    }
    Ok(out)
}

fn inner_outer(outer: &[Option<usize>]) -> Vec<(usize, usize)> {
    outer.iter().enumerate().filter_map(|(k, o)| o.map(|o| (k, o))).collect()
}

/// Per contour: its group (see [`Topology::groups`]), from the links between
/// contours: inner/outer pairs and common cuts.
fn groups(k: usize, inner_outer: &[(usize, usize)], common_cuts: &[CommonCut]) -> Vec<usize> {
    let mut parent: Vec<usize> = (0..k).collect();
    fn root(parent: &mut [usize], mut c: usize) -> usize {
        while parent[c] != c {
            parent[c] = parent[parent[c]];
            c = parent[c];
        }
        c
    }
    let links = inner_outer.iter().copied().chain(common_cuts.iter().map(|cc| cc.contours));
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

type Box2 = GeomWithData<Rectangle<[f64; 2]>, (usize, usize)>;

fn rect(lo: Point, hi: Point) -> Rectangle<[f64; 2]> {
    Rectangle::from_corners([lo.x, lo.y], [hi.x, hi.y])
}
