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

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use laserd_sim::gcode::LineBuilder;
use laserd_sim::wire::{self, realtime, MachineState, Response, StatusReport};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader, ReadHalf, WriteHalf};
use tokio::time::{timeout, Instant};

use super::resume::ModalState;
use crate::error::{Error, Result};

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

/// Acknowledged lines kept while no status report says they ran: far more
/// than any planner holds (Grbl 15 to 35 blocks, grblHAL hundreds).
const MAX_PENDING_LINES: usize = 4096;

/// Time a dwell may take beyond its `P` before its line counts as lost:
/// Grbl dwells in steps of 50 ms and a busy host reads late.
const DWELL_MARGIN_S: f64 = 1.0;

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

struct Link<R, W, F> {
    reader: BufReader<R>,
    /// The line being read, at most `MAX_CONTROLLER_LINE` bytes.
    partial: Vec<u8>,
    /// The rest of an over-long line is being skipped.
    skipping: bool,
    writer: W,
    origin: Instant,
    on_event: F,
    bytes_sent: usize,
    /// Every answer is booked here as it is read, whoever reads it.
    book: Book,
    /// Status requests go out at most this often, whoever asks (Grbl's
    /// interface document: about 5 Hz at most), and when the last one went.
    status_interval: Duration,
    last_status_request: Option<Instant>,
}

/// How a safe stop went.
#[derive(Debug, Default)]
struct SafeStop {
    /// The state it left the machine in.
    status: Option<StatusReport>,
    /// Alarms the controller raised on the way (`ALARM:3` for a reset while moving).
    alarms: Vec<u16>,
    /// What went differently from a hold to rest and a reset.
    note: Option<String>,
}

/// Why a stream ends when the other end has gone (a read at its end, a write refused).
const LINK_CLOSED: &str = "the controller closed the link";

impl<R, W, F> Link<R, W, F>
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin,
    F: FnMut(f64, LinkEvent),
{
    /// Puts bytes on the wire now (flushed: the link must not sit on them).
    async fn write(&mut self, bytes: &[u8]) -> Result<()> {
        // A pipe or socket whose reader has gone, or a pseudo-terminal whose
        // other side closed (EIO on Linux): the controller has left the link.
        const EIO: i32 = 5;
        let failed = |e: std::io::Error| match e.kind() {
            std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset => Error::Stream(LINK_CLOSED.into()),
            _ if e.raw_os_error() == Some(EIO) => Error::Stream(LINK_CLOSED.into()),
            _ => Error::Stream(format!("write failed: {e}")),
        };
        self.writer.write_all(bytes).await.map_err(failed)?;
        self.writer.flush().await.map_err(failed)
    }

    async fn send_line(&mut self, line: usize, text: &str) -> Result<()> {
        let mut bytes = Vec::with_capacity(text.len() + 1);
        bytes.extend_from_slice(text.as_bytes());
        bytes.push(b'\n');
        self.write(&bytes).await?;
        self.bytes_sent += bytes.len();
        (self.on_event)(
            secs(self.origin),
            LinkEvent::Sent {
                line,
                text: text.to_string(),
            },
        );
        Ok(())
    }

    /// A command of the sender's own (not a program line), answered before
    /// anything else is sent: waits for its `ok` or `error:N`.
    async fn command(&mut self, text: &str) -> Result<Response> {
        self.command_within(text, Duration::from_secs(3)).await
    }

    /// `command` for commands that answer only when done (homing).
    async fn command_within(&mut self, text: &str, limit: Duration) -> Result<Response> {
        self.command_seeing(text, limit, |_| {}).await
    }

    /// `command_within`, showing `seen` every line read before the answer
    /// (the feedback a `$` command prints).
    async fn command_seeing(&mut self, text: &str, limit: Duration, mut seen: impl FnMut(&Response)) -> Result<Response> {
        let before = self.bytes_sent;
        self.send_line(0, text).await?;
        self.book.sent(0, text);
        self.bytes_sent = before;
        self.wait_for(limit, |r| {
            seen(r);
            matches!(r, Response::Ok | Response::Error(_))
        })
        .await?
        .ok_or_else(|| Error::Stream(format!("no answer to `{text}` within {} s", limit.as_secs_f64())))
    }

    /// A status request once the status interval since the last one has
    /// passed (it waits for that): no caller asks faster than the status rate.
    async fn request_status(&mut self) -> Result<()> {
        if let Some(last) = self.last_status_request {
            tokio::time::sleep_until(last + self.status_interval).await;
        }
        self.send_realtime(realtime::STATUS).await
    }

    /// A status request if one is due (the streaming loop's ticks, which
    /// must not wait: the answers they would not read meanwhile are its work).
    async fn request_status_if_due(&mut self) -> Result<()> {
        match self.last_status_request {
            Some(last) if last + self.status_interval > Instant::now() => Ok(()),
            _ => self.send_realtime(realtime::STATUS).await,
        }
    }

    async fn send_realtime(&mut self, byte: u8) -> Result<()> {
        if byte == realtime::STATUS {
            self.last_status_request = Some(Instant::now());
        }
        self.write(&[byte]).await?;
        if byte == realtime::STATUS {
            self.book.status_requested();
        }
        (self.on_event)(secs(self.origin), LinkEvent::Realtime { byte });
        Ok(())
    }

    /// Next line from the controller without its `\n`, `None` at the end of
    /// the link. A line longer than `MAX_CONTROLLER_LINE` is an error (and its
    /// rest is skipped): memory never grows with what the controller sends.
    /// Cancel-safe: bytes move from the buffer only after the await.
    async fn read_line(&mut self) -> Result<Option<Vec<u8>>> {
        const EIO: i32 = 5;
        loop {
            let available = match self.reader.fill_buf().await {
                Ok(bytes) => bytes,
                // A pseudo-terminal whose other side closed reads EIO.
                Err(e) if e.raw_os_error() == Some(EIO) => return Ok(None),
                Err(e) => return Err(Error::Stream(format!("read failed: {e}"))),
            };
            if available.is_empty() {
                return Ok(None);
            }
            let end = available.iter().position(|&b| b == b'\n');
            let chunk = &available[..end.unwrap_or(available.len())];
            let used = end.map_or(chunk.len(), |i| i + 1);
            let too_long = !self.skipping && self.partial.len() + chunk.len() > MAX_CONTROLLER_LINE;
            if !self.skipping && !too_long {
                self.partial.extend_from_slice(chunk);
            }
            self.reader.consume(used);
            if too_long {
                self.book.distrust();
                self.partial.clear();
                self.skipping = end.is_none();
                return Err(Error::Stream(format!(
                    "the controller sent more than {MAX_CONTROLLER_LINE} bytes without a line end: garbage, not a GRBL answer"
                )));
            }
            if end.is_some() {
                if std::mem::take(&mut self.skipping) {
                    continue;
                }
                return Ok(Some(std::mem::take(&mut self.partial)));
            }
        }
    }

    /// Next line from the controller, parsed and booked, with the line it
    /// answered (for `ok` and `error:N`); `None` when the link closed. Cancel-safe.
    async fn next_line(&mut self) -> Result<Option<(String, Response, Option<(usize, String)>)>> {
        loop {
            let Some(line) = self.read_line().await? else { return Ok(None) };
            let text = String::from_utf8_lossy(&line)
                .trim_matches(|c| c == '\r' || c == '\n')
                .to_string();
            if text.is_empty() {
                continue;
            }
            (self.on_event)(
                secs(self.origin),
                LinkEvent::Received { text: text.clone() },
            );
            let response = Response::parse(&text);
            let answered = self.book.answer(&response);
            self.book.publish();
            return Ok(Some((text, response, answered)));
        }
    }

    /// Reads responses until `want` accepts one, or `limit` passes.
    async fn wait_for(
        &mut self,
        limit: Duration,
        mut want: impl FnMut(&Response) -> bool,
    ) -> Result<Option<Response>> {
        let deadline = Instant::now() + limit;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match timeout(left, self.next_line()).await {
                Err(_) => return Ok(None),
                Ok(Err(e)) => return Err(e),
                Ok(Ok(None)) => return Err(Error::Stream(LINK_CLOSED.into())),
                Ok(Ok(Some((_, r, _)))) => {
                    if want(&r) {
                        return Ok(Some(r));
                    }
                }
            }
        }
    }

    /// Asks for status until one arrives (up to `limit`).
    async fn query_status(&mut self, limit: Duration) -> Result<Option<StatusReport>> {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            self.request_status().await?;
            if let Some(Response::Status(s)) = self
                .wait_for(Duration::from_millis(250), |r| {
                    matches!(r, Response::Status(_))
                })
                .await?
            {
                return Ok(Some(s));
            }
        }
        Ok(None)
    }

    /// Feed hold until stopped (up to `hold_limit`), then soft reset: the
    /// laser ends off, nothing queued is executed any more. Status requests
    /// meanwhile keep to the status rate (`send_realtime`).
    async fn safe_stop(&mut self, hold_limit: Duration) -> SafeStop {
        let mut stop = SafeStop::default();
        if self.send_realtime(realtime::FEED_HOLD).await.is_err() {
            return stop;
        }
        let deadline = Instant::now() + hold_limit;
        let mut at_rest = false;
        while !at_rest && Instant::now() < deadline {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.query_status(left.min(Duration::from_millis(500))).await {
                Ok(Some(s)) => {
                    at_rest = matches!(
                        s.state,
                        MachineState::Hold(0) | MachineState::Door(0) | MachineState::Door(1) | MachineState::Idle | MachineState::Alarm
                    );
                }
                Ok(None) => {}
                Err(Error::Stream(m)) if m == LINK_CLOSED => return stop,
                // Garbage while the machine holds: the reset comes anyway,
                // after the time a hold takes.
                Err(_) => {}
            }
        }
        if !at_rest {
            stop.note = Some(format!("no hold to rest within {:.1} s: reset, maybe while moving", hold_limit.as_secs_f64()));
        }
        if self.send_realtime(realtime::SOFT_RESET).await.is_err() {
            return stop;
        }
        let alarms = &mut stop.alarms;
        let _ = self
            .wait_for(Duration::from_secs(3), |r| {
                if let Response::Alarm(code) = r {
                    alarms.push(*code);
                }
                matches!(r, Response::Banner(_))
            })
            .await;
        stop.status = self.query_status(Duration::from_secs(1)).await.ok().flatten();
        stop
    }
}

