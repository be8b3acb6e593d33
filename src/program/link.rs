//! Whether the controller link carries a program as fast as the machine runs
//! it. A line must have reached the controller before its block is due; a
//! slow link (115200 baud, the usual GRBL board) cannot carry a dense
//! program at full speed, and a controller that runs dry stops abruptly, far
//! beyond its acceleration and jerk limits. Such a job is planned again,
//! uniformly slower (`slowdown`), until the link keeps up.
//!
//! The model follows the sender: it counts characters, keeping at most the
//! controller's receive buffer unanswered, and the controller answers a line
//! when its planner takes it, i.e. once the motion block `planner_blocks`
//! earlier has run. The link moves `baud / 10` bytes a second, less a share
//! for the status requests, and the sender reacts to an answer within
//! `ANSWER_LATENCY`. The controller runs a block only with a way to stop
//! queued behind it: a full planner or a block ending at rest (the
//! simulator's timed controller keeps the same rule). The machine starts as
//! early as that holds (a later start would leave the link more time than
//! it gets), and every block must be runnable by the time the block before
//! it ends: the job runs in its planned time, never waiting for the link.

use std::collections::VecDeque;

use super::Program;
use crate::config::MachineConfig;
use crate::motion::Trajectory;
use crate::error::{Error, Result};

/// Share of the link's bytes left for program lines (the rest: status
/// requests, and timing noise of the sender).
const LINE_SHARE: f64 = 0.95;

/// How long after an answer the sender's next line leaves when it waited
/// for that answer (s): its reaction time, on 1 ms timer ticks (tokio's, in
/// the simulator's virtual time as on a real host), with a margin.
const ANSWER_LATENCY: f64 = 2e-3;

/// The most a job is slowed for its link; a link slower than that is
/// refused, naming the figures.
const MAX_SLOWDOWN: f64 = 64.0;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkModel {
    pub bytes_per_s: f64,
    pub rx_buffer: usize,
    pub planner_blocks: usize,
}

/// A line as the link sees it: its bytes (with the newline), for lines of
/// the trajectory when its block starts and ends (s), and whether the
/// machine is at rest at its end.
#[derive(Debug, Clone, Copy)]
struct Line {
    bytes: usize,
    due: Option<(f64, f64)>,
    rest: bool,
    /// Planner blocks it takes: an arc's chords, else 1.
    blocks: usize,
}

impl Line {
    /// A motion block (it takes a place in the controller's planner).
    fn moves(&self) -> bool {
        self.due.is_some_and(|(s, e)| e > s)
    }
}

/// For each line of `program`, whether `trajectory` is at rest where its
/// block ends (under 5 mm/s on every axis).
pub fn rests(program: &Program, trajectory: &Trajectory) -> Vec<bool> {
    // Short enough that a scanner at full jerk moves well under the
    // threshold's distance in it.
    const DT: f64 = 2e-6;
    const MOVE: f64 = 5.0 * DT;
    let state = |t: f64| {
        let s = trajectory.state_at(t);
        [s.stage.x, s.stage.y, s.scanner.x, s.scanner.y]
    };
    let still = |a: [f64; 4], b: [f64; 4]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= MOVE);
    program
        .lines
        .iter()
        .map(|l| {
            l.plan_time.is_some_and(|(_, e)| {
                let at = state(e);
                still(state(e - DT), at) && still(at, state(e + DT))
            })
        })
        .collect()
}

impl LinkModel {
    /// The machine's link and controller (the planner depth is the
    /// simulator's, which stands for the controller's).
    pub fn of(machine: &MachineConfig) -> LinkModel {
        LinkModel {
            bytes_per_s: f64::from(machine.serial.baud) / 10.0 * LINE_SHARE,
            rx_buffer: machine.serial.rx_buffer,
            planner_blocks: machine.simulator.planner_blocks.max(1),
        }
    }

