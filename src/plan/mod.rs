//! Plan: decides the order in which geometries are marked, where each one is
//! entered, and (on machines with a scanner, in step-and-scan) which scan field
//! each belongs to. Input: `Job`; output: `Sequence`.

pub mod area;
pub mod auto;
pub mod bridges;
pub mod cutting;
pub mod ecp;
pub mod fields;
pub mod galvo;
pub mod lead;
pub mod nearest;
pub mod objective;
pub mod precut;
pub mod split;
pub mod stop;
pub mod tabs;
pub mod thermal;
pub mod tipping;

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
    /// Points of a lead-in before the contour's own (the first one is the
    /// pierce), and of a lead-out after them and any overcut (`lead`).
    pub lead_in: usize,
    pub lead_out: usize,
    /// Whether it starts with a bridge from where the path before ended
    /// (its first segment, counted in `lead_in`; `bridges`).
    pub bridge: bool,
    /// Pieces (job geometries) this path cuts free that may tip: the head
    /// lifts over them from here on (`tipping`).
    pub falls: Vec<usize>,
    /// Seconds to stand at its start, the laser off, before it begins: a
    /// cooling wait of the thermal planner (0: none).
    pub cooling_wait: f64,
}

impl PlannedPath {
    /// A path of `points` with no lead-in or lead-out.
    pub fn new(geometry: usize, points: Vec<Point>, process: usize, pierce: bool) -> PlannedPath {
        PlannedPath { geometry, points, process, pierce, lead_in: 0, lead_out: 0, bridge: false, falls: Vec::new(), cooling_wait: 0.0 }
    }

    pub fn start(&self) -> Point {
        self.points[0]
    }
    pub fn end(&self) -> Point {
        self.points[self.points.len() - 1]
    }

    /// The lead-in (a bridge before it included), ending on the contour.
    pub fn lead_in_points(&self) -> &[Point] {
        &self.points[..=self.lead_in]
    }

    /// The lead-out, from where it leaves the contour.
    pub fn lead_out_points(&self) -> &[Point] {
        &self.points[self.points.len() - 1 - self.lead_out..]
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PlannerKind {
    /// Layers that pierce by ecp, marking layers by hha, marks first, fills before all.
    Auto,
    /// Nearest neighbour over scan fields (the baseline).
    Nearest,
    /// The cutting planner: End-point Cutting Problem with precedence.
    Ecp,
    /// The galvo planner of seed 003, hierarchical.
    Hha,
    /// The galvo planner of seed 003, genetic (from the HHA's route).
    Hga,
    /// As `Auto`, but fills as a plain raster, line after line across the
    /// job (the yardstick the fill planner is measured against).
    Raster,
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
            "raster" => Ok(PlannerKind::Raster),
            _ => Err(format!("unknown planner '{s}' (available: auto, nearest, ecp, hha, hga, raster)")),
        }
    }
}

