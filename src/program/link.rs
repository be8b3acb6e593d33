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
//! for the status requests. A program that never comes to rest runs only
//! with the controller's planner full (its queue must hold a way to stop):
//! the machine starts once it is full, and each block must have arrived by
//! the time the block `planner_blocks` before it ends. That errs on the slow
//! side where the program rests.

use std::collections::VecDeque;

use super::Program;
use crate::config::MachineConfig;
use crate::motion::Trajectory;
use crate::error::{Error, Result};

/// Share of the link's bytes left for program lines (the rest: status
/// requests, and timing noise of the sender).
const LINE_SHARE: f64 = 0.95;

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
    /// (`rests`); asked only when the program does not keep up without
    /// counting them (rests only help).
    pub fn slowdown(&self, program: &Program, rests: impl FnOnce() -> Vec<bool>) -> Result<f64> {
        let blocks = super::arcs::planner_blocks(program);
        let mut lines: Vec<Line> = program.lines.iter().zip(blocks).map(|(l, blocks)| Line { bytes: l.text.len() + 1, due: l.plan_time, rest: false, blocks }).collect();
        if self.on_time(&lines, 1.0) {
            return Ok(1.0);
        }
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
    /// `scale` times slower.
    fn on_time(&self, lines: &[Line], scale: f64) -> bool {
        let p = self.planner_blocks;
        // The motion blocks' plan times and whether each ends at rest, in
        // order; lines without motion (set-up, laser switches) take no
        // planner block.
        // An arc's chords share its time evenly.
        let blocks: Vec<(f64, f64, bool)> = lines
            .iter()
            .filter(|l| l.moves())
            .flat_map(|l| {
                let (s, e) = l.due.unwrap_or_default();
                let n = l.blocks.max(1);
                (0..n).map(move |k| (s + (e - s) * k as f64 / n as f64, s + (e - s) * (k + 1) as f64 / n as f64, l.rest && k + 1 == n))
            })
            .collect();
        if blocks.is_empty() {
            return true;
        }
        // The machine starts once its planner is full or holds a rest (or
        // has the whole program).
        let first_rest = blocks.iter().position(|b| b.2).unwrap_or(blocks.len() - 1);
        let starts_with = first_rest.min(p - 1);
        let t0 = blocks[0].0;
        let at = |clock: f64, t: f64| clock + scale * (t - t0);
        let mut answered: Vec<f64> = Vec::with_capacity(lines.len());
        // Lines sent and not yet answered: their index and bytes.
        let mut unanswered: VecDeque<(usize, usize)> = VecDeque::new();
        let mut in_flight = 0;
        let mut link_free = 0.0_f64;
        let mut last_answer = 0.0_f64;
        let mut clock = 0.0;
        let mut block = 0;
        // The last block before this one that ends at rest.
        let mut last_rest: Option<usize> = None;
        for (j, line) in lines.iter().enumerate() {
            // Room in the receive buffer: wait for the answers that make it.
            let mut send = link_free;
            while in_flight + line.bytes > self.rx_buffer {
                let Some((i, bytes)) = unanswered.pop_front() else { break };
                in_flight -= bytes;
                send = send.max(answered[i]);
            }
            let arrived = send + line.bytes as f64 / self.bytes_per_s;
            link_free = arrived;
            // Lines are taken in order; a motion line once the planner has room.
            let mut taken = arrived.max(last_answer);
            for _ in 0..if line.moves() { line.blocks.max(1) } else { 0 } {
                if block == starts_with {
                    clock = taken;
                } else if block > starts_with {
                    // A block runs only when the planner behind it is full
                    // or holds a rest: the first block that needs this one
                    // is `planner_blocks` back, or the one after a rest.
                    let needed_by = (block + 1).saturating_sub(p).max(last_rest.map_or(0, |r| r + 1));
                    if arrived > at(clock, blocks[needed_by].0) + 1e-6 {
                        return false;
                    }
                }
                if block >= p {
                    taken = taken.max(at(clock, blocks[block - p].1));
                }
                if blocks[block].2 {
                    last_rest = Some(block);
                }
                block += 1;
            }
            last_answer = taken;
            answered.push(taken);
            unanswered.push_back((j, line.bytes));
            in_flight += line.bytes;
        }
        true
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
