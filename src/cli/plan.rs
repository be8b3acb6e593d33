//! `plan` and `dry-run`: plan a job; write its program and picture, or run it
//! in the built-in simulator.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use laserd::config::{Anchor, ConfigSearch, DrawingUnit, FoundConfig, MachineConfig};
use laserd::error::{Error, Result};
use laserd::mode::Mode;
use laserd::plan::PlannerKind;
use laserd::run::{self, gcode};
use laserd_sim::controller::{Faults, MotionModel};

use super::common::{check_time_limit, exit, print_json, write_file, StageProgress};

/// What `plan` and `dry-run` share: the job and how to plan it.
#[derive(clap::Args)]
pub struct JobArgs {
    /// The job: a drawing (SVG, DXF), laserd's JSON job file, or G-code
    /// (nc, gcode, ngc, gc, g, tap; planned anew unless dry-run --keep-order).
    job: PathBuf,
    /// Machine config (default: $LASERD_CONFIG, else /etc/laserd/laserd.toml,
    /// else ~/.config/laserd/laserd.toml, else the built-in default machine).
    #[arg(long)]
    config: Option<PathBuf>,
    /// auto (the default): the cutting planner ecp for layers that pierce,
    /// the galvo planner hha for marking layers, marking first, fills
    /// before all (ordered by the fill planner); or one of ecp, hha, hga,
    /// nearest for the whole job; or raster: as auto, with fills as a plain
    /// raster, line after line across the job (the yardstick).
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
    /// Seed of the galvo planners' and the fill planner's random choices
    /// (default: the config's [galvo] seed).
    #[arg(long)]
    seed: Option<u64>,
    /// What the planners minimise: time (machine time), length (laser-off
    /// travel), turns, heat, or a weighted sum such as "time+0.2*turns"
    /// (default: the config's [fill], [cutting] and [galvo] objective: time
    /// for fills, length for cutting and galvo routes, which weigh length
    /// and time only).
    #[arg(long)]
    objective: Option<String>,
    /// Plan the cutting route so that no pierce, cut or sharp corner starts
    /// where the plate is hotter than its critical temperature (seed 000's
    /// plate heat model; needs [material] and laser.watts), and report the
    /// heat (`[thermal] enabled`).
    #[arg(long)]
    thermal: bool,
    /// DXF: the unit the drawing was made in, whatever its header says
    /// (default: the config's [import] units, else the header's $INSUNITS).
    #[arg(long)]
    units: Option<DrawingUnit>,
    /// Where the job goes: drawing (as drawn: the SVG document's
    /// bottom-left corner or the DXF origin at the machine origin), origin
    /// (the job's lower-left corner at the machine origin), center (centred
    /// on the bed), or X,Y (its lower-left corner there, mm). Default: the
    /// config's [job] anchor.
    #[arg(long)]
    place: Option<Anchor>,
}

impl JobArgs {
    fn plan(&self, progress: &dyn run::Progress) -> Result<(MachineConfig, run::Planned)> {
        check_time_limit(self.time_limit).map_err(Error::Config)?;
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
        if let Some(objective) = &self.objective {
            laserd::config::objective_terms(objective).map_err(|e| Error::Config(format!("--objective: {e}")))?;
            machine.fill.objective = objective.clone();
            // Turns and heat order fills only: the cutting and galvo routes
            // keep their own then (the report's `objective` says each one's).
            if laserd::config::route_objective_terms(objective).is_ok() {
                machine.cutting.objective = objective.clone();
                machine.galvo.objective = objective.clone();
            }
        }
        if self.thermal {
            laserd::thermal::model_of(&machine)?;
            machine.thermal.enabled = true;
        }
        import_flags(&mut machine, &self.job, self.units, self.place)?;
        let mut planned = run::plan_showing(&self.job, &machine, self.planner, self.mode, progress)?;
        planned.report.config = Some(source);
        Ok((machine, planned))
    }
}

/// `--units` and `--place` into the machine's import settings.
fn import_flags(machine: &mut MachineConfig, job: &Path, units: Option<DrawingUnit>, place: Option<Anchor>) -> Result<()> {
    if let Some(anchor) = place {
        machine.job.anchor = anchor;
    }
    if let Some(units) = units {
        if !job.extension().is_some_and(|e| e.eq_ignore_ascii_case("dxf")) {
            return Err(Error::Config(format!("--units: {} is no DXF drawing (an SVG document carries its own units)", job.display())));
        }
        machine.import.units = Some(units);
    }
    Ok(())
}

