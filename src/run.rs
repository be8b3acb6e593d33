//! The pipeline put together: `plan` (import → plan → motion → program) and
//! `dry_run` (plan, then stream into the in-process simulator in virtual time,
//! recording everything, and measure the run).

pub mod gcode;

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::time::Instant as WallInstant;

use laserd_sim::controller::{AxisConfig, Controller, Faults, SimConfig};
use tokio::sync::watch;

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::figures::{sim_figures, PlannedLine, RunLog, RunSetup, SimFigures};
use crate::import::import_job;
use crate::job::{Job, Point};
use crate::mode::Mode;
use crate::motion::{self, Trajectory};
use crate::plan::split::{check_fits, split_at_field_borders};
use crate::plan::cutting::{cuts_through, describe, topology_options};
use crate::topology::kerf;
use crate::topology::plate::{lay_out, PlateLayout};
use crate::plan::{plan_job, PlanContext, PlanOutcome, PlannerKind, Sequence};
use crate::program::{self, Program};
use crate::record::{Recorder, Recording, TOPIC_JOB, TOPIC_PLAN_LINES, TOPIC_PLATE_HEAT, TOPIC_REPORT, TOPIC_SETUP};
use crate::report::PlanReport;
use crate::stream::{self, SenderOptions, StreamOutcome};

/// Where the tool is before a job: the machine origin (after homing), scanner
/// centred. The sender checks the machine is there before streaming.
pub fn job_start() -> Point {
    Point::origin()
}

/// Where a long `plan` or `dry_run` is, for the command line to show on a
/// terminal (the library prints nothing): each stage as it starts, and the
/// share of it done where that is known.
pub trait Progress {
    /// A stage starts: import, plate layout, planning, motion, program, simulation.
    fn stage(&self, name: &str);
    /// Of the stage under way, this share (0 to 1) is done.
    fn done(&self, _share: f64) {}
}

/// No progress shown.
pub struct Quiet;

impl Progress for Quiet {
    fn stage(&self, _: &str) {}
}

pub struct Planned {
    pub job: Job,
    pub sequence: Sequence,
    pub trajectory: Trajectory,
    pub program: Program,
    pub report: PlanReport,
    /// The precedence rules the order breaks, in words (`None`: unknown,
    /// the job's topology could not be built).
    pub broken_rules: Option<Vec<String>>,
    /// The job as drawn, where kerf offsets made `job` differ from it.
    pub drawn: Option<Job>,
    /// `--thermal`: the plate's grid and its temperatures at the hottest
    /// moment (the heat map).
    pub heat: Option<(crate::thermal::Grid, crate::thermal::Snapshot)>,
    /// ... and over the job, for the recording.
    pub plates: Vec<crate::thermal::Snapshot>,
}

pub fn plan(job_path: &Path, machine: &MachineConfig, kind: PlannerKind, mode: Option<Mode>) -> Result<Planned> {
    plan_showing(job_path, machine, kind, mode, &Quiet)
}

