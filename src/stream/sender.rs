//! The sender: streams G-code lines to a GRBL-style controller over any byte
//! transport (serial port, pseudo-terminal, in-process pipe to the simulator).
//!
//! Flow control is GRBL's character counting: the byte lengths of lines sent but
//! not yet answered are kept in a FIFO, and a line goes out only when it fits in
//! what is left of the controller's receive buffer. Every `ok` or `error:N` pops
//! the oldest entry. Status requests (`?`) are realtime bytes: they never enter
//! the receive buffer and are not counted.
//!
//! On the first `error:` or `ALARM:` the sender stops streaming and brings the
//! machine to a safe stop: feed hold (the laser goes off in laser mode), wait for
//! the hold to complete, then soft reset, which flushes what the controller still
//! had queued and switches the laser off.
//!
//! This file holds the options, the outcome types and the line helpers
//! (`clean_line`, `quote`). The rest:
//! * `link.rs`: bytes on the wire both ways, answers and status requests;
//! * `book.rs`: character counting and the executed-line lower bound;
//! * `connection.rs`: connecting and the sender's own commands between jobs;
//! * `streaming.rs`: the streaming loop, resume, and its fault detection;
//! * `safe_stop.rs`: feed hold to rest, then soft reset;
//! * `tests.rs`: the sender against scripted controllers.

use std::time::Duration;

use laserd_sim::gcode::LineBuilder;
use laserd_sim::wire::StatusReport;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use tokio::time::Instant;

mod book;
mod connection;
mod link;
mod safe_stop;
mod streaming;
#[cfg(test)]
mod tests;

pub use book::ExecutedLine;
pub use connection::{jog_block, Connection};
pub use streaming::stream;

#[derive(Debug, Clone)]
pub struct SenderOptions {
    /// The controller's receive buffer in bytes (GRBL 1.1: 128).
    pub rx_buffer: usize,
    /// Interval between status requests while streaming.
    pub status_interval: Duration,
    /// A controller that sends nothing intelligible (no answer, no status report)
    /// for this long while lines are outstanding is treated as gone.
    pub silence_timeout: Duration,
    /// Axis positions the program starts from; the machine must be there.
    pub expect_start: Option<Vec<f64>>,
    /// Validate only: run the lines in the controller's check mode (`$C`), where
    /// nothing moves; every rejected line is reported, none stops the run.
    pub check_mode: bool,
    /// Send-response streaming: one line at a time, each after the previous one
    /// is answered (the simple method; the baseline character counting beats).
    pub send_response: bool,
    /// A controller that reports it runs but whose position, buffers, line
    /// number and answers have not changed for this long (plus the dwells it
    /// may be in) has stalled.
    pub stall_timeout: Duration,
    /// How long a safe stop waits for its feed hold to bring the machine to
    /// rest before it resets anyway (a reset while moving loses the
    /// position: `ALARM:3`, reported). See [`SenderOptions::hold_limit_for`].
    pub hold_limit: Duration,
    /// The longest step of any of the controller's axes (mm), when known
    /// beforehand (reading `$$` also tells it): which moves surely make a
    /// planner block, for the executed line.
    pub step_mm: Option<f64>,
}

/// Grbl never moves slower than 1 mm/min (`MINIMUM_FEED_RATE`, overrides
/// included), so a moving machine changes its reported position (0.001 mm)
/// at least every 60 ms whatever the block's length; 10 s of no change at
/// all is a stall with a wide margin for coarse or slow status reports.
/// Dwells (`G4`) come on top: see `dwell_seconds`.
pub const STALL_TIMEOUT: Duration = Duration::from_secs(10);

/// The longest line accepted from a controller. Grbl 1.1's longest answer is
/// a status report of a little over 100 bytes; grblHAL's full report with 8
/// axes and every field, or its setting enumerations, a few hundred. 4 KiB is
/// ten times that and still nothing in memory: anything longer is garbage.
pub const MAX_CONTROLLER_LINE: usize = 4096;

/// Why nothing is streamed to a controller in alarm.
const IN_ALARM: &str = "the controller is in alarm: home ($H) or unlock ($X) it first";

/// How many characters of a G-code line a message quotes.
const QUOTE_CHARS: usize = 80;

impl SenderOptions {
    pub fn new(rx_buffer: usize, status_hz: f64) -> SenderOptions {
        SenderOptions {
            rx_buffer,
            status_interval: Duration::from_secs_f64(1.0 / status_hz),
            // At least three status requests go unanswered before a
            // controller counts as silent.
            silence_timeout: Duration::from_millis(800).max(Duration::from_secs_f64(3.0 / status_hz)),
            expect_start: None,
            check_mode: false,
            send_response: false,
            stall_timeout: STALL_TIMEOUT,
            hold_limit: HOLD_LIMIT,
            step_mm: None,
        }
    }

