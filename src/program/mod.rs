//! Program: turns the `Trajectory` into G-code blocks a GRBL-style controller
//! executes with the planned timing.
//!
//! Every motion block is `G1` in inverse-time mode (G93: `F` = 1 / block duration
//! in minutes), so the controller reproduces the planned velocity profile; the
//! laser runs in M4 (or M3) with `S<power>` on marking blocks and `S0` on jumps,
//! S changes riding on motion lines (a stand-alone S line forces a planner sync).
//!
//! A pierce (a `Pierce` segment of the trajectory: standing still at a path's
//! entry with the laser on) is written as
//!
//! ```text
//! G1M3S<pierce power>F60   laser on at the pierce power where the machine stands
//! G4P<pierce time>         stand still for that long (seconds)
//! M4                       dynamic power again for the cut (only in laser mode M4)
//! ```
//!
//! Why so, in GRBL's laser mode (`$32=1`, reference §9): M4 scales the power
//! with actual over programmed speed, so a machine standing still has the laser
//! off, during `G4` too; M3 (constant power) keeps it at S while stopped. An
//! M3/M4/M5 change forces a planner sync, so the laser lights only once the jump
//! to the entry has ended, never on the way there; `G4` syncs as well and then
//! waits, laser as it is. Grbl lights a standing M3 laser only in a feed motion
//! mode (G1/G2/G3; in G0 it keeps it off), hence the `G1` on the line, which makes
//! the line right whatever came before (the first line of a program, a resume):
//! in G93 a G1 needs an F, and without axis words nothing moves. The closing
//! `M4` switches the laser off there (a standing M4 laser is dark) and the first
//! cut block brings its own S. A feed hold during the dwell turns the laser off
//! and stops the dwell's clock until `~` (Grbl dwells in its realtime loop);
//! the rest of the dwell then runs dark (in laser mode Grbl lights the laser
//! again only with motion), so a held pierce comes out short. A reset ends it
//! with the laser off; a job resumed at a pierce's first line pierces again
//! (that line needs nothing before it). Grbl 1.1h counts a dwell in 50 ms
//! steps, rounding up, so pierce times in steps of 0.05 s are exact there.
//!
//! A cooling wait (a `Cool` segment: the thermal planner's last resort) is
//! `S0` where the laser may still be lit, then `G4` lines of a minute at most.
//!
//! Blocks are chosen per segment: each block is as long as possible while the
//! straight, constant-velocity block stays within `program.tolerance` of the
//! trajectory at every instant, and at least as long as the rounding of
//! coordinates allows without the controller seeing false acceleration or jerk.
//! Stage-only, runs of them on one circle become one G2/G3 (`arcs.rs`).

pub mod arcs;
pub mod link;
pub mod plain;
pub mod times;

