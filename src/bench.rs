//! `laserd bench link`: how well the sender uses the serial link. A synthetic
//! program of short 4-axis blocks (the stage drifting, the scanner circling)
//! streams into the simulator in virtual time, once with character counting
//! and once with send-response streaming as the baseline, in the same run.

pub mod fill;
pub mod thermal;
pub mod vs_grbl;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::figures::{sim_figures, RunLog};
use crate::program::{format_number, LineKind, Program, ProgramLine};
use crate::run::{run_setup, sim_config, stream_into_simulator};
use crate::stream::SenderOptions;
use crate::config::SearchKind;
use crate::plan::stop::SearchStop;

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct StreamFigures {
    pub stream_time_s: f64,
    pub job_time_s: f64,
    pub link_utilization: f64,
    pub planner_starved_s: f64,
    pub completed: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct LinkBench {
    pub blocks: usize,
    pub baud: u32,
    pub rx_buffer: usize,
    /// Duration of every block of the program.
    pub block_s: f64,
    /// Mean wire time of one line at this baud rate.
    pub line_time_s: f64,
    pub character_counting: StreamFigures,
    pub send_response: StreamFigures,
    /// Send-response stream time over character-counting stream time.
    pub speedup: f64,
}

/// The synthetic program: `blocks` G93 blocks of `block_s` seconds each, all four
/// axes moving: the stage drifting at 0.1 mm/s (slow enough that the machine
/// may stop after any block within its limits), the scanner round a 10 mm
/// circle at 200 mm/s.
pub fn link_program(machine: &MachineConfig, blocks: usize, block_s: f64) -> Result<Program> {
    let letters = machine.axis_letters();
    if letters.len() < 4 {
        return Err(Error::Config("bench link needs a machine with a scanner (four axes)".into()));
    }
    let decimals = machine.program.decimals;
    let omega = 200.0 / 10.0;
    let mut lines = vec![ProgramLine { text: "G21G90G93".into(), kind: LineKind::Setup, geometry: None, plan_time: None, checks: vec![] }];
    for k in 1..=blocks {
        let t = k as f64 * block_s;
        let values = [0.1 * t, 0.05 * t, 10.0 * (omega * t).sin(), 10.0 * (1.0 - (omega * t).cos())];
        let mut text = String::from("G1");
        for (letter, v) in letters.iter().zip(values) {
            text.push(*letter);
            text.push_str(&format_number(v, decimals));
        }
        text.push('F');
        text.push_str(&format_number(60.0 / block_s, 3));
        lines.push(ProgramLine { text, kind: LineKind::Jump, geometry: None, plan_time: Some((t - block_s, t)), checks: vec![] });
    }
    lines.push(ProgramLine { text: "G94".into(), kind: LineKind::End, geometry: None, plan_time: None, checks: vec![] });
    Ok(Program { lines, axis_letters: letters, start: vec![0.0; 4], sources: vec![] })
}

fn measure(machine: &MachineConfig, program: &Program, send_response: bool) -> Result<StreamFigures> {
    let sim = sim_config(machine, Default::default());
    let setup = run_setup(machine, &sim);
    let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    options.hold_limit = options.hold_limit_for(machine.stop_time_s());
    options.send_response = send_response;
    let (outcome, log) = stream_into_simulator(program, sim, machine.serial.baud, &options, None)?;
    let figures = sim_figures(&RunLog { setup: Some(setup), ..log });
    Ok(StreamFigures {
        stream_time_s: outcome.stream_time_s,
        job_time_s: figures.job_time_s,
        link_utilization: figures.link_utilization,
        planner_starved_s: figures.planner_starved_s,
        completed: outcome.completed,
    })
}

pub fn link_bench(machine: &MachineConfig, blocks: usize, block_s: f64) -> Result<LinkBench> {
    if blocks == 0 || !(block_s.is_finite() && block_s > 0.0) {
        return Err(Error::Config(format!("bench link: --blocks must be positive and --block-ms a positive number (got {blocks}, {block_s} s)")));
    }
    let program = link_program(machine, blocks, block_s)?;
    let bytes: usize = program.lines.iter().map(|l| l.text.len() + 1).sum();
    let baud = machine.serial.baud;
    let counting = measure(machine, &program, false)?;
    let ping_pong = measure(machine, &program, true)?;
    Ok(LinkBench {
        blocks,
        baud,
        rx_buffer: machine.serial.rx_buffer,
        block_s,
        line_time_s: bytes as f64 / program.lines.len() as f64 * 10.0 / baud as f64,
        speedup: ping_pong.stream_time_s / counting.stream_time_s,
        character_counting: counting,
        send_response: ping_pong,
    })
}

/// `bench ecp`: the cutting planner on a TSPLIB instance made
/// precedence-constrained (`gen::tsplib`), or on the plain TSP of its cities
/// (`--no-precedence`), against its known optimum.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct EcpBench {
    pub instance: String,
    /// The .tsp's EDGE_WEIGHT_TYPE: EUC_2D, CEIL_2D, ATT or GEO.
    pub edge_weight_type: String,
    /// False with `--no-precedence`: every city its own contour, no
    /// precedence at all (the plain TSP, a closed tour from the depot city).
    pub precedence: bool,
    pub elements: usize,
    pub contours: usize,
    pub precedences: usize,
    /// Of which inner/outer pairs and common cuts.
    pub inner_outer: usize,
    pub common_cuts: usize,
    pub optimum: f64,
    /// `tour`: the tour's own length, unchecked; `published`: `--optimum`
    /// or the .tsp's `OPTIMAL :` / `BEST_KNOWN :` line, which the tour's
    /// length (if a tour was given) was checked to equal.
    pub optimum_source: OptimumSource,
    /// The construction (insertion, seed 001's IB, + dir-opt) and the best route found.
    pub construction: f64,
    pub best: f64,
    pub gap: f64,
    pub time_to_best_s: f64,
    /// The cap `--time-limit` set (`null`: none, the budget alone ends the search).
    pub time_limit_s: Option<f64>,
    /// `budget` or `time-limit`: what ended the search.
    pub search_stopped_by: SearchStop,
    /// Kicks of the iterated search (or tabu iterations), over all searches.
    pub iterations: u64,
    /// `ils` (the default) or `tabu` (seed 001's, the reference).
    pub search: String,
    /// Independent searches (a fixed number) and the threads they ran on.
    pub searches: usize,
    pub threads: usize,
    /// Checked by the independent checker, not by the search.
    pub feasible: bool,
}

