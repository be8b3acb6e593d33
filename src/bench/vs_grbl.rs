//! `bench motion --vs-grbl`: laserd against Grbl's own planner on the same
//! path. Each job is planned as laserd plans it and dry-run on the `timed`
//! controller (the one laserd plans for); the same planned path is also
//! written as plain `G1 F` moves (`program::plain`) and streamed into the
//! `grbl` motion model (Grbl 1.1's look-ahead planner) with the machine's
//! velocity and acceleration limits and a junction deviation (`$11`) equal to
//! `[motion] corner_tolerance`. Both job times are simulated machine time
//! from the end of the approach to the last block, over the same link.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::figures::{sim_figures, PlannedLine};
use crate::mode::Mode;
use crate::plan::PlannerKind;
use laserd_sim::controller::MotionModel;

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct VsGrblBench {
    pub mode: String,
    /// Grbl's `$11` in the comparison: `[motion] corner_tolerance`.
    pub junction_deviation_mm: f64,
    pub jobs: Vec<VsGrblCase>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct VsGrblCase {
    pub job: String,
    pub geometries: usize,
    /// laserd's plan: planned machine time and the bound no machine with
    /// these limits beats on this sequence.
    pub trajectory_time_s: f64,
    pub lower_bound_s: f64,
    /// laserd's program on the `timed` controller.
    pub laserd_job_time_s: f64,
    pub laserd_planner_starved_s: f64,
    pub laserd_limit_breaches: usize,
    /// The same path as plain `G1 F` moves on the `grbl` motion model.
    pub grbl_job_time_s: f64,
    pub grbl_planner_starved_s: f64,
    pub grbl_program_lines: usize,
    /// Limits of the machine the Grbl run broke (a stock Grbl keeps no jerk
    /// limit and takes corners at its junction speed: expect some).
    pub grbl_limit_breaches: usize,
    /// Each of those limits and how far the Grbl run exceeded it ("jerk of
    /// X: 4.68 times its limit of 250000 mm/s³").
    pub grbl_limits_broken: Vec<String>,
    /// laserd's job time over Grbl's (below 1: laserd is faster).
    pub ratio: f64,
    /// laserd's job time over `lower_bound_s`.
    pub laserd_vs_bound: f64,
}

/// The machine Grbl runs the plain program on: the stage alone (X Y) with
/// the configured velocity and acceleration limits as `$110`/`$120`, its
/// junction deviation the corner tolerance laserd blends corners within.
pub fn grbl_machine(machine: &MachineConfig) -> MachineConfig {
    let mut grbl = machine.clone();
    grbl.scanner = None;
    grbl.simulator.motion = MotionModel::Grbl;
    grbl.simulator.junction_deviation = machine.motion.corner_tolerance;
    // Settings stored in the simulated EEPROM would override the comparison's.
    grbl.simulator.settings.retain(|(n, _)| !matches!(n, 11 | 110..=112 | 120..=122));
    grbl
}

/// Both runs of each job in `jobs` (planned with `auto` in `mode`, default
/// the machine's).
pub fn vs_grbl(machine: &MachineConfig, jobs: &[std::path::PathBuf], mode: Option<Mode>) -> Result<VsGrblBench> {
    if jobs.is_empty() {
        return Err(Error::Config("bench motion --vs-grbl: give at least one job".into()));
    }
    let mode = mode.unwrap_or_else(|| Mode::default_for(machine));
    let mut timed = machine.clone();
    timed.simulator.motion = MotionModel::Timed;
    let grbl = grbl_machine(machine);
    let mut cases = Vec::new();
    for path in jobs {
        let planned = crate::run::plan(path, &timed, PlannerKind::Auto, Some(mode))?;
        let (laserd, outcome) = crate::run::measure(&planned, &timed)?;
        if let Some(why) = outcome.stop_reason {
            return Err(Error::Stream(format!("{}: laserd's program stopped in the simulator: {why}", path.display())));
        }
        let plain = crate::program::plain::plain_program(&planned.job, &planned.sequence, machine)?;
        let (outcome, log) = crate::run::gcode::simulate(&plain, PlannedLine::from_program(&plain), &grbl, None)?;
        if let Some(why) = outcome.stop_reason {
            return Err(Error::Stream(format!("{}: the plain G1 program stopped in the simulator: {why}", path.display())));
        }
        let on_grbl = sim_figures(&log);
        cases.push(VsGrblCase {
            job: path.display().to_string(),
            geometries: planned.job.geometries.len(),
            trajectory_time_s: planned.report.trajectory_time_s,
            lower_bound_s: planned.report.lower_bound_s,
            laserd_job_time_s: laserd.job_time_s,
            laserd_planner_starved_s: laserd.planner_starved_s,
            laserd_limit_breaches: laserd.limit_breaches.len(),
            grbl_job_time_s: on_grbl.job_time_s,
            grbl_planner_starved_s: on_grbl.planner_starved_s,
            grbl_program_lines: plain.lines.len(),
            grbl_limit_breaches: on_grbl.limit_breaches.len(),
            grbl_limits_broken: on_grbl.limit_breaches.clone(),
            ratio: laserd.job_time_s / on_grbl.job_time_s.max(1e-9),
            laserd_vs_bound: laserd.job_time_s / planned.report.lower_bound_s.max(1e-9),
        });
    }
    Ok(VsGrblBench { mode: mode.as_str().to_string(), junction_deviation_mm: grbl.simulator.junction_deviation, jobs: cases })
}
