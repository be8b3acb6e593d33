//! Record and replay: MCAP files with JSON messages described by JSON Schemas,
//! which Foxglove opens and plots (e.g. `/sim/axes.tcp_x` over time).
//!
//! Writing happens on a thread of its own, fed through a channel, so neither the
//! sender nor the real-time simulator ever waits for the disk. The file is
//! flushed about once a second, so a run cut short keeps what came before.
//!
//! Channels:
//! - `/run/setup`   machine setup of the run (axes and limits, baud, field, the
//!   machine config as run, whether recorded in real time)
//! - `/run/job`     job and plan summary
//! - `/plan/lines`  each program line: kind and planned check points
//! - `/link`        each line sent and received, each realtime byte, with its time
//! - `/status`      parsed status reports
//! - `/sim/axes`    the executed motion: axis positions, TCP and laser power.
//!   Of the simulator in a dry-run: at every block boundary (motion is linear
//!   in between), and where the laser changes while the machine stands still
//!   (a pierce). Of a controller on a link (the service): at each of its
//!   status reports, as it reported it (`ReportedMotion`)
//! - `/run/report`  the final report
//!
//! A recorder may also carry the live server (`live.rs`): every message then
//! goes to it too; one without a file (`Recorder::live_only`) writes only there.

pub mod live;