use crate::config::{LaserMode, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{Job, Point};
use crate::motion::tcp::PieceKind;
use crate::motion::{AxisState, Trajectory};
use serde::{Deserialize, Serialize};
use schemars::JsonSchema;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LineKind {
    Setup,
    /// Moving from where the machine rests to the job's first point.
    Approach,
    Mark,
    Jump,
    StageMove,
    /// The lines of a pierce: laser on standing still, the dwell, laser mode back.
    Pierce,
    /// A cooling wait before a path (thermal planning): the laser off, a dwell.
    Cool,
    End,
}

/// Planned TCP at a fraction of a block's duration, kept to measure afterwards
/// how closely the machine followed the plan.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct CheckPoint {
    pub fraction: f64,
    pub tcp: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct ProgramLine {
    /// The G-code text, without line terminator.
    pub text: String,
    pub kind: LineKind,
    /// The geometry marked (for error messages: where in the job file).
    pub geometry: Option<usize>,
    /// Planned start and end time of the block in the trajectory.
    pub plan_time: Option<(f64, f64)>,
    pub checks: Vec<CheckPoint>,
}

#[derive(Debug, Clone)]
pub struct Program {
    pub lines: Vec<ProgramLine>,
    /// Controller axis letters, in the order of axis positions.
    pub axis_letters: Vec<char>,
    /// Axis positions the program expects the machine to start from.
    pub start: Vec<f64>,
    /// `Job::geometries[i].source`, for messages naming the job file.
    pub sources: Vec<String>,
}

impl Program {
    /// The G-code file: one block per line, `\n` terminated.
    pub fn to_gcode(&self) -> String {
        let mut s = String::with_capacity(self.lines.len() * 40);
        for l in &self.lines {
            s.push_str(&l.text);
            s.push('\n');
        }
        s
    }

    /// Where program line `number` (1-based) came from, for messages.
    pub fn describe_line(&self, number: usize) -> String {
        match self.lines.get(number.wrapping_sub(1)) {
            None => format!("G-code line {number}"),
            Some(l) => match l.geometry {
                Some(g) => format!("G-code line {number} `{}` ({})", l.text, self.sources[g]),
                None => format!("G-code line {number} `{}`", l.text),
            },
        }
    }
}

/// Axis values of a state in controller order (X Y, then the scanner's two).
pub fn axis_values(state: &AxisState, has_scanner: bool) -> Vec<f64> {
    let mut v = vec![state.stage.x, state.stage.y];
    if has_scanner {
        v.push(state.scanner.x);
        v.push(state.scanner.y);
    }
    v
}

/// Axis values of the trajectory at `t` in controller order: X Y, the
/// head's Z where it has one, then the scanner's two.
fn values_at(trajectory: &Trajectory, t: f64) -> Vec<f64> {
    let mut v = axis_values(&trajectory.state_at(t), trajectory.has_scanner);
    if trajectory.head.is_some() {
        v.insert(2, trajectory.z_at(t));
    }
    v
}

/// TCP from controller axis values (stage + scanner).
pub fn tcp_of(values: &[f64]) -> Point {
    if values.len() >= 4 {
        Point::new(values[0] + values[2], values[1] + values[3])
    } else {
        Point::new(values[0], values.get(1).copied().unwrap_or(0.0))
    }
}

struct Writer {
    /// Decimals per axis.
    decimals: Vec<usize>,
    /// Whether the modal motion mode is G1 already (then lines leave it out).
    in_g1: bool,
    /// Whether the feed mode is G93 (an arc leaves it in G94).
    in_g93: bool,
    letters: Vec<char>,
    last_words: Vec<String>,
    last_power: Option<f64>,
    lines: Vec<ProgramLine>,
}

impl Writer {
    fn setup(&mut self, text: &str) {
        self.lines.push(ProgramLine { text: text.into(), kind: LineKind::Setup, geometry: None, plan_time: None, checks: vec![] });
    }

    /// The pierce lines (see the module's doc) for `time` seconds at `power`,
    /// starting at `start` in the trajectory; the dwell line carries the time.
    fn pierce(&mut self, geometry: usize, power: f64, start: f64, time: f64, mode: LaserMode) {
        let line = |text: String, plan_time| ProgramLine { text, kind: LineKind::Pierce, geometry: Some(geometry), plan_time, checks: vec![] };
        self.lines.push(line(format!("G1M3S{}F60", format_number(power, 1)), None));
        self.in_g1 = true;
        self.lines.push(line(format!("G4P{}", format_number(time, 4)), Some((start, start + time))));
        if mode == LaserMode::M4 {
            self.lines.push(line("M4".into(), None));
        }
        self.last_power = Some(power);
    }

    /// A cooling wait of `time` seconds from `start`: the laser off (`S0`,
    /// unless the line before left it at 0: M3 would keep it lit), then
    /// dwells of at most a minute each (Grbl 1.1 counts one in 50 ms steps
    /// in 16 bits: at most 3276 s).
    fn cool(&mut self, geometry: usize, start: f64, time: f64) {
        let line = |text: String, plan_time| ProgramLine { text, kind: LineKind::Cool, geometry: Some(geometry), plan_time, checks: vec![] };
        if self.last_power != Some(0.0) {
            self.lines.push(line("S0".into(), None));
            self.last_power = Some(0.0);
        }
        // Whole minutes, then the rest (so each stays in 50 ms steps).
        let mut a = start;
        while a < start + time - 1e-9 {
            let b = (a + MAX_DWELL_LINE).min(start + time);
            self.lines.push(line(format!("G4P{}", format_number(b - a, 4)), Some((a, b))));
            a = b;
        }
    }

    /// Appends the motion block ending at `values`, taking `duration` seconds with
    /// the laser at `power`; `line` carries everything but the text.
    fn block(&mut self, values: &[f64], power: f64, duration: f64, line: ProgramLine) -> Result<()> {
        let plan_time = line.plan_time.unwrap_or_default();
        let mut text = String::from(if self.in_g93 { "" } else { "G93" });
        text.push_str(if self.in_g1 { "" } else { "G1" });
        self.in_g1 = true;
        self.in_g93 = true;
        self.axis_words(values, plan_time.0, &mut text)?;
        self.finish(text, power, 60.0 / duration, duration, line)
    }

    /// An arc block (see `arcs.rs`) ending at `values`, in G94: both plane
    /// axes written (a full circle ends where it starts), then `I J`.
    fn arc_block(&mut self, values: &[f64], power: f64, duration: f64, arc: &arcs::ArcWords, line: ProgramLine) -> Result<()> {
        let plan_time = line.plan_time.unwrap_or_default();
        let mut text = String::from(if arc.clockwise { "G2" } else { "G3" });
        if self.in_g93 {
            text.push_str("G94");
        }
        self.in_g1 = false;
        self.in_g93 = false;
        self.last_words[0].clear();
        self.last_words[1].clear();
        self.axis_words(values, plan_time.0, &mut text)?;
        for (letter, v) in ['I', 'J'].iter().zip(arc.centre_offset) {
            text.push(*letter);
            text.push_str(&format_number(v, self.decimals[0]));
        }
        self.finish(text, power, arc.feed, duration, line)
    }

    /// The axis words of the values that changed.
    fn axis_words(&mut self, values: &[f64], at: f64, text: &mut String) -> Result<()> {
        for (i, v) in values.iter().enumerate() {
            if !v.is_finite() {
                return Err(Error::Program(format!("non-finite {} coordinate at t={at:.6}", self.letters[i])));
            }
            let word = format_number(*v, self.decimals[i]);
            if self.last_words[i] != word {
                text.push(self.letters[i]);
                text.push_str(&word);
                self.last_words[i] = word;
            }
        }
        Ok(())
    }

    /// Power (where it changed) and `F` (`f`, for a block of `duration`
    /// seconds) end the block's text.
    fn finish(&mut self, mut text: String, power: f64, f: f64, duration: f64, mut line: ProgramLine) -> Result<()> {
        if self.last_power != Some(power) {
            text.push('S');
            text.push_str(&format_number(power, 1));
            self.last_power = Some(power);
        }
        // G93: F is the inverse of the block time in minutes (an arc's, in
        // G94, its speed). Six significant digits keep a block's timing
        // within 1e-6 of the plan; short blocks get eight, since a timing
        // error is a velocity error, which the controller sees as
        // acceleration and jerk over the block's duration.
        let significant = if duration < 2e-3 { 8 } else { 6 };
        let digits = (significant - (f.log10().floor() as i64 + 1)).clamp(0, 8) as usize;
        text.push('F');
        text.push_str(&format_number(f, digits));
        if text.len() > 79 {
            return Err(Error::Program(format!("block longer than GRBL's 79 characters: {text}")));
        }
        line.text = text;
        self.lines.push(line);
        Ok(())
    }
}

/// Longest dwell written on one line, s.
const MAX_DWELL_LINE: f64 = 60.0;

/// Spans whose blocks `generate` plans at a time.
const SPANS_AT_A_TIME: usize = 1 << 14;

/// `v` with at most `decimals` decimals, trailing zeros trimmed (`-0` as `0`).
pub fn format_number(v: f64, decimals: usize) -> String {
    let scale = 10f64.powi(decimals as i32);
    let scaled = (v * scale).round();
    // Integer arithmetic where the value fits (always, for machine
    // coordinates): formatting floats is a large share of writing a program.
    if scaled.abs() < 9.0e15 {
        let n = scaled as i64;
        let unit = 10i64.pow(decimals as u32);
        let (int, mut frac) = (n.unsigned_abs() / unit as u64, n.unsigned_abs() % unit as u64);
        let mut s = String::with_capacity(24);
        if n < 0 {
            s.push('-');
        }
        s.push_str(&int.to_string());
        if frac > 0 {
            let mut digits = decimals;
            while frac % 10 == 0 {
                frac /= 10;
                digits -= 1;
            }
            s.push('.');
            s.push_str(&format!("{frac:0digits$}"));
        }
        return s;
    }
    let mut s = format!("{:.*}", decimals, v);
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" {
        s = "0".into();
    }
    s
}