    /// The least uniform slow-down (≥ 1) of the program's timing at which
    /// every line arrives before its block is due; 1 when it already does.
    /// `rests()[i]`: whether the machine is at rest at the end of line i
    /// (`rests`): how soon the machine starts, and where the link may fall behind.
    pub fn slowdown(&self, program: &Program, rests: impl FnOnce() -> Vec<bool>) -> Result<f64> {
        let blocks = super::arcs::planner_blocks(program);
        let mut lines: Vec<Line> = program.lines.iter().zip(blocks).map(|(l, blocks)| Line { bytes: l.text.len() + 1, due: l.plan_time, rest: false, blocks }).collect();
        lines.iter_mut().zip(rests()).for_each(|(l, rest)| l.rest = rest);
        if self.on_time(&lines, 1.0) {
            return Ok(1.0);
        }
        let mut hi = 2.0;
        while !self.on_time(&lines, hi) {
            hi *= 2.0;
            if hi > MAX_SLOWDOWN {
                return Err(Error::Program(format!(
                    "the link ({:.0} bytes/s, {} bytes of receive buffer, {} planner blocks) cannot carry this program even {MAX_SLOWDOWN} times slower",
                    self.bytes_per_s / LINE_SHARE,
                    self.rx_buffer,
                    self.planner_blocks
                )));
            }
        }
        let mut lo = hi / 2.0;
        // To a thousandth: the job is then planned again with a margin.
        while hi - lo > 1e-3 * lo {
            let mid = 0.5 * (lo + hi);
            if self.on_time(&lines, mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Ok(hi)
    }

    /// For each of the job's `geometries`, how much slower its marks must
    /// run for the link to carry their lines at the rate they are due: the
    /// bytes of the geometry's lines, with those of the laser-off moves
    /// leading to it, over their time, against the link's rate (1 where it
    /// already keeps up). Marks denser than the link are slowed alone first;
    /// what bursts remain is left to a uniform slow-down.
    pub fn geometry_slowdowns(&self, program: &Program, geometries: usize) -> Vec<f64> {
        let mut bytes = vec![0.0; geometries];
        let mut time = vec![0.0; geometries];
        // The laser-off lines waiting for the geometry they lead to.
        let (mut lead_bytes, mut lead_time) = (0.0, 0.0);
        for line in &program.lines {
            let b = (line.text.len() + 1) as f64;
            let dt = line.plan_time.map_or(0.0, |(s, e)| (e - s).max(0.0));
            match line.geometry.filter(|&g| g < geometries) {
                Some(g) => {
                    bytes[g] += b + lead_bytes;
                    time[g] += dt + lead_time;
                    (lead_bytes, lead_time) = (0.0, 0.0);
                }
                None => {
                    lead_bytes += b;
                    lead_time += dt;
                }
            }
        }
        bytes.iter().zip(&time).map(|(b, t)| if *t > 0.0 { (b / t / self.bytes_per_s).max(1.0) } else { 1.0 }).collect()
    }

    /// Whether every line arrives in time when the program's clock runs
    /// `scale` times slower: the controller run block by block as the
    /// simulator's timed controller runs it. A block runs once the planner
    /// behind it is full or holds a rest (its queue holds a way to stop).
    /// The machine starts as soon as that holds for the first block, and
    /// from then on it must hold for each block by the time the block
    /// before it ends: the program runs in its planned time, never waiting
    /// for the link (a wait in full motion would be an abrupt stop).
    fn on_time(&self, lines: &[Line], scale: f64) -> bool {
        let p = self.planner_blocks;
        // Each planner block's duration and whether it ends at rest; an
        // arc's chords share its time evenly.
        let mut blocks: Vec<(f64, bool)> = Vec::with_capacity(lines.iter().filter(|l| l.moves()).map(|l| l.blocks.max(1)).sum());
        blocks.extend(lines.iter().filter(|l| l.moves()).flat_map(|l| {
            let (s, e) = l.due.unwrap_or_default();
            let n = l.blocks.max(1);
            (0..n).map(move |k| ((e - s) / n as f64, l.rest && k + 1 == n))
        }));
        let n = blocks.len();
        // The first block at or after each that ends at rest (the program's
        // last ends at rest).
        let mut rest_from = vec![n.saturating_sub(1); n];
        for k in (0..n.saturating_sub(1)).rev() {
            rest_from[k] = if blocks[k].1 { k } else { rest_from[k + 1] };
        }
        let mut feed = Feed::new(self, lines);
        let mut end: Vec<f64> = Vec::with_capacity(n);
        for k in 0..n {
            let needed = rest_from[k].min(k + p - 1);
            let Some(may) = feed.taken_by(needed, p, &end) else { return true };
            let start = match end.last() {
                None => may,
                Some(&before) if may <= before + 1e-6 => before,
                // The jump to the job's start, ending at rest: a block late
                // after it costs the wait, not the motion (a job whose first
                // cut starts where the machine stands has a jump of a few ms
                // before it, which no link fills). Anywhere later, a wait
                // starves the controller: the job is slowed instead.
                Some(&before) if k == 1 && blocks[0].1 => may.max(before),
                Some(_) => return false,
            };
            end.push(start + scale * blocks[k].0);
        }
        true
    }
}

/// The sender and the controller's receive buffer and planner: when each
/// planner block is taken.
struct Feed<'a> {
    model: &'a LinkModel,
    lines: &'a [Line],
    /// Next line to send, and how many of its blocks are taken.
    next: usize,
    chord: usize,
    /// Answer time of each line sent so far.
    answered: Vec<f64>,
    /// Lines sent and not yet answered: their index and bytes.
    unanswered: VecDeque<(usize, usize)>,
    in_flight: usize,
    link_free: f64,
    arrived: f64,
    last_taken: f64,
    /// When each block was taken.
    taken: Vec<f64>,
}

impl<'a> Feed<'a> {
    fn new(model: &'a LinkModel, lines: &'a [Line]) -> Feed<'a> {
        Feed {
            model,
            lines,
            next: 0,
            chord: 0,
            answered: Vec::with_capacity(lines.len()),
            unanswered: VecDeque::new(),
            in_flight: 0,
            link_free: 0.0,
            arrived: 0.0,
            last_taken: 0.0,
            taken: Vec::new(),
        }
    }

