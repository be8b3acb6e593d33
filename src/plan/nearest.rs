//! The nearest-neighbour baseline: from the current position, always go to the
//! closest unmarked geometry, entering a closed one at its nearest vertex and an
//! open one at its nearer end. With scan fields, fields are visited
//! nearest-first by their centres and the rule applies inside each field.
//! It stays as the reference the better planners are compared against.

use super::fields::{cover, Field};
use super::{check_reach, PathGroup, PlanContext, PlannedPath, Planner, Sequence};
use crate::error::Result;
use crate::job::{Geometry, Job, Point};
use crate::mode::Mode;

pub struct NearestNeighbour;

impl Planner for NearestNeighbour {
    fn name(&self) -> &'static str {
        "nearest"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        check_reach(job, ctx.machine, ctx.mode)?;
        let scanner = ctx.machine.scanner.as_ref().filter(|_| ctx.mode != Mode::StageOnly);
        let Some(scanner) = scanner else {
            let all: Vec<usize> = (0..job.geometries.len()).collect();
            let paths = order_paths(job, &all, ctx.start);
            return Ok(Sequence { groups: vec![PathGroup { field_center: None, paths }] });
        };
        let travel = (ctx.machine.stage.travel_x, ctx.machine.stage.travel_y);
        let mut fields = cover(job, scanner.usable_half_field, travel)?;
        let mut groups = Vec::with_capacity(fields.len());
        let mut here = ctx.start;
        while !fields.is_empty() {
            let k = nearest_index(fields.iter().map(|f: &Field| f.center), here);
            let field = fields.swap_remove(k);
            let paths = order_paths(job, &field.members, here);
            if let Some(last) = paths.last() {
                here = last.end();
            }
            groups.push(PathGroup { field_center: Some(field.center), paths });
        }
        Ok(Sequence { groups })
    }
}

fn nearest_index(points: impl Iterator<Item = Point>, from: Point) -> usize {
    let mut best = (0, f64::INFINITY);
    for (i, p) in points.enumerate() {
        let d = (p - from).norm_squared();
        if d < best.1 {
            best = (i, d);
        }
    }
    best.0
}

/// Nearest-neighbour order of `members`, starting at `from`; each geometry
/// repeated for its passes. The entries left (a closed geometry's vertices,
/// an open one's ends) are in an R-tree, so each step costs O(log n), not a
/// scan of every geometry left; of entries equally near, the geometry that
/// comes first in the list of those left (swap-removed as they are taken),
/// then its first vertex (a closed one) or its start (an open one).
fn order_paths(job: &Job, members: &[usize], from: Point) -> Vec<PlannedPath> {
    use rstar::primitives::GeomWithData;
    use rstar::RTree;
    let entries = |gi: usize| {
        let p = &job.geometries[gi].points;
        let vertices: Vec<usize> = if job.geometries[gi].closed { (0..p.len()).collect() } else { vec![0, p.len() - 1] };
        vertices.into_iter().map(move |v| GeomWithData::new([p[v].x, p[v].y], (gi, v)))
    };
    let mut tree = RTree::bulk_load(members.iter().flat_map(|&gi| entries(gi)).collect());
    let mut left: Vec<usize> = members.to_vec();
    let mut slot = vec![usize::MAX; job.geometries.len()];
    for (k, &gi) in left.iter().enumerate() {
        slot[gi] = k;
    }
    let mut here = from;
    let mut out = Vec::with_capacity(members.len());
    while !left.is_empty() {
        let mut best: Option<(usize, usize)> = None;
        let mut nearest = None;
        for (hit, d2) in tree.nearest_neighbor_iter_with_distance_2([here.x, here.y]) {
            if nearest.is_some_and(|d: f64| d2 > d) {
                break;
            }
            nearest = Some(d2);
            let (gi, v) = hit.data;
            if best.is_none_or(|b| (slot[gi], v) < b) {
                best = Some((slot[gi], v));
            }
        }
        let (k, v) = best.expect("every geometry left has entries in the tree");
        let gi = left.swap_remove(k);
        if let Some(&moved) = left.get(k) {
            slot[moved] = k;
        }
        for entry in entries(gi) {
            tree.remove(&entry);
        }
        let g = &job.geometries[gi];
        let (entry, reversed) = if g.closed { (v, false) } else { (0, v != 0) };
        let points = path_points(g, entry, reversed);
        here = points[points.len() - 1];
        for _ in 0..job.processes[g.process].passes {
            out.push(PlannedPath::new(gi, points.clone(), g.process, true));
        }
    }
    out
}

