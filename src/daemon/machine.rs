//! The controller link of the service: one task owns it. It connects (and
//! reconnects when the device vanishes and returns), polls the status while
//! idle, runs jobs from the queue on the operator's word, and passes hold,
//! resume and abort to a running stream. It never starts or resumes motion
//! on its own: after a reconnect the machine waits for the operator.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use laserd_sim::wire::{MachineState, StatusReport};
use tokio::sync::{mpsc, oneshot};

use super::queue::{JobRecord, JobState, Progress as SavedProgress, ProgressFile};
use super::{Daemon, MachineStatus, Progress};
use crate::error::{Error, Result};
use crate::record::Recording;
use crate::stream::{Connection, Control, LinkEvent, SenderOptions, StreamOutcome};

/// The answer to an operator's command: a line saying what was done.
pub type Reply = oneshot::Sender<Result<String>>;

/// What the API asks of the machine.
#[derive(Debug)]
pub enum Command {
    /// Run the next queued job (or this one).
    Start { id: Option<String>, reply: Reply },
    /// Resume an interrupted job at line `from` (default: after its last
    /// executed line), its modal state and position restored first.
    ResumeJob { id: String, from: Option<usize>, reply: Reply },
    /// Feed hold (laser off, the job stays loaded).
    Pause(Reply),
    /// Cycle start after a hold.
    Resume(Reply),
    /// Stop the running job for good.
    Abort(Reply),
    /// `$J=` + block.
    Jog { block: String, reply: Reply },
    Home(Reply),
    Unlock(Reply),
    /// Trace the job's bounds (or the next queued job's) with the laser off.
    Frame { id: Option<String>, reply: Reply },
    /// The tool's place now, in the bed coordinates jobs run in: the work
    /// origin of the jobs submitted next.
    Origin(Reply),
    /// Realtime override bytes for the running job.
    Override { bytes: Vec<u8>, reply: Reply },
    /// The service is stopping: a safe stop, then acknowledge.
    Shutdown(oneshot::Sender<()>),
}

impl Command {
    fn refuse(self, why: &str) {
        let reply = match self {
            Command::Start { reply, .. } | Command::ResumeJob { reply, .. } | Command::Pause(reply) | Command::Resume(reply) | Command::Abort(reply) | Command::Jog { reply, .. } | Command::Home(reply) | Command::Unlock(reply) | Command::Frame { reply, .. } | Command::Origin(reply) | Command::Override { reply, .. } => reply,
            Command::Shutdown(done) => {
                let _ = done.send(());
                return;
            }
        };
        let _ = reply.send(Err(Error::Conflict(why.to_string())));
    }
}

pub fn disconnected(why: &str) -> MachineStatus {
    MachineStatus { connected: false, state: "Disconnected".into(), message: Some(why.to_string()), ..Default::default() }
}

/// The machine as a status report shows it; what the report leaves out
/// (the offset and overrides are sent now and then) is kept from `before`.
fn machine_status(report: &StatusReport, before: &MachineStatus) -> MachineStatus {
    let work_offset = report.wco.clone().or_else(|| before.work_offset.clone());
    let axis = |p: &[f64], i: usize| p.get(i).copied().unwrap_or(0.0);
    let tcp = match (&report.wpos, &work_offset) {
        (Some(w), _) if report.mpos.is_empty() => Some([axis(w, 0) + axis(w, 2), axis(w, 1) + axis(w, 3)]),
        (_, Some(o)) if report.mpos.len() >= 2 => Some([axis(&report.mpos, 0) + axis(&report.mpos, 2) - axis(o, 0) - axis(o, 2), axis(&report.mpos, 1) + axis(&report.mpos, 3) - axis(o, 1) - axis(o, 3)]),
        _ => None,
    };
    MachineStatus {
        connected: true,
        state: report.state.as_field(),
        position: report.mpos.clone(),
        laser: report.spindle.unwrap_or(0.0),
        feed: report.feed.unwrap_or(0.0),
        message: None,
        tcp,
        work_offset,
        overrides: report.overrides.or(before.overrides),
        alarm: before.alarm.clone().filter(|_| report.state == MachineState::Alarm),
        controller: before.controller.clone(),
    }
}

/// What the link's event callback shares with the loop: the running job's
/// progress and recording.
#[derive(Default)]
struct Running {
    job: Option<String>,
    last_sent: usize,
    /// The sender's lower bound on the lines executed, the job's clock and its plan.
    executed: Option<crate::stream::ExecutedLine>,
    started: Option<std::time::Instant>,
    eta: Option<super::eta::Eta>,
    /// Bytes sent for the job (lines with their newline, realtime bytes).
    bytes: usize,
    recorder: Option<crate::record::Recorder>,
}

impl Running {
    /// Where the running job is now, from its executed line and its plan.
    fn progress(&mut self, tcp: Option<[f64; 2]>) -> Option<ProgressNow> {
        let (started, eta) = (self.started?, self.eta.as_mut()?);
        let executed = self.executed.as_ref().and_then(|e| e.get());
        let elapsed = started.elapsed().as_secs_f64();
        Some(ProgressNow { executed, elapsed, estimate: eta.estimate(elapsed, executed.unwrap_or(0), self.last_sent, tcp) })
    }
}