/// `plan`, telling `progress` of its stages.
pub fn plan_showing(job_path: &Path, machine: &MachineConfig, kind: PlannerKind, mode: Option<Mode>, progress: &dyn Progress) -> Result<Planned> {
    let mode = mode.unwrap_or_else(|| Mode::default_for(machine));
    mode.check(machine)?;
    progress.stage("import");
    let job = import_job(job_path, machine)?;
    let fills = job.processes.iter().any(|p| p.fill);
    let (mut job, hatched) = crate::plan::area::hatch::hatch(job, machine)?;
    if kind == PlannerKind::Raster && mode == Mode::StageOnly {
        job = crate::plan::area::raster_lines(job, machine);
    }
    let kerfed = kerf::compensate(&job, &kerf_layers(&job, machine), machine.import.tolerance)?;
    let (drawn, kerf_mm) = ((kerfed.offset > 0).then_some(job), (kerfed.offset > 0).then_some(kerfed.kerf_mm));
    let job = kerfed.job;
    // In step-and-scan a geometry larger than the scanner's usable field is
    // split at field borders into pieces, which are then the job's geometries
    // from planning to the report; with splitting off, the job fails naming it.
    // On the fly the planner leaves a margin at the field's edge for marks
    // that begin and end at speed (see `Mode::planning_half_field`).
    let planning_machine = mode.planning_machine(machine);
    let job = match planning_machine.scanner.as_ref().filter(|_| mode != Mode::StageOnly) {
        Some(s) if s.split_oversize => split_at_field_borders(&job, s.usable_half_field),
        Some(s) => {
            check_fits(&job, s.usable_half_field)?;
            job
        }
        None => job,
    };
    let started = WallInstant::now();
    // The plate a job file names, else the config's (laying it out is planning).
    let (job, plate) = match crate::import::json::plate_of(job_path, machine)?.or_else(|| machine.plate.clone()) {
        Some(plate) => {
            // Only the cutting planner knows the plate's rules (what its
            // regions hold, its edge): the others would cut skeleton pieces
            // away under parts, unseen by their precedence count.
            if !matches!(kind, PlannerKind::Auto | PlannerKind::Raster | PlannerKind::Ecp) && cuts_through(&job, machine).contains(&true) {
                return Err(Error::Plan(format!(
                    "{}: on a [plate], parts are planned by the cutting planner (--planner auto or ecp), which keeps the plate's rules; remove [plate] to plan with another",
                    job_path.display()
                )));
            }
            progress.stage("plate layout");
            let (job, layout) = lay_out_plate(job, machine, &plate)?;
            (job, Some(layout))
        }
        None => (job, None),
    };
    // Under a machine-time objective other routes are planned too, each
    // judged by its motion (the first of equal values kept): a time limit
    // is shared among them.
    let judge = RouteObjective::of(kind, &job, &planning_machine)?;
    let variants = judge.variants(&planning_machine);
    let shares = 1 + variants.len();
    let planning_machine = share_time_limits(planning_machine, shares);
    let ctx = PlanContext { machine: &planning_machine, mode, start: job_start(), plate: plate.as_ref() };
    // Cutting layers' topology is built in planning.
    let planning = if cuts_through(&job, machine).contains(&true) { "topology and planning" } else { "planning" };
    let route = |k: usize| if shares > 1 { format!("{planning} (route {k} of {shares})") } else { planning.to_string() };
    let base = plan_with_motion(kind, &job, &ctx, machine, &Named { progress, planning: route(1) })?;
    let mut plan_time_s = started.elapsed().as_secs_f64() - base.motion_time_s;
    let mut best = (judge.value(&base), base);
    for (k, variant) in variants.into_iter().map(|v| share_time_limits(v, shares)).enumerate() {
        let started = WallInstant::now();
        match plan_with_motion(kind, &job, &PlanContext { machine: &variant, ..ctx }, machine, &Named { progress, planning: route(k + 2) }) {
            Ok(c) if c.broken() <= best.1.broken() => {
                let value = judge.value(&c);
                if value < best.0 {
                    best = (value, c);
                }
            }
            Ok(_) => {}
            Err(e) => tracing::debug!("no plan for a route variant: {e}"),
        }
        plan_time_s += started.elapsed().as_secs_f64();
    }
    let Candidate { outcome, trajectory, program, link_slowdown, motion_time_s } = best.1;
    let objective = RouteObjective::describe(&outcome.planner, &planning_machine);
    let outcome_edge_saved = outcome.edge_length_saved_mm;
    let outcome_leads = outcome.leads;
    let outcome_tabs = outcome.tabs;
    let outcome_bridges = outcome.bridges;
    let tipping_pieces = machine.support_grid().map(|_| outcome.may_tip);
    let precuts = outcome.precuts;
    let thermal = outcome.thermal.as_ref().map(|t| crate::report::ThermalReport::of(t, &planning_machine));
    let heat = outcome.thermal.as_ref().and_then(|t| t.hottest_plate.clone().map(|s| (t.planned.grid, s)));
    let plates = outcome.thermal.as_ref().map(|t| t.plates.clone()).unwrap_or_default();
    let sequence = outcome.sequence;
    let cut_paths = || sequence.paths().filter(|p| machine.pierce(&job.processes[p.process].layer).active());
    let broken_rules: Option<Vec<String>> = outcome.broken_rules.map(|rules| rules.iter().map(|r| describe(&job, r)).collect());
    let lower_bound_s = motion::lower_bound(&job, &sequence, machine, mode)?;
    let program_bytes: usize = program.lines.iter().map(|l| l.text.len() + 1).sum();
    let blocks = program.lines.iter().filter(|l| l.plan_time.is_some() && l.kind != program::LineKind::Approach).count();
    let mean_line = program_bytes as f64 / program.lines.len().max(1) as f64;
    let lines_per_s = |baud: f64| baud / 10.0 / mean_line;
    let report = PlanReport {
        job: job_path.display().to_string(),
        planner: outcome.planner,
        mode: mode.as_str().to_string(),
        geometries: job.geometries.len(),
        scan_fields: sequence.scan_fields(),
        stage_reversals: sequence.stage_reversals(),
        stage_flow: trajectory.stage_flow,
        mark_length_mm: job.mark_length(),
        idle_stroke_mm: sequence.idle_stroke(),
        plan_time_s,
        objective,
        search_stopped_by: outcome.search_stopped_by,
        precedence_violations: broken_rules.as_ref().map(|r| r.len() as u64),
        pierces: cut_paths().filter(|p| p.pierce).count(),
        kerf_mm,
        lead_ins: outcome_leads.lead_ins,
        lead_outs: outcome_leads.lead_outs,
        lead_ins_moved: outcome_leads.moved,
        leads_skipped: outcome_leads.skipped,
        tabs: outcome_tabs,
        bridges: outcome_bridges.bridges,
        pierces_saved: outcome_bridges.pierces_saved,
        precuts: precuts.precuts,
        precut_sharp_angles: precuts.macros,
        tipping_pieces,
        lifts: tipping_pieces.and(trajectory.head.as_ref()).map(|h| h.lifts()),
        fill_areas: fills.then_some(hatched.areas),
        hatch_lines: fills.then_some(hatched.lines),
        thin_fill_areas: fills.then_some(hatched.thin_areas),
        cut_length_mm: cut_paths().map(|p| p.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum::<f64>()).sum(),
        edge_length_saved_mm: plate.as_ref().map(|_| outcome_edge_saved),
        edge_starts: plate.as_ref().map(|p| cut_paths().filter(|c| !c.pierce && p.on_edge(c.start())).count()),
        skeleton_cuts: plate.as_ref().map(|p| p.skeleton_cuts),
        remnant_cuts: plate.as_ref().map(|p| p.remnant_cuts),
        trajectory_time_s: trajectory.job_time(),
        lower_bound_s,
        program_lines: program.lines.len(),
        program_bytes,
        blocks_per_s: blocks as f64 / trajectory.job_time().max(1e-9),
        link_lines_per_s: lines_per_s(f64::from(machine.serial.baud)),
        link_115200_lines_per_s: lines_per_s(115_200.0),
        link_slowdown,
        motion_time_s,
        sim: None,
        recording: None,
        thermal,
        config: None,
    };
    Ok(Planned { job, sequence, trajectory, program, report, broken_rules, drawn, heat, plates })
}

