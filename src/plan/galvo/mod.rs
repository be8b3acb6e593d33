//! The galvo planners of seed 003: a scanner on a base stage marks the job
//! field by field; the order of the fields and of the geometries in them, and
//! where each geometry is entered, decide the idle stroke (laser-off jumps).
//!
//! * [`hha`]: the hierarchical heuristic (`--planner hha`), field order,
//!   start and end per field, in-field order with the directionality penalty,
//!   vertex enhancement, then our route search.
//! * [`route`]: the route and its local search, shared by the planners.
//! * [`instances`]: generated jobs of the paper's test-case families.
//!
//! On a machine without a scanner (stage-only) the whole job is one "field".

pub mod hga;
pub mod hha;
pub mod instances;
pub mod route;

use super::fields::{centre_within_travel, cover, Field};
use super::nearest::path_points;
use super::{check_reach, PathGroup, PlanContext, PlannedPath, Planner, Sequence};
use crate::error::Result;
use crate::job::{bounds_of, Job, Point};
use crate::motion::Mode;
use route::{Route, Stop};
use std::time::{Duration, Instant};

/// Settings of the galvo planners.
#[derive(Debug, Clone)]
pub struct GalvoSettings {
    /// Weight of Eq. 7's directionality penalty with several fields.
    pub direction_weight: f64,
    /// The same with a single field (seed 003 uses a smaller one there).
    pub direction_weight_single_field: f64,
    /// Kicks of the route search per geometry.
    pub kicks_per_geometry: usize,
    /// Route search time per geometry (a bound next to the kicks).
    pub time_per_geometry: Duration,
    pub threads: usize,
    pub seed: u64,
}

impl Default for GalvoSettings {
    fn default() -> Self {
        GalvoSettings {
            direction_weight: 0.5,
            direction_weight_single_field: 0.1,
            kicks_per_geometry: 6,
            time_per_geometry: Duration::from_micros(150),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()).min(4),
            seed: 1,
        }
    }
}

/// The fields of a job and its geometries as route stops.
pub struct Layout {
    pub fields: Vec<Field>,
    pub stops: Vec<Stop>,
    /// Half the side of a field's square.
    pub half: f64,
    /// Stage-only: one field without a stage position.
    stage_only: bool,
}

impl Layout {
    pub fn new(job: &Job, ctx: &PlanContext) -> Result<Layout> {
        let scanner = ctx.machine.scanner.as_ref().filter(|_| ctx.mode != Mode::StageOnly);
        let (fields, half, stage_only) = match scanner {
            None => {
                let (lo, hi) = job.bounds();
                let centre = Point::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0);
                let half = ((hi.x - lo.x).max(hi.y - lo.y) / 2.0).max(1e-9);
                (vec![Field { center: centre, members: (0..job.geometries.len()).collect() }], half, true)
            }
            Some(s) => {
                let travel = (ctx.machine.stage.travel_x, ctx.machine.stage.travel_y);
                (cover(job, s.usable_half_field, travel)?, s.usable_half_field, false)
            }
        };
        let slack = 1e-9 * (1.0 + half);
        let stops = job
            .geometries
            .iter()
            .map(|g| {
                let (lo, hi) = g.bounds();
                let fields = if stage_only {
                    vec![0]
                } else {
                    (0..fields.len() as u32)
                        .filter(|&f| {
                            let c = fields[f as usize].center;
                            lo.x >= c.x - half - slack && lo.y >= c.y - half - slack && hi.x <= c.x + half + slack && hi.y <= c.y + half + slack
                        })
                        .collect()
                };
                let vertices = if g.closed { g.points.clone() } else { vec![g.points[0], g.points[g.points.len() - 1]] };
                Stop::new(vertices, g.closed, fields)
            })
            .collect();
        Ok(Layout { fields, stops, half, stage_only })
    }

    /// The planned sequence of a route: its fields in order, each at the
    /// centre of what it holds now (geometries may have changed fields).
    pub fn sequence(&self, job: &Job, route: &Route, ctx: &PlanContext) -> Sequence {
        let mut groups: Vec<PathGroup> = Vec::new();
        let mut members: Vec<usize> = Vec::new();
        let order = route.order();
        for (p, &s) in order.iter().enumerate() {
            let s = s as usize;
            if p == 0 || route.fields()[s] != route.fields()[order[p - 1] as usize] {
                groups.push(PathGroup { field_center: None, paths: Vec::new() });
                members.clear();
            }
            members.push(s);
            let geometry = &job.geometries[s];
            let choice = route.choices()[s] as usize;
            let points = if geometry.closed { path_points(geometry, choice, false) } else { path_points(geometry, 0, choice == 1) };
            for _ in 0..job.processes[geometry.process].passes {
                groups.last_mut().unwrap().paths.push(PlannedPath { geometry: s, points: points.clone(), process: geometry.process });
            }
            let field_ends = p + 1 == order.len() || route.fields()[order[p + 1] as usize] != route.fields()[s];
            if field_ends && !self.stage_only {
                let field = &self.fields[route.fields()[s] as usize];
                let (lo, hi) = bounds_of(members.iter().flat_map(|&g| job.geometries[g].points.iter()));
                let travel = (ctx.machine.stage.travel_x, ctx.machine.stage.travel_y);
                groups.last_mut().unwrap().field_center = Some(centre_within_travel(lo, hi, self.half, travel).unwrap_or(field.center));
            }
        }
        Sequence { groups }
    }
}