/// A running job's progress at one status report.
#[derive(Debug, Clone, Copy)]
struct ProgressNow {
    executed: Option<usize>,
    elapsed: f64,
    estimate: super::eta::Estimate,
}

impl Progress {
    /// A job just started, from line `line` on.
    fn start(id: String, line: usize, lines_total: usize, planned_time_s: Option<f64>) -> Progress {
        let percent = if lines_total > 0 { 100.0 * line as f64 / lines_total as f64 } else { 0.0 };
        let eta_s = planned_time_s.map(|p| p * (1.0 - percent / 100.0));
        Progress { id, state: JobState::Running, line, lines_total, executed_line: Some(line), percent, time_percent: percent, elapsed_s: 0.0, eta_s }
    }

    /// Takes what a status report says; whether anything shown changed.
    fn update(&mut self, now: ProgressNow) -> bool {
        let before = self.clone();
        self.executed_line = now.executed;
        if let Some(line) = now.executed {
            self.percent = if self.lines_total > 0 { (100.0 * line as f64 / self.lines_total as f64).min(100.0) } else { 0.0 };
        }
        self.time_percent = now.estimate.time_percent;
        self.elapsed_s = now.elapsed;
        self.eta_s = now.estimate.eta_s;
        *self != before
    }
}

/// The machine loop: runs until the service stops.
pub async fn run(daemon: Arc<Daemon>, mut commands: mpsc::UnboundedReceiver<Command>) {
    let running = Arc::new(Mutex::new(Running::default()));
    let mut retry = Duration::from_millis(250);
    loop {
        let port = daemon.machine.serial.port.clone();
        match open(&daemon, &port, running.clone()).await {
            Ok((mut connection, refusal)) => {
                retry = Duration::from_millis(250);
                tracing::info!("connected to the controller on {port}");
                let reason = connected(&daemon, &mut connection, refusal, &mut commands, &running).await;
                match reason {
                    Ok(()) => return,
                    Err(e) => {
                        tracing::warn!("controller link lost: {e}");
                        daemon.status.send_modify(|s| s.machine = disconnected(&e.to_string()));
                    }
                }
            }
            Err(e) => {
                tracing::debug!("{port}: {e}");
                daemon.status.send_if_modified(|s| {
                    let new = disconnected(&e.to_string());
                    let changed = s.machine != new;
                    s.machine = new;
                    changed
                });
            }
        }
        // Wait before the next attempt, answering the operator meanwhile.
        let wait = tokio::time::sleep(retry);
        tokio::pin!(wait);
        loop {
            tokio::select! {
                _ = &mut wait => break,
                command = commands.recv() => match command {
                    None => return,
                    Some(Command::Shutdown(done)) => {
                        let _ = done.send(());
                        return;
                    }
                    Some(c) => c.refuse("the controller is not connected"),
                },
            }
        }
        retry = (retry * 2).min(Duration::from_secs(2));
    }
}

type Link = Connection<tokio_serial::SerialStream, Box<dyn FnMut(f64, LinkEvent) + Send>>;

/// Opens the link and re-syncs: banner, status, `$I`, and `$$` compared with
/// the config (the second value: why jobs must not run, if they must not).
async fn open(daemon: &Arc<Daemon>, port: &str, running: Arc<Mutex<Running>>) -> Result<(Link, Option<String>)> {
    use tokio_serial::SerialPortBuilderExt;
    let io = tokio_serial::new(port, daemon.machine.serial.baud).open_native_async().map_err(|e| Error::Stream(format!("{port}: cannot open: {e}")))?;
    let mut options = SenderOptions::new(daemon.machine.serial.rx_buffer, daemon.machine.serial.status_hz);
    options.hold_limit = options.hold_limit_for(daemon.machine.stop_time_s());
    let on_event: Box<dyn FnMut(f64, LinkEvent) + Send> = {
        let daemon = daemon.clone();
        Box::new(move |t, event| on_link_event(&daemon, &running, t, &event))
    };
    let mut connection = Connection::open(io, &options, on_event).await?;
    let settings = connection.settings().await?;
    let refusal = settings_refusal(&daemon.machine, &settings);
    if let Some(why) = &refusal {
        tracing::error!("{why}");
    }
    let status = connection.status().await?;
    let controller = connection.version().map(str::to_string);
    daemon.status.send_modify(|s| {
        s.machine = machine_status(&status, &s.machine);
        s.machine.message = refusal.clone();
        s.machine.controller = controller;
    });
    Ok((connection, refusal))
}