/// Per process of `job`: its layer's kerf, and whether its contours cut parts out.
pub fn kerf_layers(job: &Job, machine: &MachineConfig) -> Vec<kerf::KerfLayer> {
    job.processes
        .iter()
        .map(|p| {
            let layer = machine.layer(&p.layer);
            kerf::KerfLayer {
                kerf: layer.map_or(0.0, |l| l.kerf),
                corners: layer.map(|l| l.kerf_corners).unwrap_or_default(),
                cuts: machine.cuts_parts(&p.layer),
            }
        })
        .collect()
}

/// The job laid out on `plate` (`topology::plate`): with
/// its skeleton and remnant cuts, on the plate's layer (added to the job's
/// processes if no geometry uses it yet).
fn lay_out_plate(mut job: Job, machine: &MachineConfig, plate: &crate::config::PlateConfig) -> Result<(Job, PlateLayout)> {
    let layer = machine.plate_layer(plate).ok_or_else(|| Error::Plan("[plate]: no layer pierces, so nothing cuts the plate".into()))?;
    let process = match job.processes.iter().position(|p| p.layer == layer) {
        Some(k) => k,
        None => {
            let l = machine.layer(layer).ok_or_else(|| Error::Plan(format!("[plate] layer '{layer}' is no [[layer]]")))?;
            job.processes.push(crate::job::Process { layer: l.name.clone(), speed: l.speed, power: l.power, passes: l.passes, fill: false });
            job.processes.len() - 1
        }
    };
    let cuts = cuts_through(&job, machine);
    lay_out(&job, &cuts, plate, process, &topology_options(&machine.cutting))
}

/// A plan with its motion and program.
struct Candidate {
    outcome: PlanOutcome,
    trajectory: Trajectory,
    program: Program,
    link_slowdown: f64,
    motion_time_s: f64,
}

impl Candidate {
    fn broken(&self) -> usize {
        self.outcome.broken_rules.as_ref().map_or(0, Vec::len)
    }
}

/// Progress with the name the planning stage goes by.
struct Named<'a> {
    progress: &'a dyn Progress,
    planning: String,
}

/// `job` planned by `kind` (again in tighter fields where the stage falls
/// behind on the fly), its motion and program; `motion_time_s` is the
/// computing time of the motion kept.
fn plan_with_motion(kind: PlannerKind, job: &Job, ctx: &PlanContext, machine: &MachineConfig, named: &Named) -> Result<Candidate> {
    let progress = named.progress;
    progress.stage(&named.planning);
    let mut outcome = plan_job(kind, job, ctx)?;
    let started = WallInstant::now();
    let (mut trajectory, mut program, mut link_slowdown) = motion_for_link(job, &outcome.sequence, machine, ctx.mode, progress)?;
    let mut motion_time_s = started.elapsed().as_secs_f64();
    if ctx.mode == Mode::OnTheFly && trajectory.stage_flow.is_some_and(|flow| flow < 1.0) {
        progress.stage(&format!("{} in tighter fields", named.planning));
    }
    if let Some(tighter) = tighter_fields(kind, job, ctx, machine, &outcome, &trajectory)? {
        let started = WallInstant::now();
        let planned = motion_for_link(job, &tighter.sequence, machine, ctx.mode, progress)?;
        if planned.0.job_time() < trajectory.job_time() {
            (trajectory, program, link_slowdown) = planned;
            outcome = tighter;
            motion_time_s = started.elapsed().as_secs_f64();
        }
    }
    Ok(Candidate { outcome, trajectory, program, link_slowdown, motion_time_s })
}

/// `machine` with its cutting and galvo time limits split into `shares`.
fn share_time_limits(mut machine: MachineConfig, shares: usize) -> MachineConfig {
    if shares > 1 {
        for limit in [&mut machine.cutting.time_limit, &mut machine.galvo.time_limit].into_iter().flatten() {
            *limit /= shares as f64;
        }
    }
    machine
}

