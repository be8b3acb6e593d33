//! `--planner auto` (the default, and the service's): each layer planned by
//! the planner made for it.
//!
//! * Layers that pierce (cut through: their `pierce_time`, else `[laser]`'s,
//!   is above 0) go to the cutting planner (`ecp`): no part falls out before
//!   everything inside it is cut.
//! * Marking layers go to the galvo planner (`hha`): with a scanner it orders
//!   scan fields; on a stage-only machine it is the same route search (2-opt,
//!   Or-opt) over the whole job, which moves less air than `nearest`.
//! * A job with both is marked first, then cut: a mark on a part is made while
//!   the sheet still holds the part, never after it has fallen or moved. The
//!   cuts start where the marking ended.
//! * Fills (hatch lines of fill layers) come before both, ordered by the fill
//!   planner (`area`); the outlines of `fill+line` then mark their edges clean.

use super::cutting::{self, cuts_through};
use super::ecp::checker::Violation;
use super::{area, galvo, PathGroup, PlanContext, PlanOutcome, Planner, Sequence};
use crate::error::Result;
use crate::job::Job;

pub use area::FillOrder;

pub struct Auto;

impl Planner for Auto {
    fn name(&self) -> &'static str {
        "auto"
    }

    fn plan(&self, job: &Job, ctx: &PlanContext) -> Result<Sequence> {
        Ok(plan(job, ctx)?.sequence)
    }
}

/// The job planned layer kind by layer kind; `planner` names what planned
/// it: `hha`, `ecp`, or `hha+ecp` (marked, then cut), after `fill+` where
/// fills came first.
pub fn plan(job: &Job, ctx: &PlanContext) -> Result<PlanOutcome> {
    plan_filling(job, ctx, FillOrder::Planned)
}

/// `plan`, the fills ordered as `fill_order` says, first (the outlines of
/// `fill+line` then mark their edges clean), then the other marks, then
/// the cuts.
pub fn plan_filling(job: &Job, ctx: &PlanContext, fill_order: FillOrder) -> Result<PlanOutcome> {
    let (fills, rest): (Vec<usize>, Vec<usize>) = (0..job.geometries.len()).partition(|&g| job.processes[job.geometries[g].process].fill && !job.geometries[g].closed);
    if fills.is_empty() {
        return plan_layers(job, ctx);
    }
    let (filled, search_stopped_by) = area::plan_fills(job, &fills, ctx, fill_order)?;
    let name = match fill_order {
        FillOrder::Raster => "raster",
        FillOrder::Planned => "fill",
    };
    if rest.is_empty() {
        return Ok(PlanOutcome { sequence: filled, planner: name.into(), broken_rules: Some(Vec::new()), search_stopped_by, edge_length_saved_mm: 0.0, leads: Default::default(), tabs: 0, bridges: Default::default(), may_tip: 0, precuts: Default::default(), thermal: None });
    }
    let start = filled.paths().last().map_or(ctx.start, |p| p.end());
    let plate = ctx.plate.and_then(|p| p.select(&rest));
    let mut then = plan_layers(&part_of(job, &rest), &PlanContext { machine: ctx.machine, mode: ctx.mode, start, plate: plate.as_ref() })?;
    renumber(&mut then.sequence, &rest);
    then.sequence = joined(filled, then.sequence);
    then.broken_rules = then.broken_rules.map(|rules| rules.into_iter().map(|v| in_job(v, &rest, job.geometries.len())).collect());
    then.planner = format!("{name}+{}", then.planner);
    then.search_stopped_by = search_stopped_by.and(then.search_stopped_by);
    Ok(then)
}

/// The job (without fills) planned layer kind by layer kind.
fn plan_layers(job: &Job, ctx: &PlanContext) -> Result<PlanOutcome> {
    let cuts = cuts_through(job, ctx.machine);
    let (cutting, marking): (Vec<usize>, Vec<usize>) = (0..job.geometries.len()).partition(|&g| cuts[g]);
    if cutting.is_empty() {
        let (sequence, search_stopped_by) = galvo::plan_galvo(job, ctx, false)?;
        return Ok(PlanOutcome { sequence, planner: "hha".into(), broken_rules: Some(Vec::new()), search_stopped_by, edge_length_saved_mm: 0.0, leads: Default::default(), tabs: 0, bridges: Default::default(), may_tip: 0, precuts: Default::default(), thermal: None });
    }
    if marking.is_empty() {
        return Ok(cutting::plan_cutting(job, ctx)?.outcome());
    }
    let (mut marked, marking_stopped_by) = galvo::plan_galvo(&part_of(job, &marking), ctx, false)?;
    renumber(&mut marked, &marking);
    let start = marked.paths().last().map_or(ctx.start, |p| p.end());
    let plate = ctx.plate.and_then(|p| p.select(&cutting));
    let cut = cutting::plan_cutting(&part_of(job, &cutting), &PlanContext { machine: ctx.machine, mode: ctx.mode, start, plate: plate.as_ref() })?;
    let mut cut_sequence = cut.sequence;
    renumber(&mut cut_sequence, &cutting);
    // The cutting route's rules, by the checker, in the job's numbering;
    // then the marks', by whole geometries against the parts around them.
    let mut broken: Vec<Violation> = cut.broken_rules.into_iter().map(|v| in_job(v, &cutting, job.geometries.len())).collect();
    let sequence = joined(marked, cut_sequence);
    let marks_broken = cutting::sequence_violations(job, &sequence, ctx).map(|all| {
        all.into_iter().filter(|v| matches!(v, Violation::InnerAfterOuter { inner, .. } if !cuts[*inner])).collect::<Vec<_>>()
    });
    let broken_rules = marks_broken.map(|m| {
        broken.extend(m);
        broken
    });
    let search_stopped_by = marking_stopped_by.and(cut.search_stopped_by);
    Ok(PlanOutcome { sequence, planner: "hha+ecp".into(), broken_rules, search_stopped_by, edge_length_saved_mm: cut.edge_length_saved_mm, leads: Default::default(), tabs: 0, bridges: Default::default(), may_tip: 0, precuts: Default::default(), thermal: cut.thermal })
}

