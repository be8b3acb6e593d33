//! `laserd bench thermal`: seed 000's thermal planning on generated sheets
//! (by default its proof of concept's scale: about 650 elements on a 2000 x
//! 1500 mm plate, the material and critical temperatures from the config).
//! Per seed: the plain cutting route's thermal violations against the
//! thermal route's, the extra machine time, the constructions it took, the
//! planning time, and the heat model's speed (a whole-job evaluation, cell
//! updates per second); median and worst over the seeds.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::gen::sheet;
use crate::plan::cutting::plan_cutting;
use crate::plan::PlanContext;
use super::median_worst;
use crate::thermal::{Assessment, Feature, Timeline};

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ThermalBench {
    pub width_mm: f64,
    pub height_mm: f64,
    pub material: String,
    pub cell_mm: f64,
    pub critical_c: [f64; 3],
    pub runs: Vec<ThermalRun>,
    /// Median and worst over the seeds.
    pub plain_violations: [f64; 2],
    pub thermal_violations: [f64; 2],
    pub extra_time_percent: [f64; 2],
    pub thermal_plan_s: [f64; 2],
    pub whole_plan_s: [f64; 2],
    pub thermal_wait_s: [f64; 2],
    pub evaluation_s: [f64; 2],
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ThermalRun {
    pub seed: u64,
    pub geometries: usize,
    pub elements: usize,
    pub plain_violations: usize,
    pub plain_max_overheat_c: f64,
    /// The hottest a pierce, a cut and a corner of the plain route met, °C.
    pub plain_peak_c: [f64; 3],
    pub thermal_violations: usize,
    pub max_overheat_c: f64,
    /// Cooling waits in the thermal route's program (the last resort), and
    /// the operations that would have violated without them.
    pub thermal_wait_s: f64,
    pub cooled_operations: usize,
    /// Estimated machine time of the plain and the thermal route, s.
    pub plain_time_s: f64,
    pub thermal_time_s: f64,
    pub extra_time_percent: f64,
    pub iterations: u32,
    pub penalties: usize,
    /// Wall-clock: the plain search alone; the thermal planner after the
    /// plain search it runs first; the whole thermal planning, s.
    pub plain_plan_s: f64,
    pub thermal_plan_s: f64,
    pub whole_plan_s: f64,
    /// The heat model: mean whole-job evaluation, its cells, steps, and speed.
    pub evaluations: u32,
    pub evaluation_s: f64,
    pub cells: usize,
    pub steps: u64,
    pub cell_updates_per_s: f64,
}

/// The hottest a check of `feature` met.
fn peak(a: &Assessment, timeline: &Timeline, feature: Feature) -> f64 {
    timeline.checks.iter().zip(&a.celsius).filter(|(c, _)| c.feature == feature).map(|(_, &t)| t).fold(f64::NAN, f64::max)
}

pub fn thermal_bench(machine: &MachineConfig, elements: usize, width: f64, height: f64, seeds: u64) -> Result<ThermalBench> {
    crate::thermal::model_of(machine)?;
    let mut runs = Vec::new();
    for seed in 1..=seeds {
        let params = sheet::SheetParams { width, height, ..sheet::SheetParams::with_target(elements) };
        let path = super::write_sheet(&params, seed, "thermal", None)?;
        let m = super::flatbed_for(machine, width, height);
        let job = crate::import::import_job(&path, &m);
        let _ = std::fs::remove_file(&path);
        let job = job?;
        // The plate under the sheet sizes the heat model's grid; the cutting
        // planner plans the sheet as a free job (no plate layout).
        let mut hot = m.clone();
        hot.plate = Some(crate::config::PlateConfig { x: 0.0, y: 0.0, width, height, ..plate_defaults() });
        hot.thermal.enabled = true;
        let ctx = PlanContext { machine: &m, mode: crate::mode::Mode::StageOnly, start: crate::run::job_start(), plate: None };
        let started = std::time::Instant::now();
        let plain = plan_cutting(&job, &ctx)?;
        let plain_plan_s = started.elapsed().as_secs_f64();
        let ctx = PlanContext { machine: &hot, ..ctx };
        let started = std::time::Instant::now();
        let planned = plan_cutting(&job, &ctx)?;
        let whole_plan_s = started.elapsed().as_secs_f64();
        let thermal_plan_s = (whole_plan_s - plain_plan_s).max(0.0);
        let t = planned.thermal.ok_or_else(|| Error::Plan("bench thermal: the cutting planner ran without the heat model".into()))?;
        drop(plain);
        let violations = |a: &crate::thermal::Assessment| a.violations.iter().map(|&c| (c, a.celsius[c])).collect::<Vec<_>>();
        for (name, checks, a, tl) in [("plain", violations(&t.plain), &t.plain, &t.plain_timeline), ("planned, before its waits", t.planned.waited.clone(), &t.planned, &t.planned_timeline)] {
            for (c, celsius) in checks {
                let ch = &tl.checks[c];
                tracing::debug!("{name}: {} of path {} at {:.0} s: {celsius:.1} °C at ({:.0}, {:.0}), waits {:.1} s", ch.feature.name(), ch.path, a.times[c], ch.places[0].x, ch.places[0].y, a.waits[ch.path]);
            }
        }
        let evaluation_s = t.evaluation_s / f64::from(t.evaluations.max(1));
        runs.push(ThermalRun {
            seed,
            geometries: job.geometries.len(),
            elements: t.planned_timeline.checks.len(),
            plain_violations: t.plain.violations.len(),
            plain_max_overheat_c: t.plain.max_overheat,
            plain_peak_c: [Feature::Pierce, Feature::Cut, Feature::Corner].map(|f| peak(&t.plain, &t.plain_timeline, f)),
            thermal_violations: t.planned.violations.len(),
            max_overheat_c: t.planned.max_overheat,
            thermal_wait_s: t.planned.wait,
            cooled_operations: t.planned.waited.len(),
            plain_time_s: t.plain_time,
            thermal_time_s: t.planned_time,
            extra_time_percent: 100.0 * (t.planned_time / t.plain_time - 1.0),
            iterations: t.iterations,
            penalties: t.penalties,
            plain_plan_s,
            thermal_plan_s,
            whole_plan_s,
            evaluations: t.evaluations,
            evaluation_s,
            cells: t.planned.grid.cells(),
            steps: t.planned.steps,
            cell_updates_per_s: t.planned.cell_updates as f64 / evaluation_s.max(1e-9),
        });
    }
    let material = machine.material.as_ref().map(|m| m.name.clone()).unwrap_or_default();
    let m = machine.material.as_ref().expect("checked above");
    Ok(ThermalBench {
        width_mm: width,
        height_mm: height,
        material,
        cell_mm: machine.thermal.cell,
        critical_c: [m.critical_pierce, m.critical_cut, m.critical_corner],
        plain_violations: median_worst(runs.iter().map(|r| r.plain_violations as f64)),
        thermal_violations: median_worst(runs.iter().map(|r| r.thermal_violations as f64)),
        extra_time_percent: median_worst(runs.iter().map(|r| r.extra_time_percent)),
        thermal_plan_s: median_worst(runs.iter().map(|r| r.thermal_plan_s)),
        whole_plan_s: median_worst(runs.iter().map(|r| r.whole_plan_s)),
        thermal_wait_s: median_worst(runs.iter().map(|r| r.thermal_wait_s)),
        evaluation_s: median_worst(runs.iter().map(|r| r.evaluation_s)),
        runs,
    })
}

fn plate_defaults() -> crate::config::PlateConfig {
    toml::from_str("width = 1.0\nheight = 1.0").expect("a plate of defaults")
}