use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{unbounded, RecvTimeoutError, Sender};
use laserd_sim::controller::Knot;
use laserd_sim::wire::{Response, StatusReport};
use mcap::records::MessageHeader;
use schemars::JsonSchema;
use serde::{de::DeserializeOwned, Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::figures::{PlannedLine, RunLog, RunSetup};
use crate::stream::LinkEvent;

pub const TOPIC_SETUP: &str = "/run/setup";
pub const TOPIC_JOB: &str = "/run/job";
pub const TOPIC_PLAN_LINES: &str = "/plan/lines";
pub const TOPIC_LINK: &str = "/link";
pub const TOPIC_STATUS: &str = "/status";
pub const TOPIC_AXES: &str = "/sim/axes";
pub const TOPIC_REPORT: &str = "/run/report";
/// `--thermal`: the plate's temperatures over the planned job (Foxglove's Grid).
pub const TOPIC_PLATE_HEAT: &str = "/thermal/plate";

const FLUSH_INTERVAL: Duration = Duration::from_secs(1);

/// A link event with its time (seconds from the start of the run).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct LinkMessage {
    pub t: f64,
    #[serde(flatten)]
    pub event: LinkEvent,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct StatusMessage {
    pub t: f64,
    #[serde(flatten)]
    pub status: StatusReport,
}

/// The plate's temperatures at one time as Foxglove's `foxglove.Grid` (JSON
/// encoding): one float32 field `celsius` per cell, rows from the plate's
/// lower-left corner, in the machine's frame and millimetres.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[schemars(rename = "foxglove.Grid")]
pub struct GridMessage {
    pub timestamp: GridTime,
    pub frame_id: String,
    pub pose: GridPose,
    pub column_count: u32,
    pub cell_size: GridVector2,
    pub row_stride: u32,
    pub cell_stride: u32,
    pub fields: Vec<GridField>,
    /// The cells' bytes (little-endian float32), base64.
    pub data: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GridTime {
    pub sec: u32,
    pub nsec: u32,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GridVector2 {
    pub x: f64,
    pub y: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GridVector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GridQuaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GridPose {
    pub position: GridVector3,
    pub orientation: GridQuaternion,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct GridField {
    pub name: String,
    pub offset: u32,
    /// Foxglove's NumericType: 7 is FLOAT32.
    #[serde(rename = "type")]
    pub kind: u32,
}

impl GridMessage {
    pub fn of_plate(grid: &crate::thermal::Grid, plate: &crate::thermal::Snapshot) -> GridMessage {
        use base64::Engine;
        let bytes: Vec<u8> = plate.celsius.iter().flat_map(|t| t.to_le_bytes()).collect();
        GridMessage {
            timestamp: GridTime { sec: plate.time.max(0.0).floor() as u32, nsec: (plate.time.max(0.0).fract() * 1e9) as u32 },
            frame_id: "machine".into(),
            pose: GridPose { position: GridVector3 { x: grid.origin.x, y: grid.origin.y, z: 0.0 }, orientation: GridQuaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 } },
            column_count: grid.nx as u32,
            cell_size: GridVector2 { x: grid.cell, y: grid.cell },
            row_stride: 4 * grid.nx as u32,
            cell_stride: 4,
            fields: vec![GridField { name: "celsius".into(), offset: 0, kind: 7 }],
            data: base64::engine::general_purpose::STANDARD.encode(bytes),
        }
    }
}

/// One executed knot, with named fields for plotting.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct AxesMessage {
    pub t: f64,
    /// All axis positions in controller order.
    pub pos: Vec<f64>,
    pub power: f64,
    /// Received-line number of the block.
    pub line: u64,
    pub stage_x: f64,
    pub stage_y: f64,
    pub scanner_x: Option<f64>,
    pub scanner_y: Option<f64>,
    pub tcp_x: f64,
    pub tcp_y: f64,
}

impl AxesMessage {
    pub fn from_knot(k: &Knot) -> AxesMessage {
        let tcp = crate::program::tcp_of(&k.pos);
        AxesMessage {
            t: k.t,
            pos: k.pos.clone(),
            power: k.power,
            line: k.line,
            stage_x: k.pos.first().copied().unwrap_or(0.0),
            stage_y: k.pos.get(1).copied().unwrap_or(0.0),
            scanner_x: k.pos.get(2).copied(),
            scanner_y: k.pos.get(3).copied(),
            tcp_x: tcp.x,
            tcp_y: tcp.y,
        }
    }

    pub fn to_knot(&self) -> Knot {
        Knot { t: self.t, pos: self.pos.clone(), power: self.power, line: self.line }
    }
}

struct Envelope {
    topic: &'static str,
    /// JSON Schema of the message type, sent with the first message of a topic.
    schema: Option<(String, Vec<u8>)>,
    t: f64,
    data: Vec<u8>,
}

/// Handle to a recording; clones write to the same file.
#[derive(Clone)]
pub struct Recorder {
    /// The file's writer thread; `None`: live only.
    tx: Option<Sender<Envelope>>,
    live: Option<Arc<live::Live>>,
    registered: Arc<Mutex<HashSet<&'static str>>>,
    /// Knots from the controller's status reports (a link, not the simulator).
    reported: Option<Arc<Mutex<ReportedMotion>>>,
}

/// The executed motion as a controller reports it: a knot at each status
/// report, at the time it came, at the machine position it gives (`WPos`
/// plus the last `WCO` when it reports work positions), with its laser S.
/// A report does not say which block runs: the knots' line is 0.
#[derive(Debug, Default)]
pub struct ReportedMotion {
    wco: Option<Vec<f64>>,
}

impl ReportedMotion {
    /// The knot of a report; `None` while the machine position is unknown
    /// (work positions before any `WCO`) or not a number.
    pub fn knot(&mut self, t: f64, report: &StatusReport) -> Option<Knot> {
        if let Some(wco) = &report.wco {
            self.wco = Some(wco.clone());
        }
        let pos: Vec<f64> = match (&report.wpos, &self.wco) {
            (Some(wpos), Some(wco)) if report.mpos.is_empty() => wpos.iter().zip(wco).map(|(p, o)| p + o).collect(),
            _ => report.mpos.clone(),
        };
        (!pos.is_empty() && pos.iter().all(|p| p.is_finite()))
            .then(|| Knot { t, pos, power: report.spindle.filter(|s| s.is_finite()).unwrap_or(0.0), line: 0 })
    }
}

/// Owns the writer thread; `finish` closes the file properly.
pub struct Recording {
    pub path: PathBuf,
    recorder: Option<Recorder>,
    thread: Option<JoinHandle<Result<()>>>,
}

impl Recording {
    pub fn create(path: &Path) -> Result<Recording> {
        let file = File::create(path).map_err(|e| Error::Record(format!("{}: cannot create: {e}", path.display())))?;
        let mut writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(0)
            .chunk_size(Some(1 << 20))
            .profile("")
            .library("laserd")
            .create(BufWriter::new(file))
            .map_err(|e| Error::Record(format!("{}: {e}", path.display())))?;
        let (tx, rx) = unbounded::<Envelope>();
        let base_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        let shown = path.display().to_string();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || -> Result<()> {
                let err = |e: mcap::McapError| Error::Record(format!("{shown}: {e}"));
                let mut channels: BTreeMap<&'static str, u16> = BTreeMap::new();
                let mut sequence = 0u32;
                let mut last_flush = std::time::Instant::now();
                loop {
                    // Close a chunk at least every second, busy or not, so that a
                    // crash loses at most the last second.
                    if last_flush.elapsed() >= FLUSH_INTERVAL {
                        writer.flush().map_err(err)?;
                        last_flush = std::time::Instant::now();
                    }
                    match rx.recv_timeout(FLUSH_INTERVAL) {
                        Ok(env) => {
                            if let Some((name, schema)) = &env.schema {
                                let schema_id = writer.add_schema(name, "jsonschema", schema).map_err(err)?;
                                let id = writer.add_channel(schema_id, env.topic, "json", &BTreeMap::new()).map_err(err)?;
                                channels.insert(env.topic, id);
                            }
                            let Some(&channel_id) = channels.get(env.topic) else { continue };
                            sequence += 1;
                            let time = base_ns + (env.t.max(0.0) * 1e9) as u64;
                            let header = MessageHeader { channel_id, sequence, log_time: time, publish_time: time };
                            writer.write_to_known_channel(&header, &env.data).map_err(err)?;
                        }
                        Err(RecvTimeoutError::Timeout) => {}
                        Err(RecvTimeoutError::Disconnected) => break,
                    }
                }
                writer.finish().map_err(err)?;
                Ok(())
            })
            .map_err(|e| Error::Record(format!("cannot start the recorder thread: {e}")))?;
        let recorder = Recorder { tx: Some(tx), live: None, registered: Arc::new(Mutex::new(HashSet::new())), reported: None };
        Ok(Recording { path: path.to_path_buf(), recorder: Some(recorder), thread: Some(thread) })
    }

    pub fn recorder(&self) -> Recorder {
        self.recorder.clone().expect("recorder is present until finish")
    }

    /// Closes the file (summary, index, end magic). Every `Recorder` clone must be
    /// dropped first, or this waits for them.
    pub fn finish(mut self) -> Result<()> {
        self.close()
    }

    fn close(&mut self) -> Result<()> {
        self.recorder = None;
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| Error::Record("the recorder thread panicked".into()))?,
            None => Ok(()),
        }
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        let _ = self.close();
    }
}

