//! `laserd serve`: the service on the machine PC. It keeps the job queue on
//! disk (`queue.rs`), plans submitted jobs on a thread of their own (never on
//! the streaming path), holds the controller link (`machine.rs`), and answers
//! the control API (`api.rs`, HTTP/JSON on a Unix socket; TCP only with a
//! bearer token). Under systemd it reports readiness and pings the watchdog.

pub mod api;
pub mod bench;
pub mod client;
pub mod ctl;
pub mod eta;
pub mod intake;
pub mod machine;
pub mod queue;
pub mod web;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, mpsc, watch};

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use queue::{JobRecord, JobState, Store};

/// Where the service keeps its state and listens.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    pub config: Option<PathBuf>,
    /// Queue and recordings: systemd's `$STATE_DIRECTORY`, else `/var/lib/laserd`.
    pub state_dir: PathBuf,
    /// The API's Unix socket: `[service] socket`, relative to systemd's
    /// `$RUNTIME_DIRECTORY` (else `/run/laserd`).
    pub socket: PathBuf,
}

impl ServeOptions {
    /// The defaults, from systemd's environment where it sets one.
    pub fn from_env(config: Option<PathBuf>, state_dir: Option<PathBuf>, socket: Option<PathBuf>, machine: &MachineConfig) -> ServeOptions {
        let first_dir = |var: &str, fallback: &str| {
            // systemd may list several directories, separated by colons.
            std::env::var(var).ok().and_then(|v| v.split(':').next().map(PathBuf::from)).unwrap_or_else(|| PathBuf::from(fallback))
        };
        let state_dir = state_dir.unwrap_or_else(|| first_dir("STATE_DIRECTORY", "/var/lib/laserd"));
        let socket = socket.unwrap_or_else(|| first_dir("RUNTIME_DIRECTORY", "/run/laserd").join(&machine.service.socket));
        ServeOptions { config, state_dir, socket }
    }
}

/// The machine as the API shows it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct MachineStatus {
    /// The controller link is open and in sync with the config.
    pub connected: bool,
    /// GRBL's state (`Idle`, `Run`, `Hold:0`, `Alarm`, …), or `Disconnected`.
    pub state: String,
    /// Machine position of each axis, in the controller's axis order.
    pub position: Vec<f64>,
    /// Laser power (S) and feed (units/min) as the controller reports them.
    pub laser: f64,
    pub feed: f64,
    /// Why the machine cannot run jobs, when it cannot.
    pub message: Option<String>,
    /// The tool centre point in work coordinates (mm): stage plus scanner,
    /// less the work offset; `None` until the controller gave its offset.
    #[serde(default)]
    pub tcp: Option<[f64; 2]>,
    /// The work coordinate offset last reported (`WCO:`, machine − work).
    #[serde(default)]
    pub work_offset: Option<Vec<f64>>,
    /// Feed, rapid and laser power overrides (%), as last reported (`Ov:`).
    #[serde(default)]
    pub overrides: Option<[u32; 3]>,
    /// The controller's firmware version and build, as `$I` says (`1.1h.20190830`).
    #[serde(default)]
    pub controller: Option<String>,
    /// The alarm the controller raised, in words (`ALARM:2: soft limit: …`),
    /// while it is in alarm.
    #[serde(default)]
    pub alarm: Option<String>,
}

/// The running job's progress.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Progress {
    pub id: String,
    pub state: JobState,
    /// The last line the controller accepted, and the program's length.
    pub line: usize,
    pub lines_total: usize,
    /// A lower bound on the last line executed (`None`: unknown).
    #[serde(default)]
    pub executed_line: Option<usize>,
    /// Lines executed, of all (%).
    pub percent: f64,
    /// Planned machine time executed, of all (%).
    #[serde(default)]
    pub time_percent: f64,
    /// Seconds since the job started.
    #[serde(default)]
    pub elapsed_s: f64,
    /// Seconds left: the planned time of the lines not yet executed, scaled
    /// by the machine's pace against the plan so far (`eta.rs`).
    pub eta_s: Option<f64>,
}