/// Where `bench ecp`'s optimum comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum OptimumSource {
    /// The tour's own length, not checked against a published figure.
    Tour,
    /// `--optimum` or the .tsp's OPTIMAL / BEST_KNOWN line (the tour's
    /// length, when a tour is given, checked to equal it).
    Published,
}

/// How `bench ecp` runs.
#[derive(Debug, Clone)]
pub struct EcpOptions {
    pub seed: u64,
    pub time_limit_s: Option<f64>,
    pub search: SearchKind,
    /// False: the plain TSP (`--no-precedence`).
    pub precedence: bool,
    /// A published optimal length (`--optimum`); wins over the .tsp's own.
    pub optimum: Option<u64>,
}

impl Default for EcpOptions {
    fn default() -> Self {
        EcpOptions { seed: 1, time_limit_s: None, search: SearchKind::Ils, precedence: true, optimum: None }
    }
}

pub fn ecp_bench(tsp: &std::path::Path, tour: Option<&std::path::Path>, o: &EcpOptions) -> Result<EcpBench> {
    use crate::gen::tsplib;
    use crate::plan::ecp::{checker, construct, ils, solve};
    let time_limit = positive_seconds("bench ecp", o.time_limit_s)?;
    if let Some(v) = o.optimum {
        crate::config::in_range("--optimum", v, 1, tsplib::MAX_OPTIMUM, "").map_err(Error::Config)?;
    }
    let problem = tsplib::read_tsp(tsp)?;
    let order = tour.map(|t| tsplib::read_tour(t, problem.cities.len())).transpose()?;
    let published = match (o.optimum, &problem.stated) {
        (Some(length), _) => Some(tsplib::Published { length: length as f64, given: "given with --optimum".into() }),
        (None, Some(s)) => Some(tsplib::Published { length: s.length, given: format!("of {}", s.place) }),
        (None, None) => None,
    };
    let (instance, tour_length) = match (&order, o.precedence) {
        (Some(order), true) => {
            let b = tsplib::bench_instance(&problem, order, o.seed);
            (b.instance, Some(b.optimum))
        }
        (None, true) => {
            return Err(Error::Config("bench ecp: --tour is needed unless --no-precedence (the precedences are drawn where the optimal tour keeps them)".into()));
        }
        (order, false) => {
            // The depot: the tour's first city, else the first city.
            let inst = tsplib::plain_instance(&problem, order.as_ref().map_or(0, |t| t[0]));
            let length = order.as_ref().map(|t| inst.cost(&tsplib::tour_route(t)));
            (inst, length)
        }
    };
    let (optimum, optimum_source) = match (tour_length, &published) {
        (Some(length), Some(p)) => {
            tsplib::check_tour_length(tour.expect("a tour length comes from a tour"), length, p)?;
            (p.length, OptimumSource::Published)
        }
        (Some(length), None) => (length, OptimumSource::Tour),
        (None, Some(p)) => (p.length, OptimumSource::Published),
        (None, None) => {
            return Err(Error::Config(format!(
                "bench ecp: no optimum to measure the gap against: give --tour, --optimum, or a .tsp with an OPTIMAL line ({} has none)",
                tsp.display()
            )))
        }
    };
    let inst = &instance;
    let construction = inst.cost(&construct::insertion(inst));
    // Under a time limit the time is the effort: no budget of kicks ends
    // the search first (a plan's default budget is for planning without one).
    let kicks = time_limit.map(|_| u64::MAX);
    let options = ils::SearchOptions { seed: o.seed, time_limit, kicks, threads: crate::parallel::threads()?, ..ils::SearchOptions::new() };
    let found = solve(inst, o.search, &options);
    // The checker also counts every element cut exactly once.
    let feasible = checker::check(inst, &found.route).is_empty();
    let best = inst.cost(&found.route);
    Ok(EcpBench {
        instance: problem.name,
        edge_weight_type: problem.weight.name().to_string(),
        precedence: o.precedence,
        elements: inst.elements.len(),
        contours: inst.contours.len(),
        precedences: inst.precedences(),
        inner_outer: inst.inner_outer.len(),
        common_cuts: inst.common_cuts().len(),
        optimum,
        optimum_source,
        construction,
        best,
        gap: best / optimum - 1.0,
        time_to_best_s: found.time_to_best.as_secs_f64(),
        time_limit_s: o.time_limit_s,
        search_stopped_by: found.stopped_by,
        iterations: found.iterations,
        search: o.search.name().to_string(),
        searches: options.searches,
        threads: options.threads,
        feasible,
    })
}