/// What the sender asks of every controller it connects to (before any
/// program line): the build options.
pub const BUILD_INFO: &str = "$I";

/// The sender's books: lines sent and not yet answered (their bytes are what
/// the controller's receive buffer holds or will hold), and a lower bound on
/// the lines the machine has executed.
///
/// # Why `last_executed` is a lower bound
/// Lines are answered in order, and a line's `ok` comes once its blocks are
/// in the planner (or it is done, for a line without motion), so an `ok` read
/// before a status report was sent before the report was made: every line
/// acknowledged by then has its blocks in the planner, in the step-segment
/// buffer, or done. A report bounds what is not done yet:
/// * Idle with `Bf:` showing every planner block free: no block is queued and
///   the segment buffer is empty (Grbl leaves its cycle only once it ran
///   out), so every acknowledged line is done.
/// * Idle without `Bf:`: the same once two reports in a row say so, each asked
///   with no line in flight. The first may come from the instant after the
///   last `ok` and before Grbl starts the cycle (it handles a report before a
///   cycle start in the same pass); the next was made after that pass.
/// * Otherwise, with `Bf:` from a controller whose segment buffer is known:
///   at most `queued + segment_blocks` blocks are not done, `queued` from
///   `Bf:` (blocks of a line still being parsed only add to it) and
///   `segment_blocks` the blocks the controller may have cut into step
///   segments and discarded from its planner though they have yet to run.
///   A line is done once the lines after it surely make that many blocks;
///   a line is counted as making a block only when it is a move that takes
///   some axis at least one step from where the line before left it (a move
///   to where the machine already is, or to somewhere unknown, counts none;
///   an arc or a `G28` may make more than one, which only lowers the bound).
///
/// Anything else (a running controller without `Bf:`, or of unknown firmware)
/// says nothing, and the bound stays where it was.
#[derive(Debug, Default)]
struct Book {
    fifo: VecDeque<(usize, String)>,
    in_flight: usize,
    last_acked_text: String,
    planner_blocks: Option<usize>,
    /// Blocks the controller may hold in its step-segment buffer, no longer in
    /// `Bf:` (see `segment_run_ahead`); `None` for firmware where it is unknown.
    segment_blocks: Option<usize>,
    /// The longest step of any axis (mm), from `$100`…; `None` until `$$` is read.
    step_mm: Option<f64>,
    /// Where the program's moves take the machine, to tell which lines surely
    /// make a planner block.
    moves: Option<ModalState>,
    /// Acknowledged lines not yet known to be done, oldest first, with the
    /// planner blocks each surely made (0 or 1).
    pending: VecDeque<(usize, String, usize)>,
    last_acked: usize,
    /// The lines before the stream's first: taken as done.
    base: usize,
    /// The last line known done from the controller's reports.
    last_executed: Option<usize>,
    last_executed_text: String,
    /// Lines sent and lines answered, ever (answers come in order).
    sent_total: u64,
    answered_total: u64,
    /// `sent_total` and `answered_total` when each status request not yet
    /// answered went out.
    status_requests: VecDeque<(u64, u64)>,
    /// The same for the request the latest status report answers: a
    /// controller reporting an empty, idle queue has answered every line sent
    /// before it. `None` for a report nobody asked for (an auto-report).
    report_covers: Option<(u64, u64)>,
    /// The latest report showed Idle and was asked with no line in flight.
    idle_before: bool,
    /// `executed()` for whoever watches the stream from outside (kept across
    /// streams: the handle is handed out once).
    executed_line: ExecutedLine,
    /// The controller broke the protocol (garbage, answers to nothing):
    /// what it answers after that is not taken as progress.
    distrusted: bool,
    /// An `ALARM:` came: the next `ok` answers the line it stopped (a soft
    /// limit's after the reset, a probe's, a `$H`'s), which did not run.
    alarm_answer_due: bool,
}

/// The blocks a controller may have cut into its step-segment buffer and
/// discarded from its planner (so `Bf:` no longer counts them) while they have
/// yet to run. Grbl 1.1 prepares segments of at most 10 ms, each of one block,
/// in a ring of 6 with one slot kept open (stepper.c `SEGMENT_BUFFER_SIZE`):
/// up to 5 blocks. grblHAL's ring is 10: 9. Other firmware: unknown.
fn segment_run_ahead(banner: &str) -> Option<usize> {
    if banner.starts_with("GrblHAL ") {
        Some(9)
    } else if banner.starts_with("Grbl 1.1") {
        Some(5)
    } else {
        None
    }
}

/// The step taken for an axis whose steps per mm are not known (`$$` not
/// read): 1 mm. A machine has many steps per mm; a smaller move is not taken
/// to make a block.
const UNKNOWN_STEP_MM: f64 = 1.0;

/// Every axis letter Grbl and grblHAL know: the moves are followed on all.
const AXIS_LETTERS: [char; 9] = ['X', 'Y', 'Z', 'A', 'B', 'C', 'U', 'V', 'W'];

impl Book {
    /// Fresh books for a stream whose lines before `first_line` are done:
    /// what is known of the controller stays.
    fn for_stream(&self, first_line: usize) -> Book {
        Book {
            planner_blocks: self.planner_blocks,
            segment_blocks: self.segment_blocks,
            step_mm: self.step_mm,
            base: first_line.saturating_sub(1),
            executed_line: self.executed_line.clone(),
            ..Book::default()
        }
    }

    fn sent(&mut self, line: usize, text: &str) {
        self.in_flight += text.len() + 1;
        self.sent_total += 1;
        self.fifo.push_back((line, text.to_string()));
    }

    fn status_requested(&mut self) {
        // Bounded: a controller that stops answering `?` is caught as silent.
        if self.status_requests.len() >= 256 {
            self.status_requests.pop_front();
        }
        self.status_requests.push_back((self.sent_total, self.answered_total));
    }

    /// Lines sent before the latest report was asked for and still unanswered
    /// although it shows the controller idle with nothing queued: lost.
    fn lost_before_report(&self) -> u64 {
        self.report_covers.map_or(0, |(sent, _)| sent.saturating_sub(self.answered_total))
    }

    fn distrust(&mut self) {
        self.distrusted = true;
    }

    /// Books an answer; returns the line an `ok` or `error:N` answered.
    fn answer(&mut self, response: &Response) -> Option<(usize, String)> {
        match response {
            Response::Ok | Response::Error(_) | Response::Status(_) if self.distrusted => None,
            Response::Ok | Response::Error(_) => {
                let (line, text) = self.fifo.pop_front()?;
                self.answered_total += 1;
                self.in_flight = self.in_flight.saturating_sub(text.len() + 1);
                let failed = std::mem::take(&mut self.alarm_answer_due);
                // The sender's own commands (line 0) are not program lines.
                if line > 0 && matches!(response, Response::Ok) && !failed {
                    self.acked(line, &text);
                    self.last_acked_text = text.clone();
                }
                Some((line, text))
            }
            Response::Status(s) => {
                // Reports come in the order asked; a request lost or merged
                // with the next pairs the report with an older one, which
                // only ever under-counts what it covers.
                self.report_covers = self.status_requests.pop_front();
                self.status(s);
                None
            }
            Response::Alarm(_) => {
                self.alarm_answer_due = true;
                None
            }
            Response::Banner(banner) => {
                self.alarm_answer_due = false;
                self.segment_blocks = segment_run_ahead(banner);
                self.answered_total = self.sent_total;
                self.status_requests.clear();
                self.report_covers = None;
                self.idle_before = false;
                // A reset flushed everything queued: those lines never run, and
                // lines still unanswered will never be answered.
                self.pending.clear();
                self.fifo.clear();
                self.in_flight = 0;
                None
            }
            _ => None,
        }
    }

    /// The last line surely executed: the lines before the stream's first,
    /// or what the reports showed done since. Unknown once a line has been
    /// acknowledged (it may have run) and no report has told anything.
    fn executed(&self) -> Option<usize> {
        match self.last_executed {
            Some(line) => Some(line.max(self.base)),
            None if self.last_acked == 0 || self.base > 0 => Some(self.base),
            None => None,
        }
    }

    /// Shows `executed()` to the watchers.
    fn publish(&self) {
        self.executed_line.set(self.executed());
    }