/// `GET /status`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Status {
    pub machine: MachineStatus,
    pub job: Option<Progress>,
    pub queued: usize,
    /// Why the state folder does not take writes (a full disk), while it does not.
    #[serde(default)]
    pub storage: Option<String>,
    /// The operator's work origin (bed mm): jobs submitted from now on are
    /// planned with their lower-left corner there; `None`: `[job] anchor`.
    #[serde(default)]
    pub origin: Option<[f64; 2]>,
}

/// What the live event stream carries.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// The machine's or the running job's state changed.
    Status(Status),
    /// A job's record changed (accepted, planned, started, ended, …).
    Job(JobRecord),
}

/// The service's shared state.
pub struct Daemon {
    pub machine: MachineConfig,
    pub store: Mutex<Store>,
    pub events: broadcast::Sender<Event>,
    pub status: watch::Sender<Status>,
    pub commands: mpsc::UnboundedSender<machine::Command>,
    /// `[service] foxglove`: the live server, as a recorder without a file
    /// (the link and status while no job runs; a job's recorder carries it too).
    pub live: Option<crate::record::Recorder>,
    planning: crossbeam_channel::Sender<String>,
    /// The config's text, as handed to each planning process.
    config_text: String,
    /// The job being planned now, and its cancel flag.
    planning_now: Mutex<Option<(String, Arc<AtomicBool>)>>,
}

