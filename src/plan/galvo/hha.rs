//! The hierarchical galvo planner of seed 003 (`--planner hha`), then our
//! route search on top of it.
//!
//! 1. Fields from the cover, their order an open path over the field centres
//!    from the field nearest the start (the path may end anywhere).
//! 2. A start and an end geometry per field: the one nearest the previous
//!    field's geometries and the one nearest the next field's; the first
//!    field starts far from where the path leaves it, the last ends far from
//!    where it came in; a single field runs corner to corner.
//! 3. Each field's geometries ordered from its start to its end: the cheapest
//!    next geometry by distance plus the directionality penalty of Eq. 7 (far
//!    from the way out first), then 2-opt and Or-opt.
//! 4. Entry vertices by the vertex enhancement (VEA).
//! 5. [`Route::search`]: one local search over the whole route (2-opt,
//!    Or-opt with vertex choice, geometries moving into a neighbouring field
//!    whose square holds them, whole fields moved or turned), with kicks;
//!    fields stay contiguous.

use super::route::{neighbours, Route, Stop};
use super::{GalvoSettings, Layout};
use crate::job::{Job, Point};
use crate::plan::stop::TimeCap;

/// Kicks on top of those per geometry: small jobs are cheap to search, and
/// with many small fields the order of the fields needs its own kicks.
const MIN_KICKS: usize = 400;
const KICKS_PER_FIELD: usize = 120;
/// Independent route searches from the constructed route, sharing the
/// kicks; a fixed number, so that the plan does not depend on the cores.
const ROUTE_SEARCHES: usize = 2;

/// The route of step 1–4 (before the search): order, entry choice and field
/// per stop.
pub fn construct(job: &Job, layout: &Layout, start: Point, settings: &GalvoSettings) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let centroid: Vec<Point> = layout.stops.iter().map(Stop::centre).collect();
    let fields = &layout.fields;
    let order = open_path(&fields.iter().map(|f| f.center).collect::<Vec<_>>(), start, None);
    let members = |k: usize| &fields[order[k]].members;
    let nearest_pair = |a: &[usize], b: &[usize]| -> usize {
        // The geometry of `a` nearest to any geometry of `b`.
        let mut best = (f64::INFINITY, a[0]);
        for &i in a {
            for &j in b {
                let d = (centroid[i] - centroid[j]).norm_squared();
                if d < best.0 {
                    best = (d, i);
                }
            }
        }
        best.1
    };
    let farthest_from = |a: &[usize], p: Point| *a.iter().max_by(|&&i, &&j| (centroid[i] - p).norm_squared().total_cmp(&(centroid[j] - p).norm_squared())).unwrap();
    let nearest_to = |a: &[usize], p: Point| *a.iter().min_by(|&&i, &&j| (centroid[i] - p).norm_squared().total_cmp(&(centroid[j] - p).norm_squared())).unwrap();
    let half = layout.half;
    let diagonal = 2.0 * half * std::f64::consts::SQRT_2;
    // Where the line from a field's centre towards another point leaves the field.
    let exit_point = |c: Point, towards: Point| -> (Point, nalgebra::Vector2<f64>) {
        let u = (towards - c).try_normalize(1e-12).unwrap_or(nalgebra::Vector2::x());
        (c + u * (half / u.x.abs().max(u.y.abs())), u)
    };

    let mut sequence: Vec<usize> = Vec::with_capacity(job.geometries.len());
    let mut field_of = vec![0u32; job.geometries.len()];
    let last = order.len() - 1;
    for k in 0..order.len() {
        let here = members(k);
        let centre = fields[order[k]].center;
        // Step 2: start and end geometry.
        let (first, end, penalty): (usize, usize, Box<dyn Fn(Point) -> f64>) = if order.len() == 1 {
            let corner = Point::new(if start.x <= centre.x { centre.x - half } else { centre.x + half }, if start.y <= centre.y { centre.y - half } else { centre.y + half });
            let opposite = Point::new(2.0 * centre.x - corner.x, 2.0 * centre.y - corner.y);
            let (first, end) = (nearest_to(here, corner), nearest_to(here, opposite));
            let end_at = centroid[end];
            let w = settings.direction_weight_single_field;
            (first, end, Box::new(move |p: Point| w * (diagonal - (p - end_at).norm()).max(0.0)))
        } else if k < last {
            let next_centre = fields[order[k + 1]].center;
            let (b, u) = exit_point(centre, next_centre);
            let first = if k == 0 { farthest_from(here, b) } else { nearest_pair(here, members(k - 1)) };
            let end = nearest_pair(here, members(k + 1));
            let w = settings.direction_weight;
            // Eq. 7: |AB| is the distance from the way out along the line
            // between the centres; the far ones cost less, so come first.
            (first, end, Box::new(move |p: Point| w * (diagonal - (p - b).dot(&u).abs()).max(0.0)))
        } else {
            let (b, u) = exit_point(centre, fields[order[k - 1]].center);
            let first = nearest_pair(here, members(k - 1));
            let end = farthest_from(here, b);
            let w = settings.direction_weight;
            // The last field: the nearer to where the path came in, the sooner.
            (first, end, Box::new(move |p: Point| w * (p - b).dot(&u).abs().min(diagonal)))
        };
        let end = if end == first && here.len() > 1 { *here.iter().find(|&&g| g != first).unwrap() } else { end };
        // Step 3: cheapest next by distance plus penalty, end kept for last.
        let mut left: Vec<usize> = here.iter().copied().filter(|&g| g != first && g != end).collect();
        let mut path = Vec::with_capacity(left.len());
        let mut at = centroid[first];
        while !left.is_empty() {
            let (i, _) = left.iter().enumerate().map(|(i, &g)| (i, (centroid[g] - at).norm() + penalty(centroid[g]))).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
            let g = left.swap_remove(i);
            at = centroid[g];
            path.push(g);
        }
        let points: Vec<Point> = path.iter().map(|&g| centroid[g]).collect();
        let mut idx: Vec<usize> = (0..path.len()).collect();
        let towards = (end != first).then(|| centroid[end]);
        improve_open_path(&points, &mut idx, centroid[first], towards);
        sequence.push(first);
        sequence.extend(idx.iter().map(|&i| path[i]));
        if end != first {
            sequence.push(end);
        }
        for &g in here {
            field_of[g] = order[k] as u32;
        }
    }
    // Step 4: vertex enhancement.
    let entries = select_entries(job, &sequence);
    let mut choice = vec![0u32; job.geometries.len()];
    for (&g, &(v, reversed)) in sequence.iter().zip(&entries) {
        choice[g] = if job.geometries[g].closed { v as u32 } else { reversed as u32 };
    }
    (sequence.into_iter().map(|g| g as u32).collect(), choice, field_of)
}