    fn acked(&mut self, line: usize, text: &str) {
        self.last_acked = line;
        let blocks = self.sure_blocks(text);
        // More than any planner holds: a controller that acknowledges without
        // reporting. Bounded memory; the oldest is dropped without being taken
        // for executed (the bound stays low).
        if self.pending.len() >= MAX_PENDING_LINES {
            self.pending.pop_front();
        }
        self.pending.push_back((line, text.to_string(), blocks));
    }

    /// The planner blocks a line surely makes: 1 for a straight move or an
    /// arc whose end is at least a step (`step_mm`, with a margin for the
    /// controller's single-precision arithmetic) from where the move before
    /// ended on some axis, 0 otherwise: a move in place, a probe (it may stop
    /// at once), anything after which the position is unknown, anything that
    /// shifts the coordinates (the next move is then taken from an unknown
    /// place), and every line without motion.
    fn sure_blocks(&mut self, text: &str) -> usize {
        let moves = self.moves.get_or_insert_with(|| ModalState::new(&AXIS_LETTERS));
        let before = moves.position.clone();
        moves.apply(text);
        let t = text.to_ascii_uppercase();
        if ["G10", "G92", "G43", "G49", "G5"].iter().any(|g| t.contains(g)) {
            moves.position.iter_mut().for_each(|p| *p = None);
            return 0;
        }
        if !is_motion(&t) || t.contains("G38") {
            return 0;
        }
        let step = 1.01 * self.step_mm.unwrap_or(UNKNOWN_STEP_MM);
        let moved = before.iter().zip(&moves.position).any(|(a, b)| matches!((a, b), (Some(a), Some(b)) if (b - a).abs() >= step));
        usize::from(moved)
    }

    /// The pending lines, oldest first, up to `n` of them, are done.
    fn done(&mut self, n: usize) {
        for _ in 0..n {
            if let Some((line, text, _)) = self.pending.pop_front() {
                self.last_executed = Some(line);
                self.last_executed_text = text;
            }
        }
    }

    fn status(&mut self, s: &StatusReport) {
        let asked_with_nothing_in_flight = self.report_covers.is_some_and(|(sent, answered)| sent == answered);
        let idle = s.state == MachineState::Idle;
        let idle_before = std::mem::replace(&mut self.idle_before, idle && asked_with_nothing_in_flight);
        match (s.buffer, self.planner_blocks) {
            (Some((free, _)), Some(total)) if idle && free as usize >= total => self.done(self.pending.len()),
            (None, _) if idle && asked_with_nothing_in_flight && idle_before => self.done(self.pending.len()),
            (Some((free, _)), Some(total)) => {
                let Some(run_ahead) = self.segment_blocks else { return };
                let not_done = total.saturating_sub(free as usize) + run_ahead;
                // The newest lines that surely hold `not_done` blocks; the older are done.
                let mut blocks = 0;
                let mut keep = 0;
                for (_, _, b) in self.pending.iter().rev() {
                    if blocks >= not_done {
                        break;
                    }
                    blocks += b;
                    keep += 1;
                }
                self.done(self.pending.len() - keep);
            }
            _ => {}
        }
    }

    /// The last acknowledged and the last executed line, as a message ends.
    fn progress(&self, describe: &dyn Fn(usize, &str) -> String) -> String {
        let acked = match self.last_acked {
            0 => "none".to_string(),
            n => describe(n, &quote(&self.last_acked_text)),
        };
        let executed = match (self.executed(), self.last_executed) {
            (None, _) => "unknown (no status report has told which lines ran)".to_string(),
            (Some(0), _) => "none".to_string(),
            (Some(n), Some(m)) if n == m => describe(n, &quote(&self.last_executed_text)),
            (Some(n), _) => format!("line {n} (before the resumed part)"),
        };
        format!("last acknowledged: {acked}; last executed (a lower bound): {executed}")
    }
}

/// The last program line surely executed, shared with a watcher that saves
/// progress while the stream runs (`None`: unknown).
#[derive(Debug, Clone, Default)]
pub struct ExecutedLine(Arc<AtomicUsize>);

impl ExecutedLine {
    pub fn get(&self) -> Option<usize> {
        // 0 is unknown, n + 1 is line n.
        self.0.load(Ordering::Relaxed).checked_sub(1)
    }

    pub fn set(&self, line: Option<usize>) {
        self.0.store(line.map_or(0, |n| n.saturating_add(1)), Ordering::Relaxed);
    }
}

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