/// `limit` as a time limit, refused unless a positive number of seconds.
fn positive_seconds(bench: &str, limit: Option<f64>) -> Result<Option<std::time::Duration>> {
    match limit {
        None => Ok(None),
        Some(s) if s.is_finite() && s > 0.0 => Ok(Some(std::time::Duration::from_secs_f64(s))),
        Some(s) => Err(Error::Config(format!("{bench}: --time-limit must be a positive number of seconds, got {s}"))),
    }
}

/// One way of ordering a sheet's cuts, measured as the machine would cut it.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SheetOrder {
    /// Air moves between cuts (the contract's idle stroke), mm.
    pub air_mm: f64,
    /// Paths, each entered with a pierce.
    pub pierces: usize,
    /// Cuts after the part they belong to has fallen out.
    pub precedence_violations: usize,
    /// Wall-clock planning time, s (topology included).
    pub plan_time_s: f64,
}

/// `bench sheet`: a generated sheet of nested parts (issue 4), written as SVG
/// and imported as any job, ordered three ways: the nearest-neighbour
/// baseline (whole parts, nearest first), seed 001's construction alone
/// (IB + dir-opt), and the cutting planner (`ecp`).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SheetBench {
    pub seed: u64,
    pub width_mm: f64,
    pub height_mm: f64,
    pub geometries: usize,
    pub elements: usize,
    pub contours: usize,
    pub inner_outer: usize,
    pub common_cuts: usize,
    /// Pierce cost the planners weigh against air, mm.
    pub pierce_cost_mm: f64,
    /// The cap `--time-limit` set (`null`: none).
    pub time_limit_s: Option<f64>,
    /// `budget` or `time-limit`: what ended ecp's search.
    pub search_stopped_by: SearchStop,
    pub nearest: SheetOrder,
    /// Seed 001's insertion construction (IB) + dir-opt, and its contour-order one (COB) + dir-opt.
    pub construction: SheetOrder,
    pub contour_order: SheetOrder,
    pub ecp: SheetOrder,
    /// ecp air / nearest air, and ecp air / construction air.
    pub air_vs_nearest: f64,
    pub air_vs_construction: f64,
    /// Where the sheet's SVG was written, if asked.
    pub svg: Option<String>,
}