/// A stretch of the trajectory written as blocks of one kind: the laser
/// stays as it is within it.
#[derive(Debug, Clone, Copy)]
struct Span {
    kind: LineKind,
    start: f64,
    end: f64,
    power: f64,
    geometry: Option<usize>,
    /// Pieces of the trajectory in it (indices, inclusive).
    first: usize,
    last: usize,
}

fn line_kind(kind: PieceKind) -> LineKind {
    match kind {
        PieceKind::Approach => LineKind::Approach,
        PieceKind::Mark { .. } => LineKind::Mark,
        PieceKind::Jump => LineKind::Jump,
        PieceKind::Pierce { .. } => LineKind::Pierce,
        PieceKind::Cool { .. } => LineKind::Cool,
        PieceKind::Carried => LineKind::StageMove,
    }
}

/// The trajectory cut into spans: one per mark (its legs overlap at
/// corners), per pierce, and per run of laser-off pieces of one kind. The
/// laser's response times move the switching points (`laser.on_delay`,
/// `laser.off_delay`) into the laser-off spans around a mark.
fn spans(trajectory: &Trajectory, machine: &MachineConfig) -> Vec<Span> {
    let mut out: Vec<Span> = Vec::new();
    for (k, p) in trajectory.tcp.pieces.iter().enumerate() {
        let kind = line_kind(p.kind);
        if let Some(last) = out.last_mut() {
            let same = last.kind == kind && !matches!(kind, LineKind::Pierce | LineKind::Cool) && last.geometry == p.geometry() && last.power == p.power() && p.start <= last.end + 1e-12;
            if same {
                last.end = last.end.max(p.end_time());
                last.last = k;
                continue;
            }
        }
        out.push(Span { kind, start: p.start, end: p.end_time(), power: p.power(), geometry: p.geometry(), first: k, last: k });
    }
    let (on, off) = (machine.laser.on_delay, machine.laser.off_delay);
    for i in 0..out.len() {
        if out[i].kind != LineKind::Mark {
            continue;
        }
        // At most the whole laser-off stretch before (a jump shorter than the
        // delay lights the laser at its start, the mark's first bit late).
        const MIN_SPAN: f64 = 1e-6;
        if on > 0.0 && i > 0 && out[i - 1].power == 0.0 {
            let t = (out[i].start - on).max(out[i - 1].start + MIN_SPAN).min(out[i].start);
            out[i - 1].end = t;
            out[i].start = t;
        }
        if off > 0.0 && i + 1 < out.len() && out[i + 1].power == 0.0 {
            let t = (out[i].end - off).max(out[i].start + MIN_SPAN).min(out[i].end);
            out[i].end = t;
            out[i + 1].start = t;
        }
    }
    out
}

/// Shortest block for which coordinate rounding (±half a unit of the last
/// decimal) changes the acceleration and jerk the controller sees by less
/// than 1 % of `limits`.
fn min_block_time(limits: crate::config::Limits, decimals: usize) -> f64 {
    let delta = 0.5 * 10f64.powi(-(decimals as i32));
    // Third divided difference of rounding noise ≤ 8δ/T³; second ≤ 4δ/T².
    let for_jerk = (8.0 * delta / (0.01 * limits.jerk)).cbrt();
    let for_acc = (4.0 * delta / (0.01 * limits.acceleration)).sqrt();
    for_jerk.max(for_acc)
}