/// Seconds a line dwells (`G4 P<seconds>`), 0 for any other line. Lines
/// are cleaned (`clean_line`): upper case, no spaces; split into words as
/// the controller splits them (`laserd_sim::gcode::split_words`).
fn dwell_seconds(text: &str) -> f64 {
    let Ok(words) = laserd_sim::gcode::split_words(text) else { return 0.0 };
    let dwells = words.iter().any(|w| w.letter == 'G' && w.value == 4.0);
    match words.iter().find(|w| w.letter == 'P') {
        Some(p) if dwells && p.value.is_finite() && p.value > 0.0 => p.value,
        _ => 0.0,
    }
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

/// Whether a G-code line makes the machine move (has axis words and is not one
/// of the commands that take axis words without moving).
fn is_motion(text: &str) -> bool {
    let t = text.to_ascii_uppercase();
    if t.starts_with('$')
        || t.contains("G10")
        || t.contains("G92")
        || t.contains("G28.1")
        || t.contains("G30.1")
    {
        return false;
    }
    let b = t.as_bytes();
    b.windows(2).any(|w| {
        b"XYZABCUVW".contains(&w[0])
            && (w[1].is_ascii_digit() || w[1] == b'-' || w[1] == b'.' || w[1] == b'+')
    })
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

/// An open connection to a GRBL-style controller: announced (banner), its
/// state and buffer sizes known, every answer booked.
pub struct Connection<T, F> {
    link: Link<ReadHalf<T>, WriteHalf<T>, F>,
    options: SenderOptions,
    /// The receive buffer counted on: the configured one, or the controller's
    /// if that is smaller.
    rx_buffer: usize,
    /// The status just read, if nothing was sent since (saves a round trip).
    fresh_status: Option<StatusReport>,
    /// The build option codes of `[OPT:]` (e.g. `VNM+`).
    build_codes: String,
    /// The work coordinate offset (`WCO:`, sent now and then; or set by
    /// `use_program_frame`): work position = machine position − this.
    wco: Option<Vec<f64>>,
}

impl<T, F> Connection<T, F>
where
    T: AsyncRead + AsyncWrite,
    F: FnMut(f64, LinkEvent),
{
    /// Connects: waits for the banner (asking with a soft reset if it came
    /// before we listened; nothing moves yet) and reads the first status.
    pub async fn open(io: T, options: &SenderOptions, on_event: F) -> Result<Self> {
        let (read_half, write_half) = tokio::io::split(io);
        let mut link = Link {
            reader: BufReader::new(read_half),
            partial: Vec::new(),
            skipping: false,
            writer: write_half,
            origin: Instant::now(),
            on_event,
            bytes_sent: 0,
            book: Book { step_mm: options.step_mm, ..Book::default() },
            status_interval: options.status_interval,
            last_status_request: None,
        };
        let is_banner = |r: &Response| matches!(r, Response::Banner(_));
        if link
            .wait_for(Duration::from_millis(500), is_banner)
            .await?
            .is_none()
        {
            link.send_realtime(realtime::SOFT_RESET).await?;
            if link
                .wait_for(Duration::from_millis(2500), is_banner)
                .await?
                .is_none()
            {
                return Err(Error::Stream(
                    "no GRBL banner from the controller within 3 s of connecting".into(),
                ));
            }
        }
        let mut connection = Connection {
            link,
            options: options.clone(),
            rx_buffer: options.rx_buffer,
            fresh_status: None,
            build_codes: String::new(),
            wco: None,
        };
        connection.status().await?;
        connection.learn_build_options().await?;
        Ok(connection)
    }

    /// Asks `$I` for the build options, `[OPT:<codes>,<blocks>,<rx bytes>…]`:
    /// the planner's size and the receive buffer, as the controller was built
    /// (the reference: read them, never assume them). A controller that will
    /// not answer it now (busy: error 8) keeps what the status told.
    async fn learn_build_options(&mut self) -> Result<()> {
        let mut options = None;
        self.link
            .command_seeing(BUILD_INFO, Duration::from_secs(3), |r| {
                if let Response::Feedback(f) = r {
                    if let Some(o) = f.strip_prefix("[OPT:").and_then(|o| o.strip_suffix(']')) {
                        options = Some(o.to_string());
                    }
                }
            })
            .await?;
        let fields: Vec<&str> = options.as_deref().unwrap_or("").split(',').collect();
        self.build_codes = fields.first().map_or(String::new(), |c| c.trim().to_string());
        let number = |i: usize| fields.get(i).and_then(|f| f.trim().parse::<usize>().ok()).filter(|n| *n > 0);
        if let Some(blocks) = number(1) {
            self.link.book.planner_blocks = Some(blocks);
        }
        if let Some(rx) = number(2).filter(|rx| *rx < self.rx_buffer) {
            tracing::warn!("the controller's receive buffer is {rx} bytes, less than the configured {}: using {rx}", self.rx_buffer);
            self.rx_buffer = rx;
        }
        // `$I` changes nothing: a status read just before it is still fresh.
        Ok(())
    }

    /// The controller's status now. An idle controller reports its whole
    /// planner and receive buffer free: learn their sizes, and never count on
    /// more receive buffer than it has.
    pub async fn status(&mut self) -> Result<StatusReport> {
        let status = self
            .link
            .query_status(Duration::from_secs(2))
            .await?
            .ok_or_else(|| {
                Error::Stream("the controller does not answer status requests".into())
            })?;
        if let (MachineState::Idle, Some((blocks, rx))) = (&status.state, status.buffer) {
            self.link.book.planner_blocks = Some(blocks as usize);
            // None free at all is not a size but a fault (see `stream_from`).
            if rx > 0 && (rx as usize) < self.rx_buffer {
                // A ring buffer keeps one slot unused (grblHAL's 1024-byte one
                // holds 1023): not worth a warning, only worth counting on.
                if rx as usize + 1 == self.rx_buffer {
                    tracing::debug!("the controller's receive buffer holds {rx} bytes: using {rx}");
                } else {
                    tracing::warn!("the controller's receive buffer is {rx} bytes, less than the configured {}: using {rx}", self.rx_buffer);
                }
                self.rx_buffer = rx as usize;
            }
        }
        if let Some(wco) = &status.wco {
            self.wco = Some(wco.clone());
        }
        self.fresh_status = Some(status.clone());
        Ok(status)
    }

    /// The work coordinate offset last known (machine − work position).
    pub fn work_offset(&self) -> Option<&[f64]> {
        self.wco.as_deref()
    }

    /// The work position (program coordinates) of a status report: `WPos:`
    /// as reported, or `MPos:` less the last work coordinate offset known.
    pub fn work_position(&self, status: &StatusReport) -> Vec<f64> {
        match (&status.wpos, status.wco.as_ref().or(self.wco.as_ref())) {
            (Some(w), _) if status.mpos.is_empty() => w.clone(),
            (_, Some(wco)) => status.mpos.iter().zip(wco.iter().chain(std::iter::repeat(&0.0))).map(|(m, o)| m - o).collect(),
            _ => status.mpos.clone(),
        }
    }

    /// Makes the controller's work coordinates laserd's bed coordinates (see
    /// `frame`): reads `$$` and `$#`, writes G54 (`G10 L2 P1`) if it is not
    /// already the bed's origin, then selects G54 and clears G92. `travel`
    /// is the config's stage travel (X, Y). Returns the origin (machine X, Y
    /// of the bed's 0).
    pub async fn use_program_frame(&mut self, travel: [f64; 2]) -> Result<[f64; 2]> {
        // G10 and G54 are G-code: refused in alarm (error:9).
        if self.status().await?.state == MachineState::Alarm {
            return Err(Error::Stream(IN_ALARM.into()));
        }
        let settings = self.settings().await?;
        let origin = super::frame::program_origin(&settings, &self.build_codes, travel)?;
        let mut g54 = self.work_origin().await?;
        if g54.len() < 2 {
            return Err(Error::Stream(format!("`$#` gave no G54 origin for X and Y (got {g54:?})")));
        }
        if g54.iter().zip(origin).any(|(a, b)| (a - b).abs() > 5e-4) {
            let [x, y] = origin.map(|v| crate::program::format_number(v, 3));
            self.expect_ok(&format!("G10L2P1X{x}Y{y}")).await?;
            g54[..2].copy_from_slice(&origin);
        }
        self.expect_ok("G54G92.1").await?;
        self.wco = Some(g54);
        Ok(origin)
    }

    /// The G54 origin in machine coordinates, from `$#`.
    async fn work_origin(&mut self) -> Result<Vec<f64>> {
        self.fresh_status = None;
        let mut g54 = None;
        let answer = self
            .link
            .command_seeing("$#", Duration::from_secs(3), |r| {
                if let Response::Feedback(f) = r {
                    if let Some(values) = f.strip_prefix("[G54:").and_then(|v| v.strip_suffix(']')) {
                        g54 = values.split(',').map(|v| v.trim().parse::<f64>().ok()).collect::<Option<Vec<f64>>>();
                    }
                }
            })
            .await?;
        if let Response::Error(code) = answer {
            return Err(Error::Stream(format!("`$#` refused: error:{code} ({})", wire::error_message(code))));
        }
        g54.ok_or_else(|| Error::Stream("`$#` gave no readable `[G54:...]` line".into()))
    }

    /// Sends a command of the sender's own and waits (up to `limit`) for its answer.
    async fn expect_ok_within(&mut self, command: &str, limit: Duration) -> Result<()> {
        self.fresh_status = None;
        match self.link.command_within(command, limit).await? {
            Response::Error(code) => Err(Error::Stream(format!(
                "`{command}` refused: error:{code} ({})",
                wire::error_message(code)
            ))),
            _ => Ok(()),
        }
    }

    async fn expect_ok(&mut self, command: &str) -> Result<()> {
        self.expect_ok_within(command, Duration::from_secs(3)).await
    }

    /// The controller's settings (`$$`): number and value of each `$N=value` line.
    pub async fn settings(&mut self) -> Result<Vec<(u32, f64)>> {
        self.fresh_status = None;
        let mut settings = Vec::new();
        let answer = self
            .link
            .command_seeing("$$", Duration::from_secs(3), |r| {
                if let Response::Other(text) = r {
                    let parsed = text.strip_prefix('$').and_then(|t| t.split_once('=')).and_then(|(n, v)| {
                        // grblHAL may add a comment after the value.
                        let v = v.split([' ', '(']).next().unwrap_or(v);
                        Some((n.trim().parse::<u32>().ok()?, v.trim().parse::<f64>().ok()?))
                    });
                    settings.extend(parsed);
                }
            })
            .await?;
        if let Response::Error(code) = answer {
            return Err(Error::Stream(format!("`$$` refused: error:{code} ({})", wire::error_message(code))));
        }
        // Steps per mm (`$100`…`$109`): the longest step tells which moves
        // surely make a planner block (see `Book::sure_blocks`).
        let steps: Vec<f64> = settings.iter().filter(|(n, _)| (100..110).contains(n)).map(|(_, v)| *v).collect();
        self.link.book.step_mm = (!steps.is_empty() && steps.iter().all(|v| v.is_finite() && *v > 0.0))
            .then(|| steps.iter().map(|v| 1.0 / v).fold(0.0, f64::max));
        Ok(settings)
    }

    /// Clears an alarm (`$X`).
    pub async fn unlock(&mut self) -> Result<()> {
        self.expect_ok("$X").await
    }

    /// Runs the homing cycle (`$H`); the answer comes when it is done, which
    /// may take as long as crossing the whole travel at the seek rate. The
    /// controller answers no status requests meanwhile, so none are sent. An
    /// `Abort` from `control` (or its sender gone) stops the cycle with a
    /// soft reset (the controller then raises `ALARM:6`); holds are ignored,
    /// as Grbl does while homing.
    pub async fn home(&mut self, mut control: Option<&mut tokio::sync::mpsc::UnboundedReceiver<Control>>) -> Result<()> {
        const LIMIT: Duration = Duration::from_secs(300);
        self.fresh_status = None;
        let before = self.link.bytes_sent;
        self.link.send_line(0, "$H").await?;
        self.link.book.sent(0, "$H");
        self.link.bytes_sent = before;
        let deadline = tokio::time::sleep(LIMIT);
        tokio::pin!(deadline);
        loop {
            let next_control = async {
                match control.as_deref_mut() {
                    Some(rx) => rx.recv().await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                line = self.link.next_line() => match line? {
                    None => return Err(Error::Stream(LINK_CLOSED.into())),
                    Some((_, Response::Ok, _)) => return Ok(()),
                    Some((_, Response::Error(code), _)) => {
                        return Err(Error::Stream(format!("`$H` refused: error:{code} ({})", wire::error_message(code))));
                    }
                    // A failed cycle: Grbl answers the `$H` `ok` after the
                    // alarm, then resets itself (banner) into Alarm.
                    Some((_, Response::Alarm(code), _)) => {
                        let _ = self.link.wait_for(Duration::from_secs(3), |r| matches!(r, Response::Banner(_))).await;
                        return Err(Error::Stream(format!("homing failed: ALARM:{code} ({}); unlock ($X) or home again", wire::alarm_message(code))));
                    }
                    Some(_) => {}
                },
                command = next_control => match command {
                    Some(Control::Abort) | None => {
                        self.link.send_realtime(realtime::SOFT_RESET).await?;
                        let _ = self.link.wait_for(Duration::from_secs(3), |r| matches!(r, Response::Banner(_))).await;
                        return Err(Error::Stream("homing aborted: the controller was reset and is in alarm; home again or unlock ($X)".into()));
                    }
                    Some(_) => {}
                },
                _ = &mut deadline => {
                    return Err(Error::Stream(format!("no answer to `$H` within {} s", LIMIT.as_secs())));
                }
            }
        }
    }

    /// The axis positions the next program starts from (the sender refuses
    /// to stream it from anywhere else); `None` for programs that start anywhere.
    pub fn expect_start(&mut self, start: Option<Vec<f64>>) {
        self.options.expect_start = start;
    }

    /// Jogs (`$J=` + a block such as `G91 X10 F600`).
    pub async fn jog(&mut self, block: &str) -> Result<()> {
        self.expect_ok(&format!("$J={block}")).await
    }

    /// A lower bound on the last program line the controller has executed
    /// (see `Book`), kept up to date while a stream runs: for a watcher that
    /// saves progress. A stream from line `n` starts it at `n - 1`.
    pub fn executed_line(&self) -> ExecutedLine {
        self.link.book.executed_line.clone()
    }

    /// Stops a jog at once and drops the queued jog moves.
    pub async fn jog_cancel(&mut self) -> Result<()> {
        self.fresh_status = None;
        self.link.send_realtime(realtime::JOG_CANCEL).await
    }

    /// Streams `lines`, pulled one at a time as the controller has room, so a
    /// file of any size streams in constant memory. The n-th item is program
    /// line n. `describe(n, text)` turns a line into a message naming it and
    /// where it came from. `control` carries the operator's hold, resume,
    /// abort and overrides while the job runs.
    pub async fn stream<I>(
        &mut self,
        lines: I,
        describe: &dyn Fn(usize, &str) -> String,
        control: Option<&mut tokio::sync::mpsc::UnboundedReceiver<Control>>,
    ) -> Result<StreamOutcome>
    where
        I: IntoIterator<Item = Result<String>>,
    {
        self.stream_from(lines.into_iter(), 1, true, describe, control).await
    }

    /// Resumes a program at line `from` (1-based) after an interruption: reads
    /// the lines before it to rebuild the modal state and position, brings the
    /// controller there (modes, a move with the laser off, laser and feed
    /// modes), then streams from line `from` on, numbered as in the program.
    pub async fn resume<I>(
        &mut self,
        lines: I,
        from: usize,
        axis_letters: &[char],
        describe: &dyn Fn(usize, &str) -> String,
        control: Option<&mut tokio::sync::mpsc::UnboundedReceiver<Control>>,
    ) -> Result<StreamOutcome>
    where
        I: IntoIterator<Item = Result<String>>,
    {
        let mut lines = lines.into_iter();
        let mut state = super::resume::ModalState::new(axis_letters);
        for n in 1..from {
            match lines.next() {
                Some(line) => state.apply(&line?),
                None => return Err(Error::Stream(format!("cannot resume at line {from}: the program has {} line(s)", n - 1))),
            }
        }
        for line in state.preamble() {
            self.expect_ok(&line).await?;
        }
        self.stream_from(lines, from, false, describe, control).await
    }

    async fn stream_from(
        &mut self,
        mut lines: impl Iterator<Item = Result<String>>,
        first_line: usize,
        check_start: bool,
        describe: &dyn Fn(usize, &str) -> String,
        mut control: Option<&mut tokio::sync::mpsc::UnboundedReceiver<Control>>,
    ) -> Result<StreamOutcome> {
        let status = match self.fresh_status.take() {
            Some(s) => s,
            None => self.status().await?,
        };
        if matches!(status.state, MachineState::Alarm) {
            return Err(Error::Stream(IN_ALARM.into()));
        }
        if let (MachineState::Idle, Some((blocks, 0))) = (&status.state, status.buffer) {
            return Err(Error::Stream(format!(
                "the controller reports no free receive buffer while idle (`Bf:{blocks},0`): it holds bytes it does not process \
                 (noise on the line, another program writing to the port) or misreports its buffer, so no line can be sent; \
                 reset or power-cycle it and make sure nothing else uses the port"
            )));
        }
        if let Some(start) = self.options.expect_start.as_ref().filter(|_| check_start) {
            // The program's coordinates are the work coordinates.
            let here = self.work_position(&status);
            let off = start.iter().zip(&here).any(|(a, b)| (a - b).abs() > 0.01);
            if off || here.len() < start.len() {
                return Err(Error::Stream(format!(
                    "the machine is at {here:?} (work coordinates) but the program starts at {start:?}: home it first"
                )));
            }
        }
        if self.options.check_mode {
            if let Response::Error(code) = self.link.command("$C").await? {
                return Err(Error::Stream(format!(
                    "the controller refused check mode ($C): error:{code} ({})",
                    wire::error_message(code)
                )));
            }
        }
        // A new job: fresh books (what is known of the controller stays).
        self.link.book = self.link.book.for_stream(first_line);
        self.link.book.publish();
        let options = self.options.clone();
        let rx_buffer = self.rx_buffer;
        let origin = self.link.origin;
        let link = &mut self.link;
        let mut out = StreamOutcome {
            final_status: Some(status),
            ..Default::default()
        };
        let stream_start = secs(origin);
        // Consecutive status reports showing an idle controller with nothing queued
        // while the same line is the oldest unanswered (bytes were lost on the
        // way, unless it is a dwell still running), when the first came, and
        // that line.
        let mut idle_with_lines_out = 0;
        let mut idle_with_lines_out_since = Instant::now();
        let mut idle_front: Option<usize> = None;
        let mut next: Option<String> = None;
        let mut next_number = first_line.saturating_sub(1);
        let mut exhausted = false;
        // Ticks fall when a status request is due (the one before the
        // stream, at connect, counts).
        let first_tick = link.last_status_request.map_or_else(Instant::now, |last| last + options.status_interval);
        let mut ticker = tokio::time::interval_at(first_tick, options.status_interval);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        // Silence: nothing heard (no answer, no status report, though asked
        // every tick) for the silence limit, counted while this task listens.
        let mut last_heard = Instant::now();
        let mut last_tick = Instant::now();
        // The last sign of progress (an answer, or a status report differing
        // from the one before) and that report.
        let mut last_progress = Instant::now();
        let mut last_report: Option<StatusReport> = None;
        let mut fault: Option<String> = None;
        // Every line is sent and answered: the job ends when the machine is idle.
        let mut ending = false;

        while fault.is_none() {
            loop {
                if next.is_none() && !exhausted {
                    match lines.next() {
                        None => exhausted = true,
                        Some(Err(e)) => {
                            fault = Some(format!("cannot read line {}: {e}", next_number + 1));
                            break;
                        }
                        Some(Ok(raw)) => {
                            next_number += 1;
                            // What the controller would keep of the line anyway:
                            // fewer bytes on the link, and no round trip at all
                            // for blank and comment-only lines.
                            let text = clean_line(&raw);
                            if text.is_empty() {
                                continue;
                            }
                            if text.len() + 1 > rx_buffer {
                                fault = Some(format!(
                                    "{}: {} bytes with its line end, longer than the controller's receive buffer of {rx_buffer} bytes",
                                    describe(next_number, &quote(&text)),
                                    text.len() + 1
                                ));
                                break;
                            }
                            next = Some(text);
                        }
                    }
                }
                // A line goes out when it and its `\n` fit in what is left of the buffer.
                match next.take() {
                    Some(text)
                        if link.book.in_flight + text.len() < rx_buffer
                            && (!options.send_response || link.book.fifo.is_empty()) =>
                    {
                        if let Err(e) = link.send_line(next_number, &text).await {
                            fault = Some(link_failure(e));
                            break;
                        }
                        link.book.sent(next_number, &text);
                        out.lines_sent += 1;
                    }
                    other => {
                        next = other;
                        break;
                    }
                }
            }
            if fault.is_some() {
                break;
            }
            if exhausted && next.is_none() && link.book.fifo.is_empty() {
                if options.check_mode {
                    break;
                }
                ending = true;
            }
            tokio::select! {
                line = link.next_line() => {
                    let (text, response, answered) = match line {
                        Ok(Some(line)) => line,
                        Ok(None) => {
                            fault = Some(LINK_CLOSED.into());
                            break;
                        }
                        Err(e) => {
                            fault = Some(link_failure(e));
                            break;
                        }
                    };
                    out.last_acked_line = link.book.last_acked;
                    // Garbage is not a sign of life: a controller that only babbles
                    // is as gone as a silent one.
                    if !matches!(response, Response::Other(_)) {
                        last_heard = Instant::now();
                    }
                    match response {
                        Response::Ok | Response::Error(_) if answered.is_none() => {
                            link.book.distrust();
                            fault = Some(format!(
                                "protocol error: the controller answered `{text}` with no line outstanding (more answers than lines sent)"
                            ));
                        }
                        Response::Ok => last_progress = Instant::now(),
                        Response::Error(code) => {
                            last_progress = Instant::now();
                            let (n, text) = answered.unwrap_or((0, String::new()));
                            let message = format!("controller answered error:{code} ({}) to {}", wire::error_message(code), describe(n, &quote(&text)));
                            out.errors.push(LineError { line: n, code, message: message.clone() });
                            // In check mode nothing moves: go on and report every bad line.
                            if !options.check_mode {
                                fault = Some(message);
                            }
                        }
                        Response::Alarm(code) => {
                            out.alarms.push(code);
                            fault = Some(format!("controller raised ALARM:{code} ({})", wire::alarm_message(code)));
                        }
                        Response::Banner(_) => {
                            fault = Some("the controller reset itself during the job".into());
                        }
                        Response::Status(s) => {
                            let nothing_queued = s.buffer.is_none_or(|(blocks, rx)| {
                                rx as usize >= rx_buffer && link.book.planner_blocks.is_none_or(|p| blocks as usize >= p)
                            });
                            let front = link.book.fifo.front().map(|(n, _)| *n);
                            if s.state == MachineState::Idle && nothing_queued && link.book.lost_before_report() > 0 {
                                if idle_with_lines_out == 0 || idle_front != front {
                                    idle_with_lines_out = 0;
                                    idle_with_lines_out_since = Instant::now();
                                    idle_front = front;
                                }
                                idle_with_lines_out += 1;
                            } else {
                                idle_with_lines_out = 0;
                            }
                            // Grbl dwells Idle with the `G4` line unanswered (and
                            // those behind it in its buffer): lost only once the
                            // dwell, begun by the first such report, had time to end.
                            let dwell = link.book.fifo.front().map_or(0.0, |(_, text)| dwell_seconds(text));
                            let dwell_over = idle_with_lines_out_since.elapsed().as_secs_f64() > dwell + DWELL_MARGIN_S;
                            if last_report.as_ref().is_none_or(|r| !same_progress(r, &s)) {
                                last_progress = Instant::now();
                            }
                            if idle_with_lines_out >= 2 && dwell_over {
                                fault = Some(format!(
                                    "the controller is idle with nothing queued while {} line(s) are unanswered: bytes were lost on the link",
                                    link.book.fifo.len()));
                            } else if s.state == MachineState::Alarm {
                                fault = Some("the controller went into alarm".into());
                            } else if ending && s.state == MachineState::Idle && link.book.report_covers.is_some_and(|(sent, _)| sent >= link.book.sent_total) {
                                // Idle, asked after every line was sent: done.
                                out.final_status = Some(s);
                                break;
                            }
                            last_report = Some(s.clone());
                            out.final_status = Some(s);
                        }
                        Response::Other(_) => tracing::warn!("unexpected line from the controller: {text}"),
                        _ => {}
                    }
                }
                command = async {
                    match control.as_mut() {
                        Some(rx) => rx.recv().await,
                        None => std::future::pending().await,
                    }
                } => {
                    let byte = match command {
                        None => {
                            control = None;
                            None
                        }
                        Some(Control::FeedHold) => Some(realtime::FEED_HOLD),
                        Some(Control::Resume) => Some(realtime::CYCLE_START),
                        Some(Control::Override(byte)) => Some(byte),
                        Some(Control::Abort) => {
                            fault = Some("aborted by the operator".into());
                            None
                        }
                    };
                    if let Some(Err(e)) = match byte { Some(b) => Some(link.send_realtime(b).await), None => None } {
                        fault = Some(link_failure(e));
                    }
                }
                _ = ticker.tick() => {
                    // A tick long after the one before: this task was held up (a
                    // loaded host, a slow disk on the same thread), asked nothing
                    // and read nothing meanwhile. A controller that was not asked
                    // (a long dwell or move answers no line) is not silent: judge
                    // afresh from the request this tick sends.
                    if last_tick.elapsed() > options.silence_timeout / 2 {
                        last_heard = Instant::now();
                    }
                    last_tick = Instant::now();
                    if (ending || !link.book.fifo.is_empty()) && last_heard.elapsed() > options.silence_timeout {
                        fault = Some(format!(
                            "the controller has been silent (no answer, no status report) for {:.1} s with {} line(s) unanswered{}",
                            last_heard.elapsed().as_secs_f64(), link.book.fifo.len(),
                            if ending { " at the end of the job" } else { "" }));
                        break;
                    }
                    // A dwell holds its line unanswered and the machine still.
                    let dwells: f64 = link.book.fifo.iter().map(|(_, text)| dwell_seconds(text)).sum();
                    let still = last_progress.elapsed().as_secs_f64();
                    let running = last_report.as_ref().is_some_and(|r| matches!(r.state, MachineState::Run | MachineState::Idle | MachineState::Check));
                    if running && still > options.stall_timeout.as_secs_f64() + dwells {
                        let state = last_report.as_ref().map_or(String::new(), |r| r.state.as_field());
                        fault = Some(format!(
                            "the controller has stalled: it reports {state} but its position, buffers, line number and answers have not changed for {still:.1} s{}",
                            if dwells > 0.0 { format!(" (dwells included: {dwells:.1} s)") } else { String::new() }));
                        break;
                    }
                    if let Err(e) = link.request_status_if_due().await {
                        fault = Some(link_failure(e));
                    }
                }
            }
        }
        out.stream_time_s = secs(origin) - stream_start;

        if let Some(reason) = fault {
            let stop = link.safe_stop(options.hold_limit).await;
            let mut reason = reason;
            // What the stop itself did to the machine belongs to the report too.
            if let Some(note) = stop.note {
                reason = format!("{reason}; {note}");
            }
            for code in stop.alarms {
                out.alarms.push(code);
                reason = format!("{reason}; the reset raised ALARM:{code} ({})", wire::alarm_message(code));
            }
            if stop.status.as_ref().is_some_and(|s| s.state == MachineState::Alarm) {
                reason = format!("{reason}; the controller is left in alarm: home ($H) or unlock ($X) it before the next job");
            }
            out.final_status = stop.status;
            out.last_acked_line = link.book.last_acked;
            out.last_executed_line = link.book.executed();
            out.stop_reason = Some(format!("{reason} ({})", link.book.progress(describe)));
            out.bytes_sent = link.bytes_sent;
            return Ok(out);
        }
        if options.check_mode {
            // Leaving check mode answers ok and resets the controller (banner).
            link.command("$C").await?;
            let _ = link
                .wait_for(Duration::from_secs(3), |r| matches!(r, Response::Banner(_)))
                .await?;
            out.final_status = link.query_status(Duration::from_secs(2)).await?;
            out.bytes_sent = link.bytes_sent;
            out.completed = out.errors.is_empty();
            if let Some(first) = out.errors.first() {
                out.stop_reason = Some(format!(
                    "{} line(s) rejected; first: {}",
                    out.errors.len(),
                    first.message
                ));
            }
            return Ok(out);
        }
        // Lines after the last one sent were blank or comments.
        out.last_acked_line = next_number.max(link.book.last_acked);
        out.last_executed_line = Some(out.last_acked_line);
        out.bytes_sent = link.bytes_sent;
        out.completed = true;
        Ok(out)
    }
}

/// Why a stream stops when a read or write failed.
fn link_failure(e: Error) -> String {
    match e {
        Error::Stream(m) => m,
        other => other.to_string(),
    }
}

/// Whether two status reports show the same progress: state, position,
/// buffers and line number alike (numbers compared bit for bit, so a
/// controller reporting `NaN` does not look like it moves).
fn same_progress(a: &StatusReport, b: &StatusReport) -> bool {
    let (pa, pb) = (a.position(), b.position());
    a.state == b.state
        && pa.len() == pb.len()
        && pa.iter().zip(pb).all(|(x, y)| x.to_bits() == y.to_bits())
        && a.buffer == b.buffer
        && a.line == b.line
}

/// Connects and streams `lines` (see [`Connection::stream`]), the whole job in
/// one call.
pub async fn stream<T, I, F>(
    io: T,
    lines: I,
    options: &SenderOptions,
    describe: &dyn Fn(usize, &str) -> String,
    on_event: F,
) -> Result<StreamOutcome>
where
    T: AsyncRead + AsyncWrite,
    I: IntoIterator<Item = Result<String>>,
    F: FnMut(f64, LinkEvent),
{
    let mut connection = Connection::open(io, options, on_event).await?;
    connection.stream(lines, describe, None).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, DuplexStream};

    /// A scripted controller: banner, status on `?`, one answer per line after a
    /// delay, `error:20` on line `fail_on`. Asserts it never holds more than
    /// `rx` unanswered bytes (what GRBL's receive buffer could take).
    async fn fake_controller(
        mut io: DuplexStream,
        rx: usize,
        fail_on: Option<usize>,
    ) -> (usize, Vec<u8>) {
        io.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n")
            .await
            .unwrap();
        let mut pending: VecDeque<usize> = VecDeque::new();
        let mut current = 0usize;
        let mut text = String::new();
        let mut lines = 0usize;
        let mut max_in_flight = 0usize;
        let mut realtime_seen = Vec::new();
        let mut buf = [0u8; 256];
        loop {
            let read = tokio::time::timeout(Duration::from_millis(3), io.read(&mut buf)).await;
            match read {
                Ok(Ok(0)) | Ok(Err(_)) => break,
                Ok(Ok(n)) => {
                    for &b in &buf[..n] {
                        match b {
                            b'?' => {
                                let state = if realtime_seen.contains(&b'!') {
                                    "Hold:0"
                                } else if pending.is_empty() {
                                    "Idle"
                                } else {
                                    "Run"
                                };
                                io.write_all(
                                    format!("<{state}|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n")
                                        .as_bytes(),
                                )
                                .await
                                .unwrap();
                            }
                            b'!' | 0x18 => {
                                realtime_seen.push(b);
                                if b == 0x18 {
                                    pending.clear();
                                    realtime_seen.retain(|&c| c != b'!');
                                    io.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n")
                                        .await
                                        .unwrap();
                                }
                            }
                            b'\n' if text.starts_with('$') => {
                                // The sender's own `$I`: answered at once, not a program line.
                                io.write_all(b"[VER:1.1h:]\r\n[OPT:V,15,128]\r\nok\r\n").await.unwrap();
                                current = 0;
                                text.clear();
                            }
                            b'\n' => {
                                pending.push_back(current + 1);
                                current = 0;
                                text.clear();
                            }
                            _ => {
                                current += 1;
                                text.push(b as char);
                            }
                        }
                    }
                    let in_flight: usize = pending.iter().sum::<usize>() + current;
                    max_in_flight = max_in_flight.max(in_flight);
                }
                Err(_) => {
                    // Answer the oldest line once per tick: a slow controller.
                    if pending.pop_front().is_some() {
                        lines += 1;
                        let answer = if Some(lines) == fail_on {
                            "error:20\r\n"
                        } else {
                            "ok\r\n"
                        };
                        io.write_all(answer.as_bytes()).await.unwrap();
                    }
                }
            }
            assert!(
                max_in_flight <= rx,
                "{max_in_flight} bytes in flight > receive buffer {rx}"
            );
        }
        (lines, realtime_seen)
    }

    fn program(n: usize) -> Vec<String> {
        (0..n)
            .map(|i| format!("G1X{}.12345Y{}.54321F60000", i, i))
            .collect()
    }

    #[tokio::test(start_paused = true)]
    async fn character_counting_never_overfills_and_every_line_is_acked() {
        let (a, b) = tokio::io::duplex(4096);
        let lines = program(60);
        let opts = SenderOptions::new(128, 5.0);
        let controller = tokio::spawn(fake_controller(b, 128, None));
        let mut sent = 0;
        let out = stream(
            a,
            lines.iter().cloned().map(Ok),
            &opts,
            &|n, _| format!("line {n}"),
            |_, e| {
                if matches!(e, LinkEvent::Sent { line, .. } if line > 0) {
                    sent += 1
                }
            },
        )
        .await
        .unwrap();
        assert!(out.completed, "{:?}", out.stop_reason);
        assert_eq!(out.last_acked_line, 60);
        assert_eq!(out.lines_sent, 60);
        assert_eq!(sent, 60);
        assert_eq!(
            out.bytes_sent,
            lines.iter().map(|l| l.len() + 1).sum::<usize>()
        );
        drop(controller);
    }

    #[test]
    fn lines_are_cleaned_as_grbl_would() {
        assert_eq!(clean_line("g1 x1.5 (to the edge) y2 ; then stop\r"), "G1X1.5Y2");
        assert_eq!(clean_line("%"), "");
        assert_eq!(clean_line("  (only a comment)"), "");
        assert_eq!(clean_line("$J=G91 X10 F600"), "$J=G91X10F600");
    }

    #[tokio::test(start_paused = true)]
    async fn blank_and_comment_lines_cost_no_round_trip_but_count() {
        let (a, b) = tokio::io::duplex(4096);
        let mut lines = vec!["%".to_string(), "(header)".to_string()];
        for l in program(20) {
            lines.push(format!("{l} ; comment"));
            lines.push(String::new());
        }
        lines.push("%".into());
        let controller = tokio::spawn(fake_controller(b, 128, None));
        let out = stream(a, lines.iter().cloned().map(Ok), &SenderOptions::new(128, 5.0), &|n, _| format!("line {n}"), |_, _| {}).await.unwrap();
        assert!(out.completed, "{:?}", out.stop_reason);
        assert_eq!(out.lines_sent, 20);
        assert_eq!(out.bytes_sent, program(20).iter().map(|l| l.to_ascii_uppercase().len() + 1).sum::<usize>());
        assert_eq!((out.last_acked_line, out.last_executed_line), (lines.len(), Some(lines.len())));
        drop(controller);
    }

    #[tokio::test(start_paused = true)]
    async fn an_error_stops_streaming_and_names_the_line_then_holds_and_resets() {
        let (a, b) = tokio::io::duplex(4096);
        let lines = program(60);
        let opts = SenderOptions::new(128, 5.0);
        let controller = tokio::spawn(fake_controller(b, 128, Some(17)));
        let out = stream(
            a,
            lines.iter().cloned().map(Ok),
            &opts,
            &|n, _| format!("G-code line {n}"),
            |_, _| {},
        )
        .await
        .unwrap();
        assert!(!out.completed);
        assert_eq!(out.errors[0].line, 17);
        assert!(out.stop_reason.unwrap().contains("error:20"));
        assert!(
            out.lines_sent < 17 + 5,
            "stopped sending at the error: {}",
            out.lines_sent
        );
        // The controller answers the lines it had received before the hold
        // (Grbl does too): up to the three behind the failing one.
        assert!((16..=20).contains(&out.last_acked_line), "{}", out.last_acked_line);
        drop(controller);
    }

    /// Answers what the sender asks when it connects (a status request, then
    /// `$I`), as a controller that works so far.
    async fn answer_connect(b: &mut DuplexStream) {
        answer_connect_with(b, "V,15,128").await;
    }

    /// The same, with these build options (`[OPT:...]`); the status reports
    /// have no `Bf:` (Grbl's default `$10=1`).
    async fn answer_connect_with(b: &mut DuplexStream, options: &str) {
        let mut buf = [0u8; 64];
        let mut seen = Vec::new();
        while !seen.ends_with(b"$I\n") {
            let n = b.read(&mut buf).await.unwrap_or(0);
            if n == 0 {
                return;
            }
            for &c in &buf[..n] {
                if c == b'?' {
                    b.write_all(b"<Idle|MPos:0.000,0.000|FS:0,0>\r\n").await.unwrap();
                } else {
                    seen.push(c);
                }
            }
        }
        b.write_all(format!("[VER:1.1h:]\r\n[OPT:{options}]\r\nok\r\n").as_bytes()).await.unwrap();
    }

    /// Streams ten lines to a controller that will not answer them sensibly:
    /// the stream must stop, calling the controller silent.
    async fn assert_streaming_stops_as_silent(a: DuplexStream) {
        let opts = SenderOptions::new(128, 5.0);
        let lines = program(10).into_iter().map(Ok);
        let out = stream(a, lines, &opts, &|n, _| format!("line {n}"), |_, _| {}).await.unwrap();
        assert!(!out.completed);
        assert!(out.stop_reason.unwrap().contains("silent"));
    }

    #[tokio::test(start_paused = true)]
    async fn build_options_set_the_buffers_counted_on() {
        let (a, mut b) = tokio::io::duplex(4096);
        let board = tokio::spawn(async move {
            b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
            // No Bf in the reports: only `$I` tells the sizes.
            answer_connect_with(&mut b, "VL,14,64").await;
            b
        });
        let c = Connection::open(a, &SenderOptions::new(128, 5.0), |_, _| {}).await.unwrap();
        assert_eq!((c.rx_buffer, c.link.book.planner_blocks), (64, Some(14)));
        drop(board.await.unwrap());

        // A controller that answers status but not `$I` is not one to stream to.
        let (a, mut b) = tokio::io::duplex(4096);
        let mute = tokio::spawn(async move {
            b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
            let mut buf = [0u8; 64];
            while let Ok(n) = b.read(&mut buf).await {
                if n == 0 {
                    break;
                }
                if buf[..n].contains(&b'?') {
                    b.write_all(b"<Idle|MPos:0.000,0.000|FS:0,0>\r\n").await.unwrap();
                }
            }
        });
        let err = Connection::open(a, &SenderOptions::new(128, 5.0), |_, _| {}).await.err().expect("refused");
        assert!(err.to_string().contains("$I"), "{err}");
        mute.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn a_silent_controller_is_detected() {
        let (a, mut b) = tokio::io::duplex(4096);
        let keep = tokio::spawn(async move {
            b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
            answer_connect(&mut b).await;
            // Then never a word again.
            tokio::time::sleep(Duration::from_secs(3600)).await;
        });
        assert_streaming_stops_as_silent(a).await;
        keep.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn a_controller_answering_garbage_is_detected() {
        let (a, mut b) = tokio::io::duplex(4096);
        let babble = tokio::spawn(async move {
            b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
            answer_connect(&mut b).await;
            loop {
                if b.write_all(b"\x07#~garbage~#\r\n").await.is_err() {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        });
        assert_streaming_stops_as_silent(a).await;
        babble.abort();
    }

    /// A scripted controller that misbehaves as told: the banner, the
    /// answers to connecting (`$I`: 15 planner blocks, 128 bytes), then
    /// `answer(n, line)` for the n-th program line (`None`: the link closes)
    /// and `report(answered)` for every `?`. Returns the realtime bytes it
    /// got (`!`, 0x18 ...), which it otherwise ignores.
    async fn scripted(
        mut io: DuplexStream,
        mut answer: impl FnMut(usize, &str) -> Option<Vec<u8>>,
        mut report: impl FnMut(usize) -> String,
    ) -> Vec<u8> {
        io.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
        let (mut line, mut lines, mut realtime_seen) = (Vec::new(), 0, Vec::new());
        let mut buf = [0u8; 256];
        loop {
            let n = match io.read(&mut buf).await {
                Ok(0) | Err(_) => return realtime_seen,
                Ok(n) => n,
            };
            for &b in &buf[..n] {
                let reply = match b {
                    b'?' => Some(report(lines).into_bytes()),
                    b'\n' => {
                        let text = String::from_utf8_lossy(&std::mem::take(&mut line)).to_string();
                        if text == BUILD_INFO {
                            Some(b"[VER:1.1h:]\r\n[OPT:V,15,128]\r\nok\r\n".to_vec())
                        } else {
                            lines += 1;
                            match answer(lines, &text) {
                                Some(reply) => Some(reply),
                                None => return realtime_seen,
                            }
                        }
                    }
                    b if realtime::is_realtime(b) || b >= 0x80 => {
                        realtime_seen.push(b);
                        None
                    }
                    b => {
                        line.push(b);
                        None
                    }
                };
                if let Some(reply) = reply {
                    if io.write_all(&reply).await.is_err() {
                        return realtime_seen;
                    }
                }
            }
        }
    }

    /// Streams `lines` to `peer`; the outcome and the realtime bytes the
    /// peer got. Bounded: a sender that hangs fails the test.
    async fn against(lines: Vec<String>, peer: impl std::future::Future<Output = Vec<u8>> + Send + 'static, a: DuplexStream) -> (Result<StreamOutcome>, Vec<u8>) {
        let peer = tokio::spawn(peer);
        let opts = SenderOptions::new(128, 5.0);
        let run = stream(a, lines.into_iter().map(Ok), &opts, &|n, text| format!("line {n} `{text}`"), |_, _| {});
        let out = tokio::time::timeout(Duration::from_secs(600), run).await.expect("the sender ends within 10 minutes");
        (out, peer.await.unwrap())
    }

    fn ok() -> Option<Vec<u8>> {
        Some(b"ok\r\n".to_vec())
    }

    #[tokio::test(start_paused = true)]
    async fn a_controller_running_forever_after_the_last_ok_is_a_stall_naming_the_executed_line() {
        let (a, b) = tokio::io::duplex(4096);
        // Every line acknowledged, then `Run` forever with one block queued.
        let peer = scripted(b, |_, _| ok(), |_| "<Run|MPos:1.000,2.000|Bf:14,128|FS:600,0>\r\n".into());
        let start = Instant::now();
        let lines: Vec<String> = (0..10).map(|i| format!("G1X{}Y{i}F60000", 10 * i)).collect();
        let (out, realtime_seen) = against(lines, peer, a).await;
        let out = out.unwrap();
        let reason = out.stop_reason.unwrap();
        assert!(!out.completed);
        assert!(reason.contains("stalled") && reason.contains("Run"), "{reason}");
        // One block still queued and up to 5 in Grbl's step-segment buffer
        // (every line but the first, from an unknown place, makes one): the
        // lines up to the 6th from the end have surely run.
        assert_eq!((out.last_acked_line, out.last_executed_line), (10, Some(4)));
        assert!(reason.contains("last acknowledged: line 10 `") && reason.contains("last executed (a lower bound): line 4 `G1X30Y3F60000`"), "{reason}");
        assert!(start.elapsed() < STALL_TIMEOUT + Duration::from_secs(15), "{:?}", start.elapsed());
        assert!(realtime_seen.contains(&realtime::FEED_HOLD) && realtime_seen.contains(&realtime::SOFT_RESET), "{realtime_seen:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_dwell_is_not_a_stall() {
        let (a, mut b) = tokio::io::duplex(4096);
        // The dwell's line is answered when it is over (as Grbl does); the
        // machine stands still meanwhile.
        let peer = async move {
            b.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
            answer_connect_with(&mut b, "V,15,128").await;
            let (mut text, mut buf, mut dwell_ends, mut done) = (Vec::new(), [0u8; 64], None, false);
            loop {
                let n = tokio::select! {
                    n = b.read(&mut buf) => n.unwrap_or(0),
                    _ = tokio::time::sleep_until(dwell_ends.unwrap_or(Instant::now() + Duration::from_secs(3600))), if dwell_ends.is_some() => {
                        dwell_ends = None;
                        done = true;
                        b.write_all(b"ok\r\n").await.unwrap();
                        continue;
                    }
                };
                if n == 0 {
                    return Vec::new();
                }
                for &c in &buf[..n] {
                    match c {
                        b'?' => {
                            let state = if done { "Idle" } else { "Run" };
                            b.write_all(format!("<{state}|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n").as_bytes()).await.unwrap();
                        }
                        b'\n' => {
                            if text.starts_with(b"G4") {
                                dwell_ends = Some(Instant::now() + Duration::from_secs(30));
                            } else {
                                b.write_all(b"ok\r\n").await.unwrap();
                            }
                            text.clear();
                        }
                        c => text.push(c),
                    }
                }
            }
        };
        let (out, _) = against(vec!["G1X1F600".into(), "G4P30".into()], peer, a).await;
        let out = out.unwrap();
        assert!(out.completed, "{:?}", out.stop_reason);
    }

    #[tokio::test(start_paused = true)]
    async fn more_ok_than_lines_sent_is_a_protocol_error() {
        let (a, b) = tokio::io::duplex(4096);
        let peer = scripted(b, |_, _| Some(b"ok\r\nok\r\n".to_vec()), |_| "<Idle|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n".into());
        let (out, realtime_seen) = against(program(10), peer, a).await;
        let out = out.unwrap();
        let reason = out.stop_reason.unwrap();
        assert!(!out.completed);
        assert!(reason.contains("protocol error") && reason.contains("more answers than lines sent"), "{reason}");
        // Within the first status interval no report has said what ran.
        assert!(reason.contains("last executed (a lower bound): "), "{reason}");
        assert!(realtime_seen.contains(&realtime::FEED_HOLD) && realtime_seen.contains(&realtime::SOFT_RESET), "{realtime_seen:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn no_free_receive_buffer_while_idle_is_named_not_blamed_on_a_line() {
        let (a, b) = tokio::io::duplex(4096);
        let peer = scripted(b, |_, _| ok(), |_| "<Idle|MPos:0.000,0.000|Bf:15,0|FS:0,0>\r\n".into());
        let (out, _) = against(program(3), peer, a).await;
        let err = out.expect_err("refused").to_string();
        assert!(err.contains("no free receive buffer while idle (`Bf:15,0`)"), "{err}");
        assert!(!err.contains("line 1"), "{err}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_line_without_end_from_the_controller_is_refused_in_bounded_memory() {
        let (a, b) = tokio::io::duplex(4096);
        // Line 3 is answered by a megabyte without a line end.
        let peer = scripted(b, |n, _| if n == 3 { Some(vec![b'A'; 1 << 20]) } else { ok() }, |_| "<Run|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n".into());
        let (out, realtime_seen) = against(program(10), peer, a).await;
        let out = out.unwrap();
        let reason = out.stop_reason.unwrap();
        assert!(reason.contains(&format!("more than {MAX_CONTROLLER_LINE} bytes without a line end")), "{reason}");
        // The answers after the garbage are not taken for progress.
        assert!(reason.contains("last acknowledged: line 2 `"), "{reason}");
        assert!(out.last_executed_line <= Some(2), "{reason}");
        assert!(realtime_seen.contains(&realtime::FEED_HOLD) && realtime_seen.contains(&realtime::SOFT_RESET), "{realtime_seen:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn the_line_reader_keeps_at_most_the_cap() {
        let (a, mut b) = tokio::io::duplex(1 << 16);
        let (read_half, _write_half) = tokio::io::split(a);
        let mut link = Link { reader: BufReader::new(read_half), partial: Vec::new(), skipping: false, writer: tokio::io::sink(), origin: Instant::now(), on_event: |_, _| {}, bytes_sent: 0, book: Book::default(), status_interval: Duration::from_millis(200), last_status_request: None };
        let mut flood = vec![b'x'; 3 * MAX_CONTROLLER_LINE];
        flood.extend_from_slice(b"\r\nok\r\n");
        b.write_all(&flood).await.unwrap();
        let err = link.next_line().await.expect_err("too long").to_string();
        assert!(err.contains("without a line end"), "{err}");
        assert!(link.partial.capacity() <= 2 * MAX_CONTROLLER_LINE, "{}", link.partial.capacity());
        // The rest of the long line is skipped; the next line reads.
        assert_eq!(link.next_line().await.unwrap().map(|(t, _, _)| t), Some("ok".to_string()));
    }

    #[tokio::test(start_paused = true)]
    async fn a_disconnect_names_the_last_acknowledged_and_executed_line() {
        let (a, b) = tokio::io::duplex(4096);
        let peer = scripted(b, |n, _| (n <= 5).then(|| b"ok\r\n".to_vec()), |_| "<Run|MPos:0.000,0.000|Bf:15,128|FS:0,0>\r\n".into());
        let (out, _) = against(program(20), peer, a).await;
        let out = out.unwrap();
        let reason = out.stop_reason.unwrap();
        assert!(reason.contains(LINK_CLOSED), "{reason}");
        assert!(reason.contains("last acknowledged: line 5 `G1X4.12345Y4.54321F60000`"), "{reason}");
        // Within the first status interval no report has said what ran.
        assert!(reason.contains("last executed (a lower bound): "), "{reason}");
    }

    #[tokio::test(start_paused = true)]
    async fn an_over_long_line_is_quoted_by_its_first_80_characters() {
        let (a, b) = tokio::io::duplex(4096);
        let controller = tokio::spawn(fake_controller(b, 128, None));
        let long = format!("G1X{}", "1".repeat(1_000_000));
        let lines = vec!["G1X1F600".to_string(), long];
        let out = stream(a, lines.into_iter().map(Ok), &SenderOptions::new(128, 5.0), &|n, text| format!("line {n} `{text}`"), |_, _| {}).await.unwrap();
        let reason = out.stop_reason.unwrap();
        assert!(reason.contains(&format!("line 2 `G1X{}… (1000003 bytes)`", "1".repeat(77))), "{reason}");
        assert!(reason.len() < 600, "{} bytes: {reason}", reason.len());
        drop(controller);
    }

    #[test]
    fn dwells_are_read_from_g4_p() {
        assert_eq!(dwell_seconds("G4P1.5"), 1.5);
        assert_eq!(dwell_seconds("G04P30"), 30.0);
        assert_eq!(dwell_seconds("G1X4P2"), 0.0);
        assert_eq!(dwell_seconds("G4P-1"), 0.0);
        assert_eq!(dwell_seconds("$J=G91X1"), 0.0);
    }
}
