//! Where the waste is, for what is added to the cuts after planning (lead-ins
//! and lead-outs, bridges): a point lies in a part's material when an odd
//! number of the closed cutting contours hold it (a part, its hole, a part
//! in the hole, …), else in the waste. Every geometry's segments sit in an
//! R-tree, so that how near a new cut comes to the drawing is a local query.

use rstar::primitives::GeomWithData;
use rstar::{RTree, AABB};

use super::containment::{side, Side};
use super::{rect, Box2};
use crate::job::{bounds_of, segment_distance, Job, Point};

/// The job's contours as material and waste.
pub struct Waste {
    /// Per geometry: its vertices and whether it is closed.
    outlines: Vec<(Vec<Point>, bool)>,
    /// Boxes of the closed contours that cut parts out.
    holders: RTree<Box2>,
    /// Every segment of every geometry: (geometry, segment).
    segments: RTree<Box2>,
}

impl Waste {
    /// The waste of `job`; `cuts` per process: whether its closed contours
    /// cut parts out.
    pub fn new(job: &Job, cuts: &[bool]) -> Waste {
        let outlines: Vec<(Vec<Point>, bool)> = job.geometries.iter().map(|g| (g.points.clone(), g.closed)).collect();
        let holders = RTree::bulk_load(
            job.geometries
                .iter()
                .enumerate()
                .filter(|(_, g)| g.closed && g.points.len() >= 3 && cuts.get(g.process).copied().unwrap_or(false))
                .map(|(k, g)| {
                    let (lo, hi) = bounds_of(g.points.iter());
                    GeomWithData::new(rect(lo, hi), (k, 0))
                })
                .collect(),
        );
        let segments = RTree::bulk_load(
            outlines
                .iter()
                .enumerate()
                .flat_map(|(k, (points, closed))| {
                    let n = points.len();
                    let count = if *closed && n > 2 { n } else { n.saturating_sub(1) };
                    (0..count).map(move |i| {
                        let (a, b) = (points[i], points[(i + 1) % n]);
                        GeomWithData::new(rect(Point::new(a.x.min(b.x), a.y.min(b.y)), Point::new(a.x.max(b.x), a.y.max(b.y))), (k, i))
                    })
                })
                .collect(),
        );
        Waste { outlines, holders, segments }
    }

    /// Whether `p` lies in the waste (an even number of cutting contours
    /// hold it).
    pub fn in_waste(&self, p: Point) -> bool {
        let here = AABB::from_point([p.x, p.y]);
        self.holders.locate_in_envelope_intersecting(here).filter(|h| side(p, &self.outlines[h.data.0].0, 0.0) == Side::Inside).count() % 2 == 0
    }

    /// The segment of geometry `k`, number `i`.
    fn segment(&self, (k, i): (usize, usize)) -> (Point, Point) {
        let points = &self.outlines[k].0;
        (points[i], points[(i + 1) % points.len()])
    }

    /// The drawing's segments within `reach` of segment `a`-`b`: (geometry,
    /// its ends, their distance).
    pub fn near(&self, a: Point, b: Point, reach: f64) -> impl Iterator<Item = (usize, Point, Point, f64)> + '_ {
        let query = AABB::from_corners([a.x.min(b.x) - reach, a.y.min(b.y) - reach], [a.x.max(b.x) + reach, a.y.max(b.y) + reach]);
        self.segments.locate_in_envelope_intersecting(query).filter_map(move |s| {
            let (c, d) = self.segment(s.data);
            let distance = segment_distance(a, b, c, d);
            (distance < reach).then_some((s.data.0, c, d, distance))
        })
    }
}
