//! The cutting planner (`--planner ecp`): the job's topology as an End-point
//! Cutting Problem ([`super::ecp::topology`]), searched ([`super::ecp::solve`])
//! for the shortest air moves plus pierces that keep every precedence rule,
//! and the route turned back into paths to mark. A path is what is cut from
//! one pierce to the next: a whole contour, a piece of one (a contour left and
//! finished later, where that saves more air than a pierce costs), or pieces
//! of neighbouring contours joined by a common cut.
//!
//! With a scanner (step-and-scan), the route is kept as it is and cut into
//! scan fields along it: a path joins the current field while the field's
//! content still fits the usable field, else opens the next one. The order,
//! and so the precedence, stays the search's.

use std::time::Duration;

use super::ecp::{checker, construct, ils, solve, topology};
use super::{check_reach, PathGroup, PlanContext, PlannedPath, Planner, Sequence};
use crate::config::CuttingConfig;
use crate::error::{Error, Result};
use crate::job::{bounds_of, Job, Point};
use crate::motion::Mode;

pub struct Ecp;

/// What the cutting planner found, besides the sequence.
#[derive(Debug, Clone)]
pub struct CuttingPlan {
    pub sequence: Sequence,
    /// Rules the route breaks, by the independent checker (0 unless the search is wrong).
    pub precedence_violations: usize,
    /// Air length and pierces of the construction alone (IB + dir-opt) and of the search.
    pub construction_air_mm: f64,
    pub air_mm: f64,
    pub pierces: usize,
    pub elements: usize,
    pub contours: usize,
    pub iterations: u64,
}

impl Planner for Ecp {
    fn name(&self) -> &'static str {
        "ecp"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        Ok(plan_cutting(job, ctx)?.sequence)
    }
}

/// The job as a cutting instance, with this machine's settings.
pub fn cutting_model(job: &Job, start: Point, settings: &CuttingConfig) -> Result<topology::CuttingModel> {
    let options = topology::TopologyOptions { common_cut_tolerance_mm: settings.common_cut_tolerance, corner_angle_deg: settings.corner_angle };
    let mut model = topology::build(job, start, &options)?;
    model.instance.pierce_cost = settings.pierce_cost;
    Ok(model)
}

pub fn plan_cutting(job: &Job, ctx: &PlanContext) -> Result<CuttingPlan> {
    check_reach(job, ctx.machine, ctx.mode)?;
    let settings = &ctx.machine.cutting;
    let model = cutting_model(job, ctx.start, settings)?;
    let inst = &model.instance;
    let time_limit = Duration::from_secs_f64(settings.time_limit);
    let construction = construct::insertion(inst);
    let construction_air_mm = inst.air_length(&construction);
    let (route, iterations) = if inst.elements.is_empty() {
        (Vec::new(), 0)
    } else {
        let options = ils::SearchOptions {
            // Small jobs stop early once the search has long found nothing better.
            max_stall: 20_000 + 100 * inst.elements.len() as u64,
            ..ils::SearchOptions::new(time_limit)
        };
        let found = solve(inst, settings.search, &options);
        (found.route, found.iterations)
    };
    let precedence_violations = checker::check(inst, &route).len();
    let polylines = model.polylines(&route);
    let mut paths = Vec::with_capacity(polylines.len());
    for (geometry, points) in polylines {
        let process = job.geometries[geometry].process;
        for _ in 0..job.processes[process].passes {
            paths.push(PlannedPath { geometry, points: points.clone(), process });
        }
    }
    let pierces = paths.len();
    let scanner = ctx.machine.scanner.as_ref().filter(|_| ctx.mode != Mode::StageOnly);
    let groups = match scanner {
        None => vec![PathGroup { field_center: None, paths }],
        Some(s) => fields_along(job, paths, s.usable_half_field, (ctx.machine.stage.travel_x, ctx.machine.stage.travel_y))?,
    };
    Ok(CuttingPlan {
        sequence: Sequence { groups },
        precedence_violations,
        construction_air_mm,
        air_mm: inst.air_length(&route),
        pierces,
        elements: inst.elements.len(),
        contours: inst.contours.len(),
        iterations,
    })
}

/// The paths in their order, cut into scan fields: each field takes paths
/// while its content fits `2 × usable_half` on both axes.
fn fields_along(job: &Job, paths: Vec<PlannedPath>, usable_half: f64, travel: (f64, f64)) -> Result<Vec<PathGroup>> {
    let size = 2.0 * usable_half;
    let mut groups: Vec<(Point, Point, Vec<PlannedPath>)> = Vec::new();
    for path in paths {
        let (lo, hi) = bounds_of(path.points.iter());
        if hi.x - lo.x > size + 1e-9 || hi.y - lo.y > size + 1e-9 {
            return Err(Error::Plan(format!(
                "{}: a cut of {:.3} x {:.3} mm does not fit the scanner's usable field ({size} x {size} mm); use --mode stage-only",
                job.geometries[path.geometry].source,
                hi.x - lo.x,
                hi.y - lo.y
            )));
        }
        match groups.last_mut() {
            Some((flo, fhi, members)) if {
                let (ulo, uhi) = bounds_of([*flo, *fhi, lo, hi].iter());
                uhi.x - ulo.x <= size + 1e-9 && uhi.y - ulo.y <= size + 1e-9
            } =>
            {
                (*flo, *fhi) = bounds_of([*flo, *fhi, lo, hi].iter());
                members.push(path);
            }
            _ => groups.push((lo, hi, vec![path])),
        }
    }
    groups
        .into_iter()
        .map(|(lo, hi, paths)| {
            // Centred on the content, the stage kept inside its travel.
            let mut c = Point::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0);
            c.x = c.x.clamp((hi.x - usable_half).max(0.0), (lo.x + usable_half).min(travel.0));
            c.y = c.y.clamp((hi.y - usable_half).max(0.0), (lo.y + usable_half).min(travel.1));
            if c.x < 0.0 || c.y < 0.0 || c.x > travel.0 || c.y > travel.1 {
                return Err(Error::Plan(format!("{}: cannot be reached with the stage inside its travel", job.geometries[paths[0].geometry].source)));
            }
            Ok(PathGroup { field_center: Some(c), paths })
        })
        .collect()
}

/// Inner contours (holes, parts in holes, engravings on parts) whose last cut
/// comes at or after their outer contour's last cut, for a sequence of whole
/// geometries (any planner's): the part has fallen out before they were done.
pub fn sequence_precedence_violations(model: &topology::CuttingModel, sequence: &Sequence) -> usize {
    let mut closes = vec![None; model.instance.contours.len()];
    for (i, p) in sequence.paths().enumerate() {
        if let Some(c) = closes.get_mut(p.geometry) {
            *c = Some(i);
        }
    }
    model.instance.inner_outer.iter().filter(|&&(inner, outer)| closes[inner] >= closes[outer]).count()
}