    /// When block `block` was taken by the planner (lines are taken in
    /// order; a block once the one `p` before it has ended, in `end`);
    /// none past the program's end.
    fn taken_by(&mut self, block: usize, p: usize, end: &[f64]) -> Option<f64> {
        while self.taken.len() <= block {
            let line = self.lines.get(self.next)?;
            if self.chord == 0 {
                // Room in the receive buffer: wait for the answers that make it.
                let mut send = self.link_free;
                while self.in_flight + line.bytes > self.model.rx_buffer {
                    let Some((i, bytes)) = self.unanswered.pop_front() else { break };
                    self.in_flight -= bytes;
                    send = send.max(self.answered[i] + ANSWER_LATENCY);
                }
                self.arrived = send + line.bytes as f64 / self.model.bytes_per_s;
                self.link_free = self.arrived;
                self.last_taken = self.last_taken.max(self.arrived);
            }
            let chords = if line.moves() { line.blocks.max(1) } else { 0 };
            if self.chord < chords {
                let m = self.taken.len();
                if m >= p {
                    // The caller asks for blocks at most `p - 1` ahead of
                    // the one it runs: the block `p` back has an end.
                    self.last_taken = self.last_taken.max(end[m - p]);
                }
                self.taken.push(self.last_taken);
                self.chord += 1;
            }
            if self.chord >= chords {
                self.answered.push(self.last_taken);
                self.unanswered.push_back((self.next, line.bytes));
                self.in_flight += line.bytes;
                self.next += 1;
                self.chord = 0;
            }
        }
        Some(self.taken[block])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(bytes_per_s: f64) -> LinkModel {
        LinkModel { bytes_per_s, rx_buffer: 128, planner_blocks: 15 }
    }

    /// `n` lines of `bytes` each, blocks of `dt` seconds back to back.
    fn lines(n: usize, bytes: usize, dt: f64) -> Vec<Line> {
        (0..n).map(|i| Line { bytes, due: Some((i as f64 * dt, (i + 1) as f64 * dt)), rest: false, blocks: 1 }).collect()
    }

    #[test]
    fn a_link_faster_than_the_blocks_keeps_up_and_a_slower_one_does_not() {
        // 40-byte lines every 5 ms: 8000 bytes/s needed.
        let program = lines(2000, 40, 0.005);
        assert!(model(9000.0).on_time(&program, 1.0));
        assert!(!model(7000.0).on_time(&program, 1.0), "starves once the buffer has drained");
        // Slowed by 8000/7000 and a little, it keeps up again.
        assert!(model(7000.0).on_time(&program, 8000.0 / 7000.0 * 1.01));
    }

    #[test]
    fn a_late_block_after_the_jump_to_the_start_waits_and_does_not_slow_the_job() {
        // A jump of 1 ms to where the job starts (the machine stands there
        // already), at rest before a pierce, then 5 ms lines: the link cannot
        // bring the second line within 1 ms, and needs not.
        let mut program = lines(2000, 40, 0.005);
        program[0].due = Some((0.0, 0.001));
        program[0].rest = true;
        assert!(model(9000.0).on_time(&program, 1.0));
        // Not at rest, the same 1 ms block starves the controller.
        program[0].rest = false;
        assert!(!model(9000.0).on_time(&program, 1.0));
        // Later rests are no place to wait: 1 ms blocks, each ending at rest,
        // come faster than the link brings their lines.
        let mut stops = lines(20, 40, 0.001);
        stops.iter_mut().for_each(|l| l.rest = true);
        assert!(!model(9000.0).on_time(&stops, 1.0));
    }

    #[test]
    fn a_dense_burst_is_bridged_by_the_buffers_only_while_they_last() {
        // A sparse job with 10 dense lines in the middle: the lines queued
        // ahead carry it; 200 dense lines drain them.
        let burst = |n: usize| {
            let mut v = lines(100, 40, 0.05);
            let t = 100.0 * 0.05;
            v.extend((0..n).map(|i| Line { bytes: 40, due: Some((t + i as f64 * 0.001, t + (i + 1) as f64 * 0.001)), rest: false, blocks: 1 }));
            v
        };
        assert!(model(8000.0).on_time(&burst(3), 1.0));
        assert!(!model(8000.0).on_time(&burst(200), 1.0));
    }

    #[test]
    fn a_mark_denser_than_the_link_is_slowed_by_its_own_rate_with_the_jump_to_it() {
        let line = |bytes: usize, geometry: Option<usize>, s: f64, e: f64| super::super::ProgramLine {
            text: "x".repeat(bytes - 1),
            kind: super::super::LineKind::Mark,
            geometry,
            plan_time: Some((s, e)),
            checks: Vec::new(),
        };
        // Geometry 0: 10 lines of 50 bytes in 0.1 s (5000 bytes/s); a jump
        // of 100 bytes in 0.1 s, then geometry 1: 100 bytes in 0.1 s.
        let mut lines: Vec<_> = (0..10).map(|i| line(50, Some(0), i as f64 * 0.01, (i + 1) as f64 * 0.01)).collect();
        lines.push(line(100, None, 0.1, 0.2));
        lines.push(line(100, Some(1), 0.2, 0.3));
        let program = Program { lines, axis_letters: vec!['X', 'Y'], start: vec![0.0, 0.0], sources: Vec::new() };
        let factors = model(2500.0).geometry_slowdowns(&program, 3);
        assert!((factors[0] - 2.0).abs() < 1e-9, "{factors:?}");
        assert_eq!(factors[1], 1.0, "200 bytes in 0.2 s fit: {factors:?}");
        assert_eq!(factors[2], 1.0, "no lines, no slow-down");
    }

    #[test]
    fn the_slowdown_is_the_least_that_keeps_up() {
        let m = model(7000.0);
        let program = lines(2000, 40, 0.005);
        let as_program = Program {
            lines: program
                .iter()
                .map(|l| super::super::ProgramLine { text: "x".repeat(l.bytes - 1), kind: super::super::LineKind::Mark, geometry: None, plan_time: l.due, checks: Vec::new() })
                .collect(),
            axis_letters: vec!['X', 'Y'],
            start: vec![0.0, 0.0],
            sources: Vec::new(),
        };
        let k = m.slowdown(&as_program, Vec::new).unwrap();
        assert!(k > 1.0 && m.on_time(&program, k) && !m.on_time(&program, k * 0.99), "{k}");
        assert!((k - 8000.0 / 7000.0).abs() < 0.05, "about the ratio of the rates: {k}");
        assert_eq!(model(1e6).slowdown(&as_program, Vec::new).unwrap(), 1.0);
        assert!(model(10.0).slowdown(&as_program, Vec::new).is_err(), "a link 800 times too slow is refused");
    }
}
