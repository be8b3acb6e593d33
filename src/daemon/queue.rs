//! The job queue, kept on disk so that a restart or a power loss loses no
//! accepted job: one folder per job under `<state>/jobs/<id>/` with its
//! record (`job.json`), its source file, its program (`program.nc`) and its
//! recording (`recording.mcap`), and the queue's order in `<state>/queue.json`.
//! Every file is written whole to a temporary name, flushed to the disk and
//! renamed over the old one, so a file is always either the old or the new.
//!
//! A full disk is a storage error, never a lost truth: the records stay right
//! in memory, those not written are written again as soon as space allows
//! (`flush`), and a running job's progress goes to a small file allocated
//! before it starts (`ProgressFile`), rewritten in place, which needs no new
//! space. The last job id is kept in `<state>/next-id`, so ids are never reused.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Accepted, being planned into a program.
    Planning,
    /// Planned, waiting in the queue.
    Queued,
    /// Streaming to the controller.
    Running,
    /// Streaming, in feed hold.
    Paused,
    Completed,
    /// Stopped by the operator.
    Aborted,
    /// Could not be planned, or the controller refused it.
    Failed,
    /// Cut short by a lost link or a daemon that stopped (restart, power
    /// loss): may be resumed from its last executed line, on the operator's word.
    Interrupted,
}

impl JobState {
    /// Over: nothing more will happen to the job unless the operator resumes it.
    pub fn is_final(self) -> bool {
        matches!(self, JobState::Completed | JobState::Aborted | JobState::Failed)
    }
}

/// What the daemon knows of a job, as stored in `job.json` and shown by the API.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct JobRecord {
    pub id: String,
    /// The submitted file's name.
    pub name: String,
    pub state: JobState,
    /// Unix times (s).
    pub submitted_at: f64,
    pub started_at: Option<f64>,
    pub ended_at: Option<f64>,
    /// Program lines (0 until planned).
    pub lines_total: usize,
    /// The last line the controller accepted into its buffer.
    pub last_acked_line: usize,
    /// A lower bound on the last line the controller executed (every line up
    /// to it has run, as its answers and status reports prove): where an
    /// interrupted job resumes. `None` when they proved nothing (a controller
    /// without `Bf:` in its reports that never came to rest): a resume must
    /// then name its line.
    pub last_executed_line: Option<usize>,
    /// Planned machine time of the program (s), for the ETA.
    pub planned_time_s: Option<f64>,
    /// Cuts after their part has fallen out, in the planned order (0 for
    /// marking); `None` until planned, and for G-code submitted as it is.
    #[serde(default)]
    pub precedence_violations: Option<u64>,
    /// The submitter's override: plan and run an order with precedence
    /// violations instead of refusing it.
    #[serde(default)]
    pub allow_precedence_violations: bool,
    /// Axis positions the planned program starts from (the machine is
    /// brought there first); `None` for G-code submitted as it is.
    #[serde(default)]
    pub start: Option<Vec<f64>>,
    /// Why the job failed or was interrupted.
    pub message: Option<String>,
    /// What the operator should know although the job went on (a recording
    /// cut short by a full disk).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// The link while it streamed: bytes sent, from the first byte to the last
    /// answer (s), and the bytes' share of what the link could carry then.
    #[serde(default)]
    pub bytes_sent: usize,
    #[serde(default)]
    pub stream_time_s: f64,
    /// `bytes_sent` over the nominal character rate (`baud / 10`) for
    /// `stream_time_s` (`stream::link_utilization`: an AVR's real rate is
    /// 2.1 % above it, so up to about 1.02 on one).
    #[serde(default)]
    pub link_utilization: Option<f64>,
    /// Where the planned marks lie (work mm: x min, y min, x max, y max),
    /// lead-ins included: what framing traces. `None` for G-code.
    #[serde(default)]
    pub bounds: Option<[f64; 4]>,
    /// The plan's figures (geometries, scan fields, marked length, pierces).
    #[serde(default)]
    pub figures: Option<JobFigures>,
    /// From its start to its end (s): against `planned_time_s` in the history.
    #[serde(default)]
    pub executed_time_s: Option<f64>,
}

