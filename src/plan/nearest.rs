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
/// repeated for its passes.
fn order_paths(job: &Job, members: &[usize], from: Point) -> Vec<PlannedPath> {
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
