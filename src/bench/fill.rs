//! `laserd bench fill`: seed 004's Table 1 on its own kind of test part. The
//! area of a job's fill layer (default `samples/fishhead.svg`) is laid out as
//! the seed's grid (`plan::area::grid`), and the seed's genetic search orders
//! the points under each objective; per objective: path length, turns,
//! machine time, heat, generations and the wall-clock time to converge,
//! median and worst over the seeds. The tool runs from point to point at the
//! fill layer's speed, each straight run from rest to rest (a turn stops it).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::mode::Mode;
use crate::plan::area::ga::{evolve, GaSettings, Timed};
use crate::job::Point;
use crate::plan::area::{grid, objective_context, price, Order, Segment};
use crate::plan::objective::{self, Mark};
use crate::plan::stop::TimeCap;

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct FillBench {
    pub job: String,
    pub spacing_mm: f64,
    pub radius_mm: f64,
    pub points: usize,
    pub speed_mm_s: f64,
    /// Every route visits each point once: at least points − 1 links of
    /// `spacing` each, so this long (mm) ...
    pub length_lower_bound_mm: f64,
    /// Any route runs straight from turn to turn, each run on one line: at
    /// least this many runs (`fewest_runs`) ...
    pub runs_lower_bound: f64,
    /// ... so at least this many turns (seed 004's count) ...
    pub turns_lower_bound: usize,
    /// ... and, at the speed at most, each run from rest to rest, at least
    /// this long (s): the length at the speed plus the least a run adds.
    pub time_lower_bound_s: f64,
    pub objectives: Vec<FillObjectiveRuns>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct FillObjectiveRuns {
    pub objective: String,
    pub runs: Vec<FillRun>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct FillRun {
    pub seed: u64,
    pub length_mm: f64,
    /// Vertices where the path turns by more than a degree.
    pub turns: usize,
    /// Seed 004's Eq. 10 over the path (mm): what `turns` minimises.
    pub detour_mm: f64,
    pub time_s: f64,
    pub heat: f64,
    pub generations: usize,
    pub best_generation: usize,
    /// Wall-clock time of the search (this machine's; not a planning figure).
    pub converged_s: f64,
}

/// The route through the points as the objectives see it: one straight
/// mark per link.
fn links<'a>(points: &'a [Segment], order: &'a [(u32, bool)], speed: f64) -> impl Iterator<Item = Mark> + 'a {
    order.windows(2).map(move |w| Mark::straight(points[w[0].0 as usize].from, points[w[1].0 as usize].from, speed, false))
}

/// The grid's two plain rasters (our addition, as the fill planner starts
/// from the hatch's raster): row after row and column after column, each
/// turning back at its end.
fn rasters(points: &[Point]) -> Vec<Order> {
    let by = |key: fn(&Point) -> (f64, f64)| {
        let mut idx: Vec<u32> = (0..points.len() as u32).collect();
        idx.sort_by(|&a, &b| key(&points[a as usize]).partial_cmp(&key(&points[b as usize])).unwrap_or(std::cmp::Ordering::Equal));
        let mut order = Order::with_capacity(points.len());
        let mut line: Vec<u32> = Vec::new();
        let mut back = false;
        for (k, &i) in idx.iter().enumerate() {
            line.push(i);
            let ends = k + 1 == idx.len() || key(&points[idx[k + 1] as usize]).0 != key(&points[i as usize]).0;
            if ends {
                if back {
                    line.reverse();
                }
                order.extend(line.drain(..).map(|i| (i, false)));
                back = !back;
            }
        }
        order
    };
    vec![by(|p| (p.y, p.x)), by(|p| (p.x, p.y))]
}

/// A lower bound on the straight runs of any route through `points` (grid
/// points `spacing` apart). The runs cover the points with lines; giving each
/// point 1 / (the most points on one line through it) is a feasible solution
/// of the dual of that cover's linear programme (no line sums to more than
/// 1), so the runs are at least as many as these shares add up to.
fn fewest_runs(points: &[Point], spacing: f64) -> f64 {
    let cells: Vec<(i64, i64)> = points.iter().map(|p| ((p.x / spacing).round() as i64, (p.y / spacing).round() as i64)).collect();
    let gcd = |mut a: i64, mut b: i64| {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a
    };
    let mut along: std::collections::HashMap<(i64, i64), u32> = std::collections::HashMap::new();
    let mut total = 0.0;
    for &(x0, y0) in &cells {
        along.clear();
        for &(x, y) in &cells {
            let (dx, dy) = (x - x0, y - y0);
            if (dx, dy) == (0, 0) {
                continue;
            }
            let g = gcd(dx.abs(), dy.abs());
            // One key per line through the point, whichever side the other lies.
            let (dx, dy) = if dx < 0 || (dx == 0 && dy < 0) { (-dx / g, -dy / g) } else { (dx / g, dy / g) };
            *along.entry((dx, dy)).or_default() += 1;
        }
        total += 1.0 / (1 + along.values().max().copied().unwrap_or(0)) as f64;
    }
    total
}

pub fn fill_bench(machine: &MachineConfig, job_path: &std::path::Path, spacing: f64, radius: f64, objectives: &[String], seeds: &[u64]) -> Result<FillBench> {
    let job = crate::import::import_job(job_path, machine)?;
    let areas: Vec<&crate::job::Geometry> = job.geometries.iter().filter(|g| job.processes[g.process].fill && g.closed).collect();
    let Some(first) = areas.first() else {
        return Err(Error::Plan(format!("{}: nothing on a fill layer ([[layer]] mode = \"fill\") to lay a grid over", job_path.display())));
    };
    let speed = job.processes[first.process].speed.min(machine.stage.max_velocity);
    let contours: Vec<&[crate::job::Point]> = areas.iter().map(|g| g.points.as_slice()).collect();
    let grid = grid::points(&contours, spacing, radius);
    if grid.len() < 2 {
        return Err(Error::Plan(format!("{}: fewer than two grid points {spacing} mm apart lie {radius} mm inside the area", job_path.display())));
    }
    let genes: Vec<Segment> = grid.iter().enumerate().map(|(k, &p)| Segment { geometry: k, from: p, to: p, either_way: false, across: p.y }).collect();
    let ctx = objective_context(machine, Mode::StageOnly);
    let mut out = Vec::new();
    for spec in objectives {
        let objective = objective::parse(spec).map_err(Error::Config)?;
        // The length of a point route is its links' (there is no mark to leave out).
        let cost = |order: &[(u32, bool)]| {
            if objective.is_length() {
                links(&genes, order, speed).map(|m| m.length).sum()
            } else {
                price(links(&genes, order, speed), objective.as_ref(), &ctx)
            }
        };
        // When each point is reached: its link's start (the last point, the route's end).
        let starts = |order: &[(u32, bool)]| {
            let (mut starts, end) = ctx.motion.timeline(&links(&genes, order, speed).collect::<Vec<_>>());
            starts.push(end);
            starts
        };
        let timed = objective.horizon(&ctx).map(|horizon| Timed { horizon, starts: &starts });
        let mut runs = Vec::new();
        for &seed in seeds {
            let settings = GaSettings { population: machine.fill.population, stall: machine.fill.stall_generations, seed, local: objective.is_local(), ..GaSettings::default() };
            let started = std::time::Instant::now();
            let (order, run) = evolve(&genes, genes[0].from, &cost, timed.as_ref(), rasters(&grid), &settings, &TimeCap::none());
            let converged_s = started.elapsed().as_secs_f64();
            let route: Vec<Mark> = links(&genes, &order, speed).collect();
            let (detour_mm, turns) = objective::turns(&route);
            runs.push(FillRun {
                seed,
                length_mm: route.iter().map(|m| m.length).sum(),
                turns,
                detour_mm,
                time_s: objective::route_time(&route, &ctx.motion),
                heat: objective::heat(&route, &ctx),
                generations: run.generations,
                best_generation: run.best_generation,
                converged_s,
            });
        }
        out.push(FillObjectiveRuns { objective: objective.name(), runs });
    }
    let length_lower_bound_mm = (grid.len() - 1) as f64 * spacing;
    let runs_lower_bound = fewest_runs(&grid, spacing);
    // What a run adds to its length at the speed: a run of one link from rest
    // to rest, or a first and a last link each from or to rest (the links
    // between at the speed). Both grow with the link's length up to the
    // cruise, so they are least at the shortest link, `spacing`.
    let shortest = Mark::straight(grid[0], grid[0] + nalgebra::Vector2::new(spacing, 0.0), speed, false);
    let at_speed = spacing / speed.min(ctx.motion.axis.velocity);
    let run_adds = (ctx.motion.mark_time(&shortest, false, false) - at_speed).min(2.0 * (ctx.motion.mark_time(&shortest, false, true) - at_speed));
    Ok(FillBench {
        job: job_path.display().to_string(),
        spacing_mm: spacing,
        radius_mm: radius,
        points: grid.len(),
        speed_mm_s: speed,
        length_lower_bound_mm,
        runs_lower_bound,
        turns_lower_bound: (runs_lower_bound - 1e-9).ceil().max(1.0) as usize - 1,
        time_lower_bound_s: length_lower_bound_mm / speed.min(ctx.motion.axis.velocity) + runs_lower_bound * run_adds,
        objectives: out,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_runs_bound_is_the_fewest_lines_on_a_square_and_a_row() {
        // A k x k grid takes k lines (its rows) and no fewer; a row takes one.
        let square: Vec<Point> = (0..6).flat_map(|i| (0..6).map(move |j| Point::new(2.0 * i as f64, 2.0 * j as f64))).collect();
        assert!((fewest_runs(&square, 2.0) - 6.0).abs() < 1e-12);
        let row: Vec<Point> = (0..9).map(|i| Point::new(2.0 * i as f64, 4.0)).collect();
        assert!((fewest_runs(&row, 2.0) - 1.0).abs() < 1e-12);
        // A plus sign: its two arms are two lines, the bound no more than that.
        let row = (-3..=3).map(|k| Point::new(k as f64, 0.0));
        let plus: Vec<Point> = row.chain((1..=3).map(|k| Point::new(0.0, k as f64))).collect();
        let bound = fewest_runs(&plus, 1.0);
        assert!(bound > 1.0 && bound <= 2.0 + 1e-12, "{bound}");
    }
}
