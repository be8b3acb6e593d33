//! Plan: decides the order in which geometries are marked, where each one is
//! entered, and (on machines with a scanner, in step-and-scan) which scan field
//! each belongs to. Input: `Job`; output: `Sequence`.

pub mod auto;
pub mod cutting;
pub mod ecp;
pub mod fields;
pub mod galvo;
pub mod nearest;
pub mod split;
pub mod stop;

use std::str::FromStr;

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::job::{Job, Point};
use crate::mode::Mode;

/// One geometry as it will be marked: its vertices in marking order. A closed
/// geometry starts at its entry vertex and repeats it at the end.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPath {
    pub geometry: usize,
    pub points: Vec<Point>,
    /// Index into `Job::processes`.
    pub process: usize,
    /// Whether its layer's pierce (if any) is made at its start: not where
    /// a cut through ended just before, nor on the plate's edge.
    pub pierce: bool,
}

impl PlannedPath {
    pub fn start(&self) -> Point {
        self.points[0]
    }
    pub fn end(&self) -> Point {
        self.points[self.points.len() - 1]
    }
}

/// Paths marked from one stage position (a scan field), or, on a machine without a
/// scanner, all paths with `field_center == None`.
#[derive(Debug, Clone, PartialEq)]
pub struct PathGroup {
    pub field_center: Option<Point>,
    pub paths: Vec<PlannedPath>,
}

/// The planner's output: groups in order, paths in order inside each group.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    pub groups: Vec<PathGroup>,
}

impl Sequence {
    pub fn paths(&self) -> impl Iterator<Item = &PlannedPath> {
        self.groups.iter().flat_map(|g| g.paths.iter())
    }

    /// Scan fields visited, or `None` on a stage-only plan.
    pub fn scan_fields(&self) -> Option<usize> {
        if self.groups.iter().any(|g| g.field_center.is_some()) {
            Some(self.groups.len())
        } else {
            None
        }
    }

    /// Direction reversals of the stage's path from field to field: turns of
    /// more than 90° between consecutive field-to-field moves (the stage
    /// travelling back the way it came). `None` on a stage-only plan.
    pub fn stage_reversals(&self) -> Option<usize> {
        let centres: Vec<Point> = self.groups.iter().filter_map(|g| g.field_center).collect();
        if centres.is_empty() {
            return None;
        }
        let moves: Vec<_> = centres.windows(2).map(|w| w[1] - w[0]).filter(|v| v.norm() > 1e-9).collect();
        Some(moves.windows(2).filter(|m| m[0].dot(&m[1]) < 0.0).count())
    }

    /// Laser-off travel of the TCP between consecutive paths, from the first
    /// path's start to the last path's end (the seeds' idle stroke).
    pub fn idle_stroke(&self) -> f64 {
        let mut total = 0.0;
        let mut last: Option<Point> = None;
        for p in self.paths() {
            if let Some(l) = last {
                total += (p.start() - l).norm();
            }
            last = Some(p.end());
        }
        total
    }
}

/// Everything a planner needs besides the job.
pub struct PlanContext<'a> {
    pub machine: &'a MachineConfig,
    pub mode: Mode,
    /// Where the tool centre point is before the first path.
    pub start: Point,
    /// The plate the job is laid out on (`topology::plate`), if any.
    pub plate: Option<&'a crate::topology::plate::PlateLayout>,
}

pub trait Planner {
    fn name(&self) -> &'static str;
    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence>;
}

/// The planners of the command line's `--planner`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlannerKind {
    Auto,
    Nearest,
    /// The cutting planner: End-point Cutting Problem with precedence.
    Ecp,
    /// The galvo planner of seed 003, hierarchical.
    Hha,
    /// The galvo planner of seed 003, genetic (from the HHA's route).
    Hga,
}

impl FromStr for PlannerKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(PlannerKind::Auto),
            "nearest" => Ok(PlannerKind::Nearest),
            "ecp" => Ok(PlannerKind::Ecp),
            "hha" => Ok(PlannerKind::Hha),
            "hga" => Ok(PlannerKind::Hga),
            _ => Err(format!("unknown planner '{s}' (available: auto, nearest, ecp, hha, hga)")),
        }
    }
}