/// `bench plate`: a generated sheet with parts on the plate's edge (no
/// margin), planned (and its motion built) four ways: as if in empty space,
/// on its plate, and on its plate with skeleton, remnant and clamps, their
/// cuts in the parts' route and after the parts.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct PlateBench {
    pub seed: u64,
    pub width_mm: f64,
    pub height_mm: f64,
    pub geometries: usize,
    /// No `[plate]`: every outline cut, every cut pierced.
    pub free: PlateRun,
    /// The plate alone: outlines on its edge not cut, cuts from the edge not pierced.
    pub on_plate: PlateRun,
    /// free's cut length minus on_plate's, against what the planner says lay on the edge.
    pub cut_length_drop_mm: f64,
    /// Skeleton cut into pieces of `skeleton_piece_mm` at most, the remnant
    /// ("auto") cut off, clamps at the plate's left edge; their cuts in the route.
    pub skeleton_piece_mm: f64,
    pub scrap_in_route: PlateRun,
    /// The same cuts after the parts.
    pub scrap_after: PlateRun,
    /// scrap_in_route's machine time over scrap_after's.
    pub in_route_vs_after: f64,
}

/// One plan of `bench plate`, from its report.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct PlateRun {
    /// Paths that cut: each starts with a pierce, on the plate's edge, or
    /// where the path before it ended (cutting on without a pierce).
    pub cut_paths: usize,
    pub pierces: usize,
    /// Cuts that start on the plate's edge, without a pierce.
    pub edge_starts: usize,
    /// Cuts that go on from where the one before ended, off the edge.
    pub cut_on: usize,
    pub cut_length_mm: f64,
    pub idle_stroke_mm: f64,
    pub trajectory_time_s: f64,
    pub precedence_violations: Option<u64>,
    pub edge_length_saved_mm: Option<f64>,
    pub skeleton_cuts: Option<usize>,
    pub remnant_cuts: Option<usize>,
}

/// Writes the sheet `params` and `seed` generate as SVG, to `svg_out` or
/// else to a temporary file named after `bench` (the caller removes that),
/// so that it goes through the importer as any job would.
fn write_sheet(params: &crate::gen::sheet::SheetParams, seed: u64, bench: &str, svg_out: Option<&std::path::Path>) -> Result<std::path::PathBuf> {
    use crate::gen::sheet;
    let path = match svg_out {
        Some(p) => p.to_path_buf(),
        None => std::env::temp_dir().join(format!("laserd-{bench}-{}-{}-{seed}.svg", std::process::id(), params.target_elements)),
    };
    std::fs::write(&path, sheet::to_svg(&sheet::generate_sheet(params, seed), params)).map_err(|e| Error::Io(format!("{}: cannot write: {e}", path.display())))?;
    Ok(path)
}

/// The median and the worst (largest) of `values` (NaN for none).
fn median_worst(values: impl Iterator<Item = f64>) -> [f64; 2] {
    let mut v: Vec<f64> = values.collect();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return [f64::NAN; 2];
    }
    [v[v.len() / 2], v[v.len() - 1]]
}