/// Routes from this many galvo seeds are judged under a machine-time
/// objective (the configured seed and the next ones): the galvo searches
/// shorten the idle stroke, and on the fly the stage's flow decides the
/// time (SC82C24, seeds 1-5: 2.67 to 2.99 s for idle strokes within 3 %).
const GALVO_STARTS: u64 = 4;

/// The objective a plan's routes are judged by, where one of its searches
/// weighs machine time (`[galvo]`/`[cutting] objective`, the galvo route's
/// first): its weights of length (idle stroke, mm) and job time (s), and
/// which searches weigh time.
struct RouteObjective {
    length: f64,
    time: f64,
    galvo_time: bool,
    cutting_time: bool,
}

impl RouteObjective {
    /// For `job` planned by `kind`: the galvo planner orders marks for
    /// `hha`, `hga`, and `auto` with marking layers; the cutting planner
    /// cuts for `ecp`, and `auto` with layers that pierce.
    fn of(kind: PlannerKind, job: &Job, machine: &MachineConfig) -> Result<RouteObjective> {
        let cuts = cuts_through(job, machine);
        let marks = job.geometries.iter().zip(&cuts).any(|(g, &cut)| !cut && !job.processes[g.process].fill);
        let (galvo, cutting) = match kind {
            PlannerKind::Hha | PlannerKind::Hga => (true, false),
            PlannerKind::Ecp => (false, true),
            PlannerKind::Auto | PlannerKind::Raster => (marks, cuts.contains(&true)),
            PlannerKind::Nearest => (false, false),
        };
        let weights = |name: &str, spec: &str| crate::config::route_objective_weights(spec).map_err(|e| Error::Config(format!("{name}.objective: {e}")));
        let galvo = if galvo { weights("galvo", &machine.galvo.objective)? } else { (1.0, 0.0) };
        let cutting = if cutting { weights("cutting", &machine.cutting.objective)? } else { (1.0, 0.0) };
        let (length, time) = if galvo.1 > 0.0 || cutting.1 == 0.0 { galvo } else { cutting };
        Ok(RouteObjective { length, time, galvo_time: galvo.1 > 0.0, cutting_time: cutting.1 > 0.0 })
    }

    fn value(&self, c: &Candidate) -> f64 {
        self.length * c.outcome.sequence.idle_stroke() + self.time * c.trajectory.job_time()
    }

    /// The machines whose plans are judged besides the configured one: the
    /// galvo route from the next seeds, the cutting route under `length`
    /// (so that `time` is never slower than it); none unless time is weighed.
    fn variants(&self, machine: &MachineConfig) -> Vec<MachineConfig> {
        let mut variants = Vec::new();
        if self.galvo_time {
            for k in 1..GALVO_STARTS {
                let mut m = machine.clone();
                m.galvo.seed = machine.galvo.seed.wrapping_add(k);
                variants.push(m);
            }
        }
        if self.cutting_time {
            let mut m = machine.clone();
            m.cutting.objective = "length".into();
            variants.push(m);
        }
        variants
    }

    /// The objective of each planner of `planner` (`fill+hha+ecp`), once
    /// where they agree.
    fn describe(planner: &str, machine: &MachineConfig) -> String {
        let each: Vec<(&str, &str)> = planner
            .split('+')
            .filter_map(|p| match p {
                "fill" => Some((p, machine.fill.objective.as_str())),
                "hha" | "hga" => Some((p, machine.galvo.objective.as_str())),
                "ecp" => Some((p, machine.cutting.objective.as_str())),
                "nearest" => Some((p, "length")),
                _ => None,
            })
            .collect();
        match each.as_slice() {
            [] => "none".into(),
            [(_, one), rest @ ..] if rest.iter().all(|(_, o)| o == one) => one.to_string(),
            _ => each.iter().map(|(p, o)| format!("{p}: {o}")).collect::<Vec<_>>().join(", "),
        }
    }
}

/// Shares of the scan field the marks are grouped in when the stage falls
/// behind on the fly (see `tighter_fields`).
const TIGHTER_FIELDS: [f64; 3] = [0.9, 0.8, 0.65];
/// The share of the job time tighter fields must save to be kept: more
/// fields make more field changes for the flow to plan (SC1017C16: 0.4 %
/// faster for ~20-50 % more computing per build).
const TIGHTER_FIELDS_GAIN: f64 = 0.01;