/// Block ends for one span: each block as long as its straight,
/// constant-velocity line stays within `tolerance` of the planned TCP at every
/// instant (checked at the pieces' phase changes and between them).
fn block_times(trajectory: &Trajectory, span: &Span, tolerance: f64, min_block: f64) -> std::result::Result<Vec<f64>, String> {
    let tcp = &trajectory.tcp;
    // Where the motion changes character: piece ends and phase changes.
    let mut marks = vec![span.start, span.end];
    let lo = span.first.saturating_sub(1);
    let hi = (span.last + 1).min(tcp.pieces.len().saturating_sub(1));
    let mut bp = Vec::new();
    let at = |t: f64| tcp.position_among(t, lo, hi);
    for p in &tcp.pieces[lo..=hi] {
        marks.push(p.start);
        marks.push(p.end_time());
        bp.clear();
        p.breakpoints(&mut bp);
        marks.extend(bp.iter().map(|x| p.start + x));
    }
    // The head's Z moves beside the TCP: a block is straight in Z too.
    if let Some(head) = &trajectory.head {
        head.breakpoints(span.start, span.end, &mut marks);
    }
    let z = |t: f64| trajectory.z_at(t);
    let lifting = trajectory.head.as_ref().is_some_and(|h| !h.moves.is_empty());
    marks.retain(|&t| t >= span.start && t <= span.end);
    marks.sort_by(f64::total_cmp);
    marks.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    // Legs change character only at their phase changes (free moves give
    // eighths of themselves): quarters between them.
    let parts = 4;
    // Positions at the phase changes and between them, computed once; a
    // block's error is then read off these samples (and stops at the first
    // one out of tolerance).
    let mut sample_t = Vec::with_capacity(marks.len() * parts);
    for w in marks.windows(2) {
        for q in 0..parts {
            sample_t.push(w[0] + (q as f64 / parts as f64) * (w[1] - w[0]));
        }
    }
    sample_t.push(span.end);
    let sample_p: Vec<Point> = sample_t.iter().map(|&t| at(t)).collect();
    let limit = 0.9 * tolerance;
    // Within the tolerance: a block from `a` to `b`. Where either end is not
    // a sample, the samples between and a few points of the partial
    // stretches next to the ends count.
    // A position, read off the samples where `t` is one.
    let position = |t: f64| -> (Point, bool) {
        let k = sample_t.partition_point(|&s| s < t);
        match sample_t.get(k) {
            Some(&s) if s == t => (sample_p[k], true),
            _ => (at(t), false),
        }
    };
    // The largest distance of the block from `a` to `b` from the plan, or
    // some distance over `cap` as soon as one is found.
    let error = |a: f64, b: f64, cap: f64| -> f64 {
        let ((pa, a_sampled), (pb, b_sampled)) = (position(a), position(b));
        let (za, zb) = (z(a), z(b));
        let mut worst = 0.0f64;
        let mut off = |t: f64, p: Point| {
            let f = (t - a) / (b - a);
            let xy = (p - (pa + (pb - pa) * f)).norm();
            let dz = if lifting { z(t) - (za + (zb - za) * f) } else { 0.0 };
            worst = worst.max(xy.hypot(dz));
            worst <= cap
        };
        let lo = sample_t.partition_point(|&t| t <= a);
        let hi = sample_t.partition_point(|&t| t < b);
        if !(lo..hi).all(|k| off(sample_t[k], sample_p[k])) {
            return worst;
        }
        // An end that is not a sample: the stretch from it to the nearest
        // sample counts too.
        let first = sample_t.get(lo).copied().unwrap_or(b).min(b);
        let last = if hi > lo { sample_t[hi - 1] } else { a };
        let mut stretch = |x: f64, y: f64| {
            (1..4).all(|q| {
                let t = x + (q as f64 / 4.0) * (y - x);
                off(t, at(t))
            })
        };
        // And the block's own eighths: phases may be long against a block
        // (an approach across the table, a cruise of a stage-only mark
        // sampled in quarters), its middle between two samples.
        let _ = (a_sampled || stretch(a, first))
            && (b_sampled || stretch(last, b))
            && (1..8).all(|q| {
                let t = a + (q as f64 / 8.0) * (b - a);
                off(t, at(t))
            });
        worst
    };
    // (The limit is a little inside the tolerance: the samples find nearly,
    // not exactly, the worst.)
    let mut times = vec![span.start];
    let mut a = span.start;
    let mut i = 0;
    // Every block reaches a later phase change or is at least `min_block`
    // long, so this many are always enough; more (or a block that does not
    // move on) means times too large for their own rounding, as limits or
    // speeds near zero make them: an error, not an endless loop.
    let most_blocks = marks.len() as f64 + (span.end - span.start) / min_block + 2.0;
    while span.end - a > 1e-12 {
        if times.len() as f64 > most_blocks {
            return Err(format!("more than {most_blocks:.0} blocks between {} s and {} s", span.start, span.end));
        }
        // Farthest phase change the block reaches within the tolerance:
        // galloping, then bisecting over the phase changes.
        let n = marks.len();
        let (mut good_j, mut bad_j, mut step) = (i, n, 1);
        // Errors at the good and the bad end (the bad one: at least it).
        let (mut e_good, mut e_bad) = (0.0, f64::INFINITY);
        loop {
            let j = (good_j + step).min(n - 1);
            if j <= good_j {
                break;
            }
            let e = error(a, marks[j], limit);
            if e <= limit {
                (good_j, e_good) = (j, e);
                step *= 2;
            } else {
                (bad_j, e_bad) = (j, e);
                break;
            }
        }
        while bad_j < n && bad_j - good_j > 1 {
            let mid = (good_j + bad_j) / 2;
            let e = error(a, marks[mid], limit);
            if e <= limit {
                (good_j, e_good) = (mid, e);
            } else {
                (bad_j, e_bad) = (mid, e);
            }
        }
        let reached = (good_j > i).then_some(good_j);
        let j = bad_j;
        let b = match reached {
            Some(r) if r + 1 == marks.len() => marks[r],
            _ => {
                // Between the last good end and the first bad one: the error
                // grows about with the square of the block's length, so
                // secant steps on its square root (kept off the bracket's
                // ends), to a thousandth of the block.
                let (mut good, mut bad) = (reached.map_or(a, |r| marks[r]), marks[j.min(marks.len() - 1)]);
                let excess = |e: f64| e.sqrt() - limit.sqrt();
                let (mut f_good, mut f_bad) = (excess(e_good), excess(e_bad.min(1e3 * limit)));
                for _ in 0..14 {
                    if bad - good <= 1e-3 * (good - a) {
                        break;
                    }
                    let w = bad - good;
                    let secant = if f_bad > f_good { good - f_good * w / (f_bad - f_good) } else { good + 0.5 * w };
                    let mid = secant.clamp(good + 0.1 * w, bad - 0.1 * w);
                    let f = excess(error(a, mid, 1e3 * limit));
                    if f <= 0.0 {
                        (good, f_good) = (mid, f);
                    } else {
                        (bad, f_bad) = (mid, f);
                    }
                }
                // Never so short that rounding looks like motion, nor leaving
                // a shorter rest.
                let mut b = good.max(a + min_block).min(span.end);
                if span.end - b < min_block {
                    b = if span.end - a < 2.0 * min_block { span.end } else { span.end - min_block };
                }
                b
            }
        };
        if b <= a {
            return Err(format!("no block fits after {a} s: the plan's times are too large for their rounding (speeds or limits too low?)"));
        }
        times.push(b);
        a = b;
        i = marks.partition_point(|&t| t <= a + 1e-12).saturating_sub(1);
    }
    Ok(times)
}

/// One straight block of a span: its planned times, the axes' positions at
/// its end, and the planned TCP at points along it (for the simulator's
/// deviation check while marking).
struct PlannedBlock {
    start: f64,
    end: f64,
    axes: Vec<f64>,
    checks: Vec<CheckPoint>,
    arc: Option<arcs::ArcWords>,
}

/// From rest, the end index into `times` of the first two blocks in a row
/// that a machine could stop between and start again from within `limits`
/// (`laserd_sim::controller::gentle_move`, the controller's own rule): a
/// controller planning to stop at the end of its queue starts once it holds
/// them, or once its `planner_blocks` are full (the simulator's timed
/// controller does so). 0 when no such pair comes before the planner is full.
fn first_rest_point(times: &[f64], limits: crate::config::Limits, planner_blocks: usize, position: impl Fn(f64) -> Point) -> usize {
    let gentle = |k: usize| {
        let t = times[k] - times[k - 1];
        let d = position(times[k]) - position(times[k - 1]);
        t > 0.0 && [d.x, d.y].iter().all(|&x| laserd_sim::controller::gentle_move(x, t, limits.acceleration, limits.jerk))
    };
    (2..times.len().min(planner_blocks + 1)).find(|&k| gentle(k - 1) && gentle(k)).unwrap_or(0)
}