pub fn plate_bench(machine: &MachineConfig, elements: usize, seed: u64, skeleton_piece: f64, svg_out: Option<&std::path::Path>) -> Result<PlateBench> {
    use crate::config::{ClampConfig, PlateConfig, RemnantSetting, ScrapCuts};
    use crate::gen::sheet;
    let params = sheet::SheetParams { margin: 0.0, ..sheet::SheetParams::with_target(elements) };
    let path = write_sheet(&params, seed, "plate", svg_out)?;
    // Round parts on the edge come in a few µm beyond it (an SVG arc read as
    // Bézier curves bulges out by 2.7e-4 of its radius): the sheet is put
    // 5 mm into a travel 10 mm larger, its parts' straight sides on the plate's edge.
    const INSET: f64 = 5.0;
    let mut base = flatbed_for(machine, params.width + 2.0 * INSET, params.height + 2.0 * INSET);
    let (lo, _) = crate::import::import_job(&path, &base)?.bounds();
    base.job.anchor = crate::config::Anchor::At(lo.x + INSET, lo.y + INSET);
    let plate = PlateConfig {
        x: INSET,
        y: INSET,
        width: params.width,
        height: params.height,
        thickness: 2.0,
        skeleton_piece: 0.0,
        remnant: RemnantSetting::None,
        remnant_min: 100.0,
        clearance: 3.0,
        scrap_cuts: ScrapCuts::InRoute,
        layer: None,
        clamps: Vec::new(),
        support_grid: None,
    };
    let scrap = PlateConfig {
        skeleton_piece,
        remnant: RemnantSetting::Auto,
        clamps: vec![ClampConfig { x: 0.0, y: 0.25 * params.height, radius: 10.0 }, ClampConfig { x: 0.0, y: 0.75 * params.height, radius: 10.0 }],
        ..plate.clone()
    };
    let run = |plate: Option<PlateConfig>| -> Result<(PlateRun, usize)> {
        let machine = MachineConfig { plate: plate.clone(), ..base.clone() };
        machine.clone().checked("bench plate")?;
        let planned = crate::run::plan(&path, &machine, crate::plan::PlannerKind::Auto, Some(crate::mode::Mode::StageOnly))?;
        let r = &planned.report;
        let cut_paths = planned.sequence.paths().filter(|p| machine.pierce(&planned.job.processes[p.process].layer).active()).count();
        let edge_starts = r.edge_starts.unwrap_or(0);
        let run = PlateRun {
            cut_paths,
            pierces: r.pierces,
            edge_starts,
            cut_on: cut_paths - r.pierces - edge_starts,
            cut_length_mm: r.cut_length_mm,
            idle_stroke_mm: r.idle_stroke_mm,
            trajectory_time_s: r.trajectory_time_s,
            precedence_violations: r.precedence_violations,
            edge_length_saved_mm: r.edge_length_saved_mm,
            skeleton_cuts: r.skeleton_cuts,
            remnant_cuts: r.remnant_cuts,
        };
        Ok((run, r.geometries))
    };
    let result = (|| {
        let (free, geometries) = run(None)?;
        let (on_plate, _) = run(Some(plate.clone()))?;
        let (scrap_in_route, _) = run(Some(scrap.clone()))?;
        let (scrap_after, _) = run(Some(PlateConfig { scrap_cuts: ScrapCuts::After, ..scrap.clone() }))?;
        Ok(PlateBench {
            seed,
            width_mm: params.width,
            height_mm: params.height,
            geometries,
            cut_length_drop_mm: free.cut_length_mm - on_plate.cut_length_mm,
            in_route_vs_after: scrap_in_route.trajectory_time_s / scrap_after.trajectory_time_s,
            skeleton_piece_mm: skeleton_piece,
            free,
            on_plate,
            scrap_in_route,
            scrap_after,
        })
    })();
    if svg_out.is_none() {
        let _ = std::fs::remove_file(&path);
    }
    result
}

/// The machine a sheet is cut on: `machine` as a flatbed cutter (no
/// scanner) whose travel covers the sheet.
pub fn flatbed_for(machine: &MachineConfig, width: f64, height: f64) -> MachineConfig {
    let mut m = machine.clone();
    m.scanner = None;
    m.stage.travel_x = m.stage.travel_x.max(width);
    m.stage.travel_y = m.stage.travel_y.max(height);
    m
}

