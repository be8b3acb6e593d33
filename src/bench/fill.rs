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
use crate::plan::area::ga::{evolve, GaSettings};
use crate::plan::area::{grid, objective_context, Segment};
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
    /// ... and, at the speed at most, this long (s).
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
    pub time_s: f64,
    pub heat: f64,
    pub generations: usize,
    pub best_generation: usize,
    /// Wall-clock time of the search (this machine's; not a planning figure).
    pub converged_s: f64,
}

/// The route through the points as the objectives see it: one straight
/// mark per link.
fn links(points: &[Segment], order: &[(u32, bool)], speed: f64) -> Vec<Mark> {
    order.windows(2).map(|w| Mark::straight(points[w[0].0 as usize].from, points[w[1].0 as usize].from, speed, false)).collect()
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
            let route = links(&genes, order, speed);
            if objective.is_length() {
                route.iter().map(|m| m.length).sum()
            } else {
                objective.cost(&route, &ctx)
            }
        };
        let mut runs = Vec::new();
        for &seed in seeds {
            let settings = GaSettings { population: machine.fill.population, stall: machine.fill.stall_generations, seed, local: objective.is_local(), ..GaSettings::default() };
            let started = std::time::Instant::now();
            let (order, run) = evolve(&genes, genes[0].from, &cost, Vec::new(), &settings, &TimeCap::none());
            let converged_s = started.elapsed().as_secs_f64();
            let route = links(&genes, &order, speed);
            runs.push(FillRun {
                seed,
                length_mm: route.iter().map(|m| m.length).sum(),
                turns: objective::turns(&route).1,
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
    Ok(FillBench {
        job: job_path.display().to_string(),
        spacing_mm: spacing,
        radius_mm: radius,
        points: grid.len(),
        speed_mm_s: speed,
        length_lower_bound_mm,
        time_lower_bound_s: length_lower_bound_mm / speed,
        objectives: out,
    })
}
