//! Thermally feasible cutting routes (seed 000, "Generating thermal feasible
//! tool paths"): the cutting search's route is stepped through the plate
//! heat model (`crate::thermal`); where an operation starts on plate hotter
//! than its feature's critical temperature, the decisions that led there
//! (the jumps into the paths before it, seed 000's index difference counted
//! in paths) get a penalty that grows with the relative violation and
//! decays by the responsiveness ρ per path back:
//! φ'ᵢⱼ = φᵢⱼ + penalty · (T − T_crit)/T_crit · ρ^(k_violation − k_j).
//! The search runs again under the penalties (the air moves' cost plus φ),
//! and so on until a route has no violation, `stall` constructions in a row
//! find no better one, or the constructions run out; every search of a
//! construction is assessed, and the next goes on from the best of them.
//! Routes are ranked by whether they need cooling waits (the laser off,
//! the head still at a path's start until every operation of the path is
//! below its critical temperature), then by machine time, waits included.
//! The kept route's waits are the last resort: each becomes a dwell before
//! its path in the program (`PlannedPath::cooling_wait`).

use std::time::Instant;

use super::ecp::ils::{self, SearchOptions};
use super::ecp::model::{CuttingModel, Polyline};
use super::ecp::{Cut, Instance};
use super::objective::MotionModel;
use super::stop::TimeCap;
use crate::config::{MachineConfig, ThermalConfig};
use crate::error::Result;
use crate::job::{bounds_of, Job, Point};
use crate::thermal::{self, assess, AssessOptions, Assessment, Corners, Critical, Grid, PathHeat, Physics, Snapshot, Timeline};

/// The heat model of a cutting job: plate, material, laser, and how the
/// route's times are estimated (air moves rest to rest at the axes' limits,
/// cuts at their layer's speed).
#[derive(Debug, Clone)]
pub struct HeatModel {
    pub grid: Grid,
    pub physics: Physics,
    pub critical: Critical,
    /// The heat the laser puts in at `laser.max_power`, W.
    pub watts: f64,
    pub corners: Corners,
    pub motion: MotionModel,
}

impl HeatModel {
    pub fn new(job: &Job, machine: &MachineConfig, motion: MotionModel) -> Result<HeatModel> {
        let (physics, critical, watts) = thermal::model_of(machine)?;
        let (lo, hi) = bounds_of(job.geometries.iter().flat_map(|g| g.points.iter()));
        let grid = thermal::grid_of(machine, lo, hi)?;
        let corners = Corners { cos_sharp: machine.cutting.corner_angle.to_radians().cos(), dwell: machine.thermal.corner_dwell };
        Ok(HeatModel { grid, physics, critical, watts, corners, motion })
    }

    /// The timeline of `paths` cut in order from `start`: each begins when
    /// the air move from the one before ends.
    pub fn timeline(&self, job: &Job, machine: &MachineConfig, start: Point, paths: &[Polyline]) -> Timeline {
        let rest = nalgebra::Vector2::zeros();
        let mut here = start;
        let mut clock = 0.0;
        let mut heats = Vec::with_capacity(paths.len());
        for line in paths {
            let process = &job.processes[job.geometries[line.geometry].process];
            let pierce = machine.pierce(&process.layer);
            let share = |power: f64| self.watts * (power / machine.laser.max_power).clamp(0.0, 1.0);
            for _ in 0..process.passes.max(1) {
                clock += self.motion.move_time(here, rest, line.points[0], rest);
                let heat = PathHeat {
                    points: &line.points,
                    start: clock,
                    pierce: (line.pierce && pierce.active()).then(|| (pierce.time, share(pierce.power))),
                    speed: process.speed,
                    watts: share(process.power),
                };
                clock += heat.pierce.map_or(0.0, |p| p.0) + line.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum::<f64>() / process.speed;
                heats.push(heat);
                here = line.points[line.points.len() - 1];
            }
        }
        Timeline::build(&heats, self.corners, self.grid.cell / 2.0)
    }