/// Why jobs must not run on a controller whose settings (`$$`) allow more
/// than the config laserd plans for: a longer travel or a higher rate or
/// acceleration on any axis (the config is what keeps the machine safe).
pub fn settings_refusal(machine: &crate::config::MachineConfig, settings: &[(u32, f64)]) -> Option<String> {
    let axes = crate::run::sim_config(machine, laserd_sim::controller::Faults::default()).axes;
    let value = |n: u32| settings.iter().find(|(k, _)| *k == n).map(|(_, v)| *v);
    let mut over = Vec::new();
    for (i, axis) in axes.iter().enumerate() {
        let i = i as u32;
        for (setting, what, allowed) in [(110 + i, "max rate (mm/min)", axis.max_velocity * 60.0), (120 + i, "acceleration (mm/s²)", axis.max_acceleration), (130 + i, "max travel (mm)", axis.max - axis.min)] {
            match value(setting) {
                Some(v) if v > allowed * (1.0 + 1e-6) + 1e-9 => over.push(format!("${setting}={v} ({} {what}) exceeds the config's {allowed}", axis.letter)),
                None => over.push(format!("${setting} ({} {what}) is missing from `$$`", axis.letter)),
                _ => {}
            }
        }
    }
    (!over.is_empty()).then(|| format!("the controller's settings allow more than the config: {}; jobs will not run until they match", over.join(", ")))
}

/// Every line crossing the link: into the job's recording, and the status
/// and progress the API shows.
fn on_link_event(daemon: &Daemon, running: &Mutex<Running>, t: f64, event: &LinkEvent) {
    let mut running = running.lock().unwrap_or_else(|e| e.into_inner());
    // A job's recording (live too, if on), else live alone: the idle machine.
    if let Some(r) = running.recorder.as_ref().or(daemon.live.as_ref()) {
        r.link_event(t, event);
    }
    if running.job.is_some() {
        running.bytes += match event {
            LinkEvent::Sent { text, .. } => text.len() + 1,
            LinkEvent::Realtime { .. } => 1,
            LinkEvent::Received { .. } => 0,
        };
    }
    match event {
        LinkEvent::Sent { line, .. } if *line > 0 => {
            running.last_sent = *line;
            if running.job.is_some() {
                let line = *line;
                daemon.status.send_modify(|s| {
                    if let Some(p) = &mut s.job {
                        p.line = line;
                    }
                });
            }
        }
        LinkEvent::Received { text } if text.starts_with("ALARM:") => {
            let code = text["ALARM:".len()..].trim().parse::<u16>().unwrap_or(0);
            let alarm = format!("ALARM:{code}: {}", laserd_sim::wire::alarm_message(code));
            daemon.status.send_modify(|s| s.machine.alarm = Some(alarm));
        }
        LinkEvent::Received { text } if text.starts_with('<') => {
            if let Ok(report) = StatusReport::parse(text) {
                daemon.status.send_if_modified(|s| {
                    let mut status = machine_status(&report, &s.machine);
                    let estimate = running.job.is_some().then(|| running.progress(status.tcp)).flatten();
                    // Shown once the link is open and in sync (`open` says so);
                    // a refusal found then stays shown.
                    if !s.machine.connected {
                        return false;
                    }
                    status.message = s.machine.message.clone();
                    let mut changed = s.machine != status;
                    s.machine = status;
                    if let (Some(p), Some(now)) = (&mut s.job, estimate) {
                        changed |= p.update(now);
                    }
                    changed
                });
            }
        }
        _ => {}
    }
}

/// Connected: status polls while idle, the operator's commands, jobs.
async fn connected(daemon: &Arc<Daemon>, connection: &mut Link, refusal: Option<String>, commands: &mut mpsc::UnboundedReceiver<Command>, running: &Arc<Mutex<Running>>) -> Result<()> {
    let period = Duration::from_secs_f64(1.0 / daemon.machine.serial.status_hz.max(0.5));
    let mut poll = tokio::time::interval(period);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = poll.tick() => {
                // The report is shown by `on_link_event`, as every one is.
                connection.status().await?;
            }
            command = commands.recv() => {
                let Some(command) = command else { return Ok(()) };
                match command {
                    Command::Start { id, reply } => {
                        if let Some((job, progress)) = ready(daemon, connection, &refusal, reply, |reply| {
                            answer(reply, take(daemon, id.as_deref(), JobState::Queued, |_| Ok(())), |(j, _)| format!("job {} started", j.id))
                        }).await? {
                            if run_job(daemon, connection, commands, running, job, progress, None).await? {
                                return Ok(());
                            }
                        }
                    }
                    Command::ResumeJob { id, from, reply } => {
                        if let Some(((job, progress), from)) = ready(daemon, connection, &refusal, reply, |reply| {
                            // The line is checked before anything changes: a
                            // refused resume leaves the job as it was.
                            let mut at = 0;
                            let job = take(daemon, Some(&id), JobState::Interrupted, |job| {
                                at = job.resume_line(from)?;
                                if at == 0 || at > job.lines_total {
                                    return Err(Error::Conflict(format!("job {id} has {} lines: cannot resume at line {at}", job.lines_total)));
                                }
                                Ok(())
                            });
                            answer(reply, job.map(|job| (job, at)), |((j, _), from)| format!("job {} resumed at line {from}", j.id))
                        }).await? {
                            if run_job(daemon, connection, commands, running, job, progress, Some(from)).await? {
                                return Ok(());
                            }
                        }
                    }
                    Command::Jog { block, reply } => {
                        let _ = reply.send(connection.jog(&block).await.map(|_| format!("jogging: {block}")));
                    }
                    Command::Home(reply) => {
                        if home(daemon, connection, commands, reply).await? {
                            return Ok(());
                        }
                    }
                    Command::Abort(reply) => {
                        // With no job, an abort stops what may still move: a jog.
                        let state = connection.status().await?.state;
                        if state == MachineState::Jog {
                            let _ = reply.send(connection.jog_cancel().await.map(|_| "jog cancelled".to_string()));
                        } else {
                            Command::Abort(reply).refuse("no job is running");
                        }
                    }
                    Command::Unlock(reply) => {
                        let _ = reply.send(connection.unlock().await.map(|_| "alarm cleared".to_string()));
                    }
                    Command::Origin(reply) => {
                        let here = tool_in_bed(daemon, connection).await;
                        if let Ok(at) = &here {
                            daemon.status.send_modify(|s| s.origin = Some(*at));
                        }
                        let _ = reply.send(here.map(|[x, y]| format!("jobs submitted from now on go with their lower-left corner at X {x:.3} Y {y:.3} mm")));
                    }
                    Command::Frame { id, reply } => {
                        let framed = frame(daemon, connection, &refusal, id.as_deref()).await;
                        let _ = reply.send(framed);
                    }
                    Command::Shutdown(done) => {
                        let _ = done.send(());
                        return Ok(());
                    }
                    other => other.refuse("no job is running"),
                }
            }
        }
    }
}

