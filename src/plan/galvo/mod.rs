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
pub mod route;

use super::fields::{centre_within_travel, cover, Field};
use super::nearest::path_points;
use super::{check_reach, PathGroup, PlanContext, PlannedPath, Planner, Sequence};
use crate::error::Result;
use crate::job::{bounds_of, Job, Point};
use crate::mode::Mode;
use crate::plan::stop::{SearchStop, TimeCap};
use route::{Route, Stop};
use std::time::Duration;

/// Settings of the galvo planners.
#[derive(Debug, Clone)]
pub struct GalvoSettings {
    /// Weight of Eq. 7's directionality penalty with several fields.
    pub direction_weight: f64,
    /// The same with a single field (seed 003 uses a smaller one there).
    pub direction_weight_single_field: f64,
    /// Kicks of the route search per geometry.
    pub kicks_per_geometry: usize,
    /// Threads the independent searches run on (the plan does not depend on it).
    pub threads: usize,
    pub seed: u64,
}

impl Default for GalvoSettings {
    fn default() -> Self {
        GalvoSettings {
            direction_weight: 0.5,
            direction_weight_single_field: 0.1,
            kicks_per_geometry: 6,
            threads: 1,
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
                groups.last_mut().unwrap().paths.push(PlannedPath::new(s, points.clone(), geometry.process, true));
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
        Ok(plan_galvo(job, ctx, false)?.0)
    }
}

impl Planner for Hga {
    fn name(&self) -> &'static str {
        "hga"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        Ok(plan_galvo(job, ctx, true)?.0)
    }
}

/// The HHA's route, and with `genetic` the HGA on from there; each search
/// stops on its work budget, or at the `[galvo]` time limit (a cap on the
/// whole planning step, none by default) if that comes first.
pub fn plan_galvo(job: &Job, ctx: &PlanContext, genetic: bool) -> Result<(Sequence, SearchStop)> {
    check_reach(job, ctx.machine, ctx.mode)?;
    let g = &ctx.machine.galvo;
    let cap = TimeCap::after(g.time_limit.map(Duration::from_secs_f64));
    let threads = crate::parallel::threads()?;
    if job.geometries.is_empty() {
        return Ok((Sequence { groups: Vec::new() }, SearchStop::Budget));
    }
    let settings = GalvoSettings { direction_weight: g.direction_weight, direction_weight_single_field: g.direction_weight_single_field, seed: g.seed, threads, ..GalvoSettings::default() };
    let layout = Layout::new(job, ctx)?;
    let mut route = hha::plan_route(job, &layout, ctx.start, &settings, &cap);
    if genetic {
        route = hga::plan_route(job, &layout, route, &settings, &cap);
    }
    Ok((layout.sequence(job, &route, ctx), cap.stop()))
}