pub fn sheet_bench(machine: &MachineConfig, elements: usize, seed: u64, time_limit_s: Option<f64>, svg_out: Option<&std::path::Path>) -> Result<SheetBench> {
    use crate::plan::cutting::{cutting_model, plan_cutting, topology, whole_geometry_violations};
    use crate::gen::sheet;
    use crate::plan::ecp::{checker, construct};
    use crate::plan::{PathGroup, PlanContext, PlannedPath, Planner, Sequence};
    positive_seconds("bench sheet", time_limit_s)?;
    if elements == 0 {
        return Err(Error::Config("bench sheet: --elements must be at least 1".into()));
    }
    let params = sheet::SheetParams::with_target(elements);
    // The sheet goes through the importer as any job would.
    let path = write_sheet(&params, seed, "sheet", svg_out)?;
    let mut machine = flatbed_for(machine, params.width, params.height);
    machine.cutting.time_limit = time_limit_s;
    let job = crate::import::import_job(&path, &machine)?;
    if svg_out.is_none() {
        let _ = std::fs::remove_file(&path);
    }
    let ctx = PlanContext { machine: &machine, mode: crate::mode::Mode::StageOnly, start: crate::run::job_start(), plate: None };
    let timed = |f: &mut dyn FnMut() -> Result<(Sequence, usize)>| -> Result<SheetOrder> {
        let started = std::time::Instant::now();
        let (sequence, precedence_violations) = f()?;
        let plan_time_s = started.elapsed().as_secs_f64();
        Ok(SheetOrder { air_mm: sequence.idle_stroke(), pierces: sequence.paths().count(), precedence_violations, plan_time_s })
    };
    let model = cutting_model(&job, ctx.start, &machine.cutting)?;
    let nearest = timed(&mut || {
        let sequence = crate::plan::nearest::NearestNeighbour.plan(&job, &ctx)?;
        let topology = topology(&job, &machine.cutting)?;
        // Every contour of the sheet is cut through, whatever the config's layers.
        let violations = whole_geometry_violations(&topology, &sequence, &vec![true; job.geometries.len()], &[]).len();
        Ok((sequence, violations))
    })?;
    let constructed = |build: fn(&crate::plan::ecp::Instance) -> Vec<crate::plan::ecp::Cut>| {
        timed(&mut || {
            let model = cutting_model(&job, ctx.start, &machine.cutting)?;
            let route = build(&model.instance);
            let paths = model
                .polylines(&route)
                .into_iter()
                .map(|l| PlannedPath::new(l.geometry, l.points, job.geometries[l.geometry].process, l.pierce))
                .collect();
            Ok((Sequence { groups: vec![PathGroup { field_center: None, paths }] }, checker::check(&model.instance, &route).len()))
        })
    };
    let contour_order = constructed(construct::contour_order_construction)?;
    let construction = constructed(construct::insertion)?;
    let mut search_stopped_by = SearchStop::Budget;
    let ecp = timed(&mut || {
        let plan = plan_cutting(&job, &ctx)?;
        search_stopped_by = plan.search_stopped_by;
        Ok((plan.sequence, plan.broken_rules.len()))
    })?;
    let inst = &model.instance;
    Ok(SheetBench {
        seed,
        width_mm: params.width,
        height_mm: params.height,
        geometries: job.geometries.len(),
        elements: inst.elements.len(),
        contours: inst.contours.len(),
        inner_outer: inst.inner_outer.len(),
        common_cuts: inst.common_cuts().len(),
        pierce_cost_mm: inst.pierce_cost,
        time_limit_s,
        search_stopped_by,
        air_vs_nearest: ecp.air_mm / nearest.air_mm,
        air_vs_construction: ecp.air_mm / construction.air_mm,
        nearest,
        construction,
        contour_order,
        ecp,
        svg: svg_out.map(|p| p.display().to_string()),
    })
}

/// One case of `bench galvo`: our figures over the seeds against the
/// reference reimplementation's.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GalvoCase {
    pub case: String,
    pub geometries: usize,
    pub scan_fields: Vec<usize>,
    pub reference_fields: f64,
    pub idle_stroke_mm: Vec<f64>,
    pub reference_idle_stroke_mm: f64,
    /// Median and worst of idle stroke / the reference's.
    pub idle_ratio_median: f64,
    pub idle_ratio_worst: f64,
    pub plan_time_s: Vec<f64>,
    pub reference_plan_time_s: f64,
    /// Median and worst of plan time / the reference's.
    pub time_ratio_median: f64,
    pub time_ratio_worst: f64,
    pub stage_reversals: Vec<usize>,
    /// `budget` unless the time limit ended a search of some seed.
    pub search_stopped_by: SearchStop,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GalvoBench {
    pub planner: String,
    pub seeds: Vec<u64>,
    pub cases: Vec<GalvoCase>,
    /// Fields over all cases (worst seed each) against the reference's means.
    pub fields_total: usize,
    pub reference_fields_total: f64,
}