/// Traces the rectangle round job `id`'s marks (or the next queued job's)
/// with jogs: the laser off, at `[service] jog_feed`, in the bed
/// coordinates the job runs in. Refused unless the machine is Idle, the
/// settings agree with the config, and the rectangle lies inside the travel.
async fn frame(daemon: &Daemon, connection: &mut Link, refusal: &Option<String>, id: Option<&str>) -> Result<String> {
    if let Some(why) = refusal {
        return Err(Error::Conflict(why.clone()));
    }
    let job = {
        let store = daemon.store();
        let id = match id {
            Some(id) => id.to_string(),
            None => store.order().iter().find(|id| store.get(id).is_some_and(|j| j.state == JobState::Queued)).cloned().ok_or_else(|| Error::Conflict("no job is queued to frame".into()))?,
        };
        store.get(&id).cloned().ok_or_else(|| Error::NotFound(format!("no job {id}")))?
    };
    let [x0, y0, x1, y1] = job.bounds.ok_or_else(|| Error::Conflict(format!("job {}: where its marks lie is not known (still planning, or G-code that could not be simulated): nothing to frame", job.id)))?;
    let [w, h] = stage_travel(daemon);
    const SLACK: f64 = 1e-3;
    if x0 < -SLACK || y0 < -SLACK || x1 > w + SLACK || y1 > h + SLACK {
        return Err(Error::Conflict(format!(
            "job {}: its marks span X {x0:.3} to {x1:.3} and Y {y0:.3} to {y1:.3} mm, outside the stage travel (X 0 to {w}, Y 0 to {h} mm): not framed",
            job.id
        )));
    }
    let state = connection.status().await?.state;
    if state != MachineState::Idle {
        return Err(Error::Conflict(format!("the machine is {}: framing starts only from Idle", state.as_field())));
    }
    connection.use_program_frame([w, h]).await.map_err(|e| Error::Conflict(format!("cannot set the work coordinates (G54) jobs run in: {e}")))?;
    let machine = &daemon.machine;
    // Any scanner axes at their centre: the stage alone traces the box.
    let rest: String = machine.axis_letters().iter().skip(2).map(|l| format!("{l}0")).collect();
    // At the operator's jog feed: slow enough to watch the head go round.
    let feed = crate::program::format_number(machine.service.jog_feed.min(machine.stage.max_velocity * 60.0), 1);
    let number = |v: f64| crate::program::format_number(v, 3);
    for (x, y) in [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)] {
        connection.jog(&format!("G90G21X{}Y{}{rest}F{feed}", number(x), number(y))).await?;
    }
    Ok(format!("framing job {}: X {x0:.3} to {x1:.3}, Y {y0:.3} to {y1:.3} mm, laser off (abort stops it)", job.id))
}

/// Where the tool is, in the bed coordinates jobs run in (G54 made the
/// bed's first): stage plus scanner. Only at rest.
async fn tool_in_bed(daemon: &Daemon, connection: &mut Link) -> Result<[f64; 2]> {
    let state = connection.status().await?.state;
    if state != MachineState::Idle {
        return Err(Error::Conflict(format!("the machine is {}: the origin is taken at rest (Idle)", state.as_field())));
    }
    connection.use_program_frame(stage_travel(daemon)).await.map_err(|e| Error::Conflict(format!("cannot set the work coordinates (G54) jobs run in: {e}")))?;
    let status = connection.status().await?;
    let at = connection.work_position(&status);
    let axis = |i: usize| at.get(i).copied().unwrap_or(0.0);
    Ok([axis(0) + axis(2), axis(1) + axis(3)])
}

