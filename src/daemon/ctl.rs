//! `laserd ctl …`: one subcommand per API call. Prints the answer for people
//! (sentences, labelled lines, a table of jobs), or with `--json` the
//! service's JSON answer as it is (for `events`, one JSON object per line as
//! events arrive): scripts and tests read that.

use std::path::{Path, PathBuf};

use clap::Subcommand;
use hyper::Method;
use serde_json::Value;

use super::client;
use crate::error::{Error, Result};

#[derive(Subcommand, Debug)]
pub enum CtlCommand {
    /// Machine state, the running job's progress (line, percent, time left), jobs queued.
    Status,
    /// Every job: the queue's in order, then the finished ones.
    Jobs,
    /// One job's record.
    Job {
        /// The job's id, e.g. j000003 (`laserd ctl jobs` lists them).
        id: String,
    },
    /// Submit a job file (SVG, DXF, laserd's JSON job file or G-code):
    /// uploaded, or with --path read by the service itself from the machine PC.
    Submit {
        /// The job file; its extension says how it is read (svg, dxf, json,
        /// nc, gcode, ngc, gc, g, tap).
        file: PathBuf,
        /// The service reads the file where it is instead of an upload (only
        /// inside its [service] job_folders).
        #[arg(long)]
        path: bool,
        /// Plan and run an order that cuts after a part has fallen out
        /// (refused otherwise).
        #[arg(long)]
        allow_precedence_violations: bool,
    },
    /// Remove a job that is not running (with its program and recording).
    Remove {
        /// The job's id.
        id: String,
    },
    /// Move a queued job to a place in the queue (0 = next).
    Move {
        /// The queued job's id.
        id: String,
        /// Its new place: 0 is next, 1 after that, …
        position: usize,
    },
    /// Start the next queued job, or this one.
    Start {
        /// A queued job's id (default: the next in the queue).
        id: Option<String>,
    },
    /// Resume an interrupted job at its last executed line (or --from), with
    /// its modal state and position restored first. Moves the machine: needs --confirm.
    ResumeJob {
        /// The interrupted job's id.
        id: String,
        /// The program line to run on from (default: after its last executed line).
        #[arg(long)]
        from: Option<usize>,
        /// Yes, move the machine (without it the service says where it would resume).
        #[arg(long)]
        confirm: bool,
    },
    /// Feed hold: the machine decelerates to a stop, laser off.
    Pause,
    /// Cycle start after a pause.
    Resume,
    /// Stop the running job for good (hold, laser and air assist off, soft reset).
    Abort,
    /// Jog: `laserd ctl jog X10` moves 10 mm in +X at the service's
    /// [service] jog_feed; a full block such as "G91 X10 F600" is sent as it is.
    Jog {
        /// Axis words (`X10 Y-5`: relative, at the jog feed), or a jog block
        /// with its own G90/G91 and F; a block without them gets G91 and the
        /// jog feed.
        block: String,
    },
    /// Trace the rectangle round a job's marks with the laser off, at the
    /// jog feed, to check where it lies on the material.
    Frame {
        /// A queued job's id (default: the next in the queue).
        id: Option<String>,
    },
    /// Change the running job's feed, rapid or laser power override.
    Override {
        /// Feed: +10, -10, +1, -1 (percent) or 100 (as programmed).
        #[arg(long, allow_hyphen_values = true)]
        feed: Option<String>,
        /// Rapids: 100, 50 or 25 (percent).
        #[arg(long)]
        rapid: Option<String>,
        /// Laser power: +10, -10, +1, -1 (percent) or 100 (as programmed).
        #[arg(long, allow_hyphen_values = true)]
        power: Option<String>,
    },
    /// Set the work origin: jobs submitted from now on are planned with their
    /// lower-left corner at the tool's place now, or at X Y; --clear goes
    /// back to the config's [job] anchor.
    Origin {
        /// X of the origin (mm, bed coordinates; default: where the tool is).
        #[arg(allow_hyphen_values = true, requires = "y")]
        x: Option<f64>,
        /// Y of the origin (mm).
        #[arg(allow_hyphen_values = true)]
        y: Option<f64>,
        /// Clear it: jobs are placed by [job] anchor again.
        #[arg(long, conflicts_with = "x")]
        clear: bool,
    },
    /// Run the homing cycle.
    Home,
    /// Clear an alarm ($X).
    Unlock,
    /// Save a job's MCAP recording.
    Recording {
        /// The job's id.
        id: String,
        /// The file to write (Foxglove and `laserd replay` read it).
        #[arg(short = 'o', long = "output")]
        output: PathBuf,
    },
    /// Follow the live events (status and job changes), a line each.
    Events {
        /// Stop after this many events (default: follow until the service ends).
        #[arg(long)]
        count: Option<usize>,
    },
}