/// On the fly, where the stage cannot flow through every field change
/// (`stage_flow` < 1): the job planned again with its marks grouped in
/// squares smaller than the scan field, each built; the fastest of those if
/// it saves `TIGHTER_FIELDS_GAIN` of `trajectory`'s time. Marks that fill a
/// field pin the stage while they are marked (a jump across the field
/// leaves it a narrow corridor), so it crosses to the next field in the
/// TCP's short jump; in smaller groups it keeps room to move while marking.
/// The time responds unevenly to the share (SC82C24 at 0.9 / 0.85 / 0.8 /
/// 0.65 of the field: 1.18 / 3.29 / 1.10 / 1.11 × the bound, 1.19 at the
/// full field), hence several, each built.
/// A plan that fails at a share (a mark larger than the smaller square) is
/// no candidate; one breaking more precedence rules neither.
fn tighter_fields(kind: PlannerKind, job: &Job, ctx: &PlanContext, machine: &MachineConfig, outcome: &PlanOutcome, trajectory: &Trajectory) -> Result<Option<PlanOutcome>> {
    let Some(half) = ctx.machine.scanner.as_ref().map(|s| s.usable_half_field) else { return Ok(None) };
    if ctx.mode != Mode::OnTheFly || trajectory.stage_flow.is_none_or(|flow| flow >= 1.0) {
        return Ok(None);
    }
    let broken = |o: &PlanOutcome| o.broken_rules.as_ref().map_or(0, Vec::len);
    let threads = crate::parallel::threads()?;
    let candidates = crate::parallel::tasks(TIGHTER_FIELDS.len(), threads, |k| {
        let mut tighter = ctx.machine.clone();
        tighter.scanner.as_mut()?.usable_half_field = half * TIGHTER_FIELDS[k];
        let planned = plan_job(kind, job, &PlanContext { machine: &tighter, ..*ctx })
            .and_then(|o| Ok((motion::build(job, &o.sequence, machine, ctx.mode, job_start())?.job_time(), o)));
        match planned {
            Ok((time, o)) if broken(&o) <= broken(outcome) => Some((time, o)),
            Ok(_) => None,
            Err(e) => {
                tracing::debug!(share = TIGHTER_FIELDS[k], "no plan in tighter fields: {e}");
                None
            }
        }
    });
    // The first of equal times: the plan does not depend on the threads.
    let best = candidates.into_iter().flatten().reduce(|a, b| if b.0 < a.0 { b } else { a });
    Ok(best.filter(|(time, _)| *time < (1.0 - TIGHTER_FIELDS_GAIN) * trajectory.job_time()).map(|(_, o)| o))
}

impl Planned {
    /// Refuses a plan that breaks precedence rules (a cut after its part has
    /// fallen out), unless `allowed`: the error names how many and the first
    /// few, and how to run it anyway (`override_with`: the flag or field).
    pub fn check_precedence(&self, allowed: bool, override_with: &str) -> Result<()> {
        let rules = self.broken_rules.as_deref().unwrap_or_default();
        if allowed || rules.is_empty() {
            return Ok(());
        }
        const SHOWN: usize = 3;
        let more = if rules.len() > SHOWN { format!(", and {} more", rules.len() - SHOWN) } else { String::new() };
        Err(Error::Plan(format!(
            "{}: the plan ({}) has {} precedence violation(s), cuts after their part has fallen out: {}{more}; plan with --planner auto or ecp, or override with {override_with}",
            self.report.job,
            self.report.planner,
            rules.len(),
            rules[..rules.len().min(SHOWN)].join("; "),
        )))
    }
}

/// The trajectory and program of `sequence`, planned so that the controller
/// link carries the program without the controller running dry
/// (`program::link`), and how much longer the job takes for it (1: not at
/// all). Where the link cannot keep up at full speed, the marks denser than
/// the link are slowed, each alone; where that is not enough, the whole
/// motion is planned again on the machine uniformly slowed, with the marks'
/// speeds. In M3 (constant power) slowed marks get as much less power, so
/// that each millimetre gets the energy it was meant to (M4 scales it by
/// itself).
fn motion_for_link(job: &Job, sequence: &Sequence, machine: &MachineConfig, mode: Mode, progress: &dyn Progress) -> Result<(Trajectory, Program, f64)> {
    progress.stage("motion");
    let trajectory = motion::build(job, sequence, machine, mode, job_start())?;
    progress.stage("program");
    let program = program::generate(job, &trajectory, machine)?;
    let link = program::link::LinkModel::of(machine);
    let needed = link.slowdown(&program, || program::link::rests(&program, &trajectory))?;
    if needed <= 1.0 {
        return Ok((trajectory, program, 1.0));
    }
    // Arcs carry curves in few lines, but the controller splits each into
    // many short planner blocks: a fast arc empties the planner faster than
    // the link refills it. Straight lines alone may keep up at full speed.
    if machine.program.arcs {
        let mut straight = machine.clone();
        straight.program.arcs = false;
        let program = program::generate(job, &trajectory, &straight)?;
        if link.slowdown(&program, || program::link::rests(&program, &trajectory))? <= 1.0 {
            return Ok((trajectory, program, 1.0));
        }
    }
    // How much longer the job takes than at full speed.
    let full_time = trajectory.job_time().max(1e-9);
    // First the marks denser than the link, each alone.
    let factors = link.geometry_slowdowns(&program, job.geometries.len());
    // A layer may ask for more than the machine marks at: slowed from what it gets.
    let cap = match (mode, &machine.scanner) {
        (Mode::StageOnly, _) | (_, None) => machine.stage.max_velocity,
        (_, Some(s)) => s.mark_speed,
    };
    let (job, sequence) = marks_slowed(job, sequence, &factors, cap, machine.laser.mode);
    progress.stage("motion (marks slowed for the link)");
    let trajectory = motion::build(&job, &sequence, machine, mode, job_start())?;
    let program = program::generate(&job, &trajectory, machine)?;
    let mut needed = link.slowdown(&program, || program::link::rests(&program, &trajectory))?;
    if needed <= 1.0 {
        let slowdown = trajectory.job_time() / full_time;
        return Ok((trajectory, program, slowdown));
    }
    // Then the whole job, uniformly.
    let mut k = 1.0;
    // The program planned slower differs a little in its lines: a small
    // margin, and a check of the program that will run.
    for _ in 0..4 {
        k *= needed * 1.02;
        progress.stage(&format!("motion ({k:.2} times slower for the link)"));
        let slow_machine = machine.slowed(k);
        let mut slow_job = job.clone();
        for p in &mut slow_job.processes {
            p.speed /= k;
            if machine.laser.mode == crate::config::LaserMode::M3 {
                p.power /= k;
            }
        }
        let trajectory = motion::build(&slow_job, &sequence, &slow_machine, mode, job_start())?;
        let program = program::generate(&slow_job, &trajectory, &slow_machine)?;
        needed = link.slowdown(&program, || program::link::rests(&program, &trajectory))?;
        if needed <= 1.0 {
            let slowdown = trajectory.job_time() / full_time;
            return Ok((trajectory, program, slowdown));
        }
    }
    Err(Error::Program(format!("the link cannot carry the program even {k:.2} times slower")))
}