/// The vertices in marking order.
pub fn path_points(g: &Geometry, entry: usize, reversed: bool) -> Vec<Point> {
    if g.closed {
        let n = g.points.len();
        (0..=n).map(|k| g.points[(entry + k) % n]).collect()
    } else if reversed {
        g.points.iter().rev().copied().collect()
    } else {
        g.points.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineConfig;
    use crate::job::Process;
    use crate::plan::PlanContext;

    /// The baseline as first written, every geometry left scanned at each
    /// step: what the R-tree's order must be.
    fn order_paths_scanning(job: &Job, members: &[usize], from: Point) -> Vec<PlannedPath> {
        let mut left: Vec<usize> = members.to_vec();
        let mut here = from;
        let mut out = Vec::with_capacity(members.len());
        while !left.is_empty() {
            let mut best = (0usize, 0usize, false, f64::INFINITY);
            for (k, &gi) in left.iter().enumerate() {
                let (entry, reversed, d) = best_entry(&job.geometries[gi], here);
                if d < best.3 {
                    best = (k, entry, reversed, d);
                }
            }
            let gi = left.swap_remove(best.0);
            let g = &job.geometries[gi];
            let points = path_points(g, best.1, best.2);
            here = points[points.len() - 1];
            for _ in 0..job.processes[g.process].passes {
                out.push(PlannedPath::new(gi, points.clone(), g.process, true));
            }
        }
        out
    }

    /// Entry vertex (closed) or direction (open) closest to `from`, with its distance².
    fn best_entry(g: &Geometry, from: Point) -> (usize, bool, f64) {
        if g.closed {
            let i = nearest_index(g.points.iter().copied(), from);
            (i, false, (g.points[i] - from).norm_squared())
        } else {
            let d0 = (g.points[0] - from).norm_squared();
            let d1 = (g.points[g.points.len() - 1] - from).norm_squared();
            if d1 < d0 {
                (0, true, d1)
            } else {
                (0, false, d0)
            }
        }
    }

    #[test]
    fn the_tree_takes_the_order_of_the_scan() {
        // A grid of squares sharing edges, some with a hole (many vertices
        // at the same place, so ties matter), with open paths of its own.
        let mut geometries: Vec<Geometry> = Vec::new();
        for i in 0..20 {
            for k in 0..15 {
                let (x, y) = (10.0 * i as f64, 10.0 * k as f64);
                geometries.push(square(x, y, 10.0));
                if (i + k) % 3 == 0 {
                    geometries.push(square(x + 3.0, y + 3.0, 4.0));
                }
            }
        }
        for k in 0..40 {
            let (x, y) = ((k * 37 % 400) as f64, (k * 53 % 300) as f64);
            geometries.push(Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(x, y), Point::new(x + 5.0, y + 1.0), Point::new(x, y)], closed: false, process: 0, source: String::new() });
        }
        let j = job(geometries);
        let all: Vec<usize> = (0..j.geometries.len()).collect();
        for from in [Point::new(0.0, 0.0), Point::new(123.4, 56.7)] {
            let ours = order_paths(&j, &all, from);
            let reference = order_paths_scanning(&j, &all, from);
            assert_eq!(ours.len(), all.len());
            assert!(ours.iter().zip(&reference).all(|(a, b)| a.geometry == b.geometry && a.points == b.points));
        }
    }

    fn square(x: f64, y: f64, s: f64) -> Geometry {
        Geometry { arcs: Vec::new(), profile: Vec::new(),
            points: vec![Point::new(x, y), Point::new(x + s, y), Point::new(x + s, y + s), Point::new(x, y + s)],
            closed: true,
            process: 0,
            source: format!("square at {x},{y}"),
        }
    }

    fn job(geometries: Vec<Geometry>) -> Job {
        Job {
            source: "test".into(),
            geometries,
            processes: vec![Process { layer: "mark".into(), speed: 1000.0, power: 100.0, passes: 1, fill: false }],
        }
    }

    #[test]
    fn visits_everything_once_entering_closed_shapes_at_the_nearest_vertex() {
        let machine = MachineConfig::load(None).unwrap();
        let j = job(vec![square(100.0, 100.0, 5.0), square(10.0, 10.0, 5.0), square(50.0, 50.0, 5.0)]);
        let ctx = PlanContext { machine: &machine, mode: Mode::StageOnly, start: Point::origin(), plate: None };
        let seq = NearestNeighbour.plan(&j, &ctx).unwrap();
        let order: Vec<usize> = seq.paths().map(|p| p.geometry).collect();
        assert_eq!(order, vec![1, 2, 0]);
        let first = seq.paths().next().unwrap();
        assert_eq!(first.start(), Point::new(10.0, 10.0));
        assert_eq!(first.start(), first.end(), "closed path returns to its entry");
        // Idle stroke: (15,15)->(50,50) ... entries are lower-left corners.
        let expected = (Point::new(50.0, 50.0) - Point::new(10.0, 10.0)).norm()
            + (Point::new(100.0, 100.0) - Point::new(50.0, 50.0)).norm();
        assert!((seq.idle_stroke() - expected).abs() < 1e-9);
        assert_eq!(seq.scan_fields(), None);
    }

    #[test]
    fn open_paths_start_at_the_nearer_end() {
        let machine = MachineConfig::load(None).unwrap();
        let g = Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(20.0, 0.0), Point::new(1.0, 0.0)], closed: false, process: 0, source: "l".into() };
        let ctx = PlanContext { machine: &machine, mode: Mode::StageOnly, start: Point::origin(), plate: None };
        let seq = NearestNeighbour.plan(&job(vec![g]), &ctx).unwrap();
        assert_eq!(seq.paths().next().unwrap().start(), Point::new(1.0, 0.0));
    }

    #[test]
    fn step_and_scan_fields_hold_their_geometries() {
        let machine = MachineConfig::load(None).unwrap();
        let half = machine.scanner.as_ref().unwrap().usable_half_field;
        let mut gs = Vec::new();
        for i in 0..10 {
            for k in 0..10 {
                gs.push(square(10.0 + 28.0 * i as f64, 10.0 + 28.0 * k as f64, 4.0));
            }
        }
        let j = job(gs);
        let ctx = PlanContext { machine: &machine, mode: Mode::StepAndScan, start: Point::origin(), plate: None };
        let seq = NearestNeighbour.plan(&j, &ctx).unwrap();
        assert_eq!(seq.paths().count(), 100);
        assert!(seq.scan_fields().unwrap() >= 16, "300 mm of content needs at least 4 x 4 fields of 64 mm");
        for g in &seq.groups {
            let c = g.field_center.unwrap();
            for p in &g.paths {
                for v in &p.points {
                    assert!((v.x - c.x).abs() <= half + 1e-9 && (v.y - c.y).abs() <= half + 1e-9);
                }
            }
        }
    }

    #[test]
    fn geometry_outside_travel_is_an_error_naming_it() {
        let machine = MachineConfig::load(None).unwrap();
        let ctx = PlanContext { machine: &machine, mode: Mode::StageOnly, start: Point::origin(), plate: None };
        let err = NearestNeighbour.plan(&job(vec![square(299.0, 10.0, 5.0)]), &ctx).unwrap_err().to_string();
        assert!(err.contains("square at 299,10"), "{err}");
    }
}