    pub fn assess(&self, timeline: &Timeline, options: &AssessOptions) -> Assessment {
        assess(self.grid, &self.physics, self.critical, timeline, options)
    }
}

/// What the thermal planner did.
#[derive(Debug, Clone)]
pub struct ThermalSearch {
    /// The plain route (the cutting search without the heat model), assessed.
    pub plain: Assessment,
    pub plain_timeline: Timeline,
    /// Its estimated machine time (air moves, pierces, cuts), s.
    pub plain_time: f64,
    /// The kept route, assessed with its cooling waits (`waits`, per path
    /// of the timeline: a path per pass), and its timeline (the checks'
    /// features and places).
    pub planned: Assessment,
    pub planned_timeline: Timeline,
    /// The plate when the operation nearest its critical temperature starts
    /// (for the heat map).
    pub hottest_plate: Option<Snapshot>,
    /// The plate every so often over the kept route (for the recording).
    pub plates: Vec<Snapshot>,
    pub planned_time: f64,
    /// Constructions searched under penalties (0: the plain route had no violation).
    pub iterations: u32,
    /// Pairs of cuts carrying a penalty at the end.
    pub penalties: usize,
    /// Seconds the heat model took, in all, and per evaluation.
    pub evaluation_s: f64,
    pub evaluations: u32,
    pub stopped_by: super::stop::SearchStop,
}

/// The paths of `route` and, per path, where in the route it starts, with
/// each path's passes (as `timeline` repeats them).
fn paths_of(model: &CuttingModel, job: &Job, route: &[Cut]) -> (Vec<Polyline>, Vec<usize>) {
    let (lines, starts) = model.polylines_from(route);
    let mut at = Vec::with_capacity(starts.len());
    for (line, &k) in lines.iter().zip(&starts) {
        let passes = job.processes[job.geometries[line.geometry].process].passes.max(1);
        at.extend(std::iter::repeat_n(k, passes as usize));
    }
    (lines, at)
}

