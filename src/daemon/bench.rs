//! `laserd bench serve`: the service under load, end to end. It starts
//! `laserd sim --pty` and `laserd serve` as child processes of this binary and
//! streams one job three times, all through the API:
//! 1. quiet;
//! 2. with many clients polling the status;
//! 3. with operator's screens open on TCP (each logged in, loading the page,
//!    following the live events and fetching the jobs and the picture as the
//!    page does);
//! 4. while the service plans big jobs (a 1000-geometry galvo job and a
//!    3000-element sheet) on its planning thread.
//!
//! Per run: the link utilization, the interval jitter a client polling the
//! status at 10 Hz sees, and the jitter of the sender's own status requests
//! to the controller (`?`, from the job's recording): whether anything
//! delayed the API or the machine loop.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hyper::Method;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::client;
use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::stream::LinkEvent;

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ServeRun {
    pub name: String,
    pub link_utilization: f64,
    pub stream_time_s: f64,
    /// Status requests (`?`) the sender made to the controller while lines
    /// went out, and how far their intervals strayed from the median (ms).
    pub controller_polls: usize,
    pub controller_poll_jitter_p99_ms: f64,
    pub controller_poll_jitter_max_ms: f64,
    /// Status reports that found the controller Idle (its planner run dry)
    /// between the job's first and last line: starvation.
    pub starved_reports: usize,
    /// A client polling `GET /status` at 10 Hz through the run: how far the
    /// intervals between its answers strayed from 100 ms.
    pub api_polls: usize,
    pub api_poll_jitter_p50_ms: f64,
    pub api_poll_jitter_p99_ms: f64,
    pub api_poll_jitter_max_ms: f64,
    /// API requests answered during the run (the polling clients', or the screens').
    pub api_requests: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ServeBench {
    pub job: String,
    pub clients: usize,
    pub client_hz: f64,
    pub runs: Vec<ServeRun>,
    /// Link utilization with the polling clients / quiet.
    pub utilization_ratio_polling: f64,
    /// Operator's screens open in the third run.
    pub pages: usize,
    /// Link utilization with the screens open / quiet.
    pub utilization_ratio_pages: f64,
    /// Link utilization while planning / quiet.
    pub utilization_ratio_planning: f64,
    /// Seconds the two big jobs took to plan while the job streamed.
    pub planning_s: f64,
}

/// A child process, stopped (SIGTERM, then SIGKILL) when dropped.
struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.0.id() as i32), nix::sys::signal::Signal::SIGTERM);
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(3) {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

async fn call(socket: &Path, method: Method, path: &str, body: Option<serde_json::Value>) -> Result<serde_json::Value> {
    let body = body.map(|b| ("application/json", b.to_string().into_bytes()));
    client::request(socket, method, path, body).await?.json()
}

async fn wait_job(socket: &Path, id: &str, states: &[&str], limit: Duration) -> Result<serde_json::Value> {
    let started = Instant::now();
    loop {
        let job = call(socket, Method::GET, &format!("/jobs/{id}"), None).await?;
        if states.iter().any(|s| job["state"] == *s) {
            return Ok(job);
        }
        if job["state"] == "failed" {
            return Err(Error::Io(format!("bench serve: job {id} failed: {}", job["message"])));
        }
        if started.elapsed() > limit {
            return Err(Error::Io(format!("bench serve: job {id} not {states:?} after {limit:?}: {job}")));
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn submit(socket: &Path, file: &Path) -> Result<String> {
    let job = call(socket, Method::POST, "/jobs", Some(serde_json::json!({ "path": file }))).await?;
    job["id"].as_str().map(str::to_string).ok_or_else(|| Error::Io(format!("bench serve: no id in {job}")))
}

/// Percentile of sorted values.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// How far intervals stray from `nominal` (s): sorted, in ms.
fn jitter(times: &[f64], nominal: f64) -> Vec<f64> {
    let mut off: Vec<f64> = times.windows(2).map(|w| (w[1] - w[0] - nominal).abs() * 1000.0).collect();
    off.sort_by(f64::total_cmp);
    off
}

/// The sender's status requests in a job's recording, while program lines
/// went out: count and sorted jitter (ms) against their median interval.
fn controller_polls(recording: &Path) -> Result<(usize, Vec<f64>, usize)> {
    let link = crate::record::read(recording)?.log.link;
    let sent: Vec<f64> = link.iter().filter(|(_, e)| matches!(e, LinkEvent::Sent { line, .. } if *line > 0)).map(|(t, _)| *t).collect();
    let (Some(&first), Some(&last)) = (sent.first(), sent.last()) else { return Ok((0, Vec::new(), 0)) };
    let starved = link.iter().filter(|(t, e)| *t > first && *t < last && matches!(e, LinkEvent::Received { text } if text.starts_with("<Idle"))).count();
    let times: Vec<f64> = link.iter().filter(|(t, e)| matches!(e, LinkEvent::Realtime { byte: b'?' }) && *t >= first && *t <= last).map(|(t, _)| *t).collect();
    let mut gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_by(f64::total_cmp);
    Ok((times.len(), jitter(&times, percentile(&gaps, 0.5)), starved))
}

/// One operator's screen on the TCP side, as `web/app.js` uses it: logs
/// in, loads the page, lists the jobs and fetches the chosen one's picture,
/// then follows the live events, listing the jobs again at each job event,
/// until `stop`. Returns the requests it made.
async fn screen(addr: String, token: String, stop: Arc<AtomicBool>) -> Result<usize> {
    let cookie = login_cookie(&addr, &token).await?;
    let page = client::Endpoint::Tcp { addr: addr.clone(), headers: vec![("Cookie".into(), cookie)] };
    let mut requests = 0;
    for path in ["/", "/ui/app.js", "/ui/app.css"] {
        page.request(Method::GET, path, None).await?;
        requests += 1;
    }
    let jobs = page.request(Method::GET, "/jobs", None).await?.json()?;
    if let Some(id) = jobs.as_array().and_then(|j| j.first()).and_then(|j| j["id"].as_str()) {
        page.request(Method::GET, &format!("/jobs/{id}/plot"), None).await?;
        requests += 1;
    }
    let job_events = Arc::new(AtomicUsize::new(0));
    let follow = {
        let (page, stop, job_events) = (page.clone(), stop.clone(), job_events.clone());
        tokio::spawn(async move {
            page.follow_events(|kind, _| {
                if kind == "job" {
                    job_events.fetch_add(1, Ordering::Relaxed);
                }
                !stop.load(Ordering::Relaxed)
            })
            .await
        })
    };
    let mut seen = 0;
    while !stop.load(Ordering::Relaxed) {
        tokio::time::sleep(Duration::from_millis(50)).await;
        let now = job_events.load(Ordering::Relaxed);
        if now != seen {
            seen = now;
            page.request(Method::GET, "/jobs", None).await?;
            requests += 1;
        }
    }
    follow.abort();
    Ok(requests)
}

/// Logs in with the form as a browser does; the session cookie.
async fn login_cookie(addr: &str, token: &str) -> Result<String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = tokio::net::TcpStream::connect(addr).await.map_err(|e| Error::Io(format!("{addr}: {e}")))?;
    let body = format!("token={token}");
    let request = format!("POST /login HTTP/1.1\r\nHost: {addr}\r\nOrigin: http://{addr}\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len());
    stream.write_all(request.as_bytes()).await.map_err(|e| Error::Io(e.to_string()))?;
    let mut answer = Vec::new();
    stream.read_to_end(&mut answer).await.map_err(|e| Error::Io(e.to_string()))?;
    let answer = String::from_utf8_lossy(&answer);
    answer
        .lines()
        .find_map(|l| l.strip_prefix("set-cookie: ").or_else(|| l.strip_prefix("Set-Cookie: ")))
        .and_then(|c| c.split(';').next())
        .map(str::to_string)
        .ok_or_else(|| Error::Io(format!("bench serve: the login gave no cookie: {}", answer.lines().next().unwrap_or(""))))
}

pub fn serve_bench(machine: &MachineConfig, config_text: &str, job: &Path, clients: usize, client_hz: f64, pages: usize) -> Result<ServeBench> {
    if !(client_hz.is_finite() && client_hz > 0.0 && client_hz <= 1000.0) {
        return Err(Error::Config(format!("bench serve: --hz must be in (0, 1000], got {client_hz}")));
    }
    let job = std::fs::canonicalize(job).map_err(|e| Error::Io(format!("{}: {e}", job.display())))?;
    let exe = std::env::current_exe().map_err(|e| Error::Io(e.to_string()))?;
    let dir = std::env::temp_dir().join(format!("laserd-bench-serve-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| Error::Io(format!("{}: {e}", dir.display())))?;
    let tty = dir.join("tty");
    // The operator's screens log in on TCP, on a free port of loopback.
    let addr = std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).map_err(|e| Error::Io(format!("bench serve: no free port: {e}")))?.to_string();
    let token = format!("bench-{:032x}", rand::random::<u128>());
    let token_file = dir.join("token");
    std::fs::write(&token_file, &token).map_err(|e| Error::Io(e.to_string()))?;
    // Jobs are submitted by path: from the job's folder and the bench's own.
    let folders = [job.parent().unwrap_or(Path::new("/")).display().to_string(), dir.display().to_string()];
    let tcp_lines = format!("tcp = {addr:?}\ntoken_file = {:?}\njob_folders = {folders:?}", token_file.display().to_string());
    // The machine's config with the simulator's device, and a table large
    // enough for the 3000-element sheet that is planned in run 3.
    let params = crate::gen::sheet::SheetParams::with_target(3000);
    let text: String = config_text
        .lines()
        .map(|l| {
            if l.starts_with("port = ") {
                format!("port = {:?}", tty.display().to_string())
            } else if l.starts_with("travel_x = ") {
                format!("travel_x = {}", params.width.max(machine.stage.travel_x))
            } else if l.starts_with("travel_y = ") {
                format!("travel_y = {}", params.height.max(machine.stage.travel_y))
            } else if l.starts_with("tcp = ") || l.starts_with("token_file = ") || l.starts_with("job_folders = ") {
                // The screens' TCP side is the bench's own, below.
                String::new()
            } else if l.trim() == "[service]" {
                format!("[service]\n{tcp_lines}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let text = if text.lines().any(|l| l.trim() == "[service]") { text } else { format!("{text}\n[service]\n{tcp_lines}\n") };
    let config = dir.join("laserd.toml");
    std::fs::write(&config, text).map_err(|e| Error::Io(e.to_string()))?;
    MachineConfig::load(Some(&config))?;
    // The big jobs to plan while streaming.
    let sheet = dir.join("sheet-3000.svg");
    let generated = crate::gen::sheet::generate_sheet(&params, 1);
    std::fs::write(&sheet, crate::gen::sheet::to_svg(&generated, &params)).map_err(|e| Error::Io(e.to_string()))?;
    let galvo = dir.join("galvo-1000.svg");
    std::fs::write(&galvo, crate::gen::galvo::generate(crate::gen::galvo::Family::Rnd, 1000, 7).map_err(Error::Io)?).map_err(|e| Error::Io(e.to_string()))?;

    let mut sim = Command::new(&exe).args(["sim", "--pty", "--config"]).arg(&config).arg("--link").arg(&tty).stdout(Stdio::piped()).spawn().map_err(|e| Error::Io(format!("laserd sim: {e}")))?;
    {
        use std::io::BufRead;
        let mut first = String::new();
        std::io::BufReader::new(sim.stdout.take().expect("piped")).read_line(&mut first).map_err(|e| Error::Io(e.to_string()))?;
    }
    let _sim = Running(sim);
    let socket = dir.join("api.sock");
    // Its job log would bury the figures: warnings only, unless asked.
    let log = std::env::var("LASERD_LOG").unwrap_or_else(|_| "warn".into());
    let serve = Command::new(&exe).env("LASERD_LOG", log).arg("serve").arg("--config").arg(&config).arg("--state-dir").arg(dir.join("state")).arg("--socket").arg(&socket).spawn().map_err(|e| Error::Io(format!("laserd serve: {e}")))?;
    let _serve = Running(serve);
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().map_err(|e| Error::Io(e.to_string()))?;
    let result = runtime.block_on(async {
        let started = Instant::now();
        while call(&socket, Method::GET, "/status", None).await.map(|s| s["machine"]["state"] != "Idle").unwrap_or(true) {
            if started.elapsed() > Duration::from_secs(15) {
                return Err(Error::Io("bench serve: the service did not connect to the simulator".into()));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let mut runs = Vec::new();
        let mut planning_s = 0.0;
        for name in ["quiet", "polling", "pages", "planning"] {
            let id = submit(&socket, &job).await?;
            wait_job(&socket, &id, &["queued"], Duration::from_secs(300)).await?;
            let stop = Arc::new(AtomicBool::new(false));
            let answered = Arc::new(AtomicUsize::new(0));
            let mut pollers = Vec::new();
            if name == "polling" {
                for k in 0..clients {
                    let (socket, stop, answered) = (socket.clone(), stop.clone(), answered.clone());
                    pollers.push(tokio::spawn(async move {
                        let period = Duration::from_secs_f64(1.0 / client_hz);
                        // Spread over the period, as independent clients are.
                        tokio::time::sleep(period.mul_f64(k as f64 / clients.max(1) as f64)).await;
                        let mut tick = tokio::time::interval(period);
                        while !stop.load(Ordering::Relaxed) {
                            tick.tick().await;
                            if client::request(&socket, Method::GET, "/status", None).await.is_ok() {
                                answered.fetch_add(1, Ordering::Relaxed);
                            }
                        }
                    }));
                }
            }
            if name == "pages" {
                for _ in 0..pages {
                    let (addr, token, stop, answered) = (addr.clone(), token.clone(), stop.clone(), answered.clone());
                    pollers.push(tokio::spawn(async move {
                        match screen(addr, token, stop).await {
                            Ok(n) => {
                                answered.fetch_add(n, Ordering::Relaxed);
                            }
                            Err(e) => tracing::warn!("bench serve: a screen stopped: {e}"),
                        }
                    }));
                }
            }
            // The operator's screen: status at 10 Hz through the run.
            let watcher = {
                let (socket, stop) = (socket.clone(), stop.clone());
                tokio::spawn(async move {
                    let origin = Instant::now();
                    let mut answers = Vec::new();
                    let mut tick = tokio::time::interval(Duration::from_millis(100));
                    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                    while !stop.load(Ordering::Relaxed) {
                        tick.tick().await;
                        if client::request(&socket, Method::GET, "/status", None).await.is_ok() {
                            answers.push(origin.elapsed().as_secs_f64());
                        }
                    }
                    answers
                })
            };
            call(&socket, Method::POST, "/start", Some(serde_json::json!({ "id": id }))).await?;
            if name == "planning" {
                tokio::time::sleep(Duration::from_millis(300)).await;
                let planning_started = Instant::now();
                let big = [submit(&socket, &galvo).await?, submit(&socket, &sheet).await?];
                for b in &big {
                    wait_job(&socket, b, &["queued"], Duration::from_secs(600)).await?;
                }
                planning_s = planning_started.elapsed().as_secs_f64();
            }
            let done = wait_job(&socket, &id, &["completed"], Duration::from_secs(600)).await?;
            stop.store(true, Ordering::Relaxed);
            for p in pollers {
                let _ = p.await;
            }
            let answers = watcher.await.map_err(|e| Error::Io(e.to_string()))?;
            let api = jitter(&answers, 0.1);
            let recording = dir.join(format!("{name}.mcap"));
            let answer = client::request(&socket, Method::GET, &format!("/jobs/{id}/recording"), None).await?;
            std::fs::write(&recording, &answer.body).map_err(|e| Error::Io(e.to_string()))?;
            let (polls, controller, starved_reports) = controller_polls(&recording)?;
            runs.push(ServeRun {
                name: name.to_string(),
                link_utilization: done["link_utilization"].as_f64().unwrap_or(0.0),
                stream_time_s: done["stream_time_s"].as_f64().unwrap_or(0.0),
                controller_polls: polls,
                controller_poll_jitter_p99_ms: percentile(&controller, 0.99),
                controller_poll_jitter_max_ms: controller.last().copied().unwrap_or(0.0),
                starved_reports,
                api_polls: answers.len(),
                api_poll_jitter_p50_ms: percentile(&api, 0.5),
                api_poll_jitter_p99_ms: percentile(&api, 0.99),
                api_poll_jitter_max_ms: api.last().copied().unwrap_or(0.0),
                api_requests: answered.load(Ordering::Relaxed),
            });
        }
        Ok((runs, planning_s))
    });
    let _ = std::fs::remove_dir_all(&dir);
    let (runs, planning_s) = result?;
    let quiet = runs[0].link_utilization.max(1e-12);
    Ok(ServeBench {
        job: job.display().to_string(),
        clients,
        client_hz,
        utilization_ratio_polling: runs[1].link_utilization / quiet,
        pages,
        utilization_ratio_pages: runs[2].link_utilization / quiet,
        utilization_ratio_planning: runs[3].link_utilization / quiet,
        runs,
        planning_s,
    })
}