impl Recorder {
    /// Records `msg` on `topic` at run time `t` (seconds).
    pub fn write<T: Serialize + JsonSchema>(&self, topic: &'static str, t: f64, msg: &T) {
        // Live: only where a client subscribed to the topic.
        let live = self.live.as_ref().and_then(|l| l.channel(topic, live::schema_of::<T>)).filter(|c| c.has_sinks());
        let Some(tx) = &self.tx else {
            if let Some(channel) = live {
                if let Ok(data) = serde_json::to_vec(msg) {
                    live::Live::send(&channel, &data);
                }
            }
            return;
        };
        let schema = {
            let mut reg = self.registered.lock().unwrap_or_else(|p| p.into_inner());
            reg.insert(topic).then(live::schema_of::<T>)
        };
        let data = match serde_json::to_vec(msg) {
            Ok(d) => d,
            Err(_) => return,
        };
        if let Some(channel) = live {
            live::Live::send(&channel, &data);
        }
        // A closed recorder (its thread failed) loses the message but never stops
        // the machine: the run's own error path reports the recording failure.
        let _ = tx.send(Envelope { topic, schema, t, data });
    }

    /// A recorder that also sends every message to `live` (none: as it was).
    pub fn with_live(self, live: Option<Arc<live::Live>>) -> Recorder {
        Recorder { live, ..self }
    }

    /// A recorder without a file: its messages go to `live` only.
    pub fn live_only(live: Arc<live::Live>) -> Recorder {
        Recorder { tx: None, live: Some(live), registered: Arc::default(), reported: None }
    }

    /// The live server this recorder sends to, if any.
    pub fn live(&self) -> Option<Arc<live::Live>> {
        self.live.clone()
    }

    /// A recorder that also takes the controller's status reports as the
    /// executed motion (for a controller on a link, whose knots nobody else
    /// records).
    pub fn with_reported_motion(self) -> Recorder {
        Recorder { reported: Some(Arc::default()), ..self }
    }