/// The geometries `which` of `job` as a job of their own (the processes
/// kept, so each geometry keeps its process index).
fn part_of(job: &Job, which: &[usize]) -> Job {
    Job { source: job.source.clone(), geometries: which.iter().map(|&g| job.geometries[g].clone()).collect(), processes: job.processes.clone() }
}

/// A sequence of `part_of(job, which)` in the job's geometry numbering.
fn renumber(sequence: &mut Sequence, which: &[usize]) {
    for path in sequence.groups.iter_mut().flat_map(|g| g.paths.iter_mut()) {
        path.geometry = which[path.geometry];
    }
}

/// A rule of a part's route in the job's numbering (contours are geometries).
fn in_job(rule: Violation, which: &[usize], geometries: usize) -> Violation {
    // Contours beyond the part's geometries are plate regions: beyond the job's.
    cutting::renumbered(rule, |c| which.get(c).copied().unwrap_or(geometries + c - which.len()))
}

/// `first` then `then`; on a stage-only plan (no scan fields) one group.
fn joined(first: Sequence, then: Sequence) -> Sequence {
    let mut groups = first.groups;
    for group in then.groups {
        match groups.last_mut() {
            Some(last) if last.field_center.is_none() && group.field_center.is_none() => last.paths.extend(group.paths),
            _ => groups.push(PathGroup { field_center: group.field_center, paths: group.paths }),
        }
    }
    Sequence { groups }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineConfig;
    use crate::job::{Geometry, Point, Process};
    use crate::mode::Mode;

    fn square(x: f64, y: f64, side: f64, process: usize, name: &str) -> Geometry {
        let points = vec![Point::new(x, y), Point::new(x + side, y), Point::new(x + side, y + side), Point::new(x, y + side)];
        Geometry { arcs: Vec::new(), profile: Vec::new(), points, closed: true, process, source: format!("t.svg: {name}") }
    }

    /// A cutting machine's layers: `cut` pierces, `engrave` does not.
    fn cutter() -> MachineConfig {
        MachineConfig::load(Some(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml"))).unwrap()
    }

    fn process(layer: &str) -> Process {
        Process { layer: layer.into(), speed: 50.0, power: 500.0, passes: 1, fill: false }
    }

    #[test]
    fn marks_first_with_the_galvo_planner_then_cuts_every_part_after_what_is_inside_it() {
        let mut machine = cutter();
        machine.cutting.time_limit = Some(0.5);
        // Two plates, each with a hole and an engraved label inside; the
        // engraved frame around the second plate holds nothing.
        let geometries = vec![
            square(10.0, 10.0, 50.0, 0, "plate a"),
            square(20.0, 20.0, 10.0, 0, "hole a"),
            square(40.0, 40.0, 5.0, 1, "label a"),
            square(100.0, 10.0, 50.0, 0, "plate b"),
            square(110.0, 20.0, 10.0, 0, "hole b"),
            square(130.0, 40.0, 5.0, 1, "label b"),
            square(95.0, 5.0, 60.0, 1, "frame b"),
        ];
        let job = Job { source: "t.svg".into(), geometries, processes: vec![process("cut"), process("engrave")] };
        let ctx = PlanContext { machine: &machine, mode: Mode::StageOnly, start: Point::origin(), plate: None };
        let outcome = plan(&job, &ctx).unwrap();
        assert_eq!(outcome.planner, "hha+ecp");
        assert_eq!(outcome.broken_rules, Some(vec![]));
        let order: Vec<usize> = outcome.sequence.paths().map(|p| p.geometry).collect();
        let marks = order.iter().take_while(|&&g| job.geometries[g].process == 1).count();
        assert_eq!(marks, 3, "every mark before any cut: {order:?}");
        let mut seen: Vec<usize> = order.clone();
        seen.sort();
        seen.dedup();
        assert_eq!(seen, (0..7).collect::<Vec<_>>(), "every geometry planned: {order:?}");
        let last = |g: usize| order.iter().rposition(|&x| x == g).unwrap();
        assert!(last(1) < last(0) && last(4) < last(3), "holes before their plates: {order:?}");
        assert_eq!(outcome.sequence.groups.len(), 1, "stage-only: one group");

        // Only marking, only cutting: the one planner, as `--planner` names it.
        let marking = Job { geometries: job.geometries.iter().filter(|g| g.process == 1).cloned().collect(), ..job.clone() };
        let outcome = plan(&marking, &ctx).unwrap();
        assert_eq!((outcome.planner.as_str(), outcome.broken_rules), ("hha", Some(vec![])));
        assert_eq!(outcome.sequence, galvo::Hha.plan(&marking, &ctx).unwrap(), "the galvo planner's own plan");
        let cutting = Job { geometries: job.geometries.iter().filter(|g| g.process == 0).cloned().collect(), ..job.clone() };
        let outcome = plan(&cutting, &ctx).unwrap();
        assert_eq!((outcome.planner.as_str(), outcome.broken_rules), ("ecp", Some(vec![])));
    }
}