/// Checks that a job may start (settings in line with the config, machine
/// Idle), then lets `take` pick it and answer; `None` when it may not.
async fn ready<T>(daemon: &Daemon, connection: &mut Link, refusal: &Option<String>, reply: Reply, take: impl FnOnce(Reply) -> Option<T>) -> Result<Option<T>> {
    if let Some(why) = refusal {
        let _ = reply.send(Err(Error::Conflict(why.clone())));
        return Ok(None);
    }
    let state = connection.status().await?.state;
    if state != MachineState::Idle {
        let _ = reply.send(Err(Error::Conflict(format!("the machine is {}: a job starts only from Idle", state.as_field()))));
        return Ok(None);
    }
    // The program, the jog to its start and a resume are in bed coordinates.
    if let Err(e) = connection.use_program_frame(stage_travel(daemon)).await {
        let _ = reply.send(Err(Error::Conflict(format!("cannot set the work coordinates (G54) jobs run in: {e}"))));
        return Ok(None);
    }
    Ok(take(reply))
}

/// The config's stage travel (X, Y): the bed coordinates programs use.
fn stage_travel(daemon: &Daemon) -> [f64; 2] {
    [daemon.machine.stage.travel_x, daemon.machine.stage.travel_y]
}

/// Answers the operator with what `taken` says, and passes on what was taken.
fn answer<T>(reply: Reply, taken: Result<T>, done: impl FnOnce(&T) -> String) -> Option<T> {
    match taken {
        Ok(t) => {
            let _ = reply.send(Ok(done(&t)));
            Some(t)
        }
        Err(e) => {
            let _ = reply.send(Err(e));
            None
        }
    }
}

/// The job `id` (or the queue's first) if it is in state `from` and passes
/// `check`, now running, with its progress file allocated. Nothing changes
/// unless all of it succeeds: one transition.
fn take(daemon: &Daemon, id: Option<&str>, from: JobState, check: impl FnOnce(&JobRecord) -> Result<()>) -> Result<(JobRecord, ProgressFile)> {
    let mut store = daemon.store();
    let id = match id {
        Some(id) => id.to_string(),
        None => store.order().iter().find(|id| store.get(id).is_some_and(|j| j.state == JobState::Queued)).cloned().ok_or_else(|| Error::Conflict("no job is queued".into()))?,
    };
    let job = store.get(&id).ok_or_else(|| Error::NotFound(format!("no job {id}")))?;
    if job.state != from {
        return Err(Error::Conflict(format!("job {id} is {:?}, not {from:?}", job.state).to_lowercase()));
    }
    check(job)?;
    // A disk too full for the progress file would lose where the job is.
    let progress = ProgressFile::create(&store.progress_path(&id)).map_err(|e| Error::Io(format!("job {id} not started: the state folder cannot take its progress: {e}")))?;
    let job = store.update(&id, |j| {
        j.state = JobState::Running;
        j.started_at = Some(super::queue::now());
        j.message = None;
        j.warnings.clear();
    })?;
    daemon.announce(&job);
    drop(store);
    daemon.queue_changed();
    Ok((job, progress))
}

