//! The sender's books: character counting (the bytes of lines sent and not
//! yet answered) and the executed-line bound that resume relies on. Separate
//! because the bound's proof (below, on `Book`) is the sender's subtlest
//! invariant and deserves a file of its own.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use laserd_sim::wire::{MachineState, Response, StatusReport};

use super::quote;
use crate::stream::resume::ModalState;

/// Acknowledged lines kept while no status report says they ran: far more
/// than any planner holds (Grbl 15 to 35 blocks, grblHAL hundreds).
const MAX_PENDING_LINES: usize = 4096;

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
pub(super) struct Book {
    pub(super) fifo: VecDeque<(usize, String)>,
    pub(super) in_flight: usize,
    last_acked_text: String,
    pub(super) planner_blocks: Option<usize>,
    /// Blocks the controller may hold in its step-segment buffer, no longer in
    /// `Bf:` (see `segment_run_ahead`); `None` for firmware where it is unknown.
    segment_blocks: Option<usize>,
    /// The longest step of any axis (mm), from `$100`…; `None` until `$$` is read.
    pub(super) step_mm: Option<f64>,
    /// Where the program's moves take the machine, to tell which lines surely
    /// make a planner block.
    moves: Option<ModalState>,
    /// Acknowledged lines not yet known to be done, oldest first, with the
    /// planner blocks each surely made (0 or 1).
    pending: VecDeque<(usize, String, usize)>,
    pub(super) last_acked: usize,
    /// The lines before the stream's first: taken as done.
    base: usize,
    /// The last line known done from the controller's reports.
    last_executed: Option<usize>,
    last_executed_text: String,
    /// Lines sent and lines answered, ever (answers come in order).
    pub(super) sent_total: u64,
    answered_total: u64,
    /// `sent_total` and `answered_total` when each status request not yet
    /// answered went out.
    status_requests: VecDeque<(u64, u64)>,
    /// The same for the request the latest status report answers: a
    /// controller reporting an empty, idle queue has answered every line sent
    /// before it. `None` for a report nobody asked for (an auto-report).
    pub(super) report_covers: Option<(u64, u64)>,
    /// The latest report showed Idle and was asked with no line in flight.
    idle_before: bool,
    /// `executed()` for whoever watches the stream from outside (kept across
    /// streams: the handle is handed out once).
    pub(super) executed_line: ExecutedLine,
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
    /// Empty books for a controller whose longest step is `step_mm`, if known.
    pub(super) fn new(step_mm: Option<f64>) -> Book {
        Book { step_mm, ..Book::default() }
    }

    /// Fresh books for a stream whose lines before `first_line` are done:
    /// what is known of the controller stays.
    pub(super) fn for_stream(&self, first_line: usize) -> Book {
        Book {
            planner_blocks: self.planner_blocks,
            segment_blocks: self.segment_blocks,
            step_mm: self.step_mm,
            base: first_line.saturating_sub(1),
            executed_line: self.executed_line.clone(),
            ..Book::default()
        }
    }

    pub(super) fn sent(&mut self, line: usize, text: &str) {
        self.in_flight += text.len() + 1;
        self.sent_total += 1;
        self.fifo.push_back((line, text.to_string()));
    }

    pub(super) fn status_requested(&mut self) {
        // Bounded: a controller that stops answering `?` is caught as silent.
        if self.status_requests.len() >= 256 {
            self.status_requests.pop_front();
        }
        self.status_requests.push_back((self.sent_total, self.answered_total));
    }

    /// Lines sent before the latest report was asked for and still unanswered
    /// although it shows the controller idle with nothing queued: lost.
    pub(super) fn lost_before_report(&self) -> u64 {
        self.report_covers.map_or(0, |(sent, _)| sent.saturating_sub(self.answered_total))
    }

    pub(super) fn distrust(&mut self) {
        self.distrusted = true;
    }

    /// Books an answer; returns the line an `ok` or `error:N` answered.
    pub(super) fn answer(&mut self, response: &Response) -> Option<(usize, String)> {
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
    pub(super) fn executed(&self) -> Option<usize> {
        match self.last_executed {
            Some(line) => Some(line.max(self.base)),
            None if self.last_acked == 0 || self.base > 0 => Some(self.base),
            None => None,
        }
    }

    /// Shows `executed()` to the watchers.
    pub(super) fn publish(&self) {
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
    pub(super) fn sure_blocks(&mut self, text: &str) -> usize {
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
    pub(super) fn done(&mut self, n: usize) {
        for _ in 0..n {
            if let Some((line, text, _)) = self.pending.pop_front() {
                self.last_executed = Some(line);
                self.last_executed_text = text;
            }
        }
    }

    pub(super) fn status(&mut self, s: &StatusReport) {
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
    pub(super) fn progress(&self, describe: &dyn Fn(usize, &str) -> String) -> String {
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