/// What the planner says of a job, for the operator's screen.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct JobFigures {
    pub geometries: usize,
    /// Scan fields visited; `None` on a stage-only plan.
    pub scan_fields: Option<usize>,
    pub mark_length_mm: f64,
    pub pierces: usize,
    pub planner: String,
    pub mode: String,
}

/// The jobs and the queue's order, with their folder.
pub struct Store {
    dir: PathBuf,
    jobs: BTreeMap<String, JobRecord>,
    /// Ids of the jobs waiting to run, in order.
    order: Vec<String>,
    next_id: u64,
    /// Records (and the queue's order) changed in memory but not yet on disk.
    unsaved: BTreeSet<String>,
    order_unsaved: bool,
    /// The last write that failed, until every record is on disk again.
    storage_error: Option<String>,
}

/// Writes `bytes` to `path` so that the file is either wholly old or wholly new,
/// even across a power loss.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |e: std::io::Error| Error::Io(format!("{}: cannot write: {e}", path.display()));
    let tmp = path.with_extension("tmp");
    let mut file = std::fs::File::create(&tmp).map_err(io)?;
    file.write_all(bytes).map_err(io)?;
    file.sync_all().map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)?;
    if let Some(parent) = path.parent() {
        // The rename is durable once the folder is.
        std::fs::File::open(parent).and_then(|d| d.sync_all()).map_err(io)?;
    }
    Ok(())
}

impl JobRecord {
    /// The line a resume starts at: `from` if given, else the one after the
    /// last executed line; refused when that is unknown (the controller's
    /// reports proved nothing of which lines ran).
    pub fn resume_line(&self, from: Option<usize>) -> Result<usize> {
        match (from, self.last_executed_line) {
            (Some(from), _) => Ok(from),
            (None, Some(done)) => Ok(done + 1),
            (None, None) => Err(Error::Conflict(format!(
                "job {}: which of its lines ran is unknown (the controller's status reports do not show its buffers; `$10=3` makes them): give the line to resume from",
                self.id
            ))),
        }
    }
}

/// An executed line as messages show it (`unknown` for `None`).
pub fn shown_line(line: Option<usize>) -> String {
    line.map_or_else(|| "unknown".to_string(), |n| n.to_string())
}

/// Unix time now (s).
/// A job's picture and line times, in its folder beside its program (the
/// planning process knows only the program's path).
pub const PLOT_FILE: &str = "plot.svg";
pub const TIMES_FILE: &str = "times.bin";

pub fn now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

impl Store {
    /// Opens (or creates) the store in `dir`. Jobs that were running or paused
    /// when the daemon last stopped are marked interrupted, and jobs caught
    /// while planning are planned again (they stay `Planning` for the caller).
    pub fn open(dir: &Path) -> Result<Store> {
        let jobs_dir = dir.join("jobs");
        std::fs::create_dir_all(&jobs_dir).map_err(|e| Error::Io(format!("{}: cannot create: {e}", jobs_dir.display())))?;
        let mut jobs = BTreeMap::new();
        let mut next_id = 1;
        let mut behind = BTreeSet::new();
        let entries = std::fs::read_dir(&jobs_dir).map_err(|e| Error::Io(format!("{}: cannot read: {e}", jobs_dir.display())))?;
        for entry in entries.flatten() {
            let file = entry.path().join("job.json");
            let Ok(text) = std::fs::read_to_string(&file) else { continue };
            let record: JobRecord = match serde_json::from_str(&text) {
                Ok(r) => r,
                Err(e) => {
                    tracing::warn!("{}: unreadable job record, skipped: {e}", file.display());
                    continue;
                }
            };
            let mut record = record;
            if ProgressFile::read(&entry.path().join(PROGRESS_FILE)).is_some_and(|p| p.merge_into(&mut record)) {
                behind.insert(record.id.clone());
            }
            if let Ok(n) = record.id.trim_start_matches('j').parse::<u64>() {
                next_id = next_id.max(n + 1);
            }
            jobs.insert(record.id.clone(), record);
        }
        // The newest job may have been deleted: the id file still knows it.
        if let Some(n) = std::fs::read_to_string(dir.join(NEXT_ID_FILE)).ok().and_then(|t| t.trim().parse::<u64>().ok()) {
            next_id = next_id.max(n);
        }
        let order_file = dir.join("queue.json");
        let mut order: Vec<String> = match std::fs::read_to_string(&order_file) {
            Ok(text) => serde_json::from_str(&text).map_err(|e| Error::Config(format!("{}: {e}", order_file.display())))?,
            Err(_) => Vec::new(),
        };
        order.retain(|id| jobs.contains_key(id));
        // Records behind their progress file (the disk was full) are written
        // by the flush below.
        let mut store = Store { dir: dir.to_path_buf(), jobs, order, next_id, unsaved: behind, order_unsaved: false, storage_error: None };
        let cut_short: Vec<String> = store.jobs.values().filter(|j| matches!(j.state, JobState::Running | JobState::Paused)).map(|j| j.id.clone()).collect();
        for id in cut_short {
            store.update(&id, |j| {
                j.state = JobState::Interrupted;
                j.message = Some(format!("the daemon stopped while the job ran; last executed line {}", shown_line(j.last_executed_line)));
            })?;
        }
        // A job accepted but not yet queued (the daemon stopped while planning)
        // keeps its place: queued jobs first, in their order, then these.
        let waiting: Vec<String> = store.jobs.values().filter(|j| matches!(j.state, JobState::Queued | JobState::Planning)).map(|j| j.id.clone()).collect();
        for id in waiting {
            if !store.order.contains(&id) {
                store.order.push(id);
            }
        }
        store.order.retain(|id| matches!(store.jobs[id].state, JobState::Queued | JobState::Planning));
        store.order_unsaved = true;
        // A disk still full keeps the service up: the status says so and
        // the records are written once there is space.
        store.flush();
        Ok(store)
    }

