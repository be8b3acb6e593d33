//! The galvo planner of seed 003, hierarchical (`--planner hha`): scan fields
//! from the cover ([`super::fields`]), their order as an open path over the
//! field centres, the geometries of each field in order from where the
//! previous field ended towards the next field, then the entry vertex of every
//! closed geometry and the direction of every open one (seed 003's vertex
//! selection, on the true jump lengths), then each field ordered again on
//! the chosen entries and the entries chosen again, a few rounds. Fields are
//! processed contiguously.
//!
//! Orders are open paths improved by 2-opt and Or-opt (runs of 1 to 3 moved,
//! kept or reversed) until no move shortens them, from a nearest-neighbour
//! start; on a machine without a scanner (stage-only) the whole job is one
//! "field".

use super::fields::cover;
use super::nearest::path_points;
use super::{check_reach, PathGroup, PlanContext, PlannedPath, Planner, Sequence};
use crate::error::Result;
use crate::job::{Geometry, Job, Point};
use crate::motion::Mode;

pub struct Hha;

/// Rounds of ordering on the chosen entries and choosing entries again.
const REFINE_ROUNDS: usize = 3;

impl Planner for Hha {
    fn name(&self) -> &'static str {
        "hha"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        check_reach(job, ctx.machine, ctx.mode)?;
        let scanner = ctx.machine.scanner.as_ref().filter(|_| ctx.mode != Mode::StageOnly);
        let fields: Vec<(Option<Point>, Vec<usize>)> = match scanner {
            None => vec![(None, (0..job.geometries.len()).collect())],
            Some(s) => {
                let travel = (ctx.machine.stage.travel_x, ctx.machine.stage.travel_y);
                let fields = cover(job, s.usable_half_field, travel)?;
                let centres: Vec<Point> = fields.iter().map(|f| f.center).collect();
                let order = open_path(&centres, ctx.start, None);
                order.into_iter().map(|k| (Some(fields[k].center), fields[k].members.clone())).collect()
            }
        };
        // The geometries of each field, from the previous field's last
        // geometry towards the next field's centre.
        let centroid: Vec<Point> = job.geometries.iter().map(centre_of).collect();
        let mut here = ctx.start;
        let mut sequence: Vec<(usize, usize)> = Vec::with_capacity(job.geometries.len());
        for (k, (_, members)) in fields.iter().enumerate() {
            let points: Vec<Point> = members.iter().map(|&g| centroid[g]).collect();
            let towards = fields.get(k + 1).map(|(c, m)| c.unwrap_or_else(|| centroid[m[0]]));
            let order = open_path(&points, here, towards);
            for &i in &order {
                sequence.push((k, members[i]));
            }
            if let Some(&last) = order.last() {
                here = centroid[members[last]];
            }
        }
        let mut entries = select_entries(job, &sequence.iter().map(|&(_, g)| g).collect::<Vec<_>>());
        // The orders were made on centroids; the jumps run between the chosen
        // entries. Each field's order again on those points (a closed shape
        // starts and ends at its entry), then the entries again.
        for _ in 0..REFINE_ROUNDS {
            let point_of = |i: usize, entries: &[(usize, bool)]| {
                let g = &job.geometries[sequence[i].1];
                if g.closed {
                    g.points[entries[i].0]
                } else {
                    centroid[sequence[i].1]
                }
            };
            let mut start = 0;
            let mut refined: Vec<(usize, usize)> = Vec::with_capacity(sequence.len());
            let mut refined_entries = Vec::with_capacity(sequence.len());
            while start < sequence.len() {
                let field = sequence[start].0;
                let end = start + sequence[start..].iter().take_while(|&&(k, _)| k == field).count();
                let from = if start == 0 { ctx.start } else { point_of(start - 1, &entries) };
                let towards = (end < sequence.len()).then(|| point_of(end, &entries));
                let points: Vec<Point> = (start..end).map(|i| point_of(i, &entries)).collect();
                let mut order: Vec<usize> = (0..points.len()).collect();
                improve_open_path(&points, &mut order, from, towards);
                for i in order {
                    refined.push(sequence[start + i]);
                    refined_entries.push(entries[start + i]);
                }
                start = end;
            }
            sequence = refined;
            entries = select_entries_from(job, &sequence.iter().map(|&(_, g)| g).collect::<Vec<_>>(), refined_entries);
        }
        let mut groups: Vec<PathGroup> = fields.iter().map(|(c, _)| PathGroup { field_center: *c, paths: Vec::new() }).collect();
        for (&(k, g), &(entry, reversed)) in sequence.iter().zip(&entries) {
            let geometry = &job.geometries[g];
            let points = path_points(geometry, entry, reversed);
            for _ in 0..job.processes[geometry.process].passes {
                groups[k].paths.push(PlannedPath { geometry: g, points: points.clone(), process: geometry.process });
            }
        }
        Ok(Sequence { groups })
    }
}

/// The point a geometry stands for while orders are made: its vertices' mean.
fn centre_of(g: &Geometry) -> Point {
    let n = g.points.len().max(1) as f64;
    let sum = g.points.iter().fold(nalgebra::Vector2::zeros(), |s, p| s + p.coords);
    Point::from(sum / n)
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
fn improve_open_path(points: &[Point], order: &mut [usize], from: Point, towards: Option<Point>) {
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
    use crate::job::Process;

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