impl Daemon {
    /// The store, even if a thread panicked while holding it (the store's
    /// files are written atomically, so what it holds is consistent).
    pub fn store(&self) -> std::sync::MutexGuard<'_, Store> {
        self.store.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Deletes a job that is not running; one being planned is stopped first.
    pub fn remove(&self, id: &str) -> Result<()> {
        let is_planning = || matches!(&*self.planning_now.lock().unwrap_or_else(|e| e.into_inner()), Some((planning, _)) if planning == id);
        if let Some((planning, cancel)) = &*self.planning_now.lock().unwrap_or_else(|e| e.into_inner()) {
            if planning == id {
                cancel.store(true, Ordering::Relaxed);
            }
        }
        // The planning process writes into the job's folder until it is
        // killed and reaped (within one poll of its watcher): the folder is
        // removed after that, or its removal races the process's writes.
        let asked = std::time::Instant::now();
        while is_planning() {
            if asked.elapsed() > std::time::Duration::from_secs(10) {
                return Err(Error::Conflict(format!("job {id}: its planning did not stop within 10 s; try again")));
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        self.store().remove(id)?;
        self.queue_changed();
        Ok(())
    }

    /// Changes a job's record and tells subscribers, as one step: the news
    /// goes out under the store's lock, so events come in the order of the
    /// changes (a job is `queued` before anyone sees it `running`).
    pub fn update_job(&self, id: &str, change: impl FnOnce(&mut JobRecord)) -> Result<JobRecord> {
        let job = {
            let mut store = self.store();
            let job = store.update(id, change)?;
            self.announce(&job);
            job
        };
        self.queue_changed();
        Ok(job)
    }

    /// Tells event subscribers about a job's new record, and the queue's count.
    pub fn job_changed(&self, job: &JobRecord) {
        self.announce(job);
        self.queue_changed();
    }

    /// Logs and sends a job's new record (no lock taken: callable with the
    /// store held).
    pub fn announce(&self, job: &JobRecord) {
        // Every call is a change of state: the journal's account of the job.
        let state = format!("{:?}", job.state).to_lowercase();
        let line = if job.state.is_final() || job.state == JobState::Interrupted { format!(", last executed line {} of {}", queue::shown_line(job.last_executed_line), job.lines_total) } else { String::new() };
        match &job.message {
            Some(why) => tracing::info!("job {} ({}): {state}{line}: {why}", job.id, job.name),
            None => tracing::info!("job {} ({}): {state}{line}", job.id, job.name),
        }
        let _ = self.events.send(Event::Job(job.clone()));
    }

    /// The status's count of waiting jobs, after the queue changed.
    pub fn queue_changed(&self) {
        let queued = self.store().order().len();
        self.status.send_if_modified(|s| {
            let changed = s.queued != queued;
            s.queued = queued;
            changed
        });
    }

    /// Accepts a job file: checks its size and that it is what its name
    /// says, stores it and hands it to the planning thread.
    /// `allow_precedence_violations`: plan an order that cuts after a part
    /// has fallen out instead of refusing it.
    pub fn submit(&self, name: &str, source: &[u8], allow_precedence_violations: bool) -> Result<JobRecord> {
        if name.is_empty() || name.len() > 255 || name.contains('/') || name.chars().any(char::is_control) {
            return Err(Error::Config(format!("job name {:?}: give a plain file name such as part.svg", name.chars().take(80).collect::<String>())));
        }
        let max = self.machine.import.max_file_bytes();
        if source.len() > max {
            return Err(Error::TooLarge(format!("{name}: {} bytes, more than the {max} a job file may have ([import] max_file_mb)", source.len())));
        }
        intake::JobKind::of(name, source)?;
        let job = self.store().add(name, source, allow_precedence_violations)?;
        self.job_changed(&job);
        self.planning.send(job.id.clone()).map_err(|_| Error::Io("the planning thread has stopped".into()))?;
        Ok(job)
    }
}

/// Plans (or, for G-code, checks and counts) a submitted job into its
/// `program.nc` in a process of its own, bounded in time and memory, then
/// queues it; a job that cannot be planned fails with the planner's message.
fn plan_job(daemon: &Daemon, id: &str) {
    let (source, program_path, name, allow) = {
        let store = daemon.store();
        match (store.source_path(id), store.get(id)) {
            (Some(source), Some(job)) if job.state == JobState::Planning => (source, store.program_path(id), job.name.clone(), job.allow_precedence_violations),
            _ => return,
        }
    };
    let cancel = Arc::new(AtomicBool::new(false));
    *daemon.planning_now.lock().unwrap_or_else(|e| e.into_inner()) = Some((id.to_string(), cancel.clone()));
    let service = &daemon.machine.service;
    let limits = intake::PlanLimits { timeout: std::time::Duration::from_secs_f64(service.plan_timeout), memory_bytes: (service.plan_memory_mb * (1u64 << 20) as f64) as u64 };
    // Placed at the operator's work origin, where one is set.
    let place = daemon.status.borrow().origin;
    let asked = intake::PlanAsked { allow_precedence_violations: allow, place };
    let planned = intake::plan_in_child(&daemon.config_text, &source, &name, &program_path, asked, &limits, &|| cancel.load(Ordering::Relaxed));
    *daemon.planning_now.lock().unwrap_or_else(|e| e.into_inner()) = None;
    let result = daemon.update_job(id, |j| match &planned {
        Ok(plan) => {
            j.precedence_violations = plan.precedence_violations;
            match &plan.error {
                None => {
                    j.state = JobState::Queued;
                    j.lines_total = plan.lines;
                    j.planned_time_s = plan.planned_time_s;
                    j.start = plan.start.clone();
                    j.bounds = plan.bounds;
                    j.figures = plan.figures.clone();
                }
                // Planned, but refused (an order with precedence violations).
                Some(why) => {
                    j.state = JobState::Failed;
                    j.message = Some(why.clone());
                }
            }
        }
        Err(e) => {
            j.state = JobState::Failed;
            j.message = Some(e.to_string());
        }
    });
    if let Err(e) = result {
        // Removed while it was planned: nothing to tell.
        tracing::debug!("job {id} after planning: {e}");
    }
}

/// Runs the service until SIGTERM or SIGINT: a safe stop (feed hold, laser
/// off, the job marked interrupted) before exiting.
pub fn serve(options: ServeOptions) -> Result<()> {
    let (machine, config_text) = MachineConfig::load_with_text(options.config.as_deref())?;
    let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().build().map_err(|e| Error::Io(e.to_string()))?;
    runtime.block_on(serve_async(options, machine, config_text))
}

async fn serve_async(options: ServeOptions, machine: MachineConfig, config_text: String) -> Result<()> {
    // A TCP API without its token is refused before anything starts.
    let tcp = match machine.service.tcp.clone() {
        Some(addr) => Some((addr, machine.service.token()?)),
        None => None,
    };
    let store = Store::open(&options.state_dir)?;
    let (events, _) = broadcast::channel(1024);
    let (status, _) = watch::channel(Status { queued: store.order().len(), machine: machine::disconnected("not connected yet"), job: None, storage: store.storage_error().map(str::to_string), origin: None });
    let (commands, command_rx) = mpsc::unbounded_channel();
    let (planning, planning_rx) = crossbeam_channel::unbounded::<String>();
    let replan: Vec<String> = store.list().into_iter().filter(|j| j.state == JobState::Planning).map(|j| j.id).collect();
    let live = match machine.service.foxglove_address().map_err(Error::Config)? {
        Some(addr) => Some(start_live(addr).await?),
        None => None,
    };
    let daemon = Arc::new(Daemon { machine, store: Mutex::new(store), events, status, commands, live, planning, config_text, planning_now: Mutex::new(None) });
    if let Some(live) = daemon.live.clone() {
        // The service's status (the API's) live as it changes: state, job
        // progress and time left, also between jobs.
        let mut status = daemon.status.subscribe();
        tokio::spawn(async move {
            loop {
                let now = status.borrow_and_update().clone();
                live.write(TOPIC_SERVICE_STATUS, 0.0, &now);
                if status.changed().await.is_err() {
                    break;
                }
            }
        });
    }
    let pruned = daemon.store().prune(daemon.machine.service.keep_jobs)?;
    if !pruned.is_empty() {
        tracing::info!("removed {} old finished job(s)", pruned.len());
    }
    // Planning on its own thread: a long plan never delays streaming or the API.
    {
        let daemon = daemon.clone();
        std::thread::Builder::new()
            .name("laserd-planner".into())
            .spawn(move || {
                // Below the machine loop and the API: a big plan takes the
                // cores' spare time, not the streaming's (the planner's
                // worker threads inherit this).
                // SAFETY: setpriority on the calling thread, no pointers.
                if unsafe { nix::libc::setpriority(nix::libc::PRIO_PROCESS, 0, 19) } != 0 {
                    tracing::warn!("cannot lower the planning thread's priority: {}", std::io::Error::last_os_error());
                }
                for id in planning_rx {
                    plan_job(&daemon, &id);
                }
            })
            .map_err(|e| Error::Io(format!("cannot start the planning thread: {e}")))?;
    }
    for id in replan {
        let _ = daemon.planning.send(id);
    }
    // Records the disk could not take are written again as soon as it can.
    {
        let daemon = daemon.clone();
        std::thread::Builder::new()
            .name("laserd-storage".into())
            .spawn(move || loop {
                let (failed, dir) = {
                    let mut store = daemon.store();
                    store.flush();
                    (store.storage_error().map(str::to_string), store.dir().to_path_buf())
                };
                // A disk about to fill is shown before a write fails (the
                // running job's recording grows without a record write).
                let storage = failed.or_else(|| low_space(&dir));
                daemon.status.send_if_modified(|s| {
                    let changed = s.storage != storage;
                    s.storage = storage;
                    changed
                });
                std::thread::sleep(std::time::Duration::from_secs(1));
            })
            .map_err(|e| Error::Io(format!("cannot start the storage thread: {e}")))?;
    }
    let heartbeat = Arc::new(std::sync::atomic::AtomicU64::new(0));
    // The controller link on a thread and runtime of its own: neither API
    // load nor planning delays streaming or the status loop.
    {
        let (daemon, heartbeat) = (daemon.clone(), heartbeat.clone());
        std::thread::Builder::new()
            .name("laserd-machine".into())
            .spawn(move || match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(runtime) => runtime.block_on(async move {
                    // The watchdog's proof of life: this runtime still runs its
                    // tasks (a long homing cycle awaits; a stuck thread does not).
                    tokio::spawn(async move {
                        let mut tick = tokio::time::interval(std::time::Duration::from_millis(100));
                        loop {
                            tick.tick().await;
                            heartbeat.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        }
                    });
                    machine::run(daemon, command_rx).await
                }),
                Err(e) => tracing::error!("cannot start the machine loop: {e}"),
            })
            .map_err(|e| Error::Io(format!("cannot start the machine thread: {e}")))?;
    }
    let listener = api::bind_unix(&options.socket)?;
    let mut servers = tokio::task::JoinSet::new();
    servers.spawn(api::serve_unix(listener, daemon.clone()));
    if let Some((addr, token)) = tcp {
        let tcp = tokio::net::TcpListener::bind(&addr).await.map_err(|e| Error::Io(format!("[service] tcp = {addr:?}: cannot listen: {e}")))?;
        servers.spawn(api::serve_tcp(tcp, daemon.clone(), token));
    }
    tracing::info!("laserd serving on {} (state in {})", options.socket.display(), options.state_dir.display());
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    watchdog(heartbeat);
    let stop = async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).map_err(|e| Error::Io(e.to_string()))?;
        tokio::select! {
            _ = term.recv() => {},
            _ = tokio::signal::ctrl_c() => {},
        }
        Ok::<_, Error>(())
    };
    tokio::select! {
        r = stop => r?,
        Some(r) = servers.join_next() => {
            r.map_err(|e| Error::Io(format!("the API server stopped: {e}")))??;
        }
    }
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    // A safe stop of whatever runs, then out.
    let (done_tx, done_rx) = tokio::sync::oneshot::channel();
    if daemon.commands.send(machine::Command::Shutdown(done_tx)).is_ok() {
        let _ = tokio::time::timeout(std::time::Duration::from_secs(5), done_rx).await;
    }
    let _ = std::fs::remove_file(&options.socket);
    Ok(())
}