    /// The state folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn job_dir(&self, id: &str) -> PathBuf {
        self.dir.join("jobs").join(id)
    }

    pub fn program_path(&self, id: &str) -> PathBuf {
        self.job_dir(id).join("program.nc")
    }

    pub fn recording_path(&self, id: &str) -> PathBuf {
        self.job_dir(id).join("recording.mcap")
    }

    /// The plan's picture (`plan --plot`).
    pub fn plot_path(&self, id: &str) -> PathBuf {
        self.job_dir(id).join(PLOT_FILE)
    }

    /// Each program line's planned end time and TCP (`eta::LineTimes`): the ETA.
    pub fn times_path(&self, id: &str) -> PathBuf {
        self.job_dir(id).join(TIMES_FILE)
    }

    pub fn progress_path(&self, id: &str) -> PathBuf {
        self.job_dir(id).join(PROGRESS_FILE)
    }

    /// Why the last write failed, while some record is not on disk.
    pub fn storage_error(&self) -> Option<&str> {
        self.storage_error.as_deref()
    }

    /// The submitted file, named as it was (its extension says how to read it).
    pub fn source_path(&self, id: &str) -> Option<PathBuf> {
        let name = &self.jobs.get(id)?.name;
        Some(self.job_dir(id).join(format!("source.{}", extension_of(name))))
    }

    /// Accepts a job: stores its source and its record (state `Planning`), and
    /// puts it at the end of the queue.
    pub fn add(&mut self, name: &str, source: &[u8], allow_precedence_violations: bool) -> Result<JobRecord> {
        let id = format!("j{:06}", self.next_id);
        let stored = self.add_as(&id, name, source, allow_precedence_violations);
        if let Err(e) = &stored {
            // Nothing of a job the disk could not take is kept.
            let _ = std::fs::remove_dir_all(self.job_dir(&id));
            self.jobs.remove(&id);
            self.failed(e);
        }
        stored
    }

    fn add_as(&mut self, id: &str, name: &str, source: &[u8], allow_precedence_violations: bool) -> Result<JobRecord> {
        // The id is spent before anything of the job is written: a job
        // deleted later never lends its id to another.
        write_atomic(&self.dir.join(NEXT_ID_FILE), format!("{}\n", self.next_id + 1).as_bytes())?;
        self.next_id += 1;
        let dir = self.job_dir(id);
        std::fs::create_dir_all(&dir).map_err(|e| Error::Io(format!("{}: cannot create: {e}", dir.display())))?;
        let id = id.to_string();
        let record = JobRecord {
            id: id.clone(),
            name: name.to_string(),
            state: JobState::Planning,
            submitted_at: now(),
            started_at: None,
            ended_at: None,
            lines_total: 0,
            last_acked_line: 0,
            last_executed_line: Some(0),
            planned_time_s: None,
            precedence_violations: None,
            allow_precedence_violations,
            start: None,
            message: None,
            warnings: Vec::new(),
            bytes_sent: 0,
            stream_time_s: 0.0,
            link_utilization: None,
            bounds: None,
            figures: None,
            executed_time_s: None,
        };
        write_atomic(&dir.join(format!("source.{}", extension_of(name))), source)?;
        self.jobs.insert(id.clone(), record.clone());
        self.save_job(&id)?;
        self.order.push(id);
        self.order_unsaved = true;
        self.flush();
        Ok(record)
    }

    pub fn get(&self, id: &str) -> Option<&JobRecord> {
        self.jobs.get(id)
    }

    /// Every job, the queue's first, in queue order, then the others newest first.
    pub fn list(&self) -> Vec<JobRecord> {
        let mut out: Vec<JobRecord> = self.order.iter().map(|id| self.jobs[id].clone()).collect();
        let mut rest: Vec<&JobRecord> = self.jobs.values().filter(|j| !self.order.contains(&j.id)).collect();
        rest.sort_by(|a, b| b.id.cmp(&a.id));
        out.extend(rest.into_iter().cloned());
        out
    }

    /// The queue's order (ids of the jobs waiting).
    pub fn order(&self) -> &[String] {
        &self.order
    }

    /// Changes a job's record and stores it. Only an unknown job is an
    /// error: a record the disk cannot take now is kept in memory, written
    /// by a later `flush`, and the failure shown by `storage_error`.
    pub fn update(&mut self, id: &str, change: impl FnOnce(&mut JobRecord)) -> Result<JobRecord> {
        let job = self.change(id, change)?;
        self.unsaved.insert(id.to_string());
        self.flush();
        Ok(job)
    }

    /// Changes a job's record in memory only (progress shown by the API,
    /// kept on disk by the job's `ProgressFile`).
    pub fn change(&mut self, id: &str, change: impl FnOnce(&mut JobRecord)) -> Result<JobRecord> {
        let job = self.jobs.get_mut(id).ok_or_else(|| Error::NotFound(format!("no job {id}")))?;
        change(job);
        let job = job.clone();
        if !matches!(job.state, JobState::Queued | JobState::Planning) && self.order.contains(&job.id) {
            self.order.retain(|o| o != id);
            self.order_unsaved = true;
        }
        Ok(job)
    }

    /// Writes what is not on disk yet; true when everything is.
    pub fn flush(&mut self) -> bool {
        let pending: Vec<String> = self.unsaved.iter().cloned().collect();
        for id in pending {
            // A job removed meanwhile has nothing left to write.
            if !self.jobs.contains_key(&id) {
                self.unsaved.remove(&id);
                continue;
            }
            match self.save_job(&id) {
                Ok(()) => {
                    self.unsaved.remove(&id);
                }
                Err(e) => return self.failed(&e),
            }
        }
        if self.order_unsaved {
            if let Err(e) = self.save_order() {
                return self.failed(&e);
            }
            self.order_unsaved = false;
        }
        if let Some(was) = self.storage_error.take() {
            tracing::info!("the state folder takes writes again (it had failed: {was})");
        }
        true
    }

    /// Notes a failed write (logged once per new failure); false.
    fn failed(&mut self, e: &Error) -> bool {
        let why = e.to_string();
        if self.storage_error.as_deref() != Some(why.as_str()) {
            tracing::error!("storage: {why}; the records are kept in memory and written when it takes writes again");
        }
        self.storage_error = Some(why);
        false
    }


    /// Moves a waiting job to `position` (0 = next) in the queue.
    pub fn reorder(&mut self, id: &str, position: usize) -> Result<()> {
        let Some(at) = self.order.iter().position(|o| o == id) else {
            return Err(Error::Conflict(format!("job {id} is not waiting in the queue")));
        };
        let id = self.order.remove(at);
        let position = position.min(self.order.len());
        self.order.insert(position, id);
        self.order_unsaved = true;
        self.flush();
        Ok(())
    }

    /// Deletes a job that is not running: its record, files and place in the queue.
    pub fn remove(&mut self, id: &str) -> Result<()> {
        let job = self.jobs.get(id).ok_or_else(|| Error::NotFound(format!("no job {id}")))?;
        if matches!(job.state, JobState::Running | JobState::Paused) {
            return Err(Error::Conflict(format!("job {id} is running: abort it first")));
        }
        self.order.retain(|o| o != id);
        self.order_unsaved = true;
        self.jobs.remove(id);
        self.unsaved.remove(id);
        self.flush();
        let dir = self.job_dir(id);
        std::fs::remove_dir_all(&dir).map_err(|e| Error::Io(format!("{}: cannot remove: {e}", dir.display())))
    }

    /// Deletes the oldest finished jobs (with their recordings) beyond `keep`.
    pub fn prune(&mut self, keep: usize) -> Result<Vec<String>> {
        let mut finished: Vec<&JobRecord> = self.jobs.values().filter(|j| j.state.is_final()).collect();
        finished.sort_by(|a, b| b.id.cmp(&a.id));
        let old: Vec<String> = finished.iter().skip(keep).map(|j| j.id.clone()).collect();
        for id in &old {
            self.remove(id)?;
        }
        Ok(old)
    }

    fn save_job(&self, id: &str) -> Result<()> {
        let job = &self.jobs[id];
        let text = serde_json::to_vec_pretty(job).map_err(|e| Error::Io(e.to_string()))?;
        write_atomic(&self.job_dir(id).join("job.json"), &text)
    }

    fn save_order(&self) -> Result<()> {
        let text = serde_json::to_vec(&self.order).map_err(|e| Error::Io(e.to_string()))?;
        write_atomic(&self.dir.join("queue.json"), &text)
    }
}

