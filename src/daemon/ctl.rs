//! `laserd ctl …`: one subcommand per API call; prints the service's JSON
//! answer (or, for `events`, one JSON object per line as events arrive).

use std::path::{Path, PathBuf};

use clap::Subcommand;
use hyper::Method;

use super::client;
use crate::error::{Error, Result};

#[derive(Subcommand, Debug)]
pub enum CtlCommand {
    /// Machine state, the running job's progress (line, percent, ETA), jobs queued.
    Status,
    /// Every job: the queue's in order, then the finished ones.
    Jobs,
    /// One job's record.
    Job { id: String },
    /// Submit a job file (SVG, DXF or G-code): uploaded, or with --path read by
    /// the service itself from the machine PC.
    Submit {
        file: PathBuf,
        /// The service reads the file where it is instead of an upload.
        #[arg(long)]
        path: bool,
        /// Plan and run an order that cuts after a part has fallen out
        /// (refused otherwise).
        #[arg(long)]
        allow_precedence_violations: bool,
    },
    /// Remove a job that is not running (with its program and recording).
    Remove { id: String },
    /// Move a queued job to a place in the queue (0 = next).
    Move { id: String, position: usize },
    /// Start the next queued job, or this one.
    Start { id: Option<String> },
    /// Resume an interrupted job at its last executed line (or --from), with
    /// its modal state and position restored first. Moves the machine: needs --confirm.
    ResumeJob {
        id: String,
        #[arg(long)]
        from: Option<usize>,
        #[arg(long)]
        confirm: bool,
    },
    /// Feed hold: the machine decelerates to a stop, laser off.
    Pause,
    /// Cycle start after a pause.
    Resume,
    /// Stop the running job for good (hold, laser off, soft reset).
    Abort,
    /// Jog, e.g. `laserd ctl jog "G91 X10 F600"`.
    Jog { block: String },
    /// Run the homing cycle.
    Home,
    /// Clear an alarm ($X).
    Unlock,
    /// Save a job's MCAP recording.
    Recording {
        id: String,
        #[arg(short = 'o', long = "output")]
        output: PathBuf,
    },
    /// Follow the live events (status and job changes), one JSON line each.
    Events {
        /// Stop after this many events.
        #[arg(long)]
        count: Option<usize>,
    },
}

/// Runs one `ctl` command against the service at `socket`.
pub fn run(socket: &Path, command: CtlCommand) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(|e| Error::Io(e.to_string()))?;
    runtime.block_on(run_async(socket, command))
}

fn print(value: &serde_json::Value) -> Result<()> {
    println!("{}", serde_json::to_string_pretty(value).map_err(|e| Error::Io(e.to_string()))?);
    Ok(())
}

async fn call(socket: &Path, method: Method, path: &str, body: Option<(&str, Vec<u8>)>) -> Result<serde_json::Value> {
    client::request(socket, method, path, body).await?.json()
}

async fn run_async(socket: &Path, command: CtlCommand) -> Result<()> {
    let json = |v: serde_json::Value| Some(("application/json", v.to_string().into_bytes()));
    let answer = match command {
        CtlCommand::Status => call(socket, Method::GET, "/status", None).await?,
        CtlCommand::Jobs => call(socket, Method::GET, "/jobs", None).await?,
        CtlCommand::Job { id } => call(socket, Method::GET, &format!("/jobs/{id}"), None).await?,
        CtlCommand::Submit { file, path: true, allow_precedence_violations } => {
            let absolute = std::fs::canonicalize(&file).map_err(|e| Error::Io(format!("{}: {e}", file.display())))?;
            call(socket, Method::POST, "/jobs", json(serde_json::json!({ "path": absolute, "allow_precedence_violations": allow_precedence_violations }))).await?
        }
        CtlCommand::Submit { file, path: false, allow_precedence_violations } => {
            let bytes = std::fs::read(&file).map_err(|e| Error::Io(format!("{}: cannot read: {e}", file.display())))?;
            let name = file.file_name().and_then(|n| n.to_str()).ok_or_else(|| Error::Io(format!("{}: no file name", file.display())))?;
            let query: String = name.bytes().map(|b| if b.is_ascii_alphanumeric() || b"-._~".contains(&b) { (b as char).to_string() } else { format!("%{b:02X}") }).collect();
            let allow = if allow_precedence_violations { "&allow_precedence_violations=true" } else { "" };
            call(socket, Method::POST, &format!("/jobs?name={query}{allow}"), Some(("application/octet-stream", bytes))).await?
        }
        CtlCommand::Remove { id } => call(socket, Method::DELETE, &format!("/jobs/{id}"), None).await?,
        CtlCommand::Move { id, position } => call(socket, Method::POST, &format!("/jobs/{id}/move"), json(serde_json::json!({ "position": position }))).await?,
        CtlCommand::Start { id } => call(socket, Method::POST, "/start", id.map(|id| serde_json::json!({ "id": id })).and_then(json)).await?,
        CtlCommand::ResumeJob { id, from, confirm } => call(socket, Method::POST, &format!("/jobs/{id}/resume"), json(serde_json::json!({ "confirm": confirm, "from": from }))).await?,
        CtlCommand::Pause => call(socket, Method::POST, "/pause", None).await?,
        CtlCommand::Resume => call(socket, Method::POST, "/resume", None).await?,
        CtlCommand::Abort => call(socket, Method::POST, "/abort", None).await?,
        CtlCommand::Jog { block } => call(socket, Method::POST, "/jog", json(serde_json::json!({ "block": block }))).await?,
        CtlCommand::Home => call(socket, Method::POST, "/home", None).await?,
        CtlCommand::Unlock => call(socket, Method::POST, "/unlock", None).await?,
        CtlCommand::Recording { id, output } => {
            let answer = client::request(socket, Method::GET, &format!("/jobs/{id}/recording"), None).await?;
            if answer.status != 200 {
                answer.json()?;
            }
            std::fs::write(&output, &answer.body).map_err(|e| Error::Io(format!("{}: cannot write: {e}", output.display())))?;
            serde_json::json!({ "recording": output, "bytes": answer.body.len() })
        }
        CtlCommand::Events { count } => {
            let mut seen = 0;
            let mut failed = None;
            client::follow_events(socket, |kind, value| {
                let line = serde_json::json!({ "event": kind, "data": value });
                if let Err(e) = serde_json::to_string(&line).map(|l| println!("{l}")) {
                    failed = Some(e);
                    return false;
                }
                seen += 1;
                count.is_none_or(|c| seen < c)
            })
            .await?;
            if let Some(e) = failed {
                return Err(Error::Io(e.to_string()));
            }
            return Ok(());
        }
    };
    print(&answer)
}