/// `job` and `sequence` with the marks of geometry g `factors[g]` times
/// slower than they run on a machine marking at most at `cap` (in M3 at as
/// much less power: the same energy per millimetre).
/// Factors are rounded up to steps of 5 %, each step of each process a
/// process of its own.
fn marks_slowed(job: &Job, sequence: &Sequence, factors: &[f64], cap: f64, laser: crate::config::LaserMode) -> (Job, Sequence) {
    let mut job = job.clone();
    let mut sequence = sequence.clone();
    let mut made: std::collections::HashMap<(usize, i32), usize> = std::collections::HashMap::new();
    for path in sequence.groups.iter_mut().flat_map(|g| g.paths.iter_mut()) {
        let factor = factors.get(path.geometry).copied().unwrap_or(1.0);
        if factor <= 1.0 {
            continue;
        }
        let step = (factor.ln() / 1.05_f64.ln()).ceil() as i32;
        path.process = *made.entry((path.process, step)).or_insert_with(|| {
            let k = 1.05_f64.powi(step);
            let mut p = job.processes[path.process].clone();
            p.speed = p.speed.min(cap) / k;
            if laser == crate::config::LaserMode::M3 {
                p.power /= k;
            }
            job.processes.push(p);
            job.processes.len() - 1
        });
    }
    (job, sequence)
}

/// The simulated controller of a machine config: stage axes over their travel,
/// scanner axes over the usable field, each with its limits.
pub fn sim_config(machine: &MachineConfig, faults: Faults) -> SimConfig {
    let s = &machine.stage;
    let mut axes = vec![
        AxisConfig { letter: 'X', min: 0.0, max: s.travel_x, max_velocity: s.max_velocity, max_acceleration: s.max_acceleration, max_jerk: s.max_jerk },
        AxisConfig { letter: 'Y', min: 0.0, max: s.travel_y, max_velocity: s.max_velocity, max_acceleration: s.max_acceleration, max_jerk: s.max_jerk },
    ];
    if let (Some(h), Some(z)) = (&machine.head, machine.head_limits()) {
        axes.push(AxisConfig { letter: 'Z', min: 0.0, max: h.travel_z, max_velocity: z.velocity, max_acceleration: z.acceleration, max_jerk: z.jerk });
    }
    if let Some(sc) = &machine.scanner {
        for letter in machine.axis_letters().into_iter().skip(2) {
            axes.push(AxisConfig {
                letter,
                min: -sc.usable_half_field,
                max: sc.usable_half_field,
                max_velocity: sc.jump_speed,
                max_acceleration: sc.max_acceleration,
                max_jerk: sc.max_jerk,
            });
        }
    }
    SimConfig {
        axes,
        rx_buffer: machine.serial.rx_buffer,
        planner_blocks: machine.simulator.planner_blocks,
        laser_max_s: machine.laser.max_power,
        motion: machine.simulator.motion,
        flavor: machine.simulator.flavor,
        settings: machine.simulator.settings.clone(),
        junction_deviation: machine.simulator.junction_deviation,
        faults,
    }
}

pub fn run_setup(machine: &MachineConfig, sim: &SimConfig) -> RunSetup {
    RunSetup {
        axes: sim.axes.clone(),
        baud: machine.serial.baud,
        usable_half_field: machine.scanner.as_ref().map(|s| s.usable_half_field),
        // A unit of the last decimal of the stage's and the scanner's
        // coordinates on top of the program's tolerance: their rounding.
        tcp_tolerance_mm: Some(machine.program.tolerance + 10f64.powi(-(machine.program.decimals as i32)) + 10f64.powi(-(machine.program.scanner_decimals as i32))),
        machine: Some(machine.clone()),
        real_time: false,
        small_pieces: Vec::new(),
        lift_height: machine.head.as_ref().map_or(0.0, |h| h.lift_height),
    }
}