/// The name of a job's progress file in its folder.
const PROGRESS_FILE: &str = "progress";
/// The next job id, in the state folder.
const NEXT_ID_FILE: &str = "next-id";
/// The progress file's fixed size: one disk sector, written whole in place.
const PROGRESS_BYTES: usize = 512;

/// A running job's progress as the progress file keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub state: JobState,
    pub last_acked_line: usize,
    pub last_executed_line: Option<usize>,
    #[serde(default)]
    pub ended_at: Option<f64>,
}

impl Progress {
    /// Brings a record up to this progress (the record may have missed the
    /// last writes); true if it changed.
    fn merge_into(&self, job: &mut JobRecord) -> bool {
        let before = job.clone();
        job.last_acked_line = job.last_acked_line.max(self.last_acked_line);
        job.last_executed_line = match (job.last_executed_line, self.last_executed_line) {
            (Some(a), Some(b)) => Some(a.max(b)),
            // The newer file: lines were answered since that no report showed done.
            (Some(a), None) if self.last_acked_line > a => None,
            (a, b) => a.or(b),
        };
        if self.state.is_final() && matches!(job.state, JobState::Running | JobState::Paused) {
            job.state = self.state;
            job.ended_at = self.ended_at;
            if self.state == JobState::Completed {
                job.message = None;
            }
        }
        *job != before
    }
}