/// The blocks of one span (none for a pierce or a cooling wait, which dwell).
fn plan_blocks(trajectory: &Trajectory, span: &Span, machine: &MachineConfig, min_block: f64) -> std::result::Result<Vec<PlannedBlock>, String> {
    if matches!(span.kind, LineKind::Pierce | LineKind::Cool) {
        return Ok(Vec::new());
    }
    let tolerance = if span.kind == LineKind::Mark { machine.program.tolerance } else { machine.program.jump_tolerance };
    // A block ends wherever one piece ends before the next begins (a
    // vertex taken from rest, a jump's end): the machine can stop there. In a
    // mark, only where it does stop: a stage-only curve's pieces (`curve.rs`)
    // continue each other at speed.
    let mut ends: Vec<f64> = (span.first..span.last)
        .filter_map(|k| {
            let (p, q) = (&trajectory.tcp.pieces[k], &trajectory.tcp.pieces[k + 1]);
            let end = p.end_time();
            let stops = span.kind != LineKind::Mark || p.motion.velocity(p.duration).norm() <= 1e-6;
            (stops && q.start >= end - 1e-12).then_some(end)
        })
        .collect();
    // The head's Z moves start and end on block ends: it is exactly at its
    // height wherever it holds it.
    if let Some(head) = &trajectory.head {
        ends.extend(head.moves_in(span.start, span.end).iter().flat_map(|m| [m.start, m.end_time()]).filter(|&t| t > span.start && t < span.end));
        ends.sort_by(f64::total_cmp);
    }
    let mut times = vec![span.start];
    let mut from = span.start;
    for end in ends {
        if end > from + 1e-12 && end < span.end - 1e-12 {
            let part = Span { start: from, end, ..*span };
            times.extend(block_times(trajectory, &part, tolerance, min_block)?.into_iter().skip(1));
            from = end;
        }
    }
    times.extend(block_times(trajectory, &Span { start: from, ..*span }, tolerance, min_block)?.into_iter().skip(1));
    let stage_only = matches!(trajectory.stage, crate::motion::stage::StagePath::FollowsTcp);
    let blocks: Vec<(usize, Option<arcs::ArcWords>)> = if span.kind == LineKind::Mark && stage_only && machine.program.arcs {
        let position = |t: f64| trajectory.tcp.position(t);
        // After a pierce's dwell the controller starts only once its queue
        // holds a rest point or its planner is full (see `first_rest_point`):
        // the blocks up to the rest point stay straight, short lines on the
        // link, rather than have it wait for an arc's long one.
        let after_pierce = span.first > 0 && matches!(trajectory.tcp.pieces[span.first - 1].kind, PieceKind::Pierce { .. });
        let first_arc = if after_pierce { first_rest_point(&times, machine.stage_limits(), machine.simulator.planner_blocks, position) } else { 0 };
        arcs::merge(&times, machine.program.decimals, 0.9 * tolerance, machine.stage_limits(), first_arc, position)
    } else {
        (1..times.len()).map(|j| (j, None)).collect()
    };
    let mut from = 0;
    Ok(blocks
        .into_iter()
        .map(|(to, arc)| {
            let (a, b) = (times[from], times[to]);
            from = to;
            let fractions: &[f64] = if arc.is_some() { &[0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0] } else { &[0.25, 0.5, 0.75, 1.0] };
            let checks = if span.kind == LineKind::Mark {
                fractions
                    .iter()
                    .map(|&f| {
                        let p = trajectory.tcp.position(a + f * (b - a));
                        CheckPoint { fraction: f, tcp: [p.x, p.y] }
                    })
                    .collect()
            } else {
                Vec::new()
            };
            PlannedBlock { start: a, end: b, axes: values_at(trajectory, b), checks, arc }
        })
        .collect())
}

/// Where air assist goes on: the start of the first span of a geometry whose
/// layer has `air = true`, and whether that span is a pierce.
fn first_air_span(job: &Job, spans: &[Span], machine: &MachineConfig) -> Option<(f64, bool)> {
    let air = |g: usize| job.geometries.get(g).and_then(|g| job.processes.get(g.process)).and_then(|p| machine.layer(&p.layer)).is_some_and(|l| l.air);
    if !job.geometries.iter().enumerate().any(|(g, _)| air(g)) {
        return None;
    }
    spans.iter().find(|s| s.geometry.is_some_and(air) && matches!(s.kind, LineKind::Pierce | LineKind::Mark)).map(|s| (s.start, s.kind == LineKind::Pierce))
}

