//! The cutting planner (`--planner ecp`): the job's topology as an End-point
//! Cutting Problem ([`super::ecp::model`]), searched ([`super::ecp::solve`])
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

use std::time::{Duration, Instant};

use super::ecp::checker::{self, Violation};
use super::ecp::model::{CuttingModel, Polyline};
use super::ecp::{ils, solve, Metric};
use super::fields::centre_within_travel;
use super::stop::SearchStop;
use super::{check_reach, PathGroup, PlanContext, PlanOutcome, PlannedPath, Planner, Sequence};
use crate::config::{CuttingConfig, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{bounds_of, Job, Point};
use crate::topology::plate::PlateLayout;
use crate::topology::{Topology, TopologyOptions};
use crate::mode::Mode;

pub struct Ecp;

/// What the cutting planner found, besides the sequence.
#[derive(Debug, Clone)]
pub struct CuttingPlan {
    pub sequence: Sequence,
    /// Rules the route breaks, by the independent checker (none unless the
    /// search is wrong); contours are the job's geometries.
    pub broken_rules: Vec<Violation>,
    /// Whether the search's budget or the time limit ended it.
    pub search_stopped_by: SearchStop,
    /// The length of the parts' outlines on the plate's edge, not cut.
    pub edge_length_saved_mm: f64,
    /// What the thermal planner did (`[thermal] enabled`).
    pub thermal: Option<super::thermal::ThermalSearch>,
}

impl CuttingPlan {
    pub fn outcome(self) -> PlanOutcome {
        PlanOutcome {
            sequence: self.sequence,
            planner: "ecp".into(),
            broken_rules: Some(self.broken_rules),
            search_stopped_by: self.search_stopped_by,
            edge_length_saved_mm: self.edge_length_saved_mm,
            leads: Default::default(),
            tabs: 0,
            bridges: Default::default(),
            may_tip: 0,
            precuts: Default::default(),
            thermal: self.thermal,
        }
    }
}

impl Planner for Ecp {
    fn name(&self) -> &'static str {
        "ecp"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        Ok(plan_cutting(job, ctx)?.sequence)
    }
}

/// The topology options of this machine's settings.
pub fn topology_options(settings: &CuttingConfig) -> TopologyOptions {
    TopologyOptions { common_cut_tolerance_mm: settings.common_cut_tolerance, corner_angle_deg: settings.corner_angle }
}

/// The job's topology, with this machine's settings.
pub fn topology(job: &Job, settings: &CuttingConfig) -> Result<Topology> {
    Topology::build(job, &topology_options(settings))
}

/// The job as a cutting instance, with this machine's settings.
pub fn cutting_model(job: &Job, start: Point, settings: &CuttingConfig) -> Result<CuttingModel> {
    Ok(CuttingModel::new(topology(job, settings)?, start, settings.pierce_cost))
}

/// How the search prices an air move under `[cutting] objective`: its
/// length, or its machine time on the axes that make it, or a mix.
fn metric(ctx: &PlanContext) -> Result<Metric> {
    let weights = crate::config::route_objective_weights(&ctx.machine.cutting.objective).map_err(|e| Error::Config(format!("cutting.objective: {e}")))?;
    Ok(match weights {
        (_, 0.0) => Metric::Euclidean,
        (length, time) => Metric::Machine { length, time, motion: super::area::objective_context(ctx.machine, ctx.mode).motion },
    })
}