    pub fn link_event(&self, t: f64, event: &LinkEvent) {
        self.write(TOPIC_LINK, t, &LinkMessage { t, event: event.clone() });
        if let LinkEvent::Received { text } = event {
            if let Response::Status(status) = Response::parse(text) {
                if let Some(reported) = &self.reported {
                    let knot = reported.lock().unwrap_or_else(|p| p.into_inner()).knot(t, &status);
                    self.knots(knot.as_slice());
                }
                self.write(TOPIC_STATUS, t, &StatusMessage { t, status });
            }
        }
    }

    pub fn knots(&self, knots: &[Knot]) {
        for k in knots {
            self.write(TOPIC_AXES, k.t, &AxesMessage::from_knot(k));
        }
    }
}

/// Everything a recording holds that the figures need, plus the job summary
/// and report as written.
#[derive(Debug, Default)]
pub struct Replay {
    pub log: RunLog,
    pub job: Option<serde_json::Value>,
    pub report: Option<serde_json::Value>,
    /// Set when the file ended early (a run cut short): what came before is kept.
    pub truncated: Option<String>,
}

/// Longest record (and decompressed chunk) a recording may hold: far above
/// what laserd writes (chunks of the writer's default size, each message one
/// line, knot or report), far below what a corrupt length field could make
/// the reader allocate.
const RECORD_LIMIT: usize = 64 << 20;

fn decode<T: DeserializeOwned>(topic: &str, data: &[u8]) -> std::result::Result<T, String> {
    serde_json::from_slice(data).map_err(|e| format!("bad message on {topic}: {e}"))
}

/// Reads a recording linearly, tolerating a missing end (a crash mid-run).
/// A corrupt part (a record or chunk whose lengths, checksum or contents do
/// not hold) ends the reading as a cut-off file does: what came before is
/// kept and `truncated` says why. Memory stays within a few `RECORD_LIMIT`s
/// whatever the file's lengths claim.
pub fn read(path: &Path) -> Result<Replay> {
    let shown = path.display();
    let mut file = File::open(path).map_err(|e| Error::Record(format!("{shown}: cannot read: {e}")))?;
    let ends_with_magic = ends_with(&mut file, mcap::MAGIC).map_err(|e| Error::Record(format!("{shown}: cannot read: {e}")))?;
    let options = mcap::sans_io::LinearReaderOptions::default()
        .with_skip_end_magic(true)
        .with_record_length_limit(RECORD_LIMIT)
        .with_emit_chunks(true);
    // Records are taken from the reader raw, chunks too, and only the ones
    // laserd needs are decoded, by hand, every length checked against what
    // holds it: the crate's parser reserves a string's claimed length (up to
    // 4 GB) before reading it, and its chunk walk underflows on a record
    // longer than its chunk.
    let mut reader = mcap::sans_io::LinearReader::new_with_options(options);
    let mut file = std::io::BufReader::new(file);
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    let mut out = Replay::default();
    let mut records = 0usize;
    loop {
        let event = match reader.next_event() {
            None => break,
            Some(Ok(event)) => event,
            Some(Err(e)) if records == 0 => return Err(Error::Record(format!("{shown}: not a readable MCAP file: {e}"))),
            Some(Err(e)) => {
                out.truncated = Some(e.to_string());
                break;
            }
        };
        match event {
            mcap::sans_io::LinearReadEvent::ReadRequest(need) => {
                let buffer = reader.insert(need);
                let got = std::io::Read::read(&mut file, buffer).map_err(|e| Error::Record(format!("{shown}: cannot read: {e}")))?;
                reader.notify_read(got);
            }
            mcap::sans_io::LinearReadEvent::Record { data, opcode } => {
                records += 1;
                let taken = match opcode {
                    mcap::records::op::CHUNK => chunk_records(data).and_then(|inner| {
                        let mut rest = &inner[..];
                        while !rest.is_empty() {
                            let (opcode, body, after) = split_record(rest)?;
                            out.take_record(&mut topics, opcode, body)?;
                            rest = after;
                        }
                        Ok(())
                    }),
                    _ => out.take_record(&mut topics, opcode, data),
                };
                if let Err(why) = taken {
                    out.truncated = Some(why);
                    break;
                }
            }
        }
    }
    if out.truncated.is_none() && !ends_with_magic {
        out.truncated = Some("no end of file record: the recording was cut off".into());
    }
    if out.log.setup.is_none() {
        return Err(Error::Record(format!("{shown}: no {TOPIC_SETUP} message: not a laserd recording")));
    }
    Ok(out)
}