    /// The wait for a hold on a machine whose longest stop from full speed
    /// takes `stop_s` (`MachineConfig::stop_time_s`): twice that (a
    /// controller's own rates may be lower than the config's, and status
    /// comes at most every `status_interval`), plus a second, never less
    /// than [`HOLD_LIMIT`].
    pub fn hold_limit_for(&self, stop_s: f64) -> Duration {
        let wait = 2.0 * stop_s.max(0.0) + 1.0 + 2.0 * self.status_interval.as_secs_f64();
        Duration::from_secs_f64(wait.min(3600.0)).max(HOLD_LIMIT)
    }
}

/// The least a safe stop waits for its hold to complete: a stop from the
/// speed of a desktop machine takes a fraction of a second.
pub const HOLD_LIMIT: Duration = Duration::from_secs(3);

/// What crossed the link, for the recorder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "dir", rename_all = "snake_case")]
pub enum LinkEvent {
    /// A G-code line sent (1-based line number in the program; 0 for lines of the
    /// sender's own), without its `\n`.
    Sent { line: usize, text: String },
    /// A realtime byte sent (`?`, `!`, `~`, 0x18).
    Realtime { byte: u8 },
    /// A line received from the controller, without `\r\n`.
    Received { text: String },
}

/// An `error:N` answer, tied to the line it answered.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct LineError {
    pub line: usize,
    pub code: u16,
    pub message: String,
}

/// How a stream ended.
#[derive(Debug, Clone, Default, Serialize, Deserialize, JsonSchema)]
pub struct StreamOutcome {
    pub lines_sent: usize,
    pub bytes_sent: usize,
    /// From the first byte sent to the last answer.
    pub stream_time_s: f64,
    pub errors: Vec<LineError>,
    pub alarms: Vec<u16>,
    pub last_acked_line: usize,
    /// A lower bound on the last line the controller has executed: every
    /// line up to it has run, as its answers and status reports prove (see
    /// `Book`); `None` when they prove nothing (a controller without `Bf:`
    /// that never came to rest, or of unknown firmware).
    pub last_executed_line: Option<usize>,
    pub completed: bool,
    /// Why the stream stopped early, one line naming the place.
    pub stop_reason: Option<String>,
    /// The last status report seen (after a safe stop: the state it left).
    pub final_status: Option<StatusReport>,
}

/// Seconds since `origin` (virtual time in the in-process simulation).
fn secs(origin: Instant) -> f64 {
    origin.elapsed().as_secs_f64()
}

/// What the sender asks of every controller it connects to (before any
/// program line): the build options.
pub const BUILD_INFO: &str = "$I";

/// A G-code line as messages quote it: whole, or its first `QUOTE_CHARS`
/// characters, `…` and its length.
pub fn quote(text: &str) -> std::borrow::Cow<'_, str> {
    match quoted_start(text) {
        start if start.len() < text.len() => format!("{start}… ({} bytes)", text.len()).into(),
        whole => whole.into(),
    }
}

/// The part of a line a message quotes: its first `QUOTE_CHARS` characters.
pub fn quoted_start(text: &str) -> &str {
    text.char_indices().nth(QUOTE_CHARS).map_or(text, |(cut, _)| &text[..cut])
}

/// A line as Grbl pre-processes it (the shared definition in `laserd_sim::gcode`:
/// spaces, control characters and comments dropped, upper case), without its
/// length limit, which is the controller's to enforce. A `%` program
/// demarcation line (CAM tools write them; Grbl 1.1 rejects them) is dropped.
pub fn clean_line(raw: &str) -> String {
    let mut builder = LineBuilder::with_max(usize::MAX);
    raw.bytes().for_each(|b| builder.push(b));
    let text = builder.finish().unwrap_or_default();
    if text == "%" {
        String::new()
    } else {
        text
    }
}

/// What the caller can ask of a running stream (the operator's buttons).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    /// Feed hold: decelerate and stop, laser off; the job stays loaded.
    FeedHold,
    /// Cycle start after a hold.
    Resume,
    /// Stop the job for good: hold, laser off, soft reset.
    Abort,
    /// A realtime override byte (`wire::realtime::FEED_OVR_*`, `RAPID_OVR_*`,
    /// `SPINDLE_OVR_*`).
    Override(u8),
}