pub fn plan_cutting(job: &Job, ctx: &PlanContext) -> Result<CuttingPlan> {
    let started = Instant::now();
    check_reach(job, ctx.machine, ctx.mode)?;
    let settings = &ctx.machine.cutting;
    let mut model = match ctx.plate {
        Some(plate) => CuttingModel::with_plate(job, plate, 0, ctx.start, settings.pierce_cost, &topology_options(settings))?,
        None => cutting_model(job, ctx.start, settings)?,
    };
    // A part held by tabs stays where it is when its outline is cut: what
    // lies inside it need not come first (contour k < the job's geometries
    // is geometry k, with or without a plate).
    let held = super::tabs::held(&super::tabs::place(job, ctx.machine)?);
    model.instance.inner_outer.retain(|&(_, outer)| !held.get(outer).copied().unwrap_or(false));
    model.charge_sharp_turns(settings.sharp_angle_cost, settings.corner_angle);
    model.instance.metric = metric(ctx)?;
    let inst = &model.instance;
    // A time limit (none by default) is for the whole planning step, topology
    // included, with a little kept back for turning the route into paths.
    let time_limit = settings.time_limit.map(|limit| {
        let keep_back = Duration::from_millis(50) + Duration::from_secs_f64(limit / 200.0);
        Duration::from_secs_f64(limit).saturating_sub(started.elapsed() + keep_back).max(Duration::from_millis(10))
    });
    let threads = crate::parallel::threads()?;
    let (route, search_stopped_by) = if inst.elements.is_empty() {
        (Vec::new(), SearchStop::Budget)
    } else {
        let options = ils::SearchOptions {
            // Small jobs stop early once the search has long found nothing better.
            max_stall: 20_000 + 100 * inst.elements.len() as u64,
            time_limit,
            threads,
            ..ils::SearchOptions::new()
        };
        let found = solve(inst, settings.search, &options);
        (found.route, found.stopped_by)
    };
    // Seed 000: a route that keeps the plate below its critical temperatures.
    let (route, thermal, search_stopped_by) = if ctx.machine.thermal.enabled && !route.is_empty() {
        let heat = super::thermal::HeatModel::new(job, ctx.machine, super::area::objective_context(ctx.machine, ctx.mode).motion)?;
        let cap = super::stop::TimeCap::after(time_limit.map(|l| l.saturating_sub(started.elapsed())));
        let options = ils::SearchOptions { kicks: Some(thermal_kicks(inst.elements.len())), time_limit: cap.remaining(), threads, max_stall: 0, ..ils::SearchOptions::new() };
        let (route, found) = super::thermal::plan(job, ctx.machine, &model, ctx.start, route, &heat, &options, &cap);
        let stopped = search_stopped_by.and(found.stopped_by);
        (route, Some(found), stopped)
    } else {
        (route, None, search_stopped_by)
    };
    let broken_rules = match ctx.plate {
        // The plate's regions are contours beyond the job's geometries:
        // named after them (see `describe`).
        Some(plate) => checker::check_plate(&model.topology, plate, &model.topology_route(&route), &held)
            .into_iter()
            .map(|v| renumbered(v, |c| if c >= plate.first_cut { job.geometries.len() + c - plate.first_cut } else { c }))
            .collect(),
        None => checker::check(inst, &route),
    };
    let mut polylines = model.polylines(&route);
    if let Some(plate) = ctx.plate.filter(|p| p.scrap_after) {
        polylines.extend(scrap_after(job, plate, polylines.last().map(|l| l.points[l.points.len() - 1]).unwrap_or(ctx.start)));
    }
    let mut paths = Vec::with_capacity(polylines.len());
    for line in polylines {
        let process = job.geometries[line.geometry].process;
        for _ in 0..job.processes[process].passes {
            paths.push(PlannedPath::new(line.geometry, line.points.clone(), process, line.pierce));
        }
    }
    // The heat model's timeline has a path per pass, as here (scrap after).
    if let Some(t) = &thermal {
        for (path, &wait) in paths.iter_mut().zip(&t.planned.waits) {
            path.cooling_wait = super::thermal::dwell_steps(wait);
        }
    }
    let scanner = ctx.machine.scanner.as_ref().filter(|_| ctx.mode != Mode::StageOnly);
    let groups = match scanner {
        None => vec![PathGroup { field_center: None, paths }],
        Some(s) => fields_along(job, paths, s.usable_half_field, (ctx.machine.stage.travel_x, ctx.machine.stage.travel_y))?,
    };
    let edge_length_saved_mm = model.edge_length_saved();
    Ok(CuttingPlan { sequence: Sequence { groups }, broken_rules, search_stopped_by, edge_length_saved_mm, thermal })
}

/// Kicks of each search under thermal penalties (from the route before):
/// a fortieth of the plain search's, so that dozens fit where one did.
fn thermal_kicks(elements: usize) -> u64 {
    (ils::default_kicks(elements) / 40).max(2_000)
}

/// A rule with its contours renumbered by `f`.
pub fn renumbered(rule: Violation, f: impl Fn(usize) -> usize) -> Violation {
    match rule {
        Violation::InnerAfterOuter { inner, outer } => Violation::InnerAfterOuter { inner: f(inner), outer: f(outer) },
        Violation::ClosesBoth { element, contours: (a, b) } => Violation::ClosesBoth { element, contours: (f(a), f(b)) },
        other => other,
    }
}