/// `--planner hha`.
pub struct Hha;

/// `--planner hga`: the HGA from the HHA's route, within the time limit.
pub struct Hga;

impl Planner for Hha {
    fn name(&self) -> &'static str {
        "hha"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        plan(job, ctx, false)
    }
}

impl Planner for Hga {
    fn name(&self) -> &'static str {
        "hga"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        plan(job, ctx, true)
    }
}

/// The HHA's route (its search capped at a time per geometry), and with
/// `genetic` the HGA on from there within the `[galvo]` time limit.
fn plan(job: &Job, ctx: &PlanContext, genetic: bool) -> Result<Sequence> {
    check_reach(job, ctx.machine, ctx.mode)?;
    if job.geometries.is_empty() {
        return Ok(Sequence { groups: Vec::new() });
    }
    let began = Instant::now();
    let g = &ctx.machine.galvo;
    let settings = GalvoSettings { direction_weight: g.direction_weight, direction_weight_single_field: g.direction_weight_single_field, seed: g.seed, ..GalvoSettings::default() };
    let layout = Layout::new(job, ctx)?;
    let hha_deadline = began + settings.time_per_geometry * job.geometries.len() as u32;
    let mut route = hha::plan_route(job, &layout, ctx.start, &settings, hha_deadline);
    if genetic {
        let deadline = began + Duration::from_secs_f64(g.time_limit);
        route = hga::plan_route(job, &layout, route, &settings, deadline);
    }
    Ok(layout.sequence(job, &route, ctx))
}

/// An order of `points` as an open path from `from`, ending near `towards`
/// when given (its distance to the last point counts as one more jump):
/// nearest neighbour, then 2-opt and Or-opt until no move shortens it.
pub fn open_path(points: &[Point], from: Point, towards: Option<Point>) -> Vec<usize> {
    let n = points.len();
    let mut left: Vec<usize> = (0..n).collect();
    let mut order = Vec::with_capacity(n);
    let mut here = from;
    while !left.is_empty() {
        let (i, _) = left.iter().enumerate().map(|(i, &p)| (i, (points[p] - here).norm_squared())).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
        let p = left.swap_remove(i);
        here = points[p];
        order.push(p);
    }
    improve_open_path(points, &mut order, from, towards);
    order
}

/// 2-opt and Or-opt on an open path with a fixed start point and an optional
/// end point.
pub fn improve_open_path(points: &[Point], order: &mut [usize], from: Point, towards: Option<Point>) {
    let n = order.len();
    if n < 2 {
        return;
    }
    // Position i of the path with the fixed ends: -1 is `from`, n is `towards`.
    let at = |order: &[usize], i: isize| -> Option<Point> {
        if i < 0 {
            Some(from)
        } else if i as usize >= order.len() {
            towards
        } else {
            Some(points[order[i as usize]])
        }
    };
    let d = |a: Option<Point>, b: Option<Point>| match (a, b) {
        (Some(a), Some(b)) => (b - a).norm(),
        _ => 0.0,
    };
    let mut improved = true;
    let mut rounds = 0;
    while improved && rounds < 100 {
        improved = false;
        rounds += 1;
        // 2-opt: reverse order[i..=j].
        for i in 0..n {
            for j in i + 1..n {
                let (a, b) = (at(order, i as isize - 1), at(order, i as isize));
                let (c, e) = (at(order, j as isize), at(order, j as isize + 1));
                if d(a, c) + d(b, e) < d(a, b) + d(c, e) - 1e-9 {
                    order[i..=j].reverse();
                    improved = true;
                }
            }
        }
        // Or-opt: a run of 1 to 3 moved elsewhere, kept or reversed.
        for len in 1..=3usize.min(n - 1) {
            let mut s = 0;
            while s + len <= n {
                let (before, first, last, after) = (at(order, s as isize - 1), at(order, s as isize), at(order, (s + len) as isize - 1), at(order, (s + len) as isize));
                let gain = d(before, first) + d(last, after) - d(before, after);
                // Targets: between positions t - 1 and t of the path as it is,
                // outside the run (no copy of the path per run).
                let mut best: Option<(f64, usize, bool)> = None;
                for t in (0..s).chain(s + len + 1..=n) {
                    let (p, q) = (at(order, t as isize - 1), at(order, t as isize));
                    for reverse in [false, true] {
                        let (h, e) = if reverse { (last, first) } else { (first, last) };
                        let cost = d(p, h) + d(e, q) - d(p, q);
                        if cost < gain - 1e-9 && best.is_none_or(|(c, _, _)| cost < c) {
                            best = Some((cost, t, reverse));
                        }
                    }
                }
                if let Some((_, t, reverse)) = best {
                    let start = if t < s {
                        order[t..s + len].rotate_right(len);
                        t
                    } else {
                        order[s..t].rotate_left(len);
                        t - len
                    };
                    if reverse {
                        order[start..start + len].reverse();
                    }
                    improved = true;
                }
                s += 1;
            }
        }
    }
}