impl Replay {
    /// One record (not a chunk) into the replay: channels name topics,
    /// messages are taken; the rest is not needed.
    fn take_record(&mut self, topics: &mut BTreeMap<u16, String>, opcode: u8, body: &[u8]) -> std::result::Result<(), String> {
        match opcode {
            mcap::records::op::CHANNEL => {
                let (id, topic) = channel_topic(body)?;
                topics.insert(id, topic);
                Ok(())
            }
            mcap::records::op::MESSAGE => {
                let (channel, data) = message(body)?;
                match topics.get(&channel) {
                    Some(topic) => self.take(topic, data),
                    None => Err(format!("a message on channel {channel}, which no channel record defined")),
                }
            }
            _ => Ok(()),
        }
    }

    /// One message of the recording into the replay.
    fn take(&mut self, topic: &str, data: &[u8]) -> std::result::Result<(), String> {
        match topic {
            TOPIC_SETUP => self.log.setup = Some(decode::<RunSetup>(topic, data)?),
            TOPIC_PLAN_LINES => self.log.planned.push(decode::<PlannedLine>(topic, data)?),
            TOPIC_LINK => {
                let m: LinkMessage = decode(topic, data)?;
                self.log.link.push((m.t, m.event));
            }
            TOPIC_AXES => self.log.knots.push(decode::<AxesMessage>(topic, data)?.to_knot()),
            TOPIC_JOB => self.job = Some(decode(topic, data)?),
            TOPIC_REPORT => self.report = Some(decode(topic, data)?),
            _ => {}
        }
        Ok(())
    }
}

/// A channel record's id and topic (MCAP: id u16, schema id u16, topic as
/// a u32-length string, …), its lengths checked against the record.
fn channel_topic(body: &[u8]) -> std::result::Result<(u16, String), String> {
    let bad = || "a damaged channel record".to_string();
    let id = u16::from_le_bytes(body.get(0..2).ok_or_else(bad)?.try_into().map_err(|_| bad())?);
    let len = u32::from_le_bytes(body.get(4..8).ok_or_else(bad)?.try_into().map_err(|_| bad())?) as usize;
    let topic = body.get(8..8usize.checked_add(len).ok_or_else(bad)?).ok_or_else(bad)?;
    Ok((id, String::from_utf8(topic.to_vec()).map_err(|_| bad())?))
}

/// Little-endian integers at `at` of a record, if it holds them.
fn u32_at(body: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(body.get(at..at.checked_add(4)?)?.try_into().ok()?))
}

fn u64_at(body: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(body.get(at..at.checked_add(8)?)?.try_into().ok()?))
}

/// The records a chunk holds, decompressed within `RECORD_LIMIT` (MCAP:
/// start and end times u64, uncompressed size u64, CRC u32, compression as
/// a u32-length string, compressed size u64, the records).
fn chunk_records(body: &[u8]) -> std::result::Result<std::borrow::Cow<'_, [u8]>, String> {
    let bad = || "a damaged chunk".to_string();
    let uncompressed = u64_at(body, 16).ok_or_else(bad)?;
    let name_len = u32_at(body, 28).ok_or_else(bad)? as usize;
    let name = body.get(32..32usize.checked_add(name_len).ok_or_else(bad)?).ok_or_else(bad)?;
    let at = 32 + name_len;
    let size = u64_at(body, at).ok_or_else(bad)?;
    let records = body.get(at + 8..).filter(|r| r.len() as u64 == size).ok_or_else(bad)?;
    if uncompressed > RECORD_LIMIT as u64 {
        return Err(format!("a chunk claiming {uncompressed} bytes, more than {RECORD_LIMIT}"));
    }
    match name {
        b"" if uncompressed == size => Ok(records.into()),
        b"zstd" => {
            let data = zstd::bulk::decompress(records, uncompressed as usize).map_err(|e| format!("a damaged chunk: {e}"))?;
            if data.len() as u64 != uncompressed {
                return Err(bad());
            }
            Ok(data.into())
        }
        b"" => Err(bad()),
        other => Err(format!("a chunk compressed with {:?}, which laserd does not write", String::from_utf8_lossy(other))),
    }
}