/// The plate's skeleton and remnant cuts after the parts (`[plate]
/// scrap_cuts = "after"`): nearest first from `here`, each in the direction
/// that starts nearer; no pierce where one starts on the plate's edge or
/// where the one before ended.
fn scrap_after(job: &Job, plate: &PlateLayout, mut here: Point) -> Vec<Polyline> {
    let mut left: Vec<usize> = (plate.first_cut..job.geometries.len()).collect();
    let mut out = Vec::with_capacity(left.len());
    while !left.is_empty() {
        let ends = |g: usize| {
            let p = &job.geometries[g].points;
            (p[0], p[p.len() - 1])
        };
        let (i, reversed, _) = left
            .iter()
            .enumerate()
            .flat_map(|(i, &g)| {
                let (a, b) = ends(g);
                [(i, false, (a - here).norm()), (i, true, (b - here).norm())]
            })
            .fold((0, false, f64::INFINITY), |best, c| if c.2 < best.2 { c } else { best });
        let g = left.remove(i);
        let mut points = job.geometries[g].points.clone();
        if reversed {
            points.reverse();
        }
        let pierce = points[0] != here && !plate.on_edge(points[0]);
        here = points[points.len() - 1];
        out.push(Polyline { geometry: g, points, pierce });
    }
    out
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
            let center = centre_within_travel(lo, hi, usable_half, travel)
                .ok_or_else(|| Error::Plan(format!("{}: cannot be reached with the stage inside its travel", job.geometries[paths[0].geometry].source)))?;
            Ok(PathGroup { field_center: Some(center), paths })
        })
        .collect()
}

/// Whether each geometry of `job` cuts through: its layer pierces. Parts
/// fall out only where the laser cuts through; a marking layer holds nothing.
pub fn cuts_through(job: &Job, machine: &MachineConfig) -> Vec<bool> {
    job.geometries.iter().map(|g| machine.pierce(&job.processes[g.process].layer).active()).collect()
}

/// The precedence rules a sequence of whole geometries (any planner's)
/// breaks: a geometry whose last cut comes at or after the last cut of the
/// nearest contour around it that cuts through (`cuts`), its part having
/// fallen out by then. A marking contour holds nothing: what lies inside an
/// engraved frame belongs to the part the frame is on.
pub fn whole_geometry_violations(topology: &Topology, sequence: &Sequence, cuts: &[bool], held: &[bool]) -> Vec<Violation> {
    let mut closes = vec![None; topology.outer.len()];
    for (i, p) in sequence.paths().enumerate() {
        if let Some(c) = closes.get_mut(p.geometry) {
            *c = Some(i);
        }
    }
    let part_around = |mut k: usize| {
        while let Some(o) = topology.outer[k] {
            if cuts.get(o).copied().unwrap_or(true) {
                return Some(o);
            }
            k = o;
        }
        None
    };
    (0..topology.outer.len())
        .filter_map(|inner| part_around(inner).map(|outer| (inner, outer)))
        .filter(|&(inner, outer)| closes[inner] >= closes[outer] && !held.get(outer).copied().unwrap_or(false))
        .map(|(inner, outer)| Violation::InnerAfterOuter { inner, outer })
        .collect()
}

/// The rules a planner's whole-geometry `sequence` of `job` breaks; `None`
/// when the job's topology cannot be built. A job with nothing that cuts
/// through breaks none.
pub fn sequence_violations(job: &Job, sequence: &Sequence, ctx: &PlanContext) -> Option<Vec<Violation>> {
    let cuts = cuts_through(job, ctx.machine);
    if !cuts.contains(&true) {
        return Some(Vec::new());
    }
    let topology = topology(job, &ctx.machine.cutting).ok()?;
    let held = super::tabs::held(&super::tabs::place(job, ctx.machine).ok()?);
    Some(whole_geometry_violations(&topology, sequence, &cuts, &held))
}