/// Seed 003's vertex selection on the true jumps: every closed geometry
/// entered at the vertex closest to the way from the previous geometry's exit
/// to the next one's entry (the sum of both jumps), every open one run in the
/// direction that makes them shorter, sweep after sweep until none changes.
/// Returns (entry vertex, reversed) per geometry of `sequence`.
pub fn select_entries(job: &Job, sequence: &[usize]) -> Vec<(usize, bool)> {
    select_entries_from(job, sequence, vec![(0, false); sequence.len()])
}

/// [`select_entries`] from given choices.
fn select_entries_from(job: &Job, sequence: &[usize], mut choice: Vec<(usize, bool)>) -> Vec<(usize, bool)> {
    let geometry = |k: usize| &job.geometries[sequence[k]];
    let ends = |k: usize, choice: (usize, bool)| -> (Point, Point) {
        let g = geometry(k);
        if g.closed {
            (g.points[choice.0], g.points[choice.0])
        } else if choice.1 {
            (g.points[g.points.len() - 1], g.points[0])
        } else {
            (g.points[0], g.points[g.points.len() - 1])
        }
    };
    for _ in 0..50 {
        let mut changed = false;
        for k in 0..sequence.len() {
            let prev = (k > 0).then(|| ends(k - 1, choice[k - 1]).1);
            let next = (k + 1 < sequence.len()).then(|| ends(k + 1, choice[k + 1]).0);
            let cost = |c: (usize, bool)| {
                let (entry, exit) = ends(k, c);
                prev.map_or(0.0, |p| (entry - p).norm()) + next.map_or(0.0, |q| (q - exit).norm())
            };
            let g = geometry(k);
            let options: Vec<(usize, bool)> = if g.closed { (0..g.points.len()).map(|v| (v, false)).collect() } else { vec![(0, false), (0, true)] };
            let now = cost(choice[k]);
            let (best, best_cost) = options.into_iter().map(|c| (c, cost(c))).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
            if best_cost < now - 1e-9 {
                choice[k] = best;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    choice
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Geometry, Process};

    #[test]
    fn an_open_path_over_points_on_a_line_runs_along_it() {
        let xs = [7.0, 2.0, 9.0, 0.5, 4.0, 3.0, 8.0, 1.0, 6.0, 5.0];
        let points: Vec<Point> = xs.iter().map(|&x| Point::new(x, 0.0)).collect();
        let order = open_path(&points, Point::new(0.0, 0.0), Some(Point::new(20.0, 0.0)));
        let along: Vec<f64> = order.iter().map(|&i| xs[i]).collect();
        let mut sorted = xs.to_vec();
        sorted.sort_by(f64::total_cmp);
        assert_eq!(along, sorted);
        // Ending towards the start instead turns it round.
        let back = open_path(&points, Point::new(10.0, 0.0), Some(Point::new(-5.0, 0.0)));
        assert_eq!(back.iter().map(|&i| xs[i]).collect::<Vec<_>>(), sorted.iter().rev().copied().collect::<Vec<_>>());
    }

    #[test]
    fn entries_are_the_vertices_on_the_way_and_open_shapes_run_onwards() {
        let square = |x: f64| Geometry {
            points: vec![Point::new(x, 0.0), Point::new(x + 1.0, 0.0), Point::new(x + 1.0, 1.0), Point::new(x, 1.0)],
            closed: true,
            process: 0,
            source: String::new(),
        };
        let line = Geometry { points: vec![Point::new(6.0, 0.0), Point::new(4.0, 0.0)], closed: false, process: 0, source: String::new() };
        let job = Job { source: String::new(), geometries: vec![square(0.0), line, square(10.0)], processes: vec![Process { layer: "m".into(), speed: 1.0, power: 1.0, passes: 1 }] };
        let entries = select_entries(&job, &[0, 1, 2]);
        // The first square left at its corner towards the line, the line run
        // left to right (reversed), the last square entered at its near corner.
        assert_eq!(entries[0], (1, false));
        assert!(entries[1].1);
        assert_eq!(entries[2], (0, false));
    }
}