/// A running job's progress on disk: a file of one sector, allocated before
/// the job starts and rewritten in place, so that a disk filling up while
/// the job runs (its recording grows) cannot stop the progress being saved.
/// (On copy-on-write file systems, btrfs or ZFS, an in-place write still
/// needs space: there the state folder wants a quota of its own.)
pub struct ProgressFile {
    file: std::fs::File,
    path: PathBuf,
    /// What was written last, and when it last reached the disk.
    written: std::sync::Mutex<(Option<Progress>, std::time::Instant)>,
}

/// How often a running job's progress is flushed to the disk (for a power
/// loss); every write reaches the page cache at once, which a crash of the
/// service does not lose.
const PROGRESS_SYNC: std::time::Duration = std::time::Duration::from_millis(500);

impl ProgressFile {
    /// Allocates the file (an error if the disk cannot take even that).
    pub fn create(path: &Path) -> Result<ProgressFile> {
        let io = |e: std::io::Error| Error::Io(format!("{}: cannot write: {e}", path.display()));
        let file = std::fs::OpenOptions::new().create(true).truncate(true).read(true).write(true).open(path).map_err(io)?;
        file.write_all_at(&[b' '; PROGRESS_BYTES], 0).map_err(io)?;
        file.sync_all().map_err(io)?;
        if let Some(parent) = path.parent() {
            std::fs::File::open(parent).and_then(|d| d.sync_all()).map_err(io)?;
        }
        Ok(ProgressFile { file, path: path.to_path_buf(), written: std::sync::Mutex::new((None, std::time::Instant::now())) })
    }

