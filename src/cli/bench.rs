//! `bench`: the benchmarks, each with a report (text, or JSON with --json).

use std::path::PathBuf;
use std::process::ExitCode;

use laserd::config::in_range;
use laserd::error::{Error, Result};
use laserd::mode::Mode;
use laserd::config::SearchKind;
use laserd::plan::PlannerKind;
use laserd::report::duration;
use laserd_sim::controller::MotionModel;

use super::common::{check_baud, check_time_limit, exit, machine_config, print_json};

#[derive(clap::Subcommand)]
pub enum BenchCommand {
    /// The service under load: `laserd sim --pty` and `laserd serve` as child
    /// processes, one job streamed quiet, with polling clients, and while the
    /// service plans a 1000-geometry galvo job and a 3000-element sheet.
    Serve {
        /// The job streamed (default: samples/marking-300.svg).
        #[arg(long, default_value = "samples/marking-300.svg")]
        job: PathBuf,
        /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
        /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Clients polling the status during the second run, and how often each polls (Hz).
        #[arg(long, default_value_t = 100)]
        clients: usize,
        /// How often each client polls the status (Hz, 0.1 to 1000).
        #[arg(long, default_value_t = 10.0)]
        hz: f64,
        /// Operator's screens (the web UI) open during the third run.
        #[arg(long, default_value_t = 10)]
        pages: usize,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// The cutting planner's search on a TSPLIB instance (EUC_2D, CEIL_2D,
    /// ATT or GEO) made precedence-constrained, or on its plain TSP
    /// (--no-precedence), against the instance's known optimum.
    Ecp {
        /// The TSPLIB instance (.tsp).
        #[arg(long)]
        tsp: PathBuf,
        /// Its optimal tour (.opt.tour), the yardstick; its first city is the
        /// depot. Needed unless --no-precedence (then --optimum or the .tsp's
        /// OPTIMAL line is the yardstick, and city 1 the depot).
        #[arg(long)]
        tour: Option<PathBuf>,
        /// The plain TSP: the same cities, each its own contour, no
        /// inner/outer pairs, no common cuts (to compare with TSP solvers).
        #[arg(long)]
        no_precedence: bool,
        /// The published optimal length (1 to 1e12); the tour must be exactly
        /// that long. Default: the .tsp's OPTIMAL or BEST_KNOWN line, if any.
        #[arg(long)]
        optimum: Option<u64>,
        /// Seed of the generator or search (the same seed, the same result).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// A wall-clock cap in seconds (default: none, the search's budget of work ends it).
        #[arg(long)]
        time_limit: Option<f64>,
        /// `ils` (iterated local search, the default) or `tabu` (seed 001's).
        #[arg(long, default_value = "ils")]
        search: SearchKind,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// The cutting planner on a generated sheet of nested parts (SVG through
    /// the importer), against the nearest-neighbour baseline and seed 001's
    /// construction alone.
    Sheet {
        /// Machine config; the bench cuts on it as a flatbed whose travel covers the sheet.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Elements (lines and arcs) the sheet should have (it gets up to 5 % more).
        #[arg(long, default_value_t = 3000)]
        elements: usize,
        /// Seed of the generator or search (the same seed, the same result).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// A wall-clock cap in seconds (default: none, the search's budget of work ends it).
        #[arg(long)]
        time_limit: Option<f64>,
        /// Also write the sheet here as SVG (to plan or dry-run it as a job).
        #[arg(long)]
        svg: Option<PathBuf>,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// Seed 000's thermal planning on generated sheets (by default its proof
    /// of concept's scale, about 650 elements on 2000 x 1500 mm, the
    /// config's material): the plain route's thermal violations against the
    /// thermal route's, extra machine time, constructions, planning time,
    /// and the heat model's speed; median and worst over the seeds.
    Thermal {
        /// Machine config with [material] and laser.watts.
        #[arg(long, default_value = "config/flatbed-cutter.toml")]
        config: PathBuf,
        /// Elements (lines and arcs) each sheet should have.
        #[arg(long, default_value_t = 650)]
        elements: usize,
        /// Sheet width, mm (10 to 100000).
        #[arg(long, default_value_t = 2000.0)]
        width: f64,
        /// Sheet height, mm (10 to 100000).
        #[arg(long, default_value_t = 1500.0)]
        height: f64,
        /// Seeds 1 to this.
        #[arg(long, default_value_t = 5)]
        seeds: u64,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// The plate: a generated sheet with parts on its edge, planned without and
    /// with the plate, and with skeleton and remnant cuts in the route and after
    /// the parts (cut length, pierces, machine time, precedence)
    Plate {
        /// Machine config; the bench cuts on it as a flatbed whose travel covers the sheet.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Elements (lines and arcs) the sheet should have (1 to 100000).
        #[arg(long, default_value_t = 3000)]
        elements: usize,
        /// Seed of the generator or search (the same seed, the same result).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The largest side of a skeleton piece, mm.
        #[arg(long, default_value_t = 500.0)]
        skeleton_piece: f64,
        /// Also write the sheet here as SVG (to plan or dry-run it on a plate).
        #[arg(long)]
        svg: Option<PathBuf>,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// Seed 004's Table 1: the area of a job's fill layer as the seed's grid,
    /// ordered by its genetic search under each objective (path length,
    /// turns, machine time, heat, convergence; median and worst over seeds).
    Fill {
        /// Machine config (default: the XY engraver, config/xy-engraver.toml,
        /// whose layers fill).
        #[arg(long, default_value = "config/xy-engraver.toml")]
        config: PathBuf,
        /// The part (its fill layer's area).
        #[arg(long, default_value = "samples/fishhead.svg")]
        job: PathBuf,
        /// Grid spacing (mm).
        #[arg(long, default_value_t = 2.0)]
        spacing: f64,
        /// Tool (spot) radius the boundary is offset by (mm).
        #[arg(long, default_value_t = 1.0)]
        radius: f64,
        /// Objectives, comma-separated (each as --objective takes it).
        #[arg(long, default_value = "length,time,turns,heat,time+0.2*turns")]
        objectives: String,
        /// Seeds 1 to this.
        #[arg(long, default_value_t = 5)]
        seeds: u64,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// The galvo planners on the 12 cases of seed 003's families against the
    /// reference reimplementation's figures (`reference.json` in the folder).
    Galvo {
        /// Machine config; its scanner's whole field is used (the benchmark's 70 x 70 mm).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Folder with the cases' SVGs and reference.json.
        #[arg(long, default_value = "tests/data/galvo")]
        dir: PathBuf,
        /// The galvo planner to run.
        #[arg(long, default_value = "hha")]
        planner: PlannerKind,
        /// Planner seeds 1 to this.
        #[arg(long, default_value_t = 5)]
        seeds: u64,
        /// A wall-clock cap per run (default: the config's [galvo] time_limit, none unless set).
        #[arg(long)]
        time_limit: Option<f64>,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// Compute time of the trajectory, the split and the program against the
    /// machine time they produce (planning excluded).
    Motion {
        /// Job files (SVG).
        jobs: Vec<PathBuf>,
        /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
        /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
        #[arg(long)]
        config: Option<PathBuf>,
        /// How stage and scanner share the work (default: on-the-fly with a scanner, else stage-only).
        #[arg(long)]
        mode: Option<Mode>,
        /// Runs per job; the median counts.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Instead: each job's simulated time as laserd plans it (timed
        /// controller) against the same path as plain G1 F moves on Grbl's
        /// planner (--motion grbl, $11 = [motion] corner_tolerance), and
        /// their ratio.
        #[arg(long)]
        vs_grbl: bool,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// Import alone: each job file read into a `Job` (median of the runs), and
    /// the process's peak memory.
    Import {
        /// Job files (SVG or DXF).
        jobs: Vec<PathBuf>,
        /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
        /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Runs per job; the median counts.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
    /// How well the sender uses the serial link: character counting against
    /// send-response streaming, on a synthetic program of short 4-axis blocks.
    Link {
        /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
        /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Blocks in the synthetic program (1 to 1000000).
        #[arg(long, default_value_t = 20_000)]
        blocks: usize,
        /// Duration of each block in milliseconds.
        #[arg(long, default_value_t = 1.0)]
        block_ms: f64,
        /// How the simulated controller executes blocks (default: the config's).
        #[arg(long)]
        motion: Option<MotionModel>,
        /// Link speed (default: 115200, the classic GRBL serial link).
        #[arg(long, default_value_t = 115_200)]
        baud: u32,
        /// Print the report as JSON (for scripts) instead of a summary for people.
        #[arg(long)]
        json: bool,
    },
}

/// Every numeric flag within its range (the config's, where the flag stands
/// for a setting), before anything runs.
fn check_flags(command: &BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Serve { clients, hz, pages, .. } => in_range("--clients", *clients, 1, 10_000, "clients").and(in_range("--hz", *hz, 0.1, 1000.0, "Hz")).and(in_range("--pages", *pages, 1, 1000, "pages")),
        BenchCommand::Ecp { time_limit: t, optimum, .. } => {
            check_time_limit(*t).and(optimum.map_or(Ok(()), |v| in_range("--optimum", v, 1, laserd::gen::tsplib::MAX_OPTIMUM, "")))
        }
        BenchCommand::Sheet { elements, time_limit: t, .. } => in_range("--elements", *elements, 1, 100_000, "elements").and(check_time_limit(*t)),
        BenchCommand::Plate { elements, skeleton_piece, .. } => {
            in_range("--elements", *elements, 1, 100_000, "elements").and(in_range("--skeleton-piece", *skeleton_piece, 10.0, 100_000.0, "mm"))
        }
        BenchCommand::Galvo { seeds, time_limit: t, .. } => in_range("--seeds", *seeds, 1, 1000, "seeds").and(check_time_limit(*t)),
        BenchCommand::Thermal { elements, width, height, seeds, .. } => in_range("--elements", *elements, 1, 100_000, "elements")
            .and(in_range("--width", *width, 10.0, 100_000.0, "mm"))
            .and(in_range("--height", *height, 10.0, 100_000.0, "mm"))
            .and(in_range("--seeds", *seeds, 1, 1000, "seeds")),
        BenchCommand::Fill { seeds, spacing, radius, .. } => in_range("--seeds", *seeds, 1, 1000, "seeds")
            .and(in_range("--spacing", *spacing, 0.01, 100.0, "mm"))
            .and(in_range("--radius", *radius, 0.0, 100.0, "mm")),
        BenchCommand::Motion { repeats, .. } | BenchCommand::Import { repeats, .. } => in_range("--repeats", *repeats, 1, 1000, "runs"),
        BenchCommand::Link { blocks, block_ms, baud: b, .. } => in_range("--blocks", *blocks, 1, 1_000_000, "blocks")
            .and(in_range("--block-ms", *block_ms, 0.01, 1000.0, "ms"))
            .and(check_baud(Some(*b))),
    }
    .map_err(Error::Config)
}

pub fn run(command: BenchCommand) -> Result<ExitCode> {
    check_flags(&command)?;
    match command {
        BenchCommand::Ecp { tsp, tour, no_precedence, optimum, seed, time_limit, search, json } => {
            let options = laserd::bench::EcpOptions { seed, time_limit_s: time_limit, search, precedence: !no_precedence, optimum };
            ecp_bench(tsp, tour, options, json)
        }
        BenchCommand::Sheet { config, elements, seed, time_limit, svg, json } => sheet_bench(config, elements, seed, time_limit, svg, json),
        BenchCommand::Thermal { config, elements, width, height, seeds, json } => thermal_bench(config, elements, width, height, seeds, json),
        BenchCommand::Plate { config, elements, seed, skeleton_piece, svg, json } => plate_bench(config, elements, seed, skeleton_piece, svg, json),
        BenchCommand::Serve { job, config, clients, hz, pages, json } => serve_bench(job, config, clients, hz, pages, json),
        BenchCommand::Motion { jobs, config, mode, vs_grbl: true, json, .. } => vs_grbl_bench(jobs, config, mode, json),
        BenchCommand::Motion { jobs, config, mode, repeats, json, .. } => motion_bench(jobs, config, mode, repeats, json),
        BenchCommand::Import { jobs, config, repeats, json } => import_bench(jobs, config, repeats, json),
        BenchCommand::Galvo { config, dir, planner, seeds, time_limit, json } => galvo_bench(config, dir, planner, seeds, time_limit, json),
        BenchCommand::Fill { config, job, spacing, radius, objectives, seeds, json } => fill_bench(config, job, spacing, radius, objectives, seeds, json),
        BenchCommand::Link { config, blocks, block_ms, motion, baud, json } => link_bench(config, blocks, block_ms, motion, baud, json),
    }
}

fn ecp_bench(tsp: PathBuf, tour: Option<PathBuf>, options: laserd::bench::EcpOptions, json: bool) -> Result<ExitCode> {
    use laserd::bench::OptimumSource;
    let report = laserd::bench::ecp_bench(&tsp, tour.as_deref(), &options)?;
    if json {
        print_json(&report)?;
    } else {
        let rules = if report.precedence {
            format!("{} elements, {} contours, {} precedences ({} inner/outer, {} common cuts)", report.elements, report.contours, report.precedences, report.inner_outer, report.common_cuts)
        } else {
            format!("plain TSP of {} cities, no precedences", report.elements)
        };
        let source = match (report.optimum_source, &tour) {
            (OptimumSource::Published, Some(t)) => format!("published, checked: {} is that long", t.display()),
            (OptimumSource::Published, None) => "published, no tour to check it with".to_string(),
            (OptimumSource::Tour, _) => "the tour's own length, not checked: give --optimum".to_string(),
        };
        println!(
            "{} ({}): {rules}; optimum {} ({source}), construction {}, best {} (gap {:.2} %) after {}, search stopped by {}, {} iterations ({}, {} searches on {} threads), feasible: {}",
            report.instance, report.edge_weight_type, report.optimum, report.construction, report.best, report.gap * 100.0, duration(report.time_to_best_s), report.search_stopped_by.as_str(), report.iterations, report.search, report.searches, report.threads, report.feasible
        );
    }
    Ok(if report.feasible { ExitCode::SUCCESS } else { ExitCode::from(exit::STOPPED) })
}

fn sheet_bench(config: Option<PathBuf>, elements: usize, seed: u64, time_limit: Option<f64>, svg: Option<PathBuf>, json: bool) -> Result<ExitCode> {
    let machine = machine_config(config.as_deref(), json)?.machine;
    let r = laserd::bench::sheet_bench(&machine, elements, seed, time_limit, svg.as_deref())?;
    if json {
        print_json(&r)?;
    } else {
        println!(
            "sheet {} x {} mm, seed {}: {} geometries, {} elements, {} contours, {} inner/outer, {} common cuts; pierce cost {} mm",
            r.width_mm, r.height_mm, r.seed, r.geometries, r.elements, r.contours, r.inner_outer, r.common_cuts, r.pierce_cost_mm
        );
        for (name, o) in [("nearest", &r.nearest), ("IB + dir-opt", &r.construction), ("COB + dir-opt", &r.contour_order), ("ecp", &r.ecp)] {
            println!(
                "  {name:<13} air {:>10.1} mm, {:>5} pierces, {:>4} precedence violations, planned in {}",
                o.air_mm, o.pierces, o.precedence_violations, duration(o.plan_time_s)
            );
        }
        println!("  ecp air / nearest {:.3}, / IB + dir-opt {:.3}", r.air_vs_nearest, r.air_vs_construction);
    }
    Ok(if r.ecp.precedence_violations == 0 { ExitCode::SUCCESS } else { ExitCode::from(exit::STOPPED) })
}

fn thermal_bench(config: PathBuf, elements: usize, width: f64, height: f64, seeds: u64, json: bool) -> Result<ExitCode> {
    let machine = machine_config(Some(&config), json)?.machine;
    let r = laserd::bench::thermal::thermal_bench(&machine, elements, width, height, seeds)?;
    if json {
        print_json(&r)?;
    } else {
        println!(
            "thermal: {} x {} mm of {}, {} mm cells, critical pierce/cut/corner {:?} °C",
            r.width_mm, r.height_mm, r.material, r.cell_mm, r.critical_c
        );
        for o in &r.runs {
            println!(
                "  seed {}: {} geometries; plain peaks pierce/cut/corner {:.0?} °C; violations plain {} (max {:.1} °C) -> thermal {} (max {:.1} °C; cooling waits {} before {} operations); machine time {} -> {} ({:+.2} %); {} constructions; planning {} ({} after its plain search; the plain search alone {}); evaluation {} ({} cells, {} steps, {:.0} M cell updates/s)",
                o.seed, o.geometries, o.plain_peak_c, o.plain_violations, o.plain_max_overheat_c, o.thermal_violations, o.max_overheat_c, duration(o.thermal_wait_s), o.cooled_operations, duration(o.plain_time_s), duration(o.thermal_time_s), o.extra_time_percent, o.iterations, duration(o.whole_plan_s), duration(o.thermal_plan_s), duration(o.plain_plan_s), duration(o.evaluation_s), o.cells, o.steps, o.cell_updates_per_s / 1e6
            );
        }
        println!(
            "  median / worst: plain violations {} / {}, thermal {} / {}, cooling waits {} / {}, extra time {:+.2} / {:+.2} %, planning {} / {}, evaluation {} / {}",
            r.plain_violations[0], r.plain_violations[1], r.thermal_violations[0], r.thermal_violations[1], duration(r.thermal_wait_s[0]), duration(r.thermal_wait_s[1]), r.extra_time_percent[0], r.extra_time_percent[1], duration(r.whole_plan_s[0]), duration(r.whole_plan_s[1]), duration(r.evaluation_s[0]), duration(r.evaluation_s[1])
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn plate_bench(config: Option<PathBuf>, elements: usize, seed: u64, skeleton_piece: f64, svg: Option<PathBuf>, json: bool) -> Result<ExitCode> {
    let machine = machine_config(config.as_deref(), json)?.machine;
    let r = laserd::bench::plate_bench(&machine, elements, seed, skeleton_piece, svg.as_deref())?;
    if json {
        print_json(&r)?;
    } else {
        println!("plate {} x {} mm, seed {}: {} geometries, parts on the plate's edge", r.width_mm, r.height_mm, r.seed, r.geometries);
        for (name, o) in [("free", &r.free), ("on plate", &r.on_plate), ("scrap in route", &r.scrap_in_route), ("scrap after", &r.scrap_after)] {
            let violations = o.precedence_violations.map_or("unknown".to_string(), |v| v.to_string());
            println!(
                "  {name:<14} cut {:>10.3} mm in {:>5} paths: {:>5} pierces, {:>4} edge starts, {:>4} cut on, air {:>9.1} mm, {:>3} skeleton + {} remnant cuts, {} machine time, {violations} precedence violations",
                o.cut_length_mm, o.cut_paths, o.pierces, o.edge_starts, o.cut_on, o.idle_stroke_mm, o.skeleton_cuts.unwrap_or(0), o.remnant_cuts.unwrap_or(0), duration(o.trajectory_time_s)
            );
        }
        println!(
            "  cut length drop {:.6} mm, edge length not cut {:.6} mm; scrap in route / after: {:.4} of the machine time",
            r.cut_length_drop_mm,
            r.on_plate.edge_length_saved_mm.unwrap_or(0.0),
            r.in_route_vs_after
        );
    }
    let broken = [&r.on_plate, &r.scrap_in_route, &r.scrap_after].iter().any(|o| o.precedence_violations != Some(0));
    Ok(if broken { ExitCode::from(exit::STOPPED) } else { ExitCode::SUCCESS })
}

fn serve_bench(job: PathBuf, config: Option<PathBuf>, clients: usize, hz: f64, pages: usize, json: bool) -> Result<ExitCode> {
    let found = machine_config(config.as_deref(), json)?;
    let r = laserd::daemon::bench::serve_bench(&found.machine, &found.text, &job, clients, hz, pages)?;
    if json {
        print_json(&r)?;
    } else {
        println!("laserd serve, job {}", r.job);
        for run in &r.runs {
            println!(
                "  {:<9} link utilization {:.4}  streamed {}  status at 10 Hz: {} answers, interval jitter p50 {:.2} ms p99 {:.2} ms max {:.2} ms  controller `?`: {} (jitter p99 {:.2} ms, {} found it starved)  load clients' answers {}",
                run.name,
                run.link_utilization,
                duration(run.stream_time_s),
                run.api_polls,
                run.api_poll_jitter_p50_ms,
                run.api_poll_jitter_p99_ms,
                run.api_poll_jitter_max_ms,
                run.controller_polls,
                run.controller_poll_jitter_p99_ms,
                run.starved_reports,
                run.api_requests
            );
        }
        println!("  utilization with {} clients at {} Hz / quiet: {:.4}", r.clients, r.client_hz, r.utilization_ratio_polling);
        println!("  utilization with {} operator's screens open / quiet: {:.4}", r.pages, r.utilization_ratio_pages);
        println!("  utilization while planning (done in {}) / quiet: {:.4}", duration(r.planning_s), r.utilization_ratio_planning);
    }
    Ok(ExitCode::SUCCESS)
}

fn motion_bench(jobs: Vec<PathBuf>, config: Option<PathBuf>, mode: Option<Mode>, repeats: usize, json: bool) -> Result<ExitCode> {
    let machine = machine_config(config.as_deref(), json)?.machine;
    let r = laserd::bench::motion_bench(&machine, &jobs, mode, repeats)?;
    if json {
        print_json(&r)?;
    } else {
        println!("trajectory + split + program, {} mode, median of {} runs", r.mode, r.repeats);
        for c in &r.jobs {
            println!(
                "  {:<40} {:>5} geometries  machine {:>14}  computed in {:>9}  ({:.3} %)",
                c.job,
                c.geometries,
                duration(c.machine_time_s),
                duration(c.motion_time_s),
                c.share * 100.0
            );
        }
        println!("  worst {:.3} %, all jobs {:.3} % of their machine time", r.worst_share * 100.0, r.total_share * 100.0);
    }
    Ok(ExitCode::SUCCESS)
}

fn import_bench(jobs: Vec<PathBuf>, config: Option<PathBuf>, repeats: usize, json: bool) -> Result<ExitCode> {
    let machine = machine_config(config.as_deref(), json)?.machine;
    let r = laserd::bench::import_bench(&machine, &jobs, repeats)?;
    if json {
        print_json(&r)?;
    } else {
        println!("import alone, median of {} runs", r.repeats);
        for c in &r.jobs {
            println!("  {:<40} {:>10} bytes  {:>7} geometries  {:>9} points  {:>9}", c.job, c.bytes, c.geometries, c.points, duration(c.import_time_s));
        }
        if let Some(mb) = r.peak_rss_mb {
            println!("  peak memory of the process {mb:.0} MB");
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn vs_grbl_bench(jobs: Vec<PathBuf>, config: Option<PathBuf>, mode: Option<Mode>, json: bool) -> Result<ExitCode> {
    let machine = machine_config(config.as_deref(), json)?.machine;
    let r = laserd::bench::vs_grbl::vs_grbl(&machine, &jobs, mode)?;
    if json {
        print_json(&r)?;
    } else {
        println!("laserd (timed controller) against the same path as plain G1 F moves on Grbl's planner ($11 = {} mm), {} mode", r.junction_deviation_mm, r.mode);
        for c in &r.jobs {
            println!(
                "  {:<40} laserd {:>14}  grbl {:>14}  ratio {:.3}  bound {:>14} (laserd {:.2} x)",
                c.job, duration(c.laserd_job_time_s), duration(c.grbl_job_time_s), c.ratio, duration(c.lower_bound_s), c.laserd_vs_bound
            );
            let grbl = if c.grbl_limits_broken.is_empty() { "none".to_string() } else { c.grbl_limits_broken.join("; ") };
            println!("    limits broken: laserd {}, grbl {grbl}", c.laserd_limit_breaches);
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn galvo_bench(config: Option<PathBuf>, dir: PathBuf, planner: PlannerKind, seeds: u64, time_limit: Option<f64>, json: bool) -> Result<ExitCode> {
    let mut machine = machine_config(config.as_deref(), json)?.machine;
    if let Some(t) = time_limit {
        machine.galvo.time_limit = Some(t);
    }
    let seeds: Vec<u64> = (1..=seeds).collect();
    let r = laserd::bench::galvo_bench(&machine, &dir, planner, &seeds)?;
    if json {
        print_json(&r)?;
    } else {
        println!("{} on {} cases, seeds 1-{}: idle stroke and plan time against the reference (median / worst)", r.planner, r.cases.len(), seeds.len());
        for c in &r.cases {
            println!(
                "  {:<10} {:>5} geometries  fields {:>3} (ref {:>5.1})  idle {:.3} / {:.3}  time {:.3} / {:.3}  stage reversals {}",
                c.case,
                c.geometries,
                c.scan_fields.iter().max().unwrap_or(&0),
                c.reference_fields,
                c.idle_ratio_median,
                c.idle_ratio_worst,
                c.time_ratio_median,
                c.time_ratio_worst,
                c.stage_reversals.iter().max().unwrap_or(&0)
            );
        }
        println!("  fields in all {} against the reference's {:.1} ({:.3})", r.fields_total, r.reference_fields_total, r.fields_total as f64 / r.reference_fields_total);
    }
    Ok(ExitCode::SUCCESS)
}

fn fill_bench(config: PathBuf, job: PathBuf, spacing: f64, radius: f64, objectives: String, seeds: u64, json: bool) -> Result<ExitCode> {
    let machine = machine_config(Some(&config), json)?.machine;
    let objectives: Vec<String> = objectives.split(',').map(|o| o.trim().to_string()).collect();
    let seeds: Vec<u64> = (1..=seeds).collect();
    let r = laserd::bench::fill::fill_bench(&machine, &job, spacing, radius, &objectives, &seeds)?;
    if json {
        print_json(&r)?;
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{}: {} grid points {} mm apart, {} mm inside; at {} mm/s; lower bounds {:.0} mm, {} turns, {} (median / worst of seeds 1-{})",
        r.job, r.points, r.spacing_mm, r.radius_mm, r.speed_mm_s, r.length_lower_bound_mm, r.turns_lower_bound, duration(r.time_lower_bound_s), seeds.len()
    );
    let median_worst = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[v.len() - 1])
    };
    for o in &r.objectives {
        let figure = |f: &dyn Fn(&laserd::bench::fill::FillRun) -> f64| median_worst(o.runs.iter().map(f).collect());
        let (length, length_w) = figure(&|run| run.length_mm);
        let (turns, turns_w) = figure(&|run| run.turns as f64);
        let (detour, detour_w) = figure(&|run| run.detour_mm);
        let (time, time_w) = figure(&|run| run.time_s);
        let (heat, heat_w) = figure(&|run| run.heat);
        let (conv, conv_w) = figure(&|run| run.converged_s);
        println!(
            "  {:<16} length {length:.0} / {length_w:.0} mm  turns {turns:.0} / {turns_w:.0} (Eq. 10 {detour:.0} / {detour_w:.0} mm)  time {} / {}  heat {heat:.1} / {heat_w:.1}  converged in {} / {}",
            o.objective,
            duration(time),
            duration(time_w),
            duration(conv),
            duration(conv_w)
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn link_bench(config: Option<PathBuf>, blocks: usize, block_ms: f64, motion: Option<MotionModel>, baud: u32, json: bool) -> Result<ExitCode> {
    let mut machine = machine_config(config.as_deref(), json)?.machine;
    machine.serial.baud = baud;
    machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
    let report = laserd::bench::link_bench(&machine, blocks, block_ms / 1000.0)?;
    if json {
        print_json(&report)?;
    } else {
        let show = |name: &str, f: &laserd::bench::StreamFigures| {
            println!(
                "  {name:<18} stream {:>12}, link {:>5.1} %, planner starved {}",
                duration(f.stream_time_s),
                f.link_utilization * 100.0,
                duration(f.planner_starved_s)
            )
        };
        println!(
            "{} blocks of {:.3} ms, line time {:.3} ms at {} baud, {}-byte receive buffer:",
            report.blocks,
            report.block_s * 1000.0,
            report.line_time_s * 1000.0,
            report.baud,
            report.rx_buffer
        );
        show("character counting", &report.character_counting);
        show("send-response", &report.send_response);
        println!("  character counting is {:.2}x faster", report.speedup);
    }
    Ok(ExitCode::SUCCESS)
}
