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
use super::{improve_open_path, select_entries, GalvoSettings, Layout};
use crate::job::{Job, Point};
use std::time::Instant;

/// Kicks on top of those per geometry: small jobs are cheap to search, and
/// with many small fields the order of the fields needs its own kicks.
const MIN_KICKS: usize = 400;
const KICKS_PER_FIELD: usize = 120;

/// The route of step 1–4 (before the search): order, entry choice and field
/// per stop.
pub fn construct(job: &Job, layout: &Layout, start: Point, settings: &GalvoSettings) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let centroid: Vec<Point> = layout.stops.iter().map(Stop::centre).collect();
    let fields = &layout.fields;
    let order = super::open_path(&fields.iter().map(|f| f.center).collect::<Vec<_>>(), start, None);
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

/// Steps 1–5: the constructed route improved by the route search.
pub fn plan_route<'a>(job: &Job, layout: &'a Layout, start: Point, settings: &GalvoSettings, deadline: Instant) -> Route<'a> {
    let (order, choice, field) = construct(job, layout, start, settings);
    let route = Route::new(&layout.stops, order, choice, field, layout.fields.len());
    let near = neighbours(&layout.stops, 8);
    let kicks = settings.kicks_per_geometry * layout.stops.len() + MIN_KICKS + KICKS_PER_FIELD * layout.fields.len();
    if settings.threads <= 1 {
        return route.search(&near, kicks, Some(deadline), settings.seed);
    }
    // Independent searches from the same start, one per thread, sharing the
    // kicks; the shortest wins.
    let kicks = kicks.div_ceil(settings.threads);
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..settings.threads as u64)
            .map(|t| {
                let route = route.clone();
                let near = &near;
                scope.spawn(move || route.search(near, kicks, Some(deadline), settings.seed.wrapping_mul(0x9E37_79B9).wrapping_add(t)))
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("route search thread")).min_by(|a, b| a.length().total_cmp(&b.length())).unwrap()
    })
}