/// `laserd import`: a drawing read into laserd's own job file.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// The drawing (SVG or DXF) or job file.
    job: PathBuf,
    /// Machine config (its layers and import settings; default as for plan).
    #[arg(long)]
    config: Option<PathBuf>,
    /// DXF: the unit the drawing was made in, whatever its header says.
    #[arg(long)]
    units: Option<DrawingUnit>,
    /// Where the job goes (as for plan).
    #[arg(long)]
    place: Option<Anchor>,
    /// The job file to write (JSON; default: standard output).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
}

pub fn import(args: ImportArgs) -> Result<ExitCode> {
    let FoundConfig { mut machine, .. } = ConfigSearch::new(args.config.as_deref()).find()?;
    import_flags(&mut machine, &args.job, args.units, args.place)?;
    let job = laserd::import::import_job(&args.job, &machine)?;
    let text = serde_json::to_string_pretty(&laserd::import::json::to_file(&job, machine.plate.as_ref())).map_err(|e| Error::Io(e.to_string()))? + "\n";
    match &args.output {
        Some(path) => write_file(path, text.as_bytes())?,
        None => print!("{text}"),
    }
    Ok(ExitCode::SUCCESS)
}

/// `laserd job-schema`: the JSON Schema of a job file.
pub fn job_schema() -> Result<ExitCode> {
    println!("{}", laserd::import::json::schema());
    Ok(ExitCode::SUCCESS)
}

#[derive(clap::Args)]
pub struct DryRunArgs {
    #[command(flatten)]
    job: JobArgs,
    /// MCAP recording of the run (default: <job stem>.mcap here).
    #[arg(long)]
    record: Option<PathBuf>,
    /// How the simulated controller executes blocks (default: the config's
    /// [simulator] motion): timed, or grbl (Grbl 1.1's planner).
    #[arg(long)]
    motion: Option<MotionModel>,
    /// A G-code file (.nc, .gcode, .ngc, .gc, .g, .tap): stream it as it
    /// is, its own order and moves, with no planning (each line checked
    /// first as the controller parses it). There is no plan to compare
    /// with: trajectory_time_s, lower_bound_s and sim.max_tcp_deviation_mm
    /// are null.
    #[arg(long)]
    keep_order: bool,
    /// Draw the plan as SVG, as plan --plot does.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Print the report as JSON (for scripts) instead of a summary for people.
    #[arg(long)]
    json: bool,
}

pub fn dry_run(args: DryRunArgs) -> Result<ExitCode> {
    if args.keep_order {
        return dry_run_as_it_is(args);
    }
    let DryRunArgs { job, record, motion, plot, json, .. } = args;
    let progress = StageProgress::on_terminal(json);
    let shown: &dyn run::Progress = progress.as_ref().map_or(&run::Quiet, |p| p);
    let (mut machine, planned) = job.plan(shown)?;
    if let Some(out) = &plot {
        write_plot(out, &planned, &machine)?;
    }
    machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
    planned.check_precedence(job.allow_precedence_violations, "--allow-precedence-violations")?;
    let recording = record.unwrap_or_else(|| run::default_recording(&job.job));
    let dry = run::dry_run_showing(&planned, &machine, &recording, Faults::default(), shown)?;
    drop(progress);
    dry_run_end(json, &dry.report, dry.report.summary(), dry.report.sim.as_ref(), &machine, &dry.outcome)
}

/// `dry-run FILE.nc --keep-order`: the G-code file streamed as it is.
fn dry_run_as_it_is(args: DryRunArgs) -> Result<ExitCode> {
    let DryRunArgs { job, record, motion, json, .. } = args;
    let path = &job.job;
    if !gcode::is_gcode(path) {
        return Err(Error::Import(format!(
            "{}: --keep-order streams a G-code file as it is (.{}); plan an SVG job without it",
            path.display(),
            gcode::GCODE_EXTENSIONS.join(", .")
        )));
    }
    // The planning flags mean nothing for a file that is not planned: refused, not ignored.
    let planning = [
        (job.planner != PlannerKind::Auto, "--planner"),
        (job.mode.is_some(), "--mode"),
        (job.time_limit.is_some(), "--time-limit"),
        (job.seed.is_some(), "--seed"),
        (job.objective.is_some(), "--objective"),
        (job.thermal, "--thermal"),
        (job.allow_precedence_violations, "--allow-precedence-violations"),
        (job.units.is_some(), "--units"),
        (job.place.is_some(), "--place"),
        (args.plot.is_some(), "--plot"),
    ];
    if let Some((_, flag)) = planning.iter().find(|(given, _)| *given) {
        return Err(Error::Config(format!("{flag}: {} is streamed as it is (--keep-order), not planned", path.display())));
    }
    let FoundConfig { mut machine, source, .. } = ConfigSearch::new(job.config.as_deref()).find()?;
    machine.simulator.motion = motion.unwrap_or(machine.simulator.motion);
    let recording = record.unwrap_or_else(|| run::default_recording(path));
    let mut dry = gcode::dry_run_gcode(path, &machine, &recording)?;
    dry.report.config = Some(source);
    dry_run_end(json, &dry.report, dry.report.summary(), dry.report.sim.as_ref(), &machine, &dry.outcome)
}