/// Streams a job, passing the operator's hold, resume and abort on; returns
/// whether the service is stopping.
async fn run_job(daemon: &Arc<Daemon>, connection: &mut Link, commands: &mut mpsc::UnboundedReceiver<Command>, running: &Arc<Mutex<Running>>, job: JobRecord, progress: ProgressFile, resume_from: Option<usize>) -> Result<bool> {
    let (program, recording_path) = {
        let store = daemon.store();
        (store.program_path(&job.id), store.recording_path(&job.id))
    };
    // What the job needs before its first byte: its recording and program.
    let prepared = Recording::create(&recording_path).and_then(|recording| {
        let file = std::fs::File::open(&program).map_err(|e| Error::Io(format!("{}: cannot read: {e}", program.display())))?;
        Ok((recording, file))
    });
    let (recording, file) = match prepared {
        Ok(prepared) => prepared,
        Err(e) => {
            // Nothing was sent: the job fails alone, the link stays up.
            daemon.status.send_modify(|s| s.job = None);
            daemon.update_job(&job.id, |j| {
                j.state = JobState::Failed;
                j.message = Some(format!("not started: {e}"));
                j.ended_at = Some(super::queue::now());
            })?;
            return Ok(false);
        }
    };
    // The machine's axes and link, as every laserd recording starts.
    let mut sim = crate::run::sim_config(&daemon.machine, laserd_sim::controller::Faults::default());
    // The controller reports machine positions: the travel lies from the
    // work origin on (negative on a homed Grbl; see `stream::frame`).
    if let Some(offset) = connection.work_offset() {
        for (axis, o) in sim.axes.iter_mut().zip(offset) {
            (axis.min, axis.max) = (axis.min + o, axis.max + o);
        }
    }
    let recorder = recording.recorder().with_live(daemon.live.as_ref().and_then(|l| l.live()));
    recorder.write(crate::record::TOPIC_SETUP, 0.0, &crate::run::run_setup(&daemon.machine, &sim));
    {
        let mut r = running.lock().unwrap_or_else(|e| e.into_inner());
        let times = super::eta::LineTimes::read(&daemon.store().times_path(&job.id), job.lines_total);
        *r = Running {
            job: Some(job.id.clone()),
            executed: Some(connection.executed_line()),
            started: Some(std::time::Instant::now()),
            eta: Some(super::eta::Eta::new(times, job.lines_total, job.planned_time_s)),
            recorder: Some(recorder.with_reported_motion()),
            ..Default::default()
        };
    }
    // Shown from the start, also while the machine moves to the job's start.
    daemon.status.send_modify(|s| {
        let line = resume_from.map_or(0, |from| from - 1);
        s.job = Some(Progress::start(job.id.clone(), line, job.lines_total, job.planned_time_s));
    });
    // Read as the controller takes lines: constant memory for any size.
    let shown = program.display().to_string();
    let lines = crate::stream::FileLines::new(std::io::BufReader::new(file), &shown);
    connection.expect_start(job.start.clone().filter(|_| resume_from.is_none()));
    // The sender's lower bound on the lines executed (from its answers and
    // status reports; unknown when they prove nothing): where an interrupted
    // job resumes.
    let executed_line = connection.executed_line();
    executed_line.set(Some(resume_from.map_or(0, |from| from - 1)));
    // The progress file knows the job runs before its first line does.
    let save_progress = |state: JobState, acked: usize, executed: Option<usize>, ended_at: Option<f64>| {
        if let Err(e) = progress.write(&SavedProgress { state, last_acked_line: acked, last_executed_line: executed, ended_at }) {
            tracing::error!("job {}: progress: {e}", job.id);
        }
    };
    save_progress(JobState::Running, resume_from.map_or(0, |from| from - 1), Some(resume_from.map_or(0, |from| from - 1)), None);
    let name = job.name.clone();
    let describe = move |n: usize, text: &str| format!("{name}:{n} `{text}`");
    let (control, mut control_rx) = mpsc::unbounded_channel();
    let mut stopping = false;
    let mut shutdown_done: Option<oneshot::Sender<()>> = None;
    let mut aborted = false;
    let mut save = tokio::time::interval(PROGRESS_INTERVAL);
    let set_state = |state: JobState| {
        daemon.status.send_modify(|s| {
            if let Some(p) = &mut s.job {
                p.state = state;
            }
        });
        // A job cannot be removed while it runs: the update finds it.
        let _ = daemon.update_job(&job.id, |j| j.state = state);
    };
    // A planned program starts where it was planned from: bring the machine
    // there first, at the controller's own rates, laser off (a resume moves
    // there itself).
    let approach = match (&job.start, resume_from) {
        (Some(start), None) => approach(daemon, connection, commands, start, &set_state).await,
        _ => Ok(Approach::There),
    };
    let outcome = if let Ok(Approach::There) = approach {
        let letters = daemon.machine.axis_letters();
        let stream = async {
            match resume_from {
                Some(from) => connection.resume(lines, from, &letters, &describe, Some(&mut control_rx)).await,
                None => connection.stream(lines, &describe, Some(&mut control_rx)).await,
            }
        };
        tokio::pin!(stream);
        loop {
                tokio::select! {
                outcome = &mut stream => break outcome,
                _ = save.tick() => {
                    // Progress on disk as the status reports move it (they
                    // come at most every 10 ms): what a restart after a crash
                    // or power loss resumes from.
                    let sent = running.lock().unwrap_or_else(|e| e.into_inner()).last_sent;
                    let executed = executed_line.get();
                    save_progress(JobState::Running, sent, executed, None);
                    let _ = daemon.store().change(&job.id, |j| {
                        j.last_acked_line = sent;
                        j.last_executed_line = executed;
                    });
                }
                command = commands.recv() => match command {
                    Some(Command::Pause(reply)) => {
                        let _ = control.send(Control::FeedHold);
                        set_state(JobState::Paused);
                        let _ = reply.send(Ok(format!("job {} held", job.id)));
                    }
                    Some(Command::Resume(reply)) => {
                        let _ = control.send(Control::Resume);
                        set_state(JobState::Running);
                        let _ = reply.send(Ok(format!("job {} resumed", job.id)));
                    }
                    Some(Command::Abort(reply)) => {
                        let _ = control.send(Control::Abort);
                        aborted = true;
                        let _ = reply.send(Ok(format!("job {} aborted", job.id)));
                    }
                    Some(Command::Shutdown(done)) => {
                        // A safe stop: hold and laser off, then the soft reset
                        // of an abort; the job is kept as interrupted. The
                        // service exits once the stream has stopped.
                        let _ = control.send(Control::Abort);
                        stopping = true;
                        shutdown_done = Some(done);
                    }
                    None => {
                        let _ = control.send(Control::Abort);
                        stopping = true;
                    }
                    Some(Command::Override { bytes, reply }) => {
                        for byte in &bytes {
                            let _ = control.send(Control::Override(*byte));
                        }
                        let _ = reply.send(Ok(format!("job {}: {} override step(s) sent", job.id, bytes.len())));
                    }
                    Some(other) => other.refuse("a job is running"),
                },
            }
        }
    } else {
        // Stopped before its first line: nothing of the program ran.
        let nothing = StreamOutcome { last_executed_line: Some(0), ..Default::default() };
        approach.map(|approach| {
            match approach {
                Approach::Aborted => aborted = true,
                Approach::Stopping(done) => (stopping, shutdown_done) = (true, done),
                Approach::There => {}
            }
            nothing
        })
    };
    let (last_sent, executed_estimate, bytes, executed_time) = {
        let mut r = running.lock().unwrap_or_else(|e| e.into_inner());
        r.recorder = None;
        r.job = None;
        r.eta = None;
        (r.last_sent, executed_line.get(), r.bytes, r.started.take().map(|s| s.elapsed().as_secs_f64()))
    };
    let recording_cut = recording.finish().err().map(|e| format!("the recording is cut short: {e}"));
    if let Some(why) = &recording_cut {
        tracing::error!("job {}: {why}", job.id);
    }
    let ended = super::queue::now();
    let record = match &outcome {
        Ok(outcome) => finish_record(outcome, aborted, stopping),
        Err(e) => (JobState::Interrupted, Some(e.to_string()), None),
    };
    let (state, message, executed) = record;
    // The end in the progress file first: it needs no new space.
    let (acked, executed_final) = match state {
        JobState::Completed => (job.lines_total, Some(job.lines_total)),
        _ => (outcome.as_ref().map_or(last_sent, |o| o.last_acked_line), executed.or(executed_estimate)),
    };
    save_progress(state, acked, executed_final, Some(ended));
    daemon.status.send_modify(|s| s.job = None);
    daemon.update_job(&job.id, |j| {
        j.warnings.extend(recording_cut.clone());
        j.state = state;
        j.message = message;
        j.ended_at = Some(ended);
        // A resumed stream counts only its own lines: a completed job all.
        (j.last_acked_line, j.last_executed_line) = (acked, executed_final);
        j.bytes_sent = bytes;
        j.executed_time_s = executed_time;
        if let Ok(o) = &outcome {
            j.stream_time_s = o.stream_time_s;
            j.link_utilization = (o.stream_time_s > 0.0).then(|| crate::stream::link_utilization(bytes, daemon.machine.serial.baud, o.stream_time_s));
        }
    })?;
    let _ = daemon.store().prune(daemon.machine.service.keep_jobs);
    if let Some(done) = shutdown_done {
        let _ = done.send(());
    }
    // A lost link ends the job as interrupted; the loop reconnects.
    outcome?;
    Ok(stopping)
}

