//! `serve`, its hidden planning child `plan-job`, and `ctl`, the service's
//! client.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use laserd::config::{ConfigSearch, ConfigSource};
use laserd::daemon::ctl::CtlCommand;
use laserd::error::Result;

#[derive(clap::Args)]
pub struct ServeArgs {
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
}

pub fn serve(args: ServeArgs) -> Result<ExitCode> {
    let ServeArgs { config, state_dir, socket } = args;
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

#[derive(clap::Args)]
pub struct PlanJobArgs {
    source: PathBuf,
    #[arg(long)]
    name: String,
    #[arg(long)]
    program: PathBuf,
    #[arg(long)]
    result: PathBuf,
    #[arg(long)]
    allow_precedence_violations: bool,
    /// The operator's work origin: the job's lower-left corner there (X,Y mm).
    #[arg(long)]
    place: Option<String>,
}

pub fn plan_job(args: PlanJobArgs) -> Result<ExitCode> {
    let PlanJobArgs { source, name, program, result, allow_precedence_violations, place } = args;
    laserd::daemon::intake::plan_job_child(&source, &name, &program, &result, allow_precedence_violations, place.as_deref())?;
    Ok(ExitCode::SUCCESS)
}

#[derive(clap::Args)]
pub struct CtlArgs {
    /// The service's socket (default: /run/laserd/laserd.sock).
    #[arg(long, default_value = "/run/laserd/laserd.sock")]
    socket: PathBuf,
    /// Print the service's JSON answers as they are (for scripts), instead
    /// of sentences and tables.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    which: CtlCommand,
}

pub fn ctl(args: CtlArgs) -> Result<ExitCode> {
    laserd::daemon::ctl::run(&args.socket, args.which, args.json)?;
    Ok(ExitCode::SUCCESS)
}