/// The planner `kind` stands for (`auto`: see [`auto`]).
pub fn planner(kind: PlannerKind) -> Box<dyn Planner> {
    match kind {
        PlannerKind::Auto => Box::new(auto::Auto),
        PlannerKind::Nearest => Box::new(nearest::NearestNeighbour),
        PlannerKind::Ecp => Box::new(cutting::Ecp),
        PlannerKind::Hha => Box::new(galvo::Hha),
        PlannerKind::Hga => Box::new(galvo::Hga),
    }
}

/// A planned job: the sequence, the planner(s) that made it, and the
/// precedence rules it breaks (cuts after their part has fallen out;
/// `None`: unknown, the job's topology could not be built).
pub struct PlanOutcome {
    pub sequence: Sequence,
    pub planner: String,
    pub broken_rules: Option<Vec<ecp::checker::Violation>>,
    /// Whether the searches ran their budgets or a time limit ended one.
    pub search_stopped_by: stop::SearchStop,
    /// The length of the parts' outlines on the plate's edge, not cut (the
    /// cutting planner's; 0 without a plate).
    pub edge_length_saved_mm: f64,
}

/// Plans `job` with the planner `kind` stands for, and judges its order: the
/// cutting planner's route by the independent checker, any other planner's
/// by whole geometries.
pub fn plan_job(kind: PlannerKind, job: &Job, ctx: &PlanContext) -> Result<PlanOutcome> {
    match kind {
        PlannerKind::Auto => auto::plan(job, ctx),
        PlannerKind::Ecp => Ok(cutting::plan_cutting(job, ctx)?.outcome()),
        _ => {
            let planner = planner(kind);
            let (sequence, search_stopped_by) = match kind {
                PlannerKind::Hha | PlannerKind::Hga => galvo::plan_galvo(job, ctx, kind == PlannerKind::Hga)?,
                _ => (planner.plan(job, ctx)?, stop::SearchStop::Budget),
            };
            let broken_rules = cutting::sequence_violations(job, &sequence, ctx);
            Ok(PlanOutcome { sequence, planner: planner.name().into(), broken_rules, search_stopped_by, edge_length_saved_mm: 0.0 })
        }
    }
}

/// Checks that every geometry can be reached: inside the stage travel (stage-only),
/// or inside travel plus the scanner's reach.
pub fn check_reach(job: &Job, machine: &MachineConfig, mode: Mode) -> Result<()> {
    let reach = match mode {
        Mode::StageOnly => 0.0,
        _ => machine.scanner.as_ref().map(|s| s.usable_half_field).unwrap_or(0.0),
    };
    let (tx, ty) = (machine.stage.travel_x, machine.stage.travel_y);
    for g in &job.geometries {
        let (lo, hi) = g.bounds();
        if lo.x < -reach - 1e-9 || lo.y < -reach - 1e-9 || hi.x > tx + reach + 1e-9 || hi.y > ty + reach + 1e-9 {
            return Err(Error::Plan(format!(
                "{}: spans ({:.3}, {:.3})–({:.3}, {:.3}) mm, outside the machine's reach (stage travel {tx} x {ty} mm)",
                g.source, lo.x, lo.y, hi.x, hi.y
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_reversals_count_turns_back() {
        let group = |x: f64, y: f64| PathGroup { field_center: Some(Point::new(x, y)), paths: Vec::new() };
        // Right, right, up (90°: not back), left and down (back), right (back).
        let seq = Sequence { groups: vec![group(0.0, 0.0), group(1.0, 0.0), group(2.0, 0.0), group(2.0, 1.0), group(0.5, 0.5), group(3.0, 1.0)] };
        assert_eq!(seq.stage_reversals(), Some(2));
        let stage_only = Sequence { groups: vec![PathGroup { field_center: None, paths: Vec::new() }] };
        assert_eq!(stage_only.stage_reversals(), None);
    }
}