/// The closed contours of `job` on layers that cut parts, smaller than
/// twice the support grid both ways: what may tip once cut free (for the
/// figures' own collision count; none without a support grid).
pub fn small_pieces(job: &Job, machine: &MachineConfig) -> Vec<Vec<[f64; 2]>> {
    let Some(grid) = machine.support_grid() else { return Vec::new() };
    job.geometries
        .iter()
        .filter(|g| crate::plan::tipping::small(job, g, machine, grid))
        .map(|g| g.points.iter().map(|p| [p.x, p.y]).collect())
        .collect()
}

/// Default recording path of a dry-run: `<job stem>.mcap` in the working directory.
pub fn default_recording(job_path: &Path) -> PathBuf {
    let stem = job_path.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_else(|| "job".into());
    PathBuf::from(format!("{stem}.mcap"))
}

pub struct DryRun {
    pub report: PlanReport,
    pub outcome: StreamOutcome,
    pub log: RunLog,
}

/// Streams the planned program into a fresh simulator in virtual time.
pub fn dry_run(planned: &Planned, machine: &MachineConfig, recording: &Path, faults: Faults) -> Result<DryRun> {
    dry_run_showing(planned, machine, recording, faults, &Quiet)
}

/// `dry_run`, telling `progress` how far the simulation is.
pub fn dry_run_showing(planned: &Planned, machine: &MachineConfig, recording: &Path, faults: Faults, progress: &dyn Progress) -> Result<DryRun> {
    progress.stage("simulation");
    let sim = sim_config(machine, faults);
    let setup = RunSetup { small_pieces: small_pieces(&planned.job, machine), ..run_setup(machine, &sim) };
    let rec = Recording::create(recording)?;
    let recorder = rec.recorder();
    recorder.write(TOPIC_SETUP, 0.0, &setup);
    let mut summary = planned.report.clone();
    summary.recording = Some(recording.display().to_string());
    recorder.write(TOPIC_JOB, 0.0, &summary);
    let planned_lines = PlannedLine::from_program(&planned.program);
    for p in &planned_lines {
        recorder.write(TOPIC_PLAN_LINES, 0.0, p);
    }
    if let Some((grid, _)) = &planned.heat {
        for plate in &planned.plates {
            recorder.write(TOPIC_PLATE_HEAT, plate.time, &crate::record::GridMessage::of_plate(grid, plate));
        }
    }

    let streamed = stream_showing(&planned.program, sim, machine.serial.baud, &planned_options(machine, &planned.program), Some(&recorder), progress);
    let (outcome, log, recorder, rec) = closed_on_error(streamed, recorder, rec)?;
    let log = RunLog { setup: Some(setup), planned: planned_lines, ..log };
    let mut report = summary;
    report.sim = Some(sim_figures(&log));
    recorder.write(TOPIC_REPORT, log.knots.last().map(|k| k.t).unwrap_or(0.0), &report);
    drop(recorder);
    rec.finish()?;
    Ok(DryRun { report, outcome, log })
}

/// The outcome of a recorded stream with its recorder and recording; on an
/// error, the recording closed first (readable up to there) and the error.
pub(crate) fn closed_on_error(streamed: Result<(StreamOutcome, RunLog)>, recorder: Recorder, rec: Recording) -> Result<(StreamOutcome, RunLog, Recorder, Recording)> {
    match streamed {
        Ok((outcome, log)) => Ok((outcome, log, recorder, rec)),
        Err(e) => {
            drop(recorder);
            rec.finish()?;
            Err(e)
        }
    }
}

/// How the sender streams a program of `machine` that laserd planned: it
/// checks first that the machine stands where the program starts.
fn planned_options(machine: &MachineConfig, program: &Program) -> SenderOptions {
    let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    options.hold_limit = options.hold_limit_for(machine.stop_time_s());
    options.expect_start = Some(program.start.clone());
    options
}

/// The `sim` figures of a dry-run of `planned`, without a recording.
pub fn measure(planned: &Planned, machine: &MachineConfig) -> Result<(SimFigures, StreamOutcome)> {
    let sim = sim_config(machine, Faults::default());
    let setup = run_setup(machine, &sim);
    let (outcome, log) = stream_into_simulator(&planned.program, sim, machine.serial.baud, &planned_options(machine, &planned.program), None)?;
    let log = RunLog { setup: Some(setup), planned: PlannedLine::from_program(&planned.program), ..log };
    Ok((sim_figures(&log), outcome))
}

/// Streams `program` into a fresh simulated controller in virtual time at
/// `baud`, recording link and motion when a recorder is given. Returns how the
/// stream ended and what crossed the link and moved (`setup` and `planned` of
/// the log are left for the caller).
pub fn stream_into_simulator(
    program: &Program,
    sim: SimConfig,
    baud: u32,
    options: &SenderOptions,
    recorder: Option<&Recorder>,
) -> Result<(StreamOutcome, RunLog)> {
    stream_showing(program, sim, baud, options, recorder, &Quiet)
}