/// How often a running job's progress is looked at and, if it moved,
/// written to its progress file.
const PROGRESS_INTERVAL: Duration = Duration::from_millis(50);

/// How the move to a job's start ended.
enum Approach {
    There,
    /// The operator aborted the job on the way.
    Aborted,
    /// The service is stopping (acknowledge once the job is put away).
    Stopping(Option<oneshot::Sender<()>>),
}

/// Brings the machine to `target` (axis positions) with a jog, laser off,
/// and waits until it is there. The operator's commands count meanwhile:
/// pause cancels the jog and waits for resume (which jogs there again),
/// abort and a service stop cancel it and end the approach.
async fn approach(daemon: &Daemon, connection: &mut Link, commands: &mut mpsc::UnboundedReceiver<Command>, target: &[f64], set_state: &dyn Fn(JobState)) -> Result<Approach> {
    let machine = &daemon.machine;
    let words: String = machine.axis_letters().iter().zip(target).map(|(l, v)| format!("{l}{}", crate::program::format_number(*v, 4))).collect();
    // Each axis is held to the controller's own rate and acceleration limits.
    let jog = format!("G90G21{words}F{}", crate::program::format_number(machine.stage.max_velocity * 60.0, 1));
    // Jogs and the program are in work coordinates (see `ready`).
    let there = |here: &[f64]| here.len() >= target.len() && here.iter().zip(target).all(|(a, b)| (a - b).abs() <= 0.001);
    loop {
        let status = connection.status().await?;
        if !there(&connection.work_position(&status)) {
            connection.jog(&jog).await?;
        }
        let started = std::time::Instant::now();
        let held = loop {
            tokio::select! {
                _ = tokio::time::sleep(Duration::from_millis(50)) => {
                    let status = connection.status().await?;
                    if status.state == MachineState::Idle {
                        let here = connection.work_position(&status);
                        if there(&here) {
                            return Ok(Approach::There);
                        }
                        return Err(Error::Stream(format!("the move to the program's start {target:?} ended at {here:?} (work coordinates)")));
                    }
                    if started.elapsed() > Duration::from_secs(120) {
                        return Err(Error::Stream(format!("the machine did not reach the program's start {target:?} within 120 s")));
                    }
                }
                command = commands.recv() => match command {
                    Some(Command::Pause(reply)) => {
                        stop_jog(connection).await?;
                        set_state(JobState::Paused);
                        let _ = reply.send(Ok("held on the way to the job's start".into()));
                        break true;
                    }
                    Some(Command::Abort(reply)) => {
                        stop_jog(connection).await?;
                        let _ = reply.send(Ok("job aborted before its first line".into()));
                        return Ok(Approach::Aborted);
                    }
                    Some(Command::Shutdown(done)) => {
                        stop_jog(connection).await?;
                        return Ok(Approach::Stopping(Some(done)));
                    }
                    None => {
                        stop_jog(connection).await?;
                        return Ok(Approach::Stopping(None));
                    }
                    Some(other) => other.refuse("a job is running (moving to its start)"),
                },
            }
        };
        if held {
            // Paused: wait for the operator, the status still polled.
            let mut poll = tokio::time::interval(Duration::from_secs_f64(1.0 / machine.serial.status_hz.max(0.5)));
            loop {
                tokio::select! {
                    _ = poll.tick() => {
                        connection.status().await?;
                    }
                    command = commands.recv() => match command {
                        Some(Command::Resume(reply)) => {
                            set_state(JobState::Running);
                            let _ = reply.send(Ok("resumed: moving to the job's start".into()));
                            break;
                        }
                        Some(Command::Abort(reply)) => {
                            let _ = reply.send(Ok("job aborted before its first line".into()));
                            return Ok(Approach::Aborted);
                        }
                        Some(Command::Shutdown(done)) => return Ok(Approach::Stopping(Some(done))),
                        None => return Ok(Approach::Stopping(None)),
                        Some(other) => other.refuse("the job is paused (on the way to its start)"),
                    },
                }
            }
        }
    }
}

