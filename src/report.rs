//! The `plan --json` / `dry-run --json` object of the command-line contract, and
//! its human-readable summary. A figure this version cannot produce is `null`.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::ConfigSource;
use crate::figures::SimFigures;
use crate::plan::stop::SearchStop;

/// A duration as people read it: `1 h 19 min 29 s`, `4 min 3 s`, `29.4 s`
/// (below a minute with three significant digits, down to `0.0123 s`). The
/// JSON reports keep seconds; this is for the text ones.
pub fn duration(seconds: f64) -> String {
    if !seconds.is_finite() {
        return format!("{seconds} s");
    }
    if seconds == 0.0 {
        return "0 s".into();
    }
    if seconds < 0.0 {
        return format!("-{}", duration(-seconds));
    }
    // Below a minute as the decimals that keep three significant digits; a
    // value that rounds to 60 s is a minute.
    let decimals = if seconds >= 10.0 { 1 } else if seconds >= 1.0 { 2 } else if seconds >= 0.1 { 3 } else { 4 };
    if format!("{seconds:.decimals$}").parse::<f64>().unwrap_or(seconds) < 60.0 {
        return format!("{seconds:.decimals$} s");
    }
    let whole = seconds.round() as u64;
    let (h, min, s) = (whole / 3600, whole / 60 % 60, whole % 60);
    if h > 0 {
        format!("{h} h {min} min {s} s")
    } else {
        format!("{min} min {s} s")
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct PlanReport {
    pub job: String,
    pub planner: String,
    pub mode: String,
    pub geometries: usize,
    /// Scan fields visited; `null` on a stage-only plan.
    pub scan_fields: Option<usize>,
    /// Turns of more than 90° of the stage's field-to-field path (it going
    /// back the way it came); `null` on a stage-only plan.
    pub stage_reversals: Option<usize>,
    /// On the fly: the share of field changes the stage takes at speed
    /// (the others stop the TCP while the stage catches up); `null` in other
    /// modes and without a field change.
    #[serde(default)]
    pub stage_flow: Option<f64>,
    pub mark_length_mm: f64,
    pub idle_stroke_mm: f64,
    pub plan_time_s: f64,
    /// What the planners minimised (`[fill]`, `[cutting]`, `[galvo]
    /// objective`, `--objective`): `time`, `length`, `turns`, `heat` or a
    /// weighted sum; each planner's (`fill: time, hha: length`) where they
    /// differ, `none` for the raster.
    #[serde(default)]
    pub objective: String,
    /// `budget` when every search ran its budget of work (the plan is the
    /// same whatever the machine's load and cores), `time-limit` when the
    /// user's time limit ended one first (the plan may differ from run to run).
    #[serde(default)]
    pub search_stopped_by: SearchStop,
    /// Cuts after the part they belong to has fallen out: by the independent
    /// checker on the cutting planner's route, or by whole geometries (a
    /// geometry finished at or after the nearest contour around it on a layer
    /// that pierces) for other planners and for `auto`'s marks; 0 for marking
    /// jobs, where nothing falls out. `null` when the job's topology cannot
    /// be built. `plan`, `dry-run` and the service refuse an order with any
    /// unless overridden.
    pub precedence_violations: Option<u64>,
    /// Paths that start with a pierce, on layers that pierce (a cut that
    /// starts where the one before ended, or on the plate's edge, does not).
    #[serde(default)]
    pub pierces: usize,
    /// The largest kerf the closed contours were offset by (half of it into
    /// the waste, `[[layer]] kerf`); `null` when no layer sets one.
    #[serde(default)]
    pub kerf_mm: Option<f64>,
    /// Cuts entered from a pierce in the waste along a lead-in, and left
    /// along a lead-out (`[[layer]] lead_in`, `lead_out`); lead-ins placed
    /// away from the planned entry for want of room there.
    #[serde(default)]
    pub lead_ins: usize,
    #[serde(default)]
    pub lead_outs: usize,
    #[serde(default)]
    pub lead_ins_moved: usize,
    /// Cuts left without a lead because no waste touches where they start
    /// or end (between parts that share their cuts).
    #[serde(default)]
    pub leads_skipped: usize,
    /// Tabs (micro-joints) left uncut on part outlines (`[[layer]] tabs`).
    #[serde(default)]
    pub tabs: usize,
    /// Bridges cut across the waste from one cut to the next instead of an
    /// air move and a pierce (`[cutting] bridge_max`), and the pierces they save.
    #[serde(default)]
    pub bridges: usize,
    #[serde(default)]
    pub pierces_saved: usize,
    /// Pre-cuts made where a cut would start with a pierce on a junction
    /// passed before (`[cutting] precut_length`), each saving a pierce, and
    /// the sharp-angle macros at those junctions in the order made.
    #[serde(default)]
    pub precuts: usize,
    #[serde(default)]
    pub precut_sharp_angles: usize,
    /// With a support grid (`[plate] support_grid`): the pieces that may
    /// tip once cut free (smaller than twice the grid), and the air moves
    /// that lift the head over them; `null` without one.
    #[serde(default)]
    pub tipping_pieces: Option<usize>,
    #[serde(default)]
    pub lifts: Option<usize>,
    /// Fill layers (`[[layer]] mode`): the separate areas filled (an
    /// outline with its holes), the hatch lines marking them, and the areas
    /// too thin for the hatch's grid, each given one line through its middle;
    /// `null` without a fill.
    #[serde(default)]
    pub fill_areas: Option<usize>,
    #[serde(default)]
    pub hatch_lines: Option<usize>,
    #[serde(default)]
    pub thin_fill_areas: Option<usize>,
    /// Length cut on layers that pierce, every pass counted, mm.
    #[serde(default)]
    pub cut_length_mm: f64,
    /// With a `[plate]`: the length of the parts' outlines on the plate's
    /// edge, which is not cut (mm), and the skeleton and remnant cuts made;
    /// `null` without a plate.
    #[serde(default)]
    pub edge_length_saved_mm: Option<f64>,
    /// With a `[plate]`: cuts that start on its edge, without a pierce.
    #[serde(default)]
    pub edge_starts: Option<usize>,
    #[serde(default)]
    pub skeleton_cuts: Option<usize>,
    #[serde(default)]
    pub remnant_cuts: Option<usize>,
    pub trajectory_time_s: f64,
    pub lower_bound_s: f64,
    /// G-code lines of the program.
    pub program_lines: usize,
    pub program_bytes: usize,
    /// Motion blocks of the program per second of machine time (the job's
    /// clock), against what the configured link carries of this program's
    /// lines per second (baud / 10 / mean bytes per line) and what a
    /// 115200-baud link would: a program denser than its link starves the
    /// controller.
    pub blocks_per_s: f64,
    pub link_lines_per_s: f64,
    pub link_115200_lines_per_s: f64,
    /// How much longer the job takes than the machine allows, so that the
    /// link keeps the controller fed: planned machine time over the time at
    /// full speed (1: not slowed). The trajectory and program are the
    /// slowed ones.
    pub link_slowdown: f64,
    /// Wall-clock time of the trajectory, the split and the program.
    pub motion_time_s: f64,
    /// Only in `dry-run`.
    pub sim: Option<SimFigures>,
    pub recording: Option<String>,
    /// The plate's heat (`--thermal`, cutting jobs; seed 000); `null` without.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal: Option<ThermalReport>,
    /// Where the machine config came from (`plan` and `dry-run`; absent in
    /// the service's reports, whose config is the service's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<ConfigSource>,
}

impl PlanReport {
    /// A few lines for a person at a terminal.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let flow = self.stage_flow.map(|f| format!(", {:.0} % of field changes at speed", 100.0 * f)).unwrap_or_default();
        let fields = match (self.scan_fields, self.stage_reversals) {
            (Some(n), Some(r)) => format!(", {n} scan fields ({r} stage reversals{flow})"),
            (Some(n), None) => format!(", {n} scan fields"),
            _ => String::new(),
        };
        s.push_str(&format!(
            "{}: {} geometries{}, planner {}{}, mode {}\n",
            self.job,
            self.geometries,
            fields,
            self.planner,
            if self.objective.is_empty() || self.objective == "none" { String::new() } else { format!(" (objective {})", self.objective) },
            self.mode
        ));
        let precedence = self.precedence_violations.map_or("unknown".to_string(), |n| n.to_string());
        if self.pierces > 0 || self.cut_length_mm > 0.0 {
            s.push_str(&format!("  cutting {:.1} mm with {} pierces", self.cut_length_mm, self.pierces));
            if let Some(kerf) = self.kerf_mm {
                s.push_str(&format!(", offset by half the kerf of {kerf} mm"));
            }
            if self.bridges > 0 {
                s.push_str(&format!(", {} bridges saving {} pierces", self.bridges, self.pierces_saved));
            }
            if self.precuts > 0 {
                s.push_str(&format!(", {} pre-cuts instead of pierces ({} sharp angles at their junctions)", self.precuts, self.precut_sharp_angles));
            }
            if self.tabs > 0 {
                s.push_str(&format!(", {} tabs left uncut", self.tabs));
            }
            if let (Some(pieces), Some(lifts)) = (self.tipping_pieces, self.lifts) {
                s.push_str(&format!(", {pieces} pieces that may tip, {lifts} lifts over them"));
            }
            if self.lead_ins + self.lead_outs > 0 {
                s.push_str(&format!(", {} lead-ins ({} moved for room), {} lead-outs", self.lead_ins, self.lead_ins_moved, self.lead_outs));
                if self.leads_skipped > 0 {
                    s.push_str(&format!(", {} cuts without a lead (no waste where they start or end)", self.leads_skipped));
                }
            }
            if let (Some(edge), Some(skeleton), Some(remnant)) = (self.edge_length_saved_mm, self.skeleton_cuts, self.remnant_cuts) {
                s.push_str(&format!("; plate: {edge:.1} mm of edge not cut, {skeleton} skeleton and {remnant} remnant cuts"));
            }
            s.push('\n');
        }
        if let Some(thermal) = &self.thermal {
            s.push_str(&thermal.summary());
        }
        if let (Some(areas), Some(lines)) = (self.fill_areas, self.hatch_lines) {
            s.push_str(&format!("  filling {areas} areas with {lines} hatch lines"));
            if let Some(thin) = self.thin_fill_areas.filter(|&t| t > 0) {
                s.push_str(&format!(" ({thin} too thin for the hatch spacing, one line through each)"));
            }
            s.push('\n');
        }
        s.push_str(&format!(
            "  marking {:.1} mm, idle stroke {:.1} mm, planned in {} (search stopped by {}), precedence_violations {precedence}\n",
            self.mark_length_mm,
            self.idle_stroke_mm,
            duration(self.plan_time_s),
            self.search_stopped_by.as_str()
        ));
        s.push_str(&format!(
            "  machine time {} (lower bound {}), program {} lines / {} bytes, computed in {}\n",
            duration(self.trajectory_time_s),
            duration(self.lower_bound_s),
            self.program_lines,
            self.program_bytes,
            duration(self.motion_time_s)
        ));
        s.push_str(&format!(
            "  {:.0} blocks per second of machine time; the link carries {:.0} lines/s (115200 baud: {:.0})\n",
            self.blocks_per_s, self.link_lines_per_s, self.link_115200_lines_per_s
        ));
        if self.link_slowdown > 1.0 {
            s.push_str(&format!("  {:.2} times the time at full speed, so that the link keeps the controller fed\n", self.link_slowdown));
        }
        if let Some(sim) = &self.sim {
            s.push_str(&sim_summary(sim));
        }
        if let Some(r) = &self.recording {
            s.push_str(&format!("  recording: {r}\n"));
        }
        if let Some(c) = &self.config {
            s.push_str(&format!("  machine config: {c}\n"));
        }
        s
    }
}

/// The lines of a summary on the simulated run: its times and link, and how
/// it kept the machine's limits (also `replay`'s).
pub fn sim_summary(sim: &SimFigures) -> String {
    let mut s = format!(
        "  simulated: job time {}, {} lines / {} bytes sent, link {:.0} % used, planner starved {}\n",
        duration(sim.job_time_s),
        sim.lines_sent,
        sim.bytes_sent,
        sim.link_utilization * 100.0,
        duration(sim.planner_starved_s)
    );
    let field = sim.peak_field_use.map(|f| format!(", field use {:.2}", f)).unwrap_or_default();
    let deviation = sim.max_tcp_deviation_mm.map_or("max TCP deviation not measured (no plan)".to_string(), |d| format!("max TCP deviation {d:.4} mm"));
    s.push_str(&format!("  {deviation}, stage use {:.2}{}, limit violations {}, alarms {:?}\n", sim.peak_stage_use, field, sim.limit_violations, sim.alarms));
    match sim.collisions {
        Some(0) => s.push_str("  no collisions with pieces that may have tipped\n"),
        Some(n) => s.push_str(&format!("  COLLISIONS: the head passed low over a piece that may have tipped {n} time(s)\n")),
        None => {}
    }
    if let Some(v) = &sim.first_violation {
        s.push_str(&format!("  first limit violation: {v}\n"));
    }
    if !sim.limit_breaches.is_empty() {
        s.push_str(&format!("  LIMITS BROKEN ({}):\n", sim.limit_breaches.len()));
        for b in &sim.limit_breaches {
            s.push_str(&format!("    {b}\n"));
        }
    }
    s
}

/// `dry-run FILE.nc --keep-order --json`: a G-code file streamed as it is,
/// with no plan behind it: `trajectory_time_s` and `lower_bound_s` are
/// `null`, and so is `sim.max_tcp_deviation_mm` (no planned TCP).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GcodeReport {
    pub job: String,
    /// `keep-order`: the file's own order and moves, not planned.
    pub planner: String,
    /// How the simulated controller ran the blocks (`--motion`).
    pub motion: laserd_sim::controller::MotionModel,
    /// The simulated controller's `$11` at power-up (the `grbl` model's corners).
    pub junction_deviation_mm: f64,
    pub program_lines: usize,
    pub program_bytes: usize,
    pub trajectory_time_s: Option<f64>,
    pub lower_bound_s: Option<f64>,
    pub sim: Option<SimFigures>,
    pub recording: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<ConfigSource>,
}

