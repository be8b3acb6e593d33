//! The `laserd` command line (see the contract in ARCHITECTURE.md): parsing
//! and dispatch; each command group lives in `cli/`.

mod cli;

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use cli::common::exit;

#[derive(Parser)]
#[command(name = "laserd", version, about = "Laser machine controller: plan, simulate, stream, record")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Plan a job, stream it into the built-in simulator (virtual time) and report.
    DryRun(cli::plan::DryRunArgs),
    /// Plan a job only: report, and write the G-code program with -o.
    Plan(cli::plan::PlanArgs),
    /// Read a drawing (SVG, DXF) into laserd's own job file (JSON), which
    /// plan, dry-run and the service take like the drawing.
    Import(cli::plan::ImportArgs),
    /// The JSON Schema of laserd's job file.
    JobSchema,
    /// Stream an existing G-code file to a controller.
    Send(cli::send::SendArgs),
    /// Run the simulated controller as a GRBL device on a pseudo-terminal.
    Sim(cli::sim::SimArgs),
    /// Benchmarks with a report.
    Bench {
        #[command(subcommand)]
        which: cli::bench::BenchCommand,
    },
    /// Generate benchmark instances.
    Gen {
        #[command(subcommand)]
        which: cli::gen::GenCommand,
    },
    /// The service: control API on a Unix socket, persistent job queue, the
    /// controller link (run it under systemd: systemd/laserd.service).
    Serve(cli::service::ServeArgs),
    /// The service's planning of one job, in a process of its own (the
    /// service starts it; the config comes on standard input).
    #[command(hide = true)]
    PlanJob(cli::service::PlanJobArgs),
    /// Talk to a running `laserd serve` (docs/api.md lists the calls).
    Ctl(cli::service::CtlArgs),
    /// Re-derive a recording's figures from the file alone.
    Replay(cli::replay::ReplayArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The service logs what an operator looks for in the journal (links,
    // jobs); the one-shot commands only warnings. LASERD_LOG overrides.
    let level = if matches!(cli.command, Command::Serve(_)) { "info" } else { "warn" };
    let filter = tracing_subscriber::EnvFilter::try_from_env("LASERD_LOG").unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let logs = tracing_subscriber::fmt().with_writer(std::io::stderr).with_env_filter(filter).with_ansi(std::io::stderr().is_terminal());
    // journald stamps each line itself.
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        logs.without_time().init();
    } else {
        logs.init();
    }
    let outcome = match cli.command {
        Command::DryRun(args) => cli::plan::dry_run(args),
        Command::Plan(args) => cli::plan::plan(args),
        Command::Import(args) => cli::plan::import(args),
        Command::JobSchema => cli::plan::job_schema(),
        Command::Send(args) => cli::send::run(args),
        Command::Sim(args) => cli::sim::run(args),
        Command::Bench { which } => cli::bench::run(which),
        Command::Gen { which } => cli::gen::run(which),
        Command::Serve(args) => cli::service::serve(args),
        Command::PlanJob(args) => cli::service::plan_job(args),
        Command::Ctl(args) => cli::service::ctl(args),
        Command::Replay(args) => cli::replay::run(args),
    };
    match outcome {
        Ok(code) => code,
        Err(e) => {
            eprintln!("laserd: error: {e}");
            ExitCode::from(exit::ERROR)
        }
    }
}