/// The live server's topic for the API's `Status`.
pub const TOPIC_SERVICE_STATUS: &str = "/service/status";

/// Starts the Foxglove server with the topics the service writes advertised.
async fn start_live(addr: std::net::SocketAddr) -> Result<crate::record::Recorder> {
    use crate::record::{live::Live, AxesMessage, LinkMessage, StatusMessage};
    let live = Live::start(addr).await?;
    live.advertise::<crate::figures::RunSetup>(crate::record::TOPIC_SETUP);
    live.advertise::<LinkMessage>(crate::record::TOPIC_LINK);
    live.advertise::<StatusMessage>(crate::record::TOPIC_STATUS);
    live.advertise::<AxesMessage>(crate::record::TOPIC_AXES);
    live.advertise::<Status>(TOPIC_SERVICE_STATUS);
    tracing::info!("Foxglove WebSocket server on {}:{}", addr.ip(), live.port());
    Ok(crate::record::Recorder::live_only(live).with_reported_motion())
}

/// Below this much free space in the state folder the status warns.
const LOW_SPACE_BYTES: u64 = 1 << 20;

/// Why the state folder's disk cannot take a job's recording, if it cannot.
fn low_space(dir: &std::path::Path) -> Option<String> {
    let stat = nix::sys::statvfs::statvfs(dir).ok()?;
    let free = stat.blocks_available() as u64 * stat.fragment_size() as u64;
    (free < LOW_SPACE_BYTES).then(|| format!("{}: No space left on the device ({} KB free): recordings and job records cannot be written", dir.display(), free / 1024))
}

/// Pings systemd's watchdog while the machine loop is alive (its heartbeat
/// moves); a stuck loop stops the pings and systemd restarts the service.
fn watchdog(heartbeat: Arc<std::sync::atomic::AtomicU64>) {
    let Some(interval) = sd_notify::watchdog_enabled() else { return };
    let every = interval / 2;
    tokio::spawn(async move {
        let mut last = u64::MAX;
        loop {
            tokio::time::sleep(every).await;
            let now = heartbeat.load(std::sync::atomic::Ordering::Relaxed);
            if now != last {
                let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
                last = now;
            } else {
                tracing::error!("the machine loop has not moved for {every:?}: no watchdog ping");
            }
        }
    });
}