/// Cancels a jog and waits until the machine has stopped.
async fn stop_jog(connection: &mut Link) -> Result<()> {
    connection.jog_cancel().await?;
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while std::time::Instant::now() < deadline {
        if connection.status().await?.state != MachineState::Jog {
            return Ok(());
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Err(Error::Stream("the jog did not stop within 10 s of its cancel".into()))
}

/// Runs the homing cycle; the operator's abort, or the service stopping,
/// resets the controller mid-cycle. Returns whether the service is stopping.
async fn home(daemon: &Daemon, connection: &mut Link, commands: &mut mpsc::UnboundedReceiver<Command>, reply: Reply) -> Result<bool> {
    // The controller sends no reports while homing: say so here.
    daemon.status.send_modify(|s| s.machine.state = "Home".into());
    let (control, mut control_rx) = mpsc::unbounded_channel();
    let mut stopping: Option<Option<oneshot::Sender<()>>> = None;
    let homed = {
        let homing = connection.home(Some(&mut control_rx));
        tokio::pin!(homing);
        loop {
            tokio::select! {
                homed = &mut homing => break homed,
                command = commands.recv() => match command {
                    Some(Command::Abort(reply)) => {
                        let _ = control.send(Control::Abort);
                        let _ = reply.send(Ok("homing aborted".into()));
                    }
                    Some(Command::Shutdown(done)) => {
                        let _ = control.send(Control::Abort);
                        stopping = Some(Some(done));
                    }
                    None => {
                        let _ = control.send(Control::Abort);
                        stopping = Some(None);
                    }
                    Some(other) => other.refuse("the machine is homing (abort stops it)"),
                },
            }
        }
    };
    // Homed: the bed's coordinates are known now, for jogs too.
    if homed.is_ok() {
        if let Err(e) = connection.use_program_frame(stage_travel(daemon)).await {
            tracing::warn!("after homing: cannot set the work coordinates (G54): {e}");
        }
    }
    let _ = reply.send(homed.map(|_| "homed".to_string()));
    // Show the state the cycle left, whatever it was.
    connection.status().await?;
    if let Some(done) = stopping {
        if let Some(done) = done {
            let _ = done.send(());
        }
        return Ok(true);
    }
    Ok(false)
}

/// The job's end state from how its stream ended.
fn finish_record(outcome: &StreamOutcome, aborted: bool, stopping: bool) -> (JobState, Option<String>, Option<usize>) {
    let executed = outcome.last_executed_line;
    if outcome.completed {
        (JobState::Completed, None, None)
    } else if stopping {
        (JobState::Interrupted, Some("the service stopped while the job ran".into()), executed)
    } else if aborted {
        (JobState::Aborted, Some("aborted by the operator".into()), executed)
    } else {
        let why = outcome.stop_reason.clone().unwrap_or_else(|| "the stream stopped".into());
        let state = if outcome.alarms.is_empty() && outcome.errors.is_empty() { JobState::Interrupted } else { JobState::Failed };
        (state, Some(why), executed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_beyond_the_config_are_refused_naming_them() {
        let machine = crate::config::MachineConfig::load(None).unwrap();
        let axes = crate::run::sim_config(&machine, laserd_sim::controller::Faults::default()).axes;
        let mut settings: Vec<(u32, f64)> = Vec::new();
        for (i, a) in axes.iter().enumerate() {
            let i = i as u32;
            settings.extend([(110 + i, a.max_velocity * 60.0), (120 + i, a.max_acceleration), (130 + i, a.max - a.min)]);
        }
        assert_eq!(settings_refusal(&machine, &settings), None, "the config's own values");
        let slower: Vec<_> = settings.iter().map(|&(n, v)| (n, v * 0.5)).collect();
        assert_eq!(settings_refusal(&machine, &slower), None, "a more cautious controller may run");
        let mut longer = settings.clone();
        longer.iter_mut().find(|(n, _)| *n == 131).unwrap().1 += 10.0;
        let why = settings_refusal(&machine, &longer).unwrap();
        assert!(why.contains("$131=310") && why.contains("Y max travel"), "{why}");
        let missing: Vec<_> = settings.iter().copied().filter(|(n, _)| *n != 120).collect();
        assert!(settings_refusal(&machine, &missing).unwrap().contains("$120"));
    }
}