/// `laserd bench galvo`: every case of `reference.json` in `dir` planned with
/// each seed on the machine's scanner with its whole field usable (the
/// benchmark's 70 × 70 mm), the planning step timed alone.
pub fn galvo_bench(machine: &MachineConfig, dir: &std::path::Path, kind: crate::plan::PlannerKind, seeds: &[u64]) -> Result<GalvoBench> {
    use crate::plan::{planner, PlanContext, PlannerKind};
    let reference_path = dir.join("reference.json");
    let text = std::fs::read_to_string(&reference_path).map_err(|e| Error::Config(format!("{}: {e}", reference_path.display())))?;
    let reference: std::collections::BTreeMap<String, serde_json::Value> =
        serde_json::from_str(&text).map_err(|e| Error::Config(format!("{}: {e}", reference_path.display())))?;
    let mut machine = machine.clone();
    let scanner = machine.scanner.as_mut().ok_or_else(|| Error::Config("bench galvo: the config has no [scanner] section".into()))?;
    scanner.usable_half_field = scanner.field_x.min(scanner.field_y) / 2.0;
    let figure = |case: &str, v: &serde_json::Value, key: &str| {
        v[key].as_f64().ok_or_else(|| Error::Config(format!("{}: {case}.{key} is missing or not a number", reference_path.display())))
    };
    let ratios = |ours: &[f64], theirs: f64| {
        let [median, worst] = median_worst(ours.iter().map(|x| x / theirs));
        (median, worst)
    };
    let mut cases = Vec::new();
    for (case, figures) in &reference {
        let job = crate::import::import_job(&dir.join(format!("{case}.svg")), &machine)?;
        let mut out = GalvoCase {
            case: case.clone(),
            geometries: job.geometries.len(),
            scan_fields: Vec::new(),
            reference_fields: figure(case, figures, "fields")?,
            idle_stroke_mm: Vec::new(),
            reference_idle_stroke_mm: figure(case, figures, "idle_stroke_mm")?,
            idle_ratio_median: 0.0,
            idle_ratio_worst: 0.0,
            plan_time_s: Vec::new(),
            reference_plan_time_s: figure(case, figures, "plan_time_s")?,
            time_ratio_median: 0.0,
            time_ratio_worst: 0.0,
            stage_reversals: Vec::new(),
            search_stopped_by: SearchStop::Budget,
        };
        for &seed in seeds {
            machine.galvo.seed = seed;
            let ctx = PlanContext { machine: &machine, mode: crate::mode::Mode::StepAndScan, start: crate::run::job_start(), plate: None };
            let started = std::time::Instant::now();
            let (sequence, stopped_by) = match kind {
                PlannerKind::Hha | PlannerKind::Hga => crate::plan::galvo::plan_galvo(&job, &ctx, kind == PlannerKind::Hga)?,
                _ => (planner(kind).plan(&job, &ctx)?, SearchStop::Budget),
            };
            out.plan_time_s.push(started.elapsed().as_secs_f64());
            out.search_stopped_by = out.search_stopped_by.and(stopped_by);
            out.idle_stroke_mm.push(sequence.idle_stroke());
            out.scan_fields.push(sequence.scan_fields().unwrap_or(0));
            out.stage_reversals.push(sequence.stage_reversals().unwrap_or(0));
        }
        (out.idle_ratio_median, out.idle_ratio_worst) = ratios(&out.idle_stroke_mm, out.reference_idle_stroke_mm);
        (out.time_ratio_median, out.time_ratio_worst) = ratios(&out.plan_time_s, out.reference_plan_time_s);
        cases.push(out);
    }
    let fields_total = cases.iter().map(|c| c.scan_fields.iter().copied().max().unwrap_or(0)).sum();
    let reference_fields_total = cases.iter().map(|c| c.reference_fields).sum();
    Ok(GalvoBench { planner: format!("{kind:?}").to_lowercase(), seeds: seeds.to_vec(), cases, fields_total, reference_fields_total })
}

