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

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Issue 24: every command, flag and argument of `laserd --help` says
    /// what it is; a value of a fixed set lists the set (not hidden).
    #[test]
    fn every_argument_has_help_and_shows_its_values() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for arg in cmd.get_arguments() {
                let id = arg.get_id().as_str();
                if arg.is_hide_set() || id == "help" || id == "version" {
                    continue;
                }
                if arg.get_help().is_none_or(|h| h.to_string().trim().is_empty()) {
                    missing.push(format!("{path} {id}: no help"));
                }
                if arg.is_hide_possible_values_set() || arg.is_hide_default_value_set() {
                    missing.push(format!("{path} {id}: its values or default hidden"));
                }
            }
            for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set() && s.get_name() != "help") {
                let name = format!("{path} {}", sub.get_name());
                if sub.get_about().is_none() {
                    missing.push(format!("{name}: no description"));
                }
                walk(sub, &name, missing);
            }
        }
        let cli = super::Cli::command();
        cli.clone().debug_assert();
        let mut missing = Vec::new();
        walk(&cli, "laserd", &mut missing);
        assert!(missing.is_empty(), "{}", missing.join("\n"));
        // The walk sees nested arguments: a flag known to need help is there.
        let ctl = cli.find_subcommand("ctl").unwrap();
        assert!(ctl.get_arguments().any(|a| a.get_id() == "json"));
        // Fixed sets are listed: the planner's names in `plan --help`.
        let plan = cli.find_subcommand("plan").unwrap();
        let planner = plan.get_arguments().find(|a| a.get_id() == "planner").unwrap();
        let names: Vec<String> = planner.get_possible_values().iter().map(|v| v.get_name().to_string()).collect();
        assert_eq!(names, ["auto", "nearest", "ecp", "hha", "hga", "raster"]);
    }
}
