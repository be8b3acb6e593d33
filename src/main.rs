//! The `laserd` command line (see the contract in ARCHITECTURE.md).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use clap::{Parser, Subcommand};
use laserd::config::{in_range, ConfigSearch, ConfigSource, FoundConfig, MachineConfig, BAUD, TIME_LIMIT, TRAVEL};
use laserd::error::{Error, Result};
use laserd::figures::sim_figures;
use laserd::motion::Mode;
use laserd::plan::PlannerKind;
use laserd::record::{self, Recording, TOPIC_SETUP};
use laserd::run;
use laserd::stream::{self, SenderOptions};
use laserd::stream::LinkEvent;
use laserd_sim::controller::{Controller, Faults};
use laserd_sim::pty::Observed;
use laserd_sim::controller::{Flavor, MotionModel};
use laserd_sim::wire::realtime;

#[derive(Parser)]
#[command(name = "laserd", version, about = "Laser machine controller: plan, simulate, stream, record")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// What `plan` and `dry-run` share: the job and how to plan it.
#[derive(clap::Args)]
struct JobArgs {
    job: PathBuf,
    /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
    /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
    #[arg(long)]
    config: Option<PathBuf>,
    /// auto (the default): the cutting planner ecp for layers that pierce,
    /// the galvo planner hha for marking layers, marking first; or one of
    /// ecp, hha, hga, nearest for the whole job.
    #[arg(long, default_value = "auto")]
    planner: PlannerKind,
    /// Plan, write and run an order that cuts after a part has fallen out
    /// (refused otherwise).
    #[arg(long)]
    allow_precedence_violations: bool,
    /// on-the-fly, step-and-scan or stage-only (default: on-the-fly with a scanner, else stage-only).
    #[arg(long)]
    mode: Option<Mode>,
    /// A wall-clock cap in seconds on the searches of ecp, hha and hga
    /// (default: the config's [cutting] or [galvo] time_limit, none unless
    /// set). Without one the searches end on their budgets of work and the
    /// plan is the same whatever the load; a cap that ends one first may
    /// change it (the report says search_stopped_by: time-limit).
    #[arg(long)]
    time_limit: Option<f64>,
    /// Seed of the galvo planners' random choices (default: the config's [galvo] seed).
    #[arg(long)]
    seed: Option<u64>,
}

impl JobArgs {
    fn plan(&self) -> Result<(MachineConfig, run::Planned)> {
        // The report says where the config came from (no line on stderr: an
        // error later stays the one line of the error contract).
        let FoundConfig { mut machine, source, .. } = ConfigSearch::new(self.config.as_deref()).find()?;
        if let Some(t) = self.time_limit {
            machine.cutting.time_limit = Some(t);
            machine.galvo.time_limit = Some(t);
        }
        if let Some(seed) = self.seed {
            machine.galvo.seed = seed;
        }
        let mut planned = run::plan(&self.job, &machine, self.planner, self.mode)?;
        planned.report.config = Some(source);
        Ok((machine, planned))
    }
}