    /// Rewrites the progress in place if it changed; flushes it to the disk
    /// at the end of the job and at most every `PROGRESS_SYNC` before.
    pub fn write(&self, progress: &Progress) -> Result<()> {
        let io = |e: std::io::Error| Error::Io(format!("{}: cannot write: {e}", self.path.display()));
        let mut written = self.written.lock().unwrap_or_else(|e| e.into_inner());
        if written.0.as_ref() != Some(progress) {
            let mut bytes = serde_json::to_vec(progress).map_err(|e| Error::Io(e.to_string()))?;
            bytes.resize(PROGRESS_BYTES, b' ');
            self.file.write_all_at(&bytes, 0).map_err(io)?;
            written.0 = Some(progress.clone());
        }
        if progress.state.is_final() || written.1.elapsed() >= PROGRESS_SYNC {
            self.file.sync_data().map_err(io)?;
            written.1 = std::time::Instant::now();
        }
        Ok(())
    }

    /// What a progress file says, if it says anything readable.
    pub fn read(path: &Path) -> Option<Progress> {
        let bytes = std::fs::read(path).ok().filter(|b| b.len() <= PROGRESS_BYTES)?;
        serde_json::from_slice(&bytes).ok()
    }
}

/// A submitted file's extension, lower case (`svg`, `dxf`, `nc`, …); `nc` when it has none.
fn extension_of(name: &str) -> String {
    Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .filter(|e| !e.is_empty() && e.len() <= 8 && e.chars().all(|c| c.is_ascii_alphanumeric()))
        .map_or_else(|| "nc".to_string(), |e| e.to_ascii_lowercase())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_queue_survives_a_restart_in_order_and_a_running_job_comes_back_interrupted() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b, c) = {
            let mut store = Store::open(dir.path()).unwrap();
            let a = store.add("a.svg", b"<svg/>", false).unwrap().id;
            let b = store.add("b.nc", b"G1X1\n", false).unwrap().id;
            let c = store.add("c.dxf", b"0\nEOF\n", false).unwrap().id;
            for id in [&a, &b, &c] {
                store.update(id, |j| j.state = JobState::Queued).unwrap();
            }
            store.reorder(&c, 0).unwrap();
            store
                .update(&a, |j| {
                    j.state = JobState::Running;
                    j.last_executed_line = Some(120);
                })
                .unwrap();
            (a, b, c)
            // Dropped without any shutdown: as after a kill -9.
        };
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(store.order(), &[c.clone(), b.clone()], "the waiting jobs in their order");
        let a = store.get(&a).unwrap();
        assert_eq!(a.state, JobState::Interrupted);
        assert_eq!(a.last_executed_line, Some(120));
        assert!(a.message.as_deref().unwrap().contains("120"));
        assert_eq!(std::fs::read(store.source_path(&b).unwrap()).unwrap(), b"G1X1\n");
        assert!(store.source_path(&c).unwrap().ends_with("source.dxf"));
        // New ids never reuse old ones.
        let mut store = store;
        let d = store.add("d.svg", b"<svg/>", false).unwrap();
        assert!(d.id > c, "{} after {c}", d.id);
    }

    #[test]
    fn a_resume_after_an_unknown_executed_line_asks_for_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        let mut job = store.add("a.nc", b"G1X1\n", false).unwrap();
        job.last_executed_line = Some(41);
        assert_eq!(job.resume_line(None).unwrap(), 42);
        assert_eq!(job.resume_line(Some(7)).unwrap(), 7);
        job.last_executed_line = None;
        let refused = job.resume_line(None).unwrap_err().to_string();
        assert!(refused.contains("unknown") && refused.contains("give the line"), "{refused}");
        assert_eq!(job.resume_line(Some(7)).unwrap(), 7);
    }

    #[test]
    fn running_jobs_cannot_be_removed_and_old_finished_jobs_are_pruned() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        let ids: Vec<String> = (0..5).map(|k| store.add(&format!("{k}.nc"), b"G0X0\n", false).unwrap().id).collect();
        store.update(&ids[0], |j| j.state = JobState::Running).unwrap();
        assert!(matches!(store.remove(&ids[0]), Err(Error::Conflict(_))));
        assert!(matches!(store.remove("j999999"), Err(Error::NotFound(_))));
        for id in &ids[1..] {
            store.update(id, |j| j.state = JobState::Completed).unwrap();
        }
        let pruned = store.prune(2).unwrap();
        assert_eq!(pruned, vec![ids[2].clone(), ids[1].clone()]);
        assert!(!store.job_dir(&ids[1]).exists());
        assert!(store.get(&ids[4]).is_some() && store.get(&ids[0]).is_some());
        assert!(matches!(store.reorder(&ids[4], 0), Err(Error::Conflict(_))), "a finished job is not in the queue");
    }

    #[test]
    fn ids_are_never_reused_even_after_the_newest_job_is_deleted() {
        let dir = tempfile::tempdir().unwrap();
        let newest = {
            let mut store = Store::open(dir.path()).unwrap();
            store.add("a.nc", b"G0X0\n", false).unwrap();
            let b = store.add("b.nc", b"G0X0\n", false).unwrap().id;
            store.remove(&b).unwrap();
            b
        };
        let mut store = Store::open(dir.path()).unwrap();
        let c = store.add("c.nc", b"G0X0\n", false).unwrap().id;
        assert!(c > newest, "{c} after the deleted {newest}");
    }

    #[test]
    fn the_progress_file_brings_a_record_that_missed_its_writes_up_to_date() {
        let dir = tempfile::tempdir().unwrap();
        let (done, cut) = {
            let mut store = Store::open(dir.path()).unwrap();
            let done = store.add("done.nc", b"G0X0\n", false).unwrap().id;
            let cut = store.add("cut.nc", b"G0X0\n", false).unwrap().id;
            for id in [&done, &cut] {
                store.update(id, |j| {
                    j.state = JobState::Running;
                    j.lines_total = 8038;
                    j.last_executed_line = Some(6818);
                })
                .unwrap();
            }
            // The disk filled up: job.json stayed at line 6818 while the
            // progress files, written in place, went on.
            let progress = ProgressFile::create(&store.progress_path(&done)).unwrap();
            progress.write(&Progress { state: JobState::Running, last_acked_line: 8000, last_executed_line: Some(7990), ended_at: None }).unwrap();
            progress.write(&Progress { state: JobState::Completed, last_acked_line: 8038, last_executed_line: Some(8038), ended_at: Some(1.0) }).unwrap();
            let progress = ProgressFile::create(&store.progress_path(&cut)).unwrap();
            progress.write(&Progress { state: JobState::Running, last_acked_line: 7700, last_executed_line: Some(7690), ended_at: None }).unwrap();
            (done, cut)
        };
        let store = Store::open(dir.path()).unwrap();
        let done = store.get(&done).unwrap();
        assert_eq!((done.state, done.last_executed_line), (JobState::Completed, Some(8038)), "completed, not offered for resume at 6818");
        let cut = store.get(&cut).unwrap();
        assert_eq!((cut.state, cut.last_acked_line, cut.last_executed_line), (JobState::Interrupted, 7700, Some(7690)));
        // And the records are on disk now.
        let on_disk: JobRecord = serde_json::from_slice(&std::fs::read(store.job_dir(&done.id).join("job.json")).unwrap()).unwrap();
        assert_eq!(on_disk.state, JobState::Completed);
    }

    #[test]
    fn a_torn_write_leaves_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.json");
        write_atomic(&path, b"old").unwrap();
        // A crash between writing the temporary file and the rename.
        std::fs::write(path.with_extension("tmp"), b"ne").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        write_atomic(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
    }
}