/// The planner `kind` stands for (`auto`: see [`auto`]).
pub fn planner(kind: PlannerKind) -> Box<dyn Planner> {
    match kind {
        PlannerKind::Auto | PlannerKind::Raster => Box::new(auto::Auto),
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
    /// The lead-ins and lead-outs added to the paths.
    pub leads: lead::LeadCount,
    /// Tabs left uncut on part outlines.
    pub tabs: usize,
    /// Bridges cut instead of an air move and a pierce.
    pub bridges: bridges::BridgeCount,
    /// Pieces smaller than twice the support grid, which may tip once cut free.
    pub may_tip: usize,
    /// Pre-cuts made instead of pierces.
    pub precuts: precut::PrecutCount,
    /// What the thermal planner did (`--thermal`, cutting jobs).
    pub thermal: Option<thermal::ThermalSearch>,
}

/// Plans `job` with the planner `kind` stands for, and judges its order: the
/// cutting planner's route by the independent checker, any other planner's
/// by whole geometries.
pub fn plan_job(kind: PlannerKind, job: &Job, ctx: &PlanContext) -> Result<PlanOutcome> {
    let mut outcome = plan_ordered(kind, job, ctx)?;
    outcome.sequence = split_profiles(outcome.sequence, job);
    let (settings, travel) = lead::settings(job, ctx.machine);
    let bridging = ctx.machine.cutting.bridge_max > 0.0 && ctx.plate.is_none();
    // The waste, only where leads or bridges need it (it indexes every segment).
    let waste = (bridging || settings.iter().any(lead::LeadSettings::any)).then(|| lead::waste(job, ctx.machine));
    if let Some(waste) = &waste {
        let leads = lead::add_leads(job, outcome.sequence, &settings, waste, travel, ctx.machine.import.tolerance)?;
        outcome.sequence = leads.sequence;
        outcome.leads = leads.count;
    }
    let tabs = tabs::place(job, ctx.machine)?;
    (outcome.sequence, outcome.tabs) = tabs::cut_tabs(outcome.sequence, &tabs, ctx.machine.cutting.common_cut_tolerance);
    if let (true, Some(waste)) = (bridging, &waste) {
        if let Ok(topology) = cutting::topology(job, &ctx.machine.cutting) {
            (outcome.sequence, outcome.bridges) = bridges::add_bridges(job, outcome.sequence, ctx.machine, waste, &topology.groups);
        }
    }
    (outcome.sequence, outcome.precuts) = precut::add_precuts(job, outcome.sequence, ctx.machine);
    if let Some(grid) = ctx.machine.support_grid() {
        let pieces = tipping::pieces(job, ctx.machine, grid, &tabs::held(&tabs));
        outcome.may_tip = pieces.len();
        outcome.sequence = tipping::mark_falls(job, outcome.sequence, ctx.machine, &pieces, ctx.machine.cutting.common_cut_tolerance);
    }
    Ok(outcome)
}

fn plan_ordered(kind: PlannerKind, job: &Job, ctx: &PlanContext) -> Result<PlanOutcome> {
    match kind {
        PlannerKind::Auto => auto::plan(job, ctx),
        PlannerKind::Raster => auto::plan_filling(job, ctx, auto::FillOrder::Raster),
        PlannerKind::Ecp => Ok(cutting::plan_cutting(job, ctx)?.outcome()),
        _ => {
            let planner = planner(kind);
            let (sequence, search_stopped_by) = match kind {
                PlannerKind::Hha | PlannerKind::Hga => galvo::plan_galvo(job, ctx, kind == PlannerKind::Hga)?,
                _ => (planner.plan(job, ctx)?, stop::SearchStop::Budget),
            };
            let broken_rules = cutting::sequence_violations(job, &sequence, ctx);
            Ok(PlanOutcome { sequence, planner: planner.name().into(), broken_rules, search_stopped_by, edge_length_saved_mm: 0.0, leads: Default::default(), tabs: 0, bridges: Default::default(), may_tip: 0, precuts: Default::default(), thermal: None })
        }
    }
}

/// Each path of a geometry with a profile (a raster line whose power changes
/// along it) cut where its process changes, in the direction it is marked:
/// the pieces follow each other with no move between, the first with the
/// path's pierce.
pub fn split_profiles(sequence: Sequence, job: &Job) -> Sequence {
    if job.geometries.iter().all(|g| g.profile.is_empty()) {
        return sequence;
    }
    let key = |p: &Point| (p.x.to_bits(), p.y.to_bits());
    let groups = sequence
        .groups
        .into_iter()
        .map(|group| {
            let mut paths = Vec::with_capacity(group.paths.len());
            for path in group.paths {
                let g = &job.geometries[path.geometry];
                if g.profile.is_empty() {
                    paths.push(path);
                    continue;
                }
                // A path's points are its geometry's, forward or back (from
                // any vertex of a closed one): each segment found by its ends.
                let mut vertex: std::collections::HashMap<(u64, u64), usize> = std::collections::HashMap::with_capacity(g.points.len());
                for (i, p) in g.points.iter().enumerate() {
                    vertex.entry(key(p)).or_insert(i);
                }
                let n = g.points.len();
                let segment = |a: &Point, b: &Point| -> usize {
                    match (vertex.get(&key(a)), vertex.get(&key(b))) {
                        (Some(&i), Some(&j)) if j == (i + 1) % n => g.profile.get(i).copied().unwrap_or(g.process),
                        (Some(&i), Some(&j)) if i == (j + 1) % n => g.profile.get(j).copied().unwrap_or(g.process),
                        _ => path.process,
                    }
                };
                let first = path.points.get(1).map_or(path.process, |b| segment(&path.points[0], b));
                let mut piece = PlannedPath::new(path.geometry, vec![path.points[0]], first, path.pierce);
                for w in path.points.windows(2) {
                    let process = segment(&w[0], &w[1]);
                    if process != piece.process {
                        let next = PlannedPath::new(path.geometry, vec![w[0]], process, false);
                        paths.push(std::mem::replace(&mut piece, next));
                    }
                    piece.points.push(w[1]);
                }
                paths.push(piece);
            }
            PathGroup { paths, ..group }
        })
        .collect();
    Sequence { groups }
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

    #[test]
    fn a_raster_line_is_cut_where_its_power_changes_in_the_direction_it_is_marked() {
        let points: Vec<Point> = (0..5).map(|k| Point::new(k as f64, 0.0)).collect();
        use crate::job::Geometry;
        let line = Geometry { points: points.clone(), closed: false, arcs: Vec::new(), profile: vec![0, 1, 1, 2], process: 0, source: "t.nc:3".into() };
        let plain = Geometry::polyline(vec![Point::new(0.0, 5.0), Point::new(4.0, 5.0)], false, 1, "t.nc:9".into());
        let process = |power: f64| crate::job::Process { layer: format!("S{power}"), speed: 10.0, power, passes: 1, fill: false };
        let job = Job { source: "t.nc".into(), geometries: vec![line, plain], processes: vec![process(100.0), process(200.0), process(300.0)] };
        let path = |geometry: usize, points: Vec<Point>, process: usize| PlannedPath::new(geometry, points, process, true);
        // Marked backwards: the last segment's process first.
        let back: Vec<Point> = points.iter().rev().copied().collect();
        let sequence = Sequence { groups: vec![PathGroup { field_center: None, paths: vec![path(0, back, 0), path(1, job.geometries[1].points.clone(), 1)] }] };
        let split = split_profiles(sequence, &job);
        let got: Vec<(usize, Vec<f64>, bool)> = split.paths().map(|p| (p.process, p.points.iter().map(|q| q.x).collect(), p.pierce)).collect();
        assert_eq!(
            got,
            vec![(2, vec![4.0, 3.0], true), (1, vec![3.0, 2.0, 1.0], false), (0, vec![1.0, 0.0], false), (1, vec![0.0, 4.0], true)],
            "pieces follow on with no pierce; a geometry without a profile is left as it is"
        );
    }
}