impl GcodeReport {
    /// A few lines for a person at a terminal.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "{}: G-code streamed as it is ({} lines / {} bytes), motion {:?}, junction deviation {} mm\n",
            self.job, self.program_lines, self.program_bytes, self.motion, self.junction_deviation_mm
        );
        if let Some(sim) = &self.sim {
            s.push_str(&sim_summary(sim));
        }
        if let Some(r) = &self.recording {
            s.push_str(&format!("  recording: {r}\n"));
        }
        if let Some(c) = &self.config {
            s.push_str(&format!("  machine config: {c}\n"));
        }
        s
    }
}

/// The plate heat model's verdict on the planned route against the plain
/// one (the cutting search without it), times as the planner estimates them
/// (air moves rest to rest at the axes' limits, cuts at their speed).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ThermalReport {
    pub material: String,
    pub cell_mm: f64,
    /// Operations (pierces, cuts, sharp corners) that start where the plate
    /// is at or above their critical temperature, on the planned route.
    pub thermal_violations: usize,
    /// The largest excess over a critical temperature, °C (0: none).
    pub max_overheat_c: f64,
    /// The operation nearest to (or furthest over) its critical temperature.
    pub hottest: Option<HottestOperation>,
    /// Cooling waits in the program (laser off, head still before paths
    /// that would violate otherwise): the last resort, s in all, and the
    /// operations they are for.
    pub thermal_wait_s: f64,
    pub cooled_operations: usize,
    /// The plain route's violations and overheat.
    pub plain_violations: usize,
    pub plain_max_overheat_c: f64,
    /// Estimated machine time of the plain and the planned route (waits included), s.
    pub plain_time_s: f64,
    pub planned_time_s: f64,
    /// Constructions searched under thermal penalties, and the pairs of cuts penalised.
    pub iterations: u32,
    pub penalties: usize,
    /// Whole-job evaluations of the heat model, their mean time, and its speed.
    pub evaluations: u32,
    pub evaluation_s: f64,
    pub cell_updates_per_s: f64,
    /// Every operation of the planned route: the temperature it met.
    pub operations: Vec<OperationHeat>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct HottestOperation {
    pub feature: String,
    pub time_s: f64,
    pub x: f64,
    pub y: f64,
    pub celsius: f64,
    pub critical_c: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct OperationHeat {
    pub feature: String,
    /// The path it belongs to, in cutting order.
    pub path: usize,
    pub time_s: f64,
    pub celsius: f64,
    pub critical_c: f64,
}

impl ThermalReport {
    pub fn of(search: &crate::plan::thermal::ThermalSearch, machine: &crate::config::MachineConfig) -> ThermalReport {
        let planned = &search.planned;
        let checks = &search.planned_timeline.checks;
        let limits = crate::thermal::model_of(machine).map(|m| m.1).ok();
        let limit = |c: usize| limits.map_or(f64::NAN, |l| l.of(checks[c].feature));
        ThermalReport {
            material: machine.material.as_ref().map(|m| m.name.clone()).unwrap_or_default(),
            cell_mm: machine.thermal.cell,
            thermal_violations: planned.violations.len(),
            max_overheat_c: planned.max_overheat,
            hottest: planned.hottest.map(|h| HottestOperation { feature: checks[h.check].feature.name().into(), time_s: h.time, x: h.at.x, y: h.at.y, celsius: h.celsius, critical_c: h.critical }),
            thermal_wait_s: planned.wait,
            cooled_operations: planned.waited.len(),
            plain_violations: search.plain.violations.len(),
            plain_max_overheat_c: search.plain.max_overheat,
            plain_time_s: search.plain_time,
            planned_time_s: search.planned_time,
            iterations: search.iterations,
            penalties: search.penalties,
            evaluations: search.evaluations,
            evaluation_s: search.evaluation_s / f64::from(search.evaluations.max(1)),
            cell_updates_per_s: planned.cell_updates as f64 / (search.evaluation_s / f64::from(search.evaluations.max(1))).max(1e-9),
            operations: (0..checks.len())
                .map(|c| OperationHeat { feature: checks[c].feature.name().into(), path: checks[c].path, time_s: planned.times[c], celsius: planned.celsius[c], critical_c: limit(c) })
                .collect(),
        }
    }

    /// One line for a person at a terminal.
    pub fn summary(&self) -> String {
        let extra = 100.0 * (self.planned_time_s / self.plain_time_s.max(1e-9) - 1.0);
        let mut s = format!(
            "  heat ({}, {} mm cells): {} thermal violations (max overheat {:.1} °C), plain route {} ({:.1} °C); {:+.2} % machine time, {} constructions",
            if self.material.is_empty() { "material" } else { &self.material },
            self.cell_mm,
            self.thermal_violations,
            self.max_overheat_c,
            self.plain_violations,
            self.plain_max_overheat_c,
            extra,
            self.iterations
        );
        if self.thermal_wait_s > 0.0 {
            s.push_str(&format!(", {} of cooling waits before {} operations", duration(self.thermal_wait_s), self.cooled_operations));
        }
        if let Some(h) = &self.hottest {
            s.push_str(&format!("; hottest: a {} at ({:.0}, {:.0}) mm, {} in, {:.0} °C of {:.0}", h.feature, h.x, h.y, duration(h.time_s), h.celsius, h.critical_c));
        }
        s.push('\n');
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_as_hours_minutes_and_seconds() {
        assert_eq!(duration(4769.0), "1 h 19 min 29 s");
        assert_eq!(duration(243.4), "4 min 3 s");
        assert_eq!(duration(29.43), "29.4 s");
        assert_eq!(duration(3.456), "3.46 s");
        assert_eq!(duration(0.0123), "0.0123 s");
        assert_eq!(duration(0.0), "0 s");
        assert_eq!(duration(-90.0), "-1 min 30 s");
        // What rounds up to a minute or an hour is said so.
        assert_eq!(duration(59.97), "1 min 0 s");
        assert_eq!(duration(3599.6), "1 h 0 min 0 s");
        assert_eq!(duration(7322.0), "2 h 2 min 2 s");
    }
}