/// The G-code program of a trajectory.
pub fn generate(job: &Job, trajectory: &Trajectory, machine: &MachineConfig) -> Result<Program> {
    let letters = machine.axis_letters();
    let has_scanner = trajectory.has_scanner;
    let mut start = axis_values(&trajectory.start, has_scanner);
    // The head's Z (at cutting height where the job starts) is a stage axis.
    let stage_axes = if trajectory.head.is_some() {
        start.insert(2, 0.0);
        3
    } else {
        2
    };
    let decimals: Vec<usize> = (0..start.len()).map(|i| if i < stage_axes { machine.program.decimals } else { machine.program.scanner_decimals }).collect();
    let mut w = Writer {
        in_g1: false,
        in_g93: true,
        letters: letters.clone(),
        last_words: start.iter().zip(&decimals).map(|(v, d)| format_number(*v, *d)).collect(),
        decimals,
        last_power: Some(0.0),
        lines: Vec::new(),
    };
    // The shortest block: the scanner's moves set it where there is one.
    let min_block = match machine.scanner_limits().filter(|_| has_scanner) {
        Some(l) => min_block_time(l, machine.program.scanner_decimals),
        None => min_block_time(machine.stage_limits(), machine.program.decimals),
    };
    let min_block = match machine.head_limits().filter(|_| trajectory.head.is_some()) {
        Some(z) => min_block.max(min_block_time(z, machine.program.decimals)),
        None => min_block,
    };
    w.setup("G21G90G93");
    let laser_on = match machine.laser.mode {
        LaserMode::M3 => "M3S0",
        LaserMode::M4 => "M4S0",
    };
    w.setup(laser_on);
    // Air assist (coolant flood) for layers with `air = true`: on before the
    // first pierce of such a layer, where the machine stands anyway (M8
    // syncs Grbl's planner); a mark entered at speed gets it from the start
    // instead, so that nothing stops where the plan does not. Off at the end.
    let spans = spans(trajectory, machine);
    let air_at = first_air_span(job, &spans, machine);
    let mut air = false;
    if air_at.is_some_and(|(_, pierce)| !pierce) {
        w.setup("M8");
        air = true;
    }
    // Finding the blocks is most of the work and each span's are its own:
    // a chunk of spans is shared out over threads, then written in order
    // (a chunk at a time: a million-line fill's blocks are not all held).
    w.lines.reserve(spans.len() + 8);
    for chunk in spans.chunks(SPANS_AT_A_TIME) {
        let planned = crate::parallel::map(chunk, 8, |span| plan_blocks(trajectory, span, machine, min_block));
        for (span, blocks) in chunk.iter().zip(planned) {
            if !air && air_at.is_some_and(|(at, _)| at == span.start) && span.kind == LineKind::Pierce {
                w.lines.push(ProgramLine { text: "M8".into(), kind: LineKind::Pierce, geometry: span.geometry, plan_time: None, checks: vec![] });
                air = true;
            }
            if span.kind == LineKind::Pierce {
                w.pierce(span.geometry.unwrap_or(0), span.power, span.start, span.end - span.start, machine.laser.mode);
                continue;
            }
            if span.kind == LineKind::Cool {
                w.cool(span.geometry.unwrap_or(0), span.start, span.end - span.start);
                continue;
            }
            let blocks = blocks.map_err(|e| {
                let place = span.geometry.and_then(|g| job.geometries.get(g)).map_or("a laser-off move", |g| g.source.as_str());
                Error::Program(format!("{place}: {e}"))
            })?;
            for block in blocks {
                let line = ProgramLine { text: String::new(), kind: span.kind, geometry: span.geometry, plan_time: Some((block.start, block.end)), checks: block.checks };
                match &block.arc {
                    Some(arc) => w.arc_block(&block.axes, span.power, block.end - block.start, arc, line)?,
                    None => w.block(&block.axes, span.power, block.end - block.start, line)?,
                }
            }
        }
    }
    let end: &[&str] = if air { &["M5S0", "M9", "G94", "M2"] } else { &["M5S0", "G94", "M2"] };
    for text in end {
        w.lines.push(ProgramLine { text: (*text).into(), kind: LineKind::End, geometry: None, plan_time: None, checks: vec![] });
    }
    w.lines.shrink_to_fit();
    Ok(Program {
        lines: w.lines,
        axis_letters: letters,
        start,
        sources: job.geometries.iter().map(|g| g.source.clone()).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Geometry, Process};
    use crate::mode::Mode;
    use crate::motion::build;
    use crate::plan::{nearest::NearestNeighbour, PlanContext, Planner};

    fn circle_job() -> Job {
        let n = 64;
        let points = (0..n)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / n as f64;
                Point::new(150.0 + 10.0 * a.cos(), 150.0 + 10.0 * a.sin())
            })
            .collect();
        Job {
            source: "t".into(),
            geometries: vec![Geometry { arcs: Vec::new(), profile: Vec::new(), points, closed: true, process: 0, source: "circle".into() }],
            processes: vec![Process { layer: "mark".into(), speed: 1000.0, power: 250.0, passes: 1, fill: false }],
        }
    }

    #[test]
    fn numbers_are_compact() {
        assert_eq!(format_number(12.30000, 4), "12.3");
        assert_eq!(format_number(-0.00001, 4), "0");
        assert_eq!(format_number(300.0, 4), "300");
        assert_eq!(format_number(-0.5, 4), "-0.5");
        assert_eq!(format_number(-12.000049, 4), "-12");
        assert_eq!(format_number(0.00123456, 8), "0.00123456");
        assert_eq!(format_number(1234567.891, 1), "1234567.9");
        assert_eq!(format_number(60.0 / 0.0042, 6), "14285.714286");
    }

    /// Re-executes `prog` as a controller would (constant velocity per block,
    /// an arc (G94, `F` in mm/min) through its chords at equal times, a dwell
    /// standing still) and returns the worst distance from the trajectory at
    /// many instants; checks that the blocks tile the trajectory's time.
    fn replay_against(prog: &Program, tr: &Trajectory) -> f64 {
        let jump_tolerance = MachineConfig::load(None).unwrap().program.jump_tolerance;
        let mut pos = prog.start.clone();
        let mut t = 0.0;
        let mut worst: f64 = 0.0;
        let word = |text: &str, letter: char| -> Option<f64> {
            let at = text.find(letter)?;
            let rest = &text[at + 1..];
            let len = rest.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(rest.len());
            Some(rest[..len].parse().unwrap())
        };
        for line in prog.lines.iter().filter(|l| l.plan_time.is_some()) {
            let (a, b) = line.plan_time.unwrap();
            assert!((a - t).abs() < 1e-9, "blocks are contiguous in time");
            let mut end = pos.clone();
            let text = &line.text;
            // The executed knots after the block's start (time, values).
            let mut knots = vec![(b, end.clone())];
            if matches!(line.kind, LineKind::Pierce | LineKind::Cool) {
                // The dwell: P seconds, nothing moves.
                assert!(text.starts_with("G4P"), "{text}");
                assert!((word(text, 'P').unwrap() - (b - a)).abs() < 1e-4);
            } else {
                for (i, letter) in prog.axis_letters.iter().enumerate() {
                    if let Some(v) = word(text, *letter) {
                        end[i] = v;
                    }
                }
                let f = word(text, 'F').unwrap();
                knots = vec![(b, end.clone())];
                if text.starts_with("G2") || text.starts_with("G3") {
                    // Stage-only arcs: the plane's axes are the first two.
                    let arc = arcs::ArcWords { clockwise: text.starts_with("G2"), centre_offset: [word(text, 'I').unwrap(), word(text, 'J').unwrap()], feed: f };
                    let (from, to) = (Point::new(pos[0], pos[1]), Point::new(end[0], end[1]));
                    let chords = arcs::chord_knots(from, to, &arc, a, b).expect("an arc the controller runs");
                    let length: f64 = std::iter::once(from).chain(chords.iter().map(|k| k.1)).collect::<Vec<_>>().windows(2).map(|w| (w[1] - w[0]).norm()).sum();
                    assert!((60.0 * length / f - (b - a)).abs() < 1e-5 * (b - a) + 1e-12, "{text}: {} s for {} s", 60.0 * length / f, b - a);
                    knots = chords.into_iter().map(|(t, p)| (t, vec![p.x, p.y])).collect();
                } else {
                    assert!(((60.0 / f) - (b - a)).abs() < 1e-5 * (b - a) + 1e-12, "{text}");
                }
            }
            for k in 0..=10 {
                let tt = a + (b - a) * k as f64 / 10.0;
                let planned = tr.state_at(tt).tcp();
                // Straight between the knots either side of `tt`.
                let next = knots.partition_point(|(t, _)| *t < tt).min(knots.len() - 1);
                let (t0, from) = if next == 0 { (a, &pos) } else { (knots[next - 1].0, &knots[next - 1].1) };
                let (t1, to) = (knots[next].0, &knots[next].1);
                let frac = if t1 > t0 { (tt - t0) / (t1 - t0) } else { 1.0 };
                let exec: Vec<f64> = from.iter().zip(to).map(|(p, e)| p + (e - p) * frac).collect();
                let dev = (tcp_of(&exec) - planned).norm();
                if line.kind == LineKind::Mark {
                    worst = worst.max(dev);
                } else {
                    assert!(dev <= jump_tolerance + 1e-4, "laser off: {dev} at {tt} ({text})");
                }
            }
            if line.kind == LineKind::Jump {
                assert!(!line.text.contains('S') || line.text.contains("S0"));
            }
            pos = end;
            t = b;
        }
        assert!((t - tr.duration()).abs() < 1e-9);
        assert!(prog.lines.iter().all(|l| l.text.len() <= 79));
        worst
    }

    #[test]
    fn blocks_follow_the_trajectory_within_tolerance_and_time() {
        let mut counts = Vec::new();
        for mode in [Mode::StepAndScan, Mode::OnTheFly, Mode::StageOnly] {
            let machine = MachineConfig::load(None).unwrap();
            let job = circle_job();
            let planning = mode.planning_machine(&machine);
            let ctx = PlanContext { machine: &planning, mode, start: Point::origin(), plate: None };
            let seq = NearestNeighbour.plan(&job, &ctx).unwrap();
            let tr = build(&job, &seq, &machine, mode, Point::origin()).unwrap();
            let prog = generate(&job, &tr, &machine).unwrap();
            assert_eq!(prog.lines[0].text, "G21G90G93");
            assert_eq!(prog.lines.last().unwrap().text, "M2");
            assert!(!prog.lines.iter().any(|l| l.kind == LineKind::Pierce), "no pierce time, no pierce");
            let worst = replay_against(&prog, &tr);
            assert!(worst <= machine.program.tolerance + 1e-4, "{mode:?}: worst deviation {worst}");
            // Blocks only where needed: on the fly the 64-gon (sides of 0.98 mm,
            // a chord within 0.01 mm of a 10 mm circle spans 0.87 mm) takes about
            // a block per side; stopping at every vertex takes several.
            let marks = prog.lines.iter().filter(|l| l.kind == LineKind::Mark).count();
            counts.push(marks);
            if mode == Mode::OnTheFly {
                assert!(marks <= 68, "{mode:?}: {marks} marking blocks");
            }
        }
        assert!(counts[0] > 2 * counts[1], "step-and-scan {} vs on-the-fly {}", counts[0], counts[1]);
    }

    #[test]
    fn laser_delays_move_the_switching_points_ahead_of_the_mark() {
        let (on, off) = (2e-4, 1e-4);
        let mut machine = MachineConfig::load(None).unwrap();
        let job = circle_job();
        let planning = Mode::OnTheFly.planning_machine(&machine);
        let ctx = PlanContext { machine: &planning, mode: Mode::OnTheFly, start: Point::origin(), plate: None };
        let seq = NearestNeighbour.plan(&job, &ctx).unwrap();
        let tr = build(&job, &seq, &machine, Mode::OnTheFly, Point::origin()).unwrap();
        let marks: Vec<_> = tr.tcp.pieces.iter().filter(|p| p.is_marking()).collect();
        let (start, end) = (marks[0].start, marks.last().unwrap().end_time());
        let switch_times = |prog: &Program| {
            let on_at = prog.lines.iter().find(|l| l.kind == LineKind::Mark).and_then(|l| l.plan_time).unwrap().0;
            let off_at = prog.lines.iter().rev().find(|l| l.kind == LineKind::Mark).and_then(|l| l.plan_time).unwrap().1;
            (on_at, off_at)
        };
        let (a, b) = switch_times(&generate(&job, &tr, &machine).unwrap());
        assert!((a - start).abs() < 1e-12 && (b - end).abs() < 1e-12, "no delays: the laser switches with the mark");
        machine.laser.on_delay = on;
        machine.laser.off_delay = off;
        let prog = generate(&job, &tr, &machine).unwrap();
        let (on_at, off_at) = switch_times(&prog);
        assert!((on_at - (start - on)).abs() < 1e-12, "laser on {on_at} for a mark at {start}");
        assert!((off_at - (end - off)).abs() < 1e-12, "laser off {off_at} for a mark ending at {end}");
        // The block that switches it on carries the power; the one after the
        // mark switches it off.
        let first = prog.lines.iter().position(|l| l.kind == LineKind::Mark).unwrap();
        assert!(prog.lines[first].text.contains("S250"), "{}", prog.lines[first].text);
        let after = prog.lines.iter().rposition(|l| l.kind == LineKind::Mark).unwrap() + 1;
        assert!(prog.lines[after].text.contains("S0"), "{}", prog.lines[after].text);
    }

    #[test]
    fn a_pierce_is_m3_then_a_dwell_then_m4_at_every_path_entry() {
        let mut job = circle_job();
        let mut second = job.geometries[0].clone();
        second.points.iter_mut().for_each(|p| p.x += 25.0);
        job.geometries.push(second);
        for (mode, laser) in [(Mode::StepAndScan, LaserMode::M4), (Mode::StageOnly, LaserMode::M4), (Mode::StepAndScan, LaserMode::M3)] {
            let mut machine = MachineConfig::load(None).unwrap();
            if mode == Mode::StageOnly {
                machine.scanner = None;
            }
            machine.laser.mode = laser;
            machine.laser.pierce_time = 0.25;
            machine.laser.pierce_power = Some(800.0);
            let ctx = PlanContext { machine: &machine, mode, start: Point::origin(), plate: None };
            let seq = NearestNeighbour.plan(&job, &ctx).unwrap();
            let tr = build(&job, &seq, &machine, mode, Point::origin()).unwrap();
            let prog = generate(&job, &tr, &machine).unwrap();
            let texts: Vec<&str> = prog.lines.iter().map(|l| l.text.as_str()).collect();
            let starts: Vec<usize> = texts.iter().enumerate().filter(|(_, t)| t.starts_with("G1M3")).map(|(i, _)| i).collect();
            assert_eq!(starts.len(), 2, "{mode:?} {laser:?}: one pierce per path");
            assert_eq!(prog.lines.iter().filter(|l| l.kind == LineKind::Pierce && l.plan_time.is_some()).count(), 2);
            for &i in &starts {
                let n = if laser == LaserMode::M4 { 3 } else { 2 };
                let expected: &[&str] = if laser == LaserMode::M4 { &["G1M3S800F60", "G4P0.25", "M4"] } else { &["G1M3S800F60", "G4P0.25"] };
                assert_eq!(&texts[i..i + n], expected, "{mode:?} {laser:?}");
                assert!(prog.lines[i..i + n].iter().all(|l| l.kind == LineKind::Pierce && l.geometry.is_some()));
                // After the jump to the entry, before the cut, which brings its own power.
                assert!(matches!(prog.lines[i - 1].kind, LineKind::Jump | LineKind::Approach), "{mode:?} {laser:?}");
                assert_eq!(prog.lines[i + n].kind, LineKind::Mark);
                assert!(texts[i + n].contains("S250"), "{mode:?} {laser:?}: {}", texts[i + n]);
                let (a, b) = prog.lines[i + 1].plan_time.unwrap();
                assert!((b - a - 0.25).abs() < 1e-12);
            }
            let worst = replay_against(&prog, &tr);
            assert!(worst <= machine.program.tolerance + 1e-4, "{mode:?} {laser:?}: worst deviation {worst}");
        }
    }

    /// Issue 24: air assist (M8) goes on before the first pierce of a layer
    /// with `air = true` (from the start when its first mark has no pierce),
    /// stays on, and goes off (M9) at the end; without it no coolant word.
    #[test]
    fn air_assist_goes_on_before_its_layers_first_pierce_and_off_at_the_end() {
        let mut job = circle_job();
        let mut second = job.geometries[0].clone();
        second.points.iter_mut().for_each(|p| p.x += 25.0);
        second.process = 1;
        job.geometries.push(second);
        job.processes.push(Process { layer: "cut".into(), speed: 200.0, power: 900.0, passes: 1, fill: false });
        let program = |machine: &MachineConfig| {
            let ctx = PlanContext { machine, mode: Mode::StepAndScan, start: Point::origin(), plate: None };
            let seq = NearestNeighbour.plan(&job, &ctx).unwrap();
            let tr = build(&job, &seq, machine, Mode::StepAndScan, Point::origin()).unwrap();
            generate(&job, &tr, machine).unwrap()
        };
        let coolant = |p: &Program| p.lines.iter().filter(|l| ["M7", "M8", "M9"].iter().any(|m| l.text.contains(m))).count();
        let mut machine = MachineConfig::load(None).unwrap();
        machine.laser.pierce_time = 0.25;
        assert_eq!(coolant(&program(&machine)), 0, "no air unless a layer asks");
        machine.layers.iter_mut().find(|l| l.name == "cut").unwrap().air = true;
        let prog = program(&machine);
        let texts: Vec<&str> = prog.lines.iter().map(|l| l.text.as_str()).collect();
        assert_eq!(coolant(&prog), 2, "{texts:?}");
        let on = texts.iter().position(|t| *t == "M8").unwrap();
        assert!(texts[on + 1].starts_with("G1M3"), "right before the pierce: {:?}", &texts[on - 1..on + 2]);
        assert_eq!(prog.lines[on].geometry, Some(1), "the cut's pierce");
        assert!(!prog.lines[..on].iter().any(|l| l.geometry == Some(1)), "nothing of the cut before it");
        assert_eq!(&texts[texts.len() - 4..], &["M5S0", "M9", "G94", "M2"]);
        // A layer whose first mark has no pierce: on from the start.
        machine.laser.pierce_time = 0.0;
        let prog = program(&machine);
        let texts: Vec<&str> = prog.lines.iter().map(|l| l.text.as_str()).collect();
        let on = texts.iter().position(|t| *t == "M8").unwrap();
        assert!(prog.lines[..=on].iter().all(|l| l.kind == LineKind::Setup), "{texts:?}");
        assert_eq!(texts[texts.len() - 3], "M9");
    }

    #[test]
    fn a_cooling_wait_is_the_laser_off_then_dwells_of_a_minute_at_most_before_its_path() {
        // Two lines end to end, at a right angle: the second starts where the
        // first ended, so no jump's S0 comes before its wait.
        let mut job = circle_job();
        let line = |points: Vec<Point>, source: &str| Geometry { arcs: Vec::new(), profile: Vec::new(), points, closed: false, process: 0, source: source.into() };
        let (a, b, c) = (Point::new(100.0, 100.0), Point::new(150.0, 100.0), Point::new(150.0, 150.0));
        job.geometries = vec![line(vec![a, b], "first"), line(vec![b, c], "second")];
        let wait = 61.35;
        let cooled = crate::plan::PlannedPath { cooling_wait: wait, ..crate::plan::PlannedPath::new(1, vec![b, c], 0, false) };
        let seq = crate::plan::Sequence { groups: vec![crate::plan::PathGroup { field_center: None, paths: vec![crate::plan::PlannedPath::new(0, vec![a, b], 0, false), cooled] }] };
        for laser in [LaserMode::M3, LaserMode::M4] {
            let mut machine = MachineConfig::load(None).unwrap();
            machine.scanner = None;
            machine.laser.mode = laser;
            let tr = build(&job, &seq, &machine, Mode::StageOnly, Point::origin()).unwrap();
            let prog = generate(&job, &tr, &machine).unwrap();
            let cool: Vec<&ProgramLine> = prog.lines.iter().filter(|l| l.kind == LineKind::Cool).collect();
            let texts: Vec<&str> = cool.iter().map(|l| l.text.as_str()).collect();
            assert_eq!(texts, ["S0", "G4P60", "G4P1.35"], "{laser:?}");
            assert!(cool.iter().all(|l| l.geometry == Some(1)));
            let (first, last) = (cool[1].plan_time.unwrap(), cool[2].plan_time.unwrap());
            assert!((last.1 - first.0 - wait).abs() < 1e-9);
            // Between the first line's last cut and the second's first, with its power.
            let at = prog.lines.iter().position(|l| l.kind == LineKind::Cool).unwrap();
            assert_eq!((prog.lines[at - 1].kind, prog.lines[at - 1].geometry), (LineKind::Mark, Some(0)));
            assert_eq!((prog.lines[at + 3].kind, prog.lines[at + 3].geometry), (LineKind::Mark, Some(1)));
            assert!(prog.lines[at + 3].text.contains("S250"), "{}", prog.lines[at + 3].text);
            // The trajectory stands there the whole wait, and the blocks follow it.
            assert!(tr.tcp.pieces.iter().any(|p| p.kind == PieceKind::Cool { geometry: 1 } && (p.duration - wait).abs() < 1e-12 && (p.start_point() - b).norm() < 1e-9));
            let worst = replay_against(&prog, &tr);
            assert!(worst <= machine.program.tolerance + 1e-4, "{laser:?}: worst deviation {worst}");
        }
    }
}