/// Seed 000's multi-start from the plain `route`: see the module's doc.
#[allow(clippy::too_many_arguments)]
pub fn plan(job: &Job, machine: &MachineConfig, model: &CuttingModel, start: Point, route: Vec<Cut>, heat: &HeatModel, options: &SearchOptions, cap: &TimeCap) -> (Vec<Cut>, ThermalSearch) {
    let settings = &machine.thermal;
    let mut evaluation_s = 0.0;
    let mut evaluations = 0;
    let mut count = |seconds: f64| {
        evaluation_s += seconds;
        evaluations += 1;
    };
    let evaluate = |route: &[Cut], waits: bool| {
        let (lines, at) = paths_of(model, job, route);
        let timeline = heat.timeline(job, machine, start, &lines);
        let began = Instant::now();
        let assessment = heat.assess(&timeline, &AssessOptions { waits, ..Default::default() });
        (assessment, timeline, at, began.elapsed().as_secs_f64())
    };
    // Every route is assessed with the waits it would need: the plain
    // route's violations are those it would have without them.
    let (plain, plain_timeline, _, seconds) = evaluate(&route, false);
    count(seconds);
    let plain_time = plain_timeline.end;
    let mut inst: Instance = model.instance.clone();
    let (a, t, at) = if plain.violations.is_empty() {
        (plain.clone(), plain_timeline.clone(), Vec::new())
    } else {
        let (a, t, at, seconds) = evaluate(&route, true);
        count(seconds);
        (a, t, at)
    };
    let mut current = (route, a, t, at);
    // The best so far: without waits if any is, then the least machine time.
    let rank = |a: &Assessment| (!a.waited.is_empty(), a.end);
    let mut best = current.clone();
    let mut iterations = 0;
    let mut since_better = 0;
    while !best.1.waited.is_empty() && iterations < settings.iterations && since_better < settings.stall && !cap.reached() {
        learn(&mut inst, &current.0, &current.1, &current.2, &current.3, heat.critical, settings);
        iterations += 1;
        // From the last route: the penalties change it where it heated.
        let initial = Some(std::sync::Arc::new(current.0.clone()));
        let search = SearchOptions { seed: options.seed.wrapping_add(1000 * iterations as u64), initial, ..options.clone() };
        let searched = Instant::now();
        // Every search's route is assessed (on the cores the searches ran
        // on): the one the heat favours need not be the cheapest under the
        // penalties. The next construction goes on from the best of them.
        let found = ils::searches(&inst, &search, cap);
        let search_s = searched.elapsed().as_secs_f64();
        let assessed = crate::parallel::tasks(found.len(), options.threads, |k| evaluate(&found[k].route, true));
        let mut next: Option<(Vec<Cut>, Assessment, Timeline, Vec<usize>)> = None;
        for (run, (assessment, timeline, at, seconds)) in found.into_iter().zip(assessed) {
            count(seconds);
            tracing::debug!("thermal construction {iterations}: {} violations, {:.1} s of waits, {:.1} s; searched in {search_s:.3} s ({} kicks)", assessment.waited.len(), assessment.wait, assessment.end, run.iterations);
            if next.as_ref().is_none_or(|n| rank(&assessment) < rank(&n.1)) {
                next = Some((run.route, assessment, timeline, at));
            }
        }
        current = next.expect("at least one search ran");
        since_better += 1;
        if rank(&current.1) < rank(&best.1) {
            best = current.clone();
            since_better = 0;
        }
    }
    let (route, planned, planned_timeline, _) = best;
    let planned_time = planned.end;
    let waits = !planned.waited.is_empty();
    let hottest_plate = planned.hottest.and_then(|h| {
        let path = planned_timeline.checks[h.check].path;
        heat.assess(&planned_timeline, &AssessOptions { waits, snapshot_path: Some(path), ..Default::default() }).snapshots.pop()
    });
    // About sixty pictures of the plate over the job, for the recording.
    let every = (planned.end / 60.0).max(5.0);
    let plates = heat.assess(&planned_timeline, &AssessOptions { waits, snapshot_every: Some(every), ..Default::default() }).snapshots;
    let search = ThermalSearch {
        hottest_plate,
        plates,
        plain,
        plain_timeline,
        plain_time,
        planned,
        planned_timeline,
        planned_time,
        iterations,
        penalties: inst.penalties.len(),
        evaluation_s,
        evaluations,
        stopped_by: cap.stop(),
    };
    (route, search)
}

/// Seed 000's update: every violation raises the penalty of the jump into
/// its path (from where the route came, and from every cut ending within
/// `reach` of it) and of the jumps into the paths before it, by its
/// relative size times ρ per path back (down to a thousandth).
fn learn(inst: &mut Instance, route: &[Cut], assessment: &Assessment, timeline: &Timeline, at: &[usize], critical: Critical, settings: &ThermalConfig) {
    let (penalty, rho) = (settings.penalty, settings.responsiveness);
    for &(c, celsius) in &assessment.waited {
        let check = &timeline.checks[c];
        let limit = critical.of(check.feature);
        let size = (celsius - limit) / limit;
        let mut weight = penalty * size.max(1e-3);
        let mut path = check.path;
        if settings.reach > 0.0 {
            let into = route[at[path]];
            let (start, _) = inst.ends(into);
            let near: Vec<Cut> = (0..inst.elements.len())
                .flat_map(|element| [false, true].map(|reversed| Cut { element, reversed }))
                .filter(|&c| c.element != into.element && (inst.ends(c).1 - start).norm() <= settings.reach)
                .collect();
            for from in near {
                inst.penalties.add(from, into, weight);
            }
        }
        loop {
            let k = at[path];
            if k > 0 {
                inst.penalties.add(route[k - 1], route[k], weight);
            }
            weight *= rho;
            if path == 0 || weight < penalty * 1e-3 {
                break;
            }
            path -= 1;
        }
    }
}

/// A cooling wait as the controller counts it: Grbl 1.1 dwells in 50 ms
/// steps, rounding up; so does this (a longer wait only cools more).
pub fn dwell_steps(wait: f64) -> f64 {
    if wait <= 0.0 {
        0.0
    } else {
        (wait / 0.05 - 1e-9).ceil() * 0.05
    }
}