/// The first record of `bytes` (opcode u8, length u64, body) and what
/// follows it.
fn split_record(bytes: &[u8]) -> std::result::Result<(u8, &[u8], &[u8]), String> {
    let bad = || "a damaged record in a chunk".to_string();
    let opcode = *bytes.first().ok_or_else(bad)?;
    let len = usize::try_from(u64_at(bytes, 1).ok_or_else(bad)?).map_err(|_| bad())?;
    let end = 9usize.checked_add(len).ok_or_else(bad)?;
    let body = bytes.get(9..end).ok_or_else(bad)?;
    Ok((opcode, body, &bytes[end..]))
}

/// A message record's channel and data (MCAP: channel u16, sequence u32,
/// log and publish times u64, then the data to the record's end).
fn message(body: &[u8]) -> std::result::Result<(u16, &[u8]), String> {
    let channel = body.get(0..2).ok_or("a damaged message record")?;
    let data = body.get(22..).ok_or("a damaged message record")?;
    Ok((u16::from_le_bytes([channel[0], channel[1]]), data))
}

/// Whether the file ends with `magic` (an MCAP file written to its end).
fn ends_with(file: &mut File, magic: &[u8]) -> std::io::Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    let len = file.metadata()?.len();
    if len < magic.len() as u64 {
        return Ok(false);
    }
    file.seek(SeekFrom::End(-(magic.len() as i64)))?;
    let mut tail = vec![0; magic.len()];
    file.read_exact(&mut tail)?;
    file.seek(SeekFrom::Start(0))?;
    Ok(tail == magic)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A channel record whose topic claims 4 GB inside a record of a few
    /// bytes is damaged, not a 4 GB allocation (fuzz/mcap_replay found the
    /// crate's parser reserving the claimed length first).
    #[test]
    fn record_lengths_are_checked_against_the_record_before_anything_is_taken() {
        let mut channel = vec![7, 0, 1, 0];
        channel.extend(4u32.to_le_bytes());
        channel.extend(b"/run");
        channel.extend(4u32.to_le_bytes());
        channel.extend(b"json");
        assert_eq!(channel_topic(&channel), Ok((7, "/run".to_string())));
        for claimed in [17u32, 0xffff_fff0, u32::MAX] {
            let mut damaged = channel.clone();
            damaged[4..8].copy_from_slice(&claimed.to_le_bytes());
            assert!(channel_topic(&damaged).is_err(), "topic length {claimed}");
        }
        assert!(channel_topic(&channel[..6]).is_err());
        let mut message_body = vec![7, 0];
        message_body.extend([0u8; 20]);
        message_body.extend(b"{}");
        assert_eq!(message(&message_body), Ok((7, &b"{}"[..])));
        assert!(message(&message_body[..21]).is_err());
    }
}

#[cfg(test)]
mod reported_motion_tests {
    use super::ReportedMotion;
    use laserd_sim::wire::StatusReport;

    #[test]
    fn a_report_is_a_knot_at_its_machine_position() {
        let mut motion = ReportedMotion::default();
        let report = |text: &str| StatusReport::parse(text).unwrap();
        let k = motion.knot(1.5, &report("<Run|MPos:1.000,2.000,0.000|FS:600,250>")).unwrap();
        assert_eq!((k.t, k.pos.clone(), k.power, k.line), (1.5, vec![1.0, 2.0, 0.0], 250.0, 0));
        // Work positions: unknown until a WCO came, then WPos + WCO.
        assert!(motion.knot(2.0, &report("<Run|WPos:1.000,2.000,0.000|FS:600,0>")).is_none());
        let k = motion.knot(2.2, &report("<Run|WPos:1.000,2.000,0.000|FS:600,0|WCO:10.000,0.000,0.000>")).unwrap();
        assert_eq!(k.pos, vec![11.0, 2.0, 0.0]);
        let k = motion.knot(2.4, &report("<Idle|WPos:2.000,2.000,0.000|FS:0,0>")).unwrap();
        assert_eq!(k.pos, vec![12.0, 2.0, 0.0]);
    }
}