/// Steps 1–5: the constructed route improved by the route search: its
/// independent searches (each its own seed) on `settings.threads` threads,
/// the shortest route wins, ties to the first search.
pub fn plan_route<'a>(job: &Job, layout: &'a Layout, start: Point, settings: &GalvoSettings, cap: &TimeCap) -> Route<'a> {
    let (order, choice, field) = construct(job, layout, start, settings);
    let route = Route::new(&layout.stops, order, choice, field, layout.fields.len());
    let near = neighbours(&layout.stops, 8);
    let kicks = settings.kicks_per_geometry * layout.stops.len() + MIN_KICKS + KICKS_PER_FIELD * layout.fields.len();
    let kicks = kicks.div_ceil(ROUTE_SEARCHES);
    let seed = |k: usize| settings.seed.wrapping_mul(0x9E37_79B9).wrapping_add(k as u64);
    let routes = crate::parallel::tasks(ROUTE_SEARCHES, settings.threads, |k| route.clone().search(&near, kicks, cap, seed(k)));
    routes.into_iter().min_by(|a, b| a.length().total_cmp(&b.length())).expect("at least one route search")
}

/// An order of `points` as an open path from `from`, ending near `towards`
/// when given (its distance to the last point counts as one more jump):
/// nearest neighbour, then 2-opt and Or-opt until no move shortens it.
fn open_path(points: &[Point], from: Point, towards: Option<Point>) -> Vec<usize> {
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
fn select_entries(job: &Job, sequence: &[usize]) -> Vec<(usize, bool)> {
    let mut choice = vec![(0, false); sequence.len()];
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
        let square = |x: f64| Geometry { arcs: Vec::new(), profile: Vec::new(),
            points: vec![Point::new(x, 0.0), Point::new(x + 1.0, 0.0), Point::new(x + 1.0, 1.0), Point::new(x, 1.0)],
            closed: true,
            process: 0,
            source: String::new(),
        };
        let line = Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(6.0, 0.0), Point::new(4.0, 0.0)], closed: false, process: 0, source: String::new() };
        let job = Job { source: String::new(), geometries: vec![square(0.0), line, square(10.0)], processes: vec![Process { layer: "m".into(), speed: 1.0, power: 1.0, passes: 1, fill: false }] };
        let entries = select_entries(&job, &[0, 1, 2]);
        // The first square left at its corner towards the line, the line run
        // left to right (reversed), the last square entered at its near corner.
        assert_eq!(entries[0], (1, false));
        assert!(entries[1].1);
        assert_eq!(entries[2], (0, false));
    }
}