/// A dry-run's report (JSON, or `summary` for a person), then its exit:
/// stopped (2), a limit broken (4), else success, each said on stderr.
fn dry_run_end(
    json: bool,
    report: &impl serde::Serialize,
    summary: String,
    sim: Option<&laserd::figures::SimFigures>,
    machine: &MachineConfig,
    outcome: &laserd::stream::StreamOutcome,
) -> Result<ExitCode> {
    if json {
        print_json(report)?;
    } else {
        print!("{summary}");
    }
    let breaches = sim.map_or(0, |s| s.limit_breaches.len());
    if !json && breaches > 0 && machine.simulator.motion == MotionModel::Grbl {
        println!("  (a stock Grbl 1.1 cannot keep a jerk limit: it plans trapezoids, and at a corner its junction deviation $11 changes each axis' velocity at once, beyond its acceleration too)");
    }
    if let Some(reason) = &outcome.stop_reason {
        eprintln!("laserd: error: job stopped: {reason}");
        return Ok(ExitCode::from(exit::STOPPED));
    }
    // A run that breaks a limit of the machine fails, its report printed.
    if breaches > 0 {
        eprintln!("laserd: error: the simulated run broke {breaches} limit(s) of the machine (listed in the report)");
        return Ok(ExitCode::from(exit::LIMIT_BROKEN));
    }
    Ok(ExitCode::SUCCESS)
}

#[derive(clap::Args)]
pub struct PlanArgs {
    #[command(flatten)]
    job: JobArgs,
    /// Write the G-code program to this file.
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Draw the plan as SVG: geometries, scan fields, TCP path (marking and
    /// jumps), stage path, and the scanner's field use over time; with
    /// --thermal also OUT.heat.svg, the plate's heat at its hottest moment.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Print the report as JSON (for scripts) instead of a summary for people.
    #[arg(long)]
    json: bool,
}

pub fn plan(args: PlanArgs) -> Result<ExitCode> {
    let PlanArgs { job, output, plot, json } = args;
    let progress = StageProgress::on_terminal(json);
    let (machine, planned) = job.plan(progress.as_ref().map_or(&run::Quiet, |p| p))?;
    drop(progress);
    // A refused order is reported (and drawn) but not written as a program.
    let refused = planned.check_precedence(job.allow_precedence_violations, "--allow-precedence-violations");
    let output = output.filter(|_| refused.is_ok());
    if let Some(out) = &output {
        write_file(out, planned.program.to_gcode())?;
    }
    if let Some(out) = &plot {
        write_plot(out, &planned, &machine)?;
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

/// `--plot OUT.svg`: the plan's picture; with --thermal, the plate's heat
/// at its hottest moment beside it.
fn write_plot(out: &Path, planned: &run::Planned, machine: &MachineConfig) -> Result<()> {
    let caption = laserd::plot::Caption::of(&planned.report);
    write_file(out, laserd::plot::plot_captioned(&planned.job, &planned.sequence, &planned.trajectory, machine, planned.drawn.as_ref(), &caption))?;
    if let Some((grid, snapshot)) = &planned.heat {
        let hottest = planned.report.thermal.as_ref().and_then(|t| t.hottest.as_ref());
        write_file(&heat_map_path(out), laserd::plot::heat_map(&planned.job, grid, snapshot, hottest))?;
    }
    Ok(())
}

/// Where `--plot OUT.svg` puts the heat map: OUT.heat.svg.
fn heat_map_path(plot: &Path) -> PathBuf {
    plot.with_extension("heat.svg")
}
