//! Streaming a program (and resuming one): the loop that sends lines as the
//! receive buffer has room, reads answers and status reports, passes the
//! operator's controls on, and tells a silent, stalled or lossy controller
//! from a busy one. Separate from the connection's one-off commands.

use laserd_sim::wire::{self, realtime, MachineState, Response, StatusReport};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::time::{Duration, Instant};

use super::link::LINK_CLOSED;
use super::{clean_line, quote, secs, Connection, Control, LineError, LinkEvent, SenderOptions, StreamOutcome, IN_ALARM};
use crate::error::{Error, Result};

/// Time a dwell may take beyond its `P` before its line counts as lost:
/// Grbl dwells in steps of 50 ms and a busy host reads late.
const DWELL_MARGIN_S: f64 = 1.0;

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

impl<T, F> Connection<T, F>
where
    T: AsyncRead + AsyncWrite,
    F: FnMut(f64, LinkEvent),
{
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
        let mut state = crate::stream::resume::ModalState::new(axis_letters);
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

    #[test]
    fn dwells_are_read_from_g4_p() {
        assert_eq!(dwell_seconds("G4P1.5"), 1.5);
        assert_eq!(dwell_seconds("G04P30"), 30.0);
        assert_eq!(dwell_seconds("G1X4P2"), 0.0);
        assert_eq!(dwell_seconds("G4P-1"), 0.0);
        assert_eq!(dwell_seconds("$J=G91X1"), 0.0);
    }
}