#[derive(Subcommand)]
enum Command {
    /// Plan a job, stream it into the built-in simulator (virtual time) and report.
    DryRun {
        #[command(flatten)]
        job: JobArgs,
        /// MCAP recording of the run (default: <job stem>.mcap here).
        #[arg(long)]
        record: Option<PathBuf>,
        /// How the simulated controller executes blocks (default: the config's
        /// [simulator] motion): timed, or grbl (Grbl 1.1's planner).
        #[arg(long)]
        motion: Option<MotionModel>,
        #[arg(long)]
        json: bool,
    },
    /// Plan a job only: report, and write the G-code program with -o.
    Plan {
        #[command(flatten)]
        job: JobArgs,
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
        /// Draw the plan as SVG: geometries, scan fields, TCP path (marking and
        /// jumps), stage path, and the scanner's field use over time.
        #[arg(long)]
        plot: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Stream an existing G-code file to a controller.
    Send {
        file: PathBuf,
        #[arg(long)]
        port: String,
        #[arg(long)]
        baud: Option<u32>,
        #[arg(long)]
        config: Option<PathBuf>,
        /// Validate only, in the controller's check mode ($C): nothing moves,
        /// every rejected line is reported.
        #[arg(long)]
        check: bool,
        #[arg(long)]
        json: bool,
    },
    /// Run the simulated controller as a GRBL device on a pseudo-terminal.
    Sim {
        #[arg(long)]
        config: Option<PathBuf>,
        /// Serve on a pseudo-terminal (the default, and the only transport in this version).
        #[arg(long)]
        pty: bool,
        /// Stable symlink to the pseudo-terminal device.
        #[arg(long)]
        link: Option<PathBuf>,
        #[arg(long)]
        baud: Option<u32>,
        /// Run in real time (always so on a pseudo-terminal).
        #[arg(long)]
        realtime: bool,
        /// Record the executed motion to this MCAP file.
        #[arg(long)]
        record: Option<PathBuf>,
        /// How the simulated controller executes blocks (default: the config's
        /// [simulator] motion): timed, or grbl (Grbl 1.1's planner).
        #[arg(long)]
        motion: Option<MotionModel>,
        /// The firmware it answers as (default: the config's [simulator]
        /// flavor): grbl (Grbl 1.1h, axes X Y Z only) or grblhal. For
        /// grblhal also set [serial] rx_buffer and [simulator]
        /// planner_blocks to the board's (1024, 100).
        #[arg(long)]
        flavor: Option<Flavor>,
        /// Inject a fault, e.g. `--fault error-on-line=40`; repeatable. Faults:
        /// error-on-line, drop-byte, corrupt-byte, mute-from-line, reset-at-line,
        /// limit-alarm-at-line, close-link-at-line (=N: lines and bytes count
        /// from 1), probe-contact-mm=D (the probe touches D mm into a G38 move),
        /// homing-switch-missing, homing-pull-off-fails.
        #[arg(long = "fault", value_name = "NAME=N")]
        faults: Vec<String>,
    },
    /// Benchmarks with a report.
    Bench {
        #[command(subcommand)]
        which: BenchCommand,
    },
    /// Generate benchmark instances.
    Gen {
        #[command(subcommand)]
        which: GenCommand,
    },
    /// The service: control API on a Unix socket, persistent job queue, the
    /// controller link (run it under systemd: systemd/laserd.service).
    Serve {
        /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
        /// else ~/.config/laserd/laserd.toml; never the built-in example machine).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Queue and recordings (default: $STATE_DIRECTORY, else /var/lib/laserd).
        #[arg(long)]
        state_dir: Option<PathBuf>,
        /// The API's socket (default: [service] socket under $RUNTIME_DIRECTORY, else /run/laserd).
        #[arg(long)]
        socket: Option<PathBuf>,
    },
    /// The service's planning of one job, in a process of its own (the
    /// service starts it; the config comes on standard input).
    #[command(hide = true)]
    PlanJob {
        source: PathBuf,
        #[arg(long)]
        name: String,
        #[arg(long)]
        program: PathBuf,
        #[arg(long)]
        result: PathBuf,
        #[arg(long)]
        allow_precedence_violations: bool,
    },
    /// Talk to a running `laserd serve` (docs/api.md lists the calls).
    Ctl {
        /// The service's socket (default: /run/laserd/laserd.sock).
        #[arg(long, default_value = "/run/laserd/laserd.sock")]
        socket: PathBuf,
        #[command(subcommand)]
        which: laserd::daemon::ctl::CtlCommand,
    },
    /// Re-derive a recording's figures from the file alone.
    Replay {
        recording: PathBuf,
        /// Re-stream the recorded program into a fresh simulator and compare.
        #[arg(long)]
        to_sim: bool,
        /// Machine config for --to-sim (default: the shipped one; the recording's
        /// axes and baud rate are used either way).
        #[arg(long)]
        config: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The service under load: `laserd sim --pty` and `laserd serve` as child
    /// processes, one job streamed quiet, with polling clients, and while the
    /// service plans a 1000-geometry galvo job and a 3000-element sheet.
    Serve {
        /// The job streamed (default: samples/marking-300.svg).
        #[arg(long, default_value = "samples/marking-300.svg")]
        job: PathBuf,
        #[arg(long)]
        config: Option<PathBuf>,
        /// Clients polling the status during the second run, and how often each polls (Hz).
        #[arg(long, default_value_t = 100)]
        clients: usize,
        #[arg(long, default_value_t = 10.0)]
        hz: f64,
        #[arg(long)]
        json: bool,
    },
    /// The cutting planner's search on a TSPLIB instance made
    /// precedence-constrained, against the instance's known optimum.
    Ecp {
        #[arg(long)]
        tsp: PathBuf,
        #[arg(long)]
        tour: PathBuf,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// A wall-clock cap in seconds (default: none, the search's budget of work ends it).
        #[arg(long)]
        time_limit: Option<f64>,
        /// `ils` (iterated local search, the default) or `tabu` (seed 001's).
        #[arg(long, default_value = "ils")]
        search: laserd::plan::ecp::SearchKind,
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
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// A wall-clock cap in seconds (default: none, the search's budget of work ends it).
        #[arg(long)]
        time_limit: Option<f64>,
        /// Also write the sheet here as SVG (to plan or dry-run it as a job).
        #[arg(long)]
        svg: Option<PathBuf>,
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
        #[arg(long, default_value = "hha")]
        planner: PlannerKind,
        /// Planner seeds 1 to this.
        #[arg(long, default_value_t = 5)]
        seeds: u64,
        /// A wall-clock cap per run (default: the config's [galvo] time_limit, none unless set).
        #[arg(long)]
        time_limit: Option<f64>,
        #[arg(long)]
        json: bool,
    },
    /// Compute time of the trajectory, the split and the program against the
    /// machine time they produce (planning excluded).
    Motion {
        /// Job files (SVG).
        jobs: Vec<PathBuf>,
        #[arg(long)]
        config: Option<PathBuf>,
        #[arg(long)]
        mode: Option<Mode>,
        /// Runs per job; the median counts.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        #[arg(long)]
        json: bool,
    },
    /// How well the sender uses the serial link: character counting against
    /// send-response streaming, on a synthetic program of short 4-axis blocks.
    Link {
        #[arg(long)]
        config: Option<PathBuf>,
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
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum GenCommand {
    /// A galvo planning job of one of seed 003's pattern families, as SVG
    /// (300 x 300 mm base, every geometry within a 70 x 70 mm field).
    Galvo {
        /// rnd (scattered rectangles), o (rings of squares), isw (the
        /// letters I, S, W of squares) or mixed (rectangles, circles,
        /// ellipses, polylines, polygons, paths).
        #[arg(long)]
        family: laserd::gen::galvo::Family,
        /// Number of geometries (1 to 5000).
        #[arg(long)]
        n: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output file (default: standard output).
        #[arg(short = 'o', long = "output")]
        output: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The service logs what an operator looks for in the journal (links,
    // jobs); the one-shot commands only warnings. LASERD_LOG overrides.
    let level = if matches!(cli.command, Command::Serve { .. }) { "info" } else { "warn" };
    let filter = tracing_subscriber::EnvFilter::try_from_env("LASERD_LOG").unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let logs = tracing_subscriber::fmt().with_writer(std::io::stderr).with_env_filter(filter).with_ansi(std::io::stderr().is_terminal());
    // journald stamps each line itself.
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        logs.without_time().init();
    } else {
        logs.init();
    }
    match run_command(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("laserd: error: {e}");
            ExitCode::from(1)
        }
    }
}

/// The machine config of a command whose text report does not carry it: the
/// search of `ConfigSearch`, and in text mode (`json` false) a line on stderr
/// saying which one was used, unless it is the one given with `--config`.
fn machine_config(option: Option<&Path>, json: bool) -> Result<FoundConfig> {
    let search = ConfigSearch::new(option);
    let found = search.find()?;
    match &found.source {
        _ if json => {}
        ConfigSource::Option { .. } => {}
        ConfigSource::Builtin => eprintln!("laserd: machine config: {} (none found at {})", found.source, search.places()),
        other => eprintln!("laserd: machine config: {other}"),
    }
    Ok(found)
}

fn print_json<T: serde::Serialize>(value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Io(e.to_string()))?;
    println!("{text}");
    Ok(())
}

/// Every numeric flag within its range (the config's, where the flag stands
/// for a setting), before anything runs.
fn check_flags(command: &Command) -> Result<()> {
    let time_limit = |t: Option<f64>| t.map_or(Ok(()), |t| TIME_LIMIT.check("--time-limit", t));
    let baud = |b: Option<u32>| b.map_or(Ok(()), |b| BAUD.check("--baud", b));
    match command {
        Command::DryRun { job, .. } | Command::Plan { job, .. } => time_limit(job.time_limit),
        Command::Send { baud: b, .. } | Command::Sim { baud: b, .. } => baud(*b),
        Command::Bench { which } => match which {
            BenchCommand::Serve { clients, hz, .. } => in_range("--clients", *clients, 1, 10_000, "clients").and(in_range("--hz", *hz, 0.1, 1000.0, "Hz")),
            BenchCommand::Ecp { time_limit: t, .. } => time_limit(*t),
            BenchCommand::Sheet { elements, time_limit: t, .. } => in_range("--elements", *elements, 1, 100_000, "elements").and(time_limit(*t)),
            BenchCommand::Galvo { seeds, time_limit: t, .. } => in_range("--seeds", *seeds, 1, 1000, "seeds").and(time_limit(*t)),
            BenchCommand::Motion { repeats, .. } => in_range("--repeats", *repeats, 1, 1000, "runs"),
            BenchCommand::Link { blocks, block_ms, baud: b, .. } => in_range("--blocks", *blocks, 1, 1_000_000, "blocks")
                .and(in_range("--block-ms", *block_ms, 0.01, 1000.0, "ms"))
                .and(baud(Some(*b))),
        },
        _ => Ok(()),
    }
    .map_err(Error::Config)
}

fn run_command(command: Command) -> Result<ExitCode> {
    check_flags(&command)?;
    match command {
        Command::DryRun { job, record, motion, json } => {
            let (mut machine, planned) = job.plan()?;
            machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
            planned.check_precedence(job.allow_precedence_violations, "--allow-precedence-violations")?;
            let recording = record.unwrap_or_else(|| run::default_recording(&job.job));
            let dry = run::dry_run(&planned, &machine, &recording, Faults::default())?;
            let breaches = dry.report.sim.as_ref().map(|s| s.limit_breaches.len()).unwrap_or(0);
            if json {
                print_json(&dry.report)?;
            } else {
                print!("{}", dry.report.summary());
                if breaches > 0 && machine.simulator.motion == MotionModel::Grbl {
                    println!("  (a stock Grbl 1.1 cannot keep a jerk limit: it plans trapezoids, and at a corner its junction deviation $11 changes each axis' velocity at once, beyond its acceleration too)");
                }
            }
            if let Some(reason) = &dry.outcome.stop_reason {
                eprintln!("laserd: error: job stopped: {reason}");
                return Ok(ExitCode::from(2));
            }
            // A run that breaks a limit of the machine fails, its report printed.
            if breaches > 0 {
                eprintln!("laserd: error: the simulated run broke {breaches} limit(s) of the machine (listed in the report)");
                return Ok(ExitCode::from(4));
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Plan { job, output, plot, json } => {
            let (machine, planned) = job.plan()?;
            // A refused order is reported (and drawn) but not written as a program.
            let refused = planned.check_precedence(job.allow_precedence_violations, "--allow-precedence-violations");
            let output = output.filter(|_| refused.is_ok());
            if let Some(out) = &output {
                std::fs::write(out, planned.program.to_gcode())
                    .map_err(|e| Error::Io(format!("{}: cannot write: {e}", out.display())))?;
            }
            if let Some(out) = &plot {
                let svg = laserd::plot::plot(&planned.job, &planned.sequence, &planned.trajectory, &machine);
                std::fs::write(out, svg).map_err(|e| Error::Io(format!("{}: cannot write: {e}", out.display())))?;
            }
            if json {
                print_json(&planned.report)?;
            } else {
                print!("{}", planned.report.summary());
                if let Some(out) = output {
                    println!("  program written to {}", out.display());
                }
            }
            refused?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Send { file, port, baud, config, check, json } => send(&file, &port, baud, config.as_deref(), check, json),
        Command::Sim { config, pty: _, link, baud, realtime: _, record, motion, flavor, faults } => {
            let faults = parse_faults(&faults)?;
            let mut machine = machine_config(config.as_deref(), false)?.machine;
            machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
            machine.simulator.flavor = flavor.unwrap_or(machine.simulator.flavor);
            sim_on_pty(&machine, link.as_deref(), baud.unwrap_or(machine.serial.baud), record.as_deref(), faults)
        }
        Command::Bench { which: BenchCommand::Ecp { tsp, tour, seed, time_limit, search, json } } => {
            let report = laserd::bench::ecp_bench(&tsp, &tour, seed, time_limit, search)?;
            if json {
                print_json(&report)?;
            } else {
                println!(
                    "{}: {} elements, {} contours, {} precedences ({} inner/outer, {} common cuts); optimum {}, construction {}, best {} (gap {:.2} %) after {:.2} s, search stopped by {}, {} iterations ({}, {} searches on {} threads), feasible: {}",
                    report.instance, report.elements, report.contours, report.precedences, report.inner_outer, report.common_cuts,
                    report.optimum, report.construction, report.best, report.gap * 100.0, report.time_to_best_s, report.search_stopped_by.as_str(), report.iterations, report.search, report.searches, report.threads, report.feasible
                );
            }
            Ok(if report.feasible { ExitCode::SUCCESS } else { ExitCode::from(2) })
        }
        Command::Bench { which: BenchCommand::Sheet { config, elements, seed, time_limit, svg, json } } => {
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
                        "  {name:<13} air {:>10.1} mm, {:>5} pierces, {:>4} precedence violations, planned in {:.2} s",
                        o.air_mm, o.pierces, o.precedence_violations, o.plan_time_s
                    );
                }
                println!("  ecp air / nearest {:.3}, / IB + dir-opt {:.3}", r.air_vs_nearest, r.air_vs_construction);
            }
            Ok(if r.ecp.precedence_violations == 0 { ExitCode::SUCCESS } else { ExitCode::from(2) })
        }
        Command::Bench { which: BenchCommand::Serve { job, config, clients, hz, json } } => {
            let found = machine_config(config.as_deref(), json)?;
            let r = laserd::daemon::bench::serve_bench(&found.machine, &found.text, &job, clients, hz)?;
            if json {
                print_json(&r)?;
            } else {
                println!("laserd serve, job {}", r.job);
                for run in &r.runs {
                    println!(
                        "  {:<9} link utilization {:.4}  streamed {:.2} s  status at 10 Hz: {} answers, interval jitter p50 {:.2} ms p99 {:.2} ms max {:.2} ms  controller `?`: {} (jitter p99 {:.2} ms, {} found it starved)  load clients' answers {}",
                        run.name,
                        run.link_utilization,
                        run.stream_time_s,
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
                println!("  utilization while planning (done in {:.1} s) / quiet: {:.4}", r.planning_s, r.utilization_ratio_planning);
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Bench { which: BenchCommand::Motion { jobs, config, mode, repeats, json } } => {
            let machine = machine_config(config.as_deref(), json)?.machine;
            let r = laserd::bench::motion_bench(&machine, &jobs, mode, repeats)?;
            if json {
                print_json(&r)?;
            } else {
                println!("trajectory + split + program, {} mode, median of {} runs", r.mode, r.repeats);
                for c in &r.jobs {
                    println!(
                        "  {:<40} {:>5} geometries  machine {:>8.3} s  computed in {:>7.4} s  ({:.3} %)",
                        c.job,
                        c.geometries,
                        c.machine_time_s,
                        c.motion_time_s,
                        c.share * 100.0
                    );
                }
                println!("  worst {:.3} %, all jobs {:.3} % of their machine time", r.worst_share * 100.0, r.total_share * 100.0);
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Bench { which: BenchCommand::Galvo { config, dir, planner, seeds, time_limit, json } } => {
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
        Command::Bench { which: BenchCommand::Link { config, blocks, block_ms, motion, baud, json } } => {
            let mut machine = machine_config(config.as_deref(), json)?.machine;
            machine.serial.baud = baud;
            machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
            let report = laserd::bench::link_bench(&machine, blocks, block_ms / 1000.0)?;
            if json {
                print_json(&report)?;
            } else {
                let show = |name: &str, f: &laserd::bench::StreamFigures| {
                    println!(
                        "  {name:<18} stream {:>8.2} s, link {:>5.1} %, planner starved {:.3} s",
                        f.stream_time_s,
                        f.link_utilization * 100.0,
                        f.planner_starved_s
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
        Command::Gen { which: GenCommand::Galvo { family, n, seed, output } } => {
            let svg = laserd::gen::galvo::generate(family, n, seed).map_err(|e| Error::Io(format!("gen galvo: {e}")))?;
            match &output {
                Some(out) => std::fs::write(out, &svg).map_err(|e| Error::Io(format!("{}: cannot write: {e}", out.display())))?,
                None => {
                    use std::io::Write;
                    let mut stdout = std::io::stdout().lock();
                    if let Err(e) = stdout.write_all(svg.as_bytes()).and_then(|_| stdout.flush()) {
                        // A reader that stops early (`| head`) is not an error.
                        if e.kind() != std::io::ErrorKind::BrokenPipe {
                            return Err(Error::Io(format!("standard output: {e}")));
                        }
                    }
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Serve { config, state_dir, socket } => {
            let found = ConfigSearch::new(config.as_deref()).find_file()?;
            // As the other commands: said unless named with --config.
            if !matches!(found.source, ConfigSource::Option { .. }) {
                tracing::info!("machine config: {}", found.source);
            }
            let config = found.source.path().map(Path::to_path_buf);
            let options = laserd::daemon::ServeOptions::from_env(config, state_dir, socket, &found.machine);
            laserd::daemon::serve(options)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::PlanJob { source, name, program, result, allow_precedence_violations } => {
            laserd::daemon::intake::plan_job_child(&source, &name, &program, &result, allow_precedence_violations)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Ctl { socket, which } => {
            laserd::daemon::ctl::run(&socket, which)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Replay { recording, to_sim, config, json } => {
            let replay = record::read(&recording)?;
            let figures = sim_figures(&replay.log);
            if let Some(why) = &replay.truncated {
                eprintln!("laserd: warning: {}: recording ends early ({why}); figures cover what it holds", recording.display());
            }
            if to_sim {
                // The recording's own machine, unless another is asked for;
                // a recording that does not hold it gets the searched one.
                let recorded = replay.log.setup.as_ref().and_then(|s| s.machine.clone());
                let (machine, used, note) = match (config.as_deref(), recorded) {
                    (Some(path), recorded) => {
                        let machine = MachineConfig::load(Some(path))?;
                        let differs = recorded.is_some_and(|r| serde_json::to_value(&r).ok() != serde_json::to_value(&machine).ok());
                        let note = differs.then(|| format!("the machine of --config {} is not the recording's", path.display()));
                        (machine, format!("{} (--config)", path.display()), note)
                    }
                    (None, Some(recorded)) => {
                        let machine = recorded.checked(&format!("{}: the recorded machine", recording.display()))?;
                        (machine, "the recording's".to_string(), None)
                    }
                    (None, None) => {
                        let found = ConfigSearch::new(None).find()?;
                        let note = format!("the recording does not hold its machine; re-simulated on {}", found.source);
                        (found.machine, found.source.to_string(), Some(note))
                    }
                };
                let (again, again_log) = laserd::run::restream(&replay.log, &machine)?;
                let differences = laserd::run::replay_differences(&figures, &replay.log, &again, &again_log, note.as_deref());
                let same = differences.is_empty();
                let report = serde_json::json!({ "recorded": figures, "re_simulated": again, "same": same, "machine": used, "differences": differences });
                if json {
                    print_json(&report)?;
                } else {
                    println!("{}", serde_json::to_string_pretty(&report).unwrap_or_default());
                    println!("machine: {used}; {}", if same { "the same figures again" } else { "differences:" });
                    for d in &differences {
                        println!("  {d}");
                    }
                }
                return Ok(if same { ExitCode::SUCCESS } else { ExitCode::from(3) });
            }
            if json {
                print_json(&figures)?;
            } else {
                println!("{}: {} knots, {} link events", recording.display(), replay.log.knots.len(), replay.log.link.len());
                println!("{}", serde_json::to_string_pretty(&figures).unwrap_or_default());
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn send(file: &Path, port: &str, baud: Option<u32>, config: Option<&Path>, check: bool, json: bool) -> Result<ExitCode> {
    use std::io::IsTerminal;
    let FoundConfig { machine, source, .. } = machine_config(config, json)?;
    let shown = file.display().to_string();
    let opened = std::fs::File::open(file).map_err(|e| Error::Io(format!("{shown}: cannot read: {e}")))?;
    let size = opened.metadata().map(|m| m.len()).unwrap_or(0);
    // Read as the controller takes lines: memory stays constant whatever the size.
    // Bytes read so far drive the progress bar (comments never reach the link).
    let read = std::cell::Cell::new(0u64);
    let lines = stream::FileLines::new(std::io::BufReader::new(opened), &shown).inspect(|l| {
        if let Ok(l) = l {
            read.set(read.get() + l.len() as u64 + 1);
        }
    });
    let baud = baud.unwrap_or(machine.serial.baud);
    let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    options.hold_limit = options.hold_limit_for(machine.stop_time_s());
    options.check_mode = check;
    let progress = (!json && std::io::stderr().is_terminal()).then(|| {
        let bar = indicatif::ProgressBar::new(size);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {percent:>3}% {bytes}/{total_bytes} line {msg} eta {eta}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let runtime = tokio::runtime::Runtime::new().map_err(|e| Error::Io(e.to_string()))?;
    let outcome = runtime.block_on(async {
        use tokio_serial::SerialPortBuilderExt;
        let io = tokio_serial::new(port, baud)
            .open_native_async()
            .map_err(|e| Error::Stream(format!("{port}: cannot open: {e}")))?;
        let describe = |n: usize, text: &str| format!("{shown}:{n} `{text}`");
        let mut connection = stream::Connection::open(io, &options, |_, event| {
            if let (Some(bar), LinkEvent::Sent { line, .. }) = (&progress, &event) {
                bar.set_position(read.get());
                bar.set_message(line.to_string());
            }
        })
        .await?;
        // laserd's programs are in bed coordinates: the controller's work
        // coordinates are made those first (G54 from its homing settings).
        connection.use_program_frame([machine.stage.travel_x, machine.stage.travel_y]).await?;
        connection.stream(lines, &describe, None).await
    })?;
    if let Some(bar) = progress {
        bar.finish_and_clear();
    }
    let report = serde_json::json!({
        "file": shown,
        "lines_sent": outcome.lines_sent,
        "bytes_sent": outcome.bytes_sent,
        "stream_time_s": outcome.stream_time_s,
        "link_utilization": stream::link_utilization(outcome.bytes_sent, baud, outcome.stream_time_s),
        "errors": outcome.errors,
        "alarms": outcome.alarms,
        "last_acked_line": outcome.last_acked_line,
        "last_executed_line": outcome.last_executed_line,
        "completed": outcome.completed,
        "config": source,
    });
    if json {
        print_json(&report)?;
    } else {
        println!(
            "{shown}: {} lines, {} bytes in {:.2} s{}{}",
            outcome.lines_sent,
            outcome.bytes_sent,
            outcome.stream_time_s,
            if check { " (check mode)" } else { "" },
            if outcome.completed { ", completed" } else { "" }
        );
    }
    if let Some(reason) = outcome.stop_reason {
        eprintln!("laserd: error: job stopped: {reason}");
        return Ok(ExitCode::from(2));
    }
    Ok(ExitCode::SUCCESS)
}

/// `--fault NAME=N` options into the simulator's faults.
fn parse_faults(specs: &[String]) -> Result<Faults> {
    let mut faults = Faults::default();
    for spec in specs {
        let (name, value) = match spec.split_once('=') {
            Some((n, v)) => (n.trim(), Some(v.trim())),
            None => (spec.trim(), None),
        };
        // Switch faults take no value; the probe's contact distance is in mm.
        match (name, value) {
            ("homing-switch-missing", None) => faults.homing_switch_missing = true,
            ("homing-pull-off-fails", None) => faults.homing_pull_off_fails = true,
            ("probe-contact-mm", Some(v)) => {
                let mm: f64 = v.parse().map_err(|_| Error::Config(format!("--fault {spec}: expected probe-contact-mm=D with D a distance in mm")))?;
                in_range(&format!("--fault {name}"), mm, 0.001, TRAVEL.hi, TRAVEL.unit).map_err(Error::Config)?;
                faults.probe_contact_mm = Some(mm);
            }
            (_, Some(v)) => {
                let slot = match name {
                    "error-on-line" => &mut faults.error_on_line,
                    "drop-byte" => &mut faults.drop_byte,
                    "corrupt-byte" => &mut faults.corrupt_byte,
                    "mute-from-line" => &mut faults.mute_from_line,
                    "reset-at-line" => &mut faults.reset_at_line,
                    "limit-alarm-at-line" => &mut faults.limit_alarm_at_line,
                    "close-link-at-line" => &mut faults.close_link_at_line,
                    other => return Err(Error::Config(format!("--fault {spec}: unknown fault '{other}'"))),
                };
                let n: u64 = v.parse().ok().filter(|n| *n > 0).ok_or_else(|| {
                    Error::Config(format!("--fault {spec}: expected NAME=N with N a positive whole number"))
                })?;
                *slot = Some(n);
            }
            (other, None) => return Err(Error::Config(format!("--fault {spec}: unknown fault '{other}' or missing =N"))),
        }
    }
    Ok(faults)
}

fn sim_on_pty(machine: &MachineConfig, link: Option<&Path>, baud: u32, record: Option<&Path>, faults: Faults) -> Result<ExitCode> {
    let sim = run::sim_config(machine, faults);
    // `--flavor grbl` with a scanner config: Grbl 1.1h has no U or V.
    if let Some(e) = sim.flavor_error() {
        return Err(Error::Config(format!("--flavor / [simulator] flavor: {e}")));
    }
    let setup = laserd::figures::RunSetup { real_time: true, ..run::run_setup(machine, &sim) };
    let device = laserd_sim::pty::open_pty(link).map_err(|e| Error::Io(format!("cannot open a pseudo-terminal: {e}")))?;
    let recording = record.map(Recording::create).transpose()?;
    let recorder = recording.as_ref().map(|r| r.recorder());
    if let Some(r) = &recorder {
        r.write(TOPIC_SETUP, 0.0, &setup);
    }
    println!("{}", link.map(|l| l.display().to_string()).unwrap_or_else(|| device.path().display().to_string()));
    use std::io::Write;
    let _ = std::io::stdout().flush();

    let stop = Arc::new(AtomicBool::new(false));
    let stop_sim = stop.clone();
    let controller = Controller::new(sim);
    let sim_recorder = recorder.clone();
    let (ended_tx, ended_rx) = tokio::sync::oneshot::channel::<()>();
    let thread = std::thread::Builder::new()
        .name("simulator".into())
        .spawn(move || {
            // Tell the main thread when the simulator stops by itself (an
            // injected link closing), so the process ends with it.
            let _ended = DropSignal(Some(ended_tx));
            let mut link = LinkLog::default();
            laserd_sim::pty::run_realtime(controller, device, baud, stop_sim, |observed| {
                if let Some(r) = &sim_recorder {
                    match observed {
                        Observed::Knots(knots) => r.knots(&knots),
                        Observed::FromHost(t, bytes) => link.host_sent(t, &bytes, |t, e| r.link_event(t, &e)),
                        Observed::ToHost(t, bytes) => link.controller_sent(t, &bytes, |t, e| r.link_event(t, &e)),
                    }
                }
            })
        })
        .map_err(|e| Error::Io(format!("cannot start the simulator thread: {e}")))?;
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(|e| Error::Io(e.to_string()))?;
    runtime.block_on(async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending::<()>().await } } => {}
            _ = ended_rx => {}
        }
    });
    stop.store(true, Ordering::SeqCst);
    let _ = thread.join();
    drop(recorder);
    if let Some(r) = recording {
        r.finish()?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Turns the bytes seen on the simulator's side of the link into the same
/// events the sender records: lines the host sent (numbered as the controller
/// counts them), realtime bytes, and lines the controller answered.
#[derive(Default)]
struct LinkLog {
    from_host: Vec<u8>,
    to_host: Vec<u8>,
    lines: usize,
}

impl LinkLog {
    fn host_sent(&mut self, t: f64, bytes: &[u8], mut emit: impl FnMut(f64, LinkEvent)) {
        for &b in bytes {
            if realtime::is_realtime(b) || b >= 0x80 {
                emit(t, LinkEvent::Realtime { byte: b });
            } else if b == b'\n' || b == b'\r' {
                self.lines += 1;
                let text = String::from_utf8_lossy(&self.from_host).to_string();
                self.from_host.clear();
                emit(t, LinkEvent::Sent { line: self.lines, text });
            } else {
                self.from_host.push(b);
            }
        }
    }

    fn controller_sent(&mut self, t: f64, bytes: &[u8], mut emit: impl FnMut(f64, LinkEvent)) {
        for &b in bytes {
            if b == b'\n' {
                let text = String::from_utf8_lossy(&self.to_host).trim().to_string();
                self.to_host.clear();
                if !text.is_empty() {
                    emit(t, LinkEvent::Received { text });
                }
            } else {
                self.to_host.push(b);
            }
        }
    }
}

/// Sends on its channel when dropped, however the owning thread ends.
struct DropSignal(Option<tokio::sync::oneshot::Sender<()>>);

impl Drop for DropSignal {
    fn drop(&mut self) {
        if let Some(tx) = self.0.take() {
            let _ = tx.send(());
        }
    }
}