/// `stream_into_simulator`, telling `progress` the share of lines sent.
fn stream_showing(program: &Program, sim: SimConfig, baud: u32, options: &SenderOptions, recorder: Option<&Recorder>, progress: &dyn Progress) -> Result<(StreamOutcome, RunLog)> {
    let log = RefCell::new(RunLog::default());
    let lines = program.lines.iter().map(|l| Ok(l.text.clone()));
    let options = &SenderOptions { step_mm: Some(sim.step_mm()), ..options.clone() };
    let describe = |n: usize, _: &str| program.describe_line(n);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(|e| Error::Io(format!("cannot start the runtime: {e}")))?;
    let outcome = runtime.block_on(async {
        let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
        let origin = tokio::time::Instant::now();
        let (stop_tx, stop_rx) = watch::channel(false);
        let controller = Controller::new(sim);
        let sim_side = stream::in_process::run(controller, sim_io, baud, origin, stop_rx, |knots| {
            if let Some(r) = recorder {
                r.knots(&knots);
            }
            log.borrow_mut().knots.extend(knots);
        });
        let sender_side = async {
            let r = stream::stream(sender_io, lines, options, &describe, |t, ev| {
                if let Some(r) = recorder {
                    r.link_event(t, &ev);
                }
                if let stream::LinkEvent::Sent { line, .. } = &ev {
                    progress.done(*line as f64 / program.lines.len().max(1) as f64);
                }
                log.borrow_mut().link.push((t, ev));
            })
            .await;
            let _ = stop_tx.send(true);
            r
        };
        let (_, outcome) = tokio::join!(sim_side, sender_side);
        outcome
    })?;
    Ok((outcome, log.into_inner()))
}

/// Re-streams the program a recording sent into a fresh simulator (with the
/// recording's axes and baud rate) and measures it again against the same
/// plan: the figures and what crossed the link and moved.
pub fn restream(log: &RunLog, machine: &MachineConfig) -> Result<(SimFigures, RunLog)> {
    let setup = log.setup.clone().ok_or_else(|| Error::Record("the recording has no machine setup".into()))?;
    let lines: Vec<program::ProgramLine> = log
        .link
        .iter()
        .filter_map(|(_, e)| match e {
            crate::stream::LinkEvent::Sent { line, text } if *line > 0 => Some(program::ProgramLine {
                text: text.clone(),
                kind: log.planned.iter().find(|p| p.line == *line).map(|p| p.kind).unwrap_or(program::LineKind::Setup),
                geometry: None,
                plan_time: None,
                checks: vec![],
            }),
            _ => None,
        })
        .collect();
    if lines.is_empty() {
        return Err(Error::Record("the recording holds no sent program lines".into()));
    }
    let program = Program { lines, axis_letters: setup.axes.iter().map(|a| a.letter).collect(), start: vec![0.0; setup.axes.len()], sources: vec![] };
    let mut sim = sim_config(machine, Faults::default());
    sim.axes = setup.axes.clone();
    let (_, again) = stream_into_simulator(&program, sim, setup.baud, &planned_options(machine, &program), None)?;
    let again = RunLog { setup: Some(setup), planned: log.planned.clone(), ..again };
    Ok((sim_figures(&again), again))
}

/// Each figure a re-simulation gives otherwise than the recording did (beyond
/// a relative 1e-9), with what explains it where that is known: lines the
/// re-stream's sender sent of its own, a real-time recording's times, another
/// machine. None: the same run again.
pub fn replay_differences(recorded: &SimFigures, recorded_log: &RunLog, again: &SimFigures, again_log: &RunLog, machine_note: Option<&str>) -> Vec<String> {
    let (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) = (serde_json::to_value(recorded), serde_json::to_value(again)) else { return vec![] };
    let own_lines = |log: &RunLog| log.link.iter().filter(|(_, e)| matches!(e, stream::LinkEvent::Sent { line: 0, .. })).count();
    let extra_lines = own_lines(again_log) as i64 - own_lines(recorded_log) as i64;
    let real_time = recorded_log.setup.as_ref().is_some_and(|s| s.real_time);
    let mut differences = Vec::new();
    for (name, value) in &a {
        let other = b.get(name).unwrap_or(&serde_json::Value::Null);
        // Times counted from another origin round differently in the last bits.
        let close = match (value.as_f64(), other.as_f64()) {
            (Some(x), Some(y)) => (x - y).abs() <= 1e-9 * x.abs().max(y.abs()) + 1e-12,
            _ => false,
        };
        if value == other || close {
            continue;
        }
        let why = match name.as_str() {
            "lines_sent" | "bytes_sent" if extra_lines != 0 && real_time => format!(
                ": the re-stream's sender sent {extra_lines} line(s) of its own (at connect) besides the recorded ones, which hold the recorded sender's own lines already"
            ),
            "lines_sent" | "bytes_sent" if extra_lines != 0 => format!(": the re-stream's sender sent {extra_lines} line(s) of its own more than the recorded one"),
            "link_utilization" if extra_lines != 0 => ": it counts the bytes sent, which differ (bytes_sent)".to_string(),
            _ if real_time => ": recorded in real time on a pseudo-terminal (with the sender's and the host's timing); the re-simulation runs in virtual time".to_string(),
            _ => machine_note.map(|m| format!(": {m}")).unwrap_or_default(),
        };
        differences.push(format!("{name}: {value} recorded, {other} re-simulated{why}"));
    }
    differences
}