/// Runs one `ctl` command against the service at `socket`; `json`: print
/// the service's JSON answers as they are.
pub fn run(socket: &Path, command: CtlCommand, json: bool) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(|e| Error::Io(e.to_string()))?;
    runtime.block_on(run_async(socket, command, json))
}

fn print(value: &Value) -> Result<()> {
    println!("{}", serde_json::to_string_pretty(value).map_err(|e| Error::Io(e.to_string()))?);
    Ok(())
}

async fn call(socket: &Path, method: Method, path: &str, body: Option<(&str, Vec<u8>)>) -> Result<Value> {
    client::request(socket, method, path, body).await?.json()
}

/// What kind of answer a call gives, for its text form.
#[derive(Clone)]
enum Shown {
    Status,
    Jobs,
    Job,
    Submitted,
    Removed,
    Queue,
    Done,
    /// The job whose recording was saved.
    Recording(String),
}

async fn run_async(socket: &Path, command: CtlCommand, json_out: bool) -> Result<()> {
    let json = |v: Value| Some(("application/json", v.to_string().into_bytes()));
    let (answer, shown) = match command {
        CtlCommand::Status => (call(socket, Method::GET, "/status", None).await?, Shown::Status),
        CtlCommand::Jobs => (call(socket, Method::GET, "/jobs", None).await?, Shown::Jobs),
        CtlCommand::Job { id } => (call(socket, Method::GET, &format!("/jobs/{id}"), None).await?, Shown::Job),
        CtlCommand::Submit { file, path: true, allow_precedence_violations } => {
            let absolute = std::fs::canonicalize(&file).map_err(|e| Error::Io(format!("{}: {e}", file.display())))?;
            let body = json(serde_json::json!({ "path": absolute, "allow_precedence_violations": allow_precedence_violations }));
            (call(socket, Method::POST, "/jobs", body).await?, Shown::Submitted)
        }
        CtlCommand::Submit { file, path: false, allow_precedence_violations } => {
            let bytes = std::fs::read(&file).map_err(|e| Error::Io(format!("{}: cannot read: {e}", file.display())))?;
            let name = file.file_name().and_then(|n| n.to_str()).ok_or_else(|| Error::Io(format!("{}: no file name", file.display())))?;
            let query: String = name.bytes().map(|b| if b.is_ascii_alphanumeric() || b"-._~".contains(&b) { (b as char).to_string() } else { format!("%{b:02X}") }).collect();
            let allow = if allow_precedence_violations { "&allow_precedence_violations=true" } else { "" };
            (call(socket, Method::POST, &format!("/jobs?name={query}{allow}"), Some(("application/octet-stream", bytes))).await?, Shown::Submitted)
        }
        CtlCommand::Remove { id } => (call(socket, Method::DELETE, &format!("/jobs/{id}"), None).await?, Shown::Removed),
        CtlCommand::Move { id, position } => (call(socket, Method::POST, &format!("/jobs/{id}/move"), json(serde_json::json!({ "position": position }))).await?, Shown::Queue),
        CtlCommand::Start { id } => (call(socket, Method::POST, "/start", id.map(|id| serde_json::json!({ "id": id })).and_then(json)).await?, Shown::Done),
        CtlCommand::ResumeJob { id, from, confirm } => {
            (call(socket, Method::POST, &format!("/jobs/{id}/resume"), json(serde_json::json!({ "confirm": confirm, "from": from }))).await?, Shown::Done)
        }
        CtlCommand::Pause => (call(socket, Method::POST, "/pause", None).await?, Shown::Done),
        CtlCommand::Resume => (call(socket, Method::POST, "/resume", None).await?, Shown::Done),
        CtlCommand::Abort => (call(socket, Method::POST, "/abort", None).await?, Shown::Done),
        CtlCommand::Jog { block } => (call(socket, Method::POST, "/jog", json(serde_json::json!({ "block": block }))).await?, Shown::Done),
        CtlCommand::Frame { id } => (call(socket, Method::POST, "/frame", id.map(|id| serde_json::json!({ "id": id })).and_then(json)).await?, Shown::Done),
        CtlCommand::Override { feed, rapid, power } => {
            (call(socket, Method::POST, "/override", json(serde_json::json!({ "feed": feed, "rapid": rapid, "power": power }))).await?, Shown::Done)
        }
        CtlCommand::Origin { clear: true, .. } => (call(socket, Method::DELETE, "/origin", None).await?, Shown::Done),
        CtlCommand::Origin { x, y, .. } => (call(socket, Method::POST, "/origin", x.zip(y).map(|(x, y)| serde_json::json!({ "x": x, "y": y })).and_then(json)).await?, Shown::Done),
        CtlCommand::Home => (call(socket, Method::POST, "/home", None).await?, Shown::Done),
        CtlCommand::Unlock => (call(socket, Method::POST, "/unlock", None).await?, Shown::Done),
        CtlCommand::Recording { id, output } => {
            let answer = client::request(socket, Method::GET, &format!("/jobs/{id}/recording"), None).await?;
            if answer.status != 200 {
                answer.json()?;
            }
            std::fs::write(&output, &answer.body).map_err(|e| Error::Io(format!("{}: cannot write: {e}", output.display())))?;
            (serde_json::json!({ "recording": output, "bytes": answer.body.len() }), Shown::Recording(id))
        }
        CtlCommand::Events { count } => {
            let mut seen = 0;
            let mut failed = None;
            client::follow_events(socket, |kind, value| {
                let line = if json_out { serde_json::to_string(&serde_json::json!({ "event": kind, "data": value })) } else { Ok(event_text(kind, value)) };
                if let Err(e) = line.map(|l| println!("{l}")) {
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
    if json_out {
        return print(&answer);
    }
    let text = match shown {
        Shown::Status => status_text(&answer),
        Shown::Jobs => jobs_table(&answer),
        Shown::Job => job_text(&answer),
        Shown::Submitted => submitted_text(&answer),
        Shown::Removed => format!("Removed job {}.", plain(&answer["removed"])),
        Shown::Queue => {
            let ids: Vec<String> = answer.as_array().map(|a| a.iter().map(plain).collect()).unwrap_or_default();
            if ids.is_empty() { "The queue is empty.".to_string() } else { format!("The queue now: {}.", ids.join(", ")) }
        }
        Shown::Done => sentence(&plain(&answer["done"])),
        Shown::Recording(id) => format!("Saved job {id}'s recording to {} ({} bytes).", plain(&answer["recording"]), plain(&answer["bytes"])),
    };
    println!("{text}");
    Ok(())
}

/// A JSON value as a person reads it: strings without quotes, `-` for null.
fn plain(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Null => "-".to_string(),
        other => other.to_string(),
    }
}

/// The service's short answers (`job j000001 started`) as a sentence.
fn sentence(text: &str) -> String {
    let mut chars = text.chars();
    let Some(first) = chars.next() else { return "Done.".to_string() };
    let end = if text.ends_with(['.', '!', '?']) { "" } else { "." };
    format!("{}{}{end}", first.to_uppercase(), chars.as_str())
}

/// A time as people read it (`report::duration`), `-` where there is none.
pub fn human_duration(seconds: f64) -> String {
    if !seconds.is_finite() || seconds < 0.0 {
        return "-".to_string();
    }
    crate::report::duration(seconds)
}

/// Axis positions with their letters (the controller's order: X Y, then the
/// scanner's U V).
fn position_text(position: &Value) -> String {
    let values = position.as_array().cloned().unwrap_or_default();
    let letters = ["X", "Y", "U", "V"];
    values
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let n = v.as_f64().map_or_else(|| plain(v), |n| format!("{n:.3}"));
            match letters.get(i).filter(|_| values.len() <= letters.len()) {
                Some(l) => format!("{l} {n}"),
                None => format!("axis {} {n}", i + 1),
            }
        })
        .collect::<Vec<_>>()
        .join("  ")
}

/// A running job's progress in one line.
fn progress_text(job: &Value) -> String {
    let mut text = format!("{} {}, line {} of {}", plain(&job["id"]), plain(&job["state"]), plain(&job["line"]), plain(&job["lines_total"]));
    if let Some(p) = job["percent"].as_f64() {
        text.push_str(&format!(" ({p:.1} %)"));
    }
    if let Some(eta) = job["eta_s"].as_f64() {
        text.push_str(&format!(", {} left", human_duration(eta)));
    }
    text
}

/// `GET /status` as labelled lines.
fn status_text(s: &Value) -> String {
    let m = &s["machine"];
    let link = if m["connected"] == true { "connected" } else { "not connected" };
    let mut lines = vec![format!("Machine:   {} ({link})", plain(&m["state"]))];
    if let Some(why) = m["message"].as_str() {
        lines.push(format!("Message:   {why}"));
    }
    lines.push(format!("Position:  {} mm", position_text(&m["position"])));
    let laser = match m["laser"].as_f64() {
        Some(p) if p > 0.0 => format!("on, S{p}"),
        Some(_) => "off".to_string(),
        None => plain(&m["laser"]),
    };
    lines.push(format!("Laser:     {laser}; feed {} mm/min", plain(&m["feed"])));
    lines.push(format!("Job:       {}", if s["job"].is_null() { "none running".to_string() } else { progress_text(&s["job"]) }));
    let queued = s["queued"].as_u64().unwrap_or(0);
    lines.push(format!("Queue:     {queued} job{} waiting", if queued == 1 { "" } else { "s" }));
    if let Some(storage) = s["storage"].as_str() {
        lines.push(format!("Storage:   {storage}"));
    }
    lines.join("\n")
}

/// How far a job got, as a percentage of its lines (`-` before it ran).
fn job_progress(job: &Value) -> String {
    let total = job["lines_total"].as_u64().unwrap_or(0);
    match (job["last_executed_line"].as_u64(), total) {
        (_, 0) => "-".to_string(),
        (Some(line), total) => format!("{:.0} %", 100.0 * line as f64 / total as f64),
        (None, _) => "-".to_string(),
    }
}

/// `GET /jobs` as an aligned table.
fn jobs_table(jobs: &Value) -> String {
    let jobs = jobs.as_array().cloned().unwrap_or_default();
    if jobs.is_empty() {
        return "No jobs.".to_string();
    }
    let mut rows = vec![["ID", "NAME", "STATE", "PLANNED TIME", "PROGRESS"].map(String::from)];
    for j in &jobs {
        let planned = j["planned_time_s"].as_f64().map_or_else(|| "-".to_string(), human_duration);
        rows.push([plain(&j["id"]), plain(&j["name"]), plain(&j["state"]), planned, job_progress(j)]);
    }
    let widths: Vec<usize> = (0..5).map(|c| rows.iter().map(|r| r[c].chars().count()).max().unwrap_or(0)).collect();
    rows.iter()
        .map(|r| r.iter().zip(&widths).map(|(cell, w)| format!("{cell:<w$}")).collect::<Vec<_>>().join("  ").trim_end().to_string())
        .collect::<Vec<_>>()
        .join("\n")
}

/// `GET /jobs/{id}` as labelled lines.
fn job_text(j: &Value) -> String {
    let mut lines = vec![format!("Job {}: {}, {}", plain(&j["id"]), plain(&j["name"]), plain(&j["state"]))];
    if let Some(t) = j["planned_time_s"].as_f64() {
        lines.push(format!("Planned time:   {}", human_duration(t)));
    }
    if let Some(total) = j["lines_total"].as_u64().filter(|t| *t > 0) {
        lines.push(format!("Lines:          {total}, executed {} ({})", plain(&j["last_executed_line"]), job_progress(j)));
    }
    if let (Some(a), Some(b)) = (j["started_at"].as_f64(), j["ended_at"].as_f64()) {
        lines.push(format!("Ran for:        {}", human_duration(b - a)));
    }
    if let Some(n) = j["precedence_violations"].as_u64().filter(|n| *n > 0) {
        let allowed = if j["allow_precedence_violations"] == true { " (allowed)" } else { "" };
        lines.push(format!("Precedence:     {n} cut(s) after their part has fallen out{allowed}"));
    }
    if let Some(m) = j["message"].as_str() {
        lines.push(format!("Message:        {m}"));
    }
    for w in j["warnings"].as_array().into_iter().flatten() {
        lines.push(format!("Warning:        {}", plain(w)));
    }
    lines.join("\n")
}

/// A submitted job's answer as a sentence.
fn submitted_text(j: &Value) -> String {
    let id = plain(&j["id"]);
    format!("Submitted {} as job {id} ({}); `laserd ctl job {id}` shows when it is queued.", plain(&j["name"]), plain(&j["state"]))
}

/// An event in one line.
fn event_text(kind: &str, v: &Value) -> String {
    match kind {
        "status" => {
            let m = &v["machine"];
            let job = if v["job"].is_null() { String::new() } else { format!("; job {}", progress_text(&v["job"])) };
            format!("status: {} at {}, laser {}{job}", plain(&m["state"]), position_text(&m["position"]), plain(&m["laser"]))
        }
        "job" => format!("job {}: {} ({})", plain(&v["id"]), plain(&v["state"]), plain(&v["name"])),
        other => format!("{other}: {v}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_as_hours_minutes_and_seconds() {
        assert_eq!(human_duration(243.0), "4 min 3 s");
        assert_eq!(human_duration(4769.4), "1 h 19 min 29 s");
        assert_eq!(human_duration(29.0), "29.0 s");
        assert_eq!(human_duration(0.2), "0.200 s");
        assert_eq!(human_duration(0.0), "0 s");
        assert_eq!(human_duration(f64::NAN), "-");
    }

    #[test]
    fn jobs_are_an_aligned_table() {
        let jobs = serde_json::json!([
            { "id": "j000002", "name": "a-long-name.svg", "state": "queued", "planned_time_s": 243.0, "lines_total": 10, "last_executed_line": null },
            { "id": "j000001", "name": "b.dxf", "state": "completed", "planned_time_s": 29.2, "lines_total": 40, "last_executed_line": 40 },
            { "id": "j000003", "name": "c.nc", "state": "planning", "planned_time_s": null, "lines_total": 0, "last_executed_line": null },
        ]);
        let table = jobs_table(&jobs);
        let lines: Vec<&str> = table.lines().collect();
        assert_eq!(lines.len(), 4, "{table}");
        // Every column starts at the same place on every line.
        for header in ["NAME", "STATE", "PLANNED TIME", "PROGRESS"] {
            let at = lines[0].find(header).unwrap();
            assert!(lines[1..].iter().all(|l| l.len() > at && l.as_bytes()[at - 1] == b' ' && l.as_bytes()[at] != b' '), "{header}:\n{table}");
        }
        assert!(lines[1].contains("4 min 3 s") && lines[2].contains("29.2 s") && lines[2].ends_with("100 %"), "{table}");
        assert!(lines[3].contains("planning") && lines[3].ends_with('-'), "{table}");
        assert_eq!(jobs_table(&serde_json::json!([])), "No jobs.");
    }

    #[test]
    fn status_is_labelled_lines() {
        let status = serde_json::json!({
            "machine": { "connected": true, "state": "Run", "position": [12.5, -3.0], "laser": 250.0, "feed": 1200.0, "message": null },
            "job": { "id": "j000004", "state": "running", "line": 120, "lines_total": 480, "percent": 25.0, "eta_s": 183.0 },
            "queued": 1, "storage": null,
        });
        let text = status_text(&status);
        assert!(text.contains("Machine:   Run (connected)"), "{text}");
        assert!(text.contains("Position:  X 12.500  Y -3.000 mm"), "{text}");
        assert!(text.contains("Laser:     on, S250"), "{text}");
        assert!(text.contains("j000004 running, line 120 of 480 (25.0 %), 3 min 3 s left"), "{text}");
        assert!(text.contains("Queue:     1 job waiting") && !text.contains("Storage"), "{text}");
    }
}