/// A broken rule in words, its geometries named as the job names them
/// (without the file name each repeats).
pub fn describe(job: &Job, rule: &Violation) -> String {
    let name = |g: usize| match job.geometries.get(g) {
        Some(g) => g.source.strip_prefix(&format!("{}: ", job.source)).unwrap_or(&g.source).to_string(),
        None => format!("plate region {}", g - job.geometries.len() + 1),
    };
    match *rule {
        Violation::InnerAfterOuter { inner, outer } => format!("{} cut after {} around it", name(inner), name(outer)),
        Violation::ClosesBoth { contours: (a, b), .. } => format!("a common cut closes both {} and {}", name(a), name(b)),
        Violation::CutCount { element, times } => format!("cut element {element} {times} times"),
        Violation::UnknownElement { element } => format!("unknown element {element}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Geometry, Process};

    fn job_of(n: usize) -> Job {
        let g = |i: usize| Geometry { arcs: Vec::new(), profile: Vec::new(), points: vec![Point::new(0.0, 0.0), Point::new(1.0, 0.0)], closed: false, process: 0, source: format!("g{i}") };
        Job { source: "t".into(), geometries: (0..n).map(g).collect(), processes: vec![Process { layer: "cut".into(), speed: 10.0, power: 1.0, passes: 1, fill: false }] }
    }

    fn path(geometry: usize, from: (f64, f64), to: (f64, f64)) -> PlannedPath {
        PlannedPath::new(geometry, vec![Point::new(from.0, from.1), Point::new(to.0, to.1)], 0, true)
    }

    #[test]
    fn fields_follow_the_route_and_keep_its_order() {
        let job = job_of(4);
        let paths = vec![path(0, (10.0, 10.0), (20.0, 10.0)), path(1, (100.0, 100.0), (110.0, 100.0)), path(2, (25.0, 15.0), (30.0, 20.0)), path(3, (105.0, 95.0), (100.0, 90.0))];
        let groups = fields_along(&job, paths, 16.0, (300.0, 300.0)).unwrap();
        // Paths 0 and 2 would fit one field, but 1 comes between them: the
        // route's order (and so its precedence) is kept, fields are not merged.
        let order: Vec<Vec<usize>> = groups.iter().map(|g| g.paths.iter().map(|p| p.geometry).collect()).collect();
        assert_eq!(order, vec![vec![0], vec![1], vec![2], vec![3]]);
        for g in &groups {
            let c = g.field_center.unwrap();
            for p in &g.paths {
                assert!(p.points.iter().all(|q| (q.x - c.x).abs() <= 16.0 + 1e-9 && (q.y - c.y).abs() <= 16.0 + 1e-9));
            }
        }
        let together = fields_along(&job, vec![path(0, (10.0, 10.0), (20.0, 10.0)), path(2, (25.0, 15.0), (30.0, 20.0))], 16.0, (300.0, 300.0)).unwrap();
        assert_eq!(together.len(), 1);
        let err = fields_along(&job, vec![path(3, (0.0, 0.0), (40.0, 0.0))], 16.0, (300.0, 300.0)).unwrap_err().to_string();
        assert!(err.contains("g3") && err.contains("stage-only"), "{err}");
    }

    #[test]
    fn whole_geometry_orders_are_judged_by_their_closing_paths() {
        let model = Topology {
            elements: Vec::new(),
            contours: vec![vec![0], vec![1], vec![2]],
            common_cuts: Vec::new(),
            // 1 inside 0, 2 inside 1.
            outer: vec![None, Some(0), Some(1)],
            levels: vec![0, 1, 2],
            ranks: vec![0; 3],
            groups: vec![0; 3],
        };
        let seq = |order: &[usize]| Sequence { groups: vec![PathGroup { field_center: None, paths: order.iter().map(|&g| path(g, (0.0, 0.0), (1.0, 0.0))).collect() }] };
        let all_cut = [true; 3];
        let broken = |order: &[usize], cuts: &[bool]| whole_geometry_violations(&model, &seq(order), cuts, &[]);
        assert_eq!(broken(&[2, 1, 0], &all_cut), vec![]);
        assert_eq!(broken(&[0, 1, 2], &all_cut), vec![Violation::InnerAfterOuter { inner: 1, outer: 0 }, Violation::InnerAfterOuter { inner: 2, outer: 1 }]);
        // A second pass of the outer after its inner: closed last, fine.
        assert_eq!(broken(&[0, 2, 1, 0], &all_cut), vec![]);
        assert_eq!(broken(&[2, 0, 1], &all_cut).len(), 1);
        // 1 engraved (it holds nothing): 2 belongs to the part 0 around both.
        let engraved = [true, false, true];
        assert_eq!(broken(&[1, 2, 0], &engraved), vec![]);
        assert_eq!(broken(&[1, 2, 0], &all_cut).len(), 1, "cut through, 1 is a part of its own");
        assert_eq!(broken(&[0, 1, 2], &engraved), vec![Violation::InnerAfterOuter { inner: 1, outer: 0 }, Violation::InnerAfterOuter { inner: 2, outer: 0 }]);
    }
}