/// `bench motion`: how long the trajectory, the split and the program take
/// against the machine time they produce.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct MotionBench {
    pub mode: String,
    pub repeats: usize,
    pub jobs: Vec<MotionCase>,
    /// Largest compute time per second of machine time over the jobs.
    pub worst_share: f64,
    /// Compute time of all jobs over their machine time.
    pub total_share: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct MotionCase {
    pub job: String,
    pub geometries: usize,
    pub machine_time_s: f64,
    /// Median wall-clock time of trajectory + split + program over the repeats.
    pub motion_time_s: f64,
    pub share: f64,
    pub program_lines: usize,
}

/// Plans each job once (the planner is not timed here), then builds the
/// trajectory and the program `repeats` times and keeps the median time.
pub fn motion_bench(machine: &MachineConfig, jobs: &[std::path::PathBuf], mode: Option<crate::mode::Mode>, repeats: usize) -> Result<MotionBench> {
    if jobs.is_empty() || repeats == 0 {
        return Err(Error::Config("bench motion: give at least one job and one repeat".into()));
    }
    let mode = mode.unwrap_or_else(|| crate::mode::Mode::default_for(machine));
    let mut cases = Vec::new();
    for path in jobs {
        let planned = crate::run::plan(path, machine, crate::plan::PlannerKind::Auto, Some(mode))?;
        let mut times = Vec::with_capacity(repeats);
        let mut lines = 0;
        for _ in 0..repeats {
            let started = std::time::Instant::now();
            let trajectory = crate::motion::build(&planned.job, &planned.sequence, machine, mode, crate::run::job_start())?;
            let program = crate::program::generate(&planned.job, &trajectory, machine)?;
            times.push(started.elapsed().as_secs_f64());
            lines = program.lines.len();
        }
        times.sort_by(f64::total_cmp);
        let motion_time_s = times[times.len() / 2];
        let machine_time_s = planned.trajectory.job_time();
        cases.push(MotionCase {
            job: path.display().to_string(),
            geometries: planned.job.geometries.len(),
            machine_time_s,
            motion_time_s,
            share: motion_time_s / machine_time_s.max(1e-9),
            program_lines: lines,
        });
    }
    let worst_share = cases.iter().map(|c| c.share).fold(0.0, f64::max);
    let total_share = cases.iter().map(|c| c.motion_time_s).sum::<f64>() / cases.iter().map(|c| c.machine_time_s).sum::<f64>().max(1e-9);
    Ok(MotionBench { mode: mode.as_str().to_string(), repeats, jobs: cases, worst_share, total_share })
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ImportBench {
    pub repeats: usize,
    pub jobs: Vec<ImportCase>,
    /// The process's peak resident memory after all imports (MB, from
    /// /proc/self/status VmHWM; null where it cannot be read).
    pub peak_rss_mb: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ImportCase {
    pub job: String,
    pub bytes: u64,
    pub geometries: usize,
    pub points: usize,
    /// Median wall time of one import: reading the file to the `Job`.
    pub import_time_s: f64,
}

/// Imports each job `repeats` times and keeps the median time.
pub fn import_bench(machine: &MachineConfig, jobs: &[std::path::PathBuf], repeats: usize) -> Result<ImportBench> {
    if jobs.is_empty() || repeats == 0 {
        return Err(Error::Config("bench import: give at least one job and one repeat".into()));
    }
    let mut cases = Vec::new();
    for path in jobs {
        let mut times = Vec::with_capacity(repeats);
        let mut job = None;
        for _ in 0..repeats {
            let started = std::time::Instant::now();
            job = Some(crate::import::import_job(path, machine)?);
            times.push(started.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        let job = job.expect("at least one repeat");
        cases.push(ImportCase {
            job: path.display().to_string(),
            bytes: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
            geometries: job.geometries.len(),
            points: job.geometries.iter().map(|g| g.points.len()).sum(),
            import_time_s: times[times.len() / 2],
        });
    }
    Ok(ImportBench { repeats, jobs: cases, peak_rss_mb: peak_rss_mb() })
}

/// This process's peak resident memory so far (MB).
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kb: f64 = status.lines().find_map(|l| l.strip_prefix("VmHWM:"))?.trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kb / 1024.0)
}
