//! How long a running job has left: the planned time of the program lines
//! not yet run, the machine placed among them by its reported position, and
//! stretched only where it has kept a pace of its own against the plan.
//! Line counts say little (a line may take 1 ms or a minute); the plan knows
//! each line's time.

use std::path::Path;

use crate::error::Result;

/// Each program line's planned end: the time (s from the program's start)
/// and where the tool centre point then is (work mm), stored as three
/// little-endian f32 a line.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LineTimes {
    end: Vec<f32>,
    tcp: Vec<[f32; 2]>,
}

/// Bytes a line takes in the file.
const LINE_BYTES: usize = 12;

impl LineTimes {
    /// From each line's planned end and TCP there, where known (a line
    /// without them, such as a setup line, ends when and where the line
    /// before it did).
    pub fn from_ends(ends: impl IntoIterator<Item = (Option<f64>, Option<[f64; 2]>)>) -> LineTimes {
        let (mut last, mut at) = (0.0f64, [0.0f64; 2]);
        let (end, tcp) = ends
            .into_iter()
            .map(|(e, p)| {
                last = e.map_or(last, |e| e.max(last));
                at = p.unwrap_or(at);
                (last as f32, [at[0] as f32, at[1] as f32])
            })
            .unzip();
        LineTimes { end, tcp }
    }

    /// A program's own lines: the TCP from their axis words (absolute, as
    /// laserd writes them; the axes after the first two are the scanner's,
    /// added to the stage's), the times from the plan.
    pub fn of_program(program: &crate::program::Program) -> LineTimes {
        let mut axes = program.start.clone();
        LineTimes::from_ends(program.lines.iter().map(|l| {
            let mut moved = false;
            let mut words = l.text.as_str();
            while let Some(at) = words.find(|c: char| c.is_ascii_alphabetic()) {
                let letter = words[at..].chars().next().unwrap_or(' ');
                let rest = &words[at + 1..];
                let len = rest.find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-')).unwrap_or(rest.len());
                if let (Some(i), Ok(v)) = (program.axis_letters.iter().position(|a| *a == letter), rest[..len].parse::<f64>()) {
                    if let Some(a) = axes.get_mut(i) {
                        *a = v;
                        moved = true;
                    }
                }
                words = &rest[len..];
            }
            let axis = |i: usize| axes.get(i).copied().unwrap_or(0.0);
            let tcp = moved.then(|| [axis(0) + axis(2), axis(1) + axis(3)]);
            (l.plan_time.map(|t| t.1), tcp)
        }))
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        let bytes: Vec<u8> = self.end.iter().zip(&self.tcp).flat_map(|(t, [x, y])| [t.to_le_bytes(), x.to_le_bytes(), y.to_le_bytes()].concat()).collect();
        super::queue::write_atomic(path, &bytes)
    }

    /// Reads `path`, which must hold `lines` lines; anything else is no times at all.
    pub fn read(path: &Path, lines: usize) -> Option<LineTimes> {
        let size = (LINE_BYTES * lines) as u64;
        let file = std::fs::File::open(path).ok()?;
        if file.metadata().ok()?.len() != size {
            return None;
        }
        let mut bytes = Vec::with_capacity(LINE_BYTES * lines);
        std::io::Read::read_to_end(&mut std::io::Read::take(file, size), &mut bytes).ok()?;
        let float = |b: &[u8]| f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let (end, tcp): (Vec<f32>, Vec<[f32; 2]>) = bytes.chunks_exact(LINE_BYTES).map(|b| (float(&b[0..4]), [float(&b[4..8]), float(&b[8..12])])).unzip();
        let sound = end.iter().all(|t| t.is_finite() && *t >= 0.0) && tcp.iter().flatten().all(|v| v.is_finite());
        sound.then_some(LineTimes { end, tcp })
    }

    /// Planned time when line `line` (1-based; 0: none) has run.
    pub fn at(&self, line: usize) -> f64 {
        match line {
            0 => 0.0,
            n => self.end.get(n - 1).or(self.end.last()).map_or(0.0, |t| *t as f64),
        }
    }

    pub fn total(&self) -> f64 {
        self.end.last().map_or(0.0, |t| *t as f64)
    }

    /// The planned time at which the tool is at `tcp`, looked for along lines
    /// `after + 1 ..= upto` (those the controller may be running): on the
    /// nearest of their moves, the earliest where several are as near; `None`
    /// when none passes within `NEAR_MM`.
    pub fn locate(&self, after: usize, upto: usize, tcp: [f64; 2]) -> Option<f64> {
        let point = |i: usize| self.tcp.get(i).map(|p| [p[0] as f64, p[1] as f64]);
        let mut best: Option<(f64, f64)> = None;
        for line in after + 1..=upto.min(self.end.len()) {
            let (a, b) = (point(line.saturating_sub(2)).filter(|_| line >= 2).or(point(line - 1))?, point(line - 1)?);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let length2 = dx * dx + dy * dy;
            let f = if length2 > 0.0 { (((tcp[0] - a[0]) * dx + (tcp[1] - a[1]) * dy) / length2).clamp(0.0, 1.0) } else { 1.0 };
            let distance = ((a[0] + f * dx - tcp[0]).powi(2) + (a[1] + f * dy - tcp[1]).powi(2)).sqrt();
            if distance < NEAR_MM && best.is_none_or(|(d, _)| distance < d - 1e-3) {
                let (t0, t1) = (self.at(line - 1), self.at(line));
                best = Some((distance, t0 + f * (t1 - t0)));
            }
        }
        best.map(|(_, t)| t)
    }
}

/// How near a planned move the reported position must be to place the machine on it (mm).
const NEAR_MM: f64 = 0.05;

/// Lines beyond the executed-line bound looked at, at most: the bound trails
/// the machine by what the controller holds (receive buffer, planner blocks,
/// step segments) and by lines too short to prove a step (hundreds of
/// hatch lines); the search stays bounded whatever was sent.
const WINDOW_LINES: usize = 4096;

/// The running job's clock against its plan.
#[derive(Debug, Clone)]
pub struct Eta {
    times: Option<LineTimes>,
    lines_total: usize,
    planned_total: Option<f64>,
    /// Wall and planned time, and the line, when the first line with a planned time ran:
    /// what went before (the move to the start, set-up lines) is not the plan's.
    anchor: Option<(f64, f64, usize)>,
    /// Wall time and planned time when the progress last moved.
    last_move: Option<(f64, f64)>,
}

/// Where the job is, by planned time, and what is left.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Planned seconds of the program executed.
    pub planned_done: f64,
    /// Share of the planned time executed (%).
    pub time_percent: f64,
    /// Seconds left.
    pub eta_s: Option<f64>,
}

impl Eta {
    pub fn new(times: Option<LineTimes>, lines_total: usize, planned_total: Option<f64>) -> Eta {
        Eta { times, lines_total, planned_total, anchor: None, last_move: None }
    }

    /// At wall time `wall` (s since the job started) with every line up to
    /// `executed` run.
    ///
    /// The time left is the plan's for the lines not yet run: a machine
    /// running as planned (laserd's own controller) ends when the plan says,
    /// however late it began. Where the machine has kept a pace of its own
    /// against the plan (Grbl's own planner, a feed override, a pause), the
    /// time left is stretched by it, but only by what lies beyond the
    /// measurement's own uncertainty: the executed line is known only to
    /// within the lines the controller holds queued.
    pub fn estimate(&mut self, wall: f64, executed: usize, sent: usize, tcp: Option<[f64; 2]>) -> Estimate {
        let Some(times) = &self.times else {
            // Without per-line times: prorated by lines.
            let share = if self.lines_total > 0 { (executed as f64 / self.lines_total as f64).min(1.0) } else { 0.0 };
            let done = self.planned_total.map_or(0.0, |t| t * share);
            return Estimate { planned_done: done, time_percent: 100.0 * share, eta_s: self.planned_total.map(|t| t * (1.0 - share)) };
        };
        let total = times.total();
        // Where the machine is among the lines it may be running, else the bound.
        let located = tcp.and_then(|p| times.locate(executed, sent.min(executed + WINDOW_LINES), p));
        let done = located.unwrap_or(times.at(executed)).max(times.at(executed));
        // The executed line is a bound that moves in steps, as status
        // reports come and lines are answered: right just as it moves, then
        // falling behind. The estimate is taken at those moments.
        let moved = self.last_move.is_none_or(|(_, before)| before != done);
        if moved {
            self.last_move = Some((wall, done));
        }
        let (at, _) = self.last_move.unwrap_or((wall, done));
        if self.anchor.is_none() && done > 0.0 {
            self.anchor = Some((at, done, executed));
        }
        let left = (total - done).max(0.0);
        let rate = match self.anchor {
            Some((w0, p0, l0)) if done > p0 && total > 0.0 => {
                let span = done - p0;
                // The bound trails the line really run by the lines the
                // controller holds queued, at both ends of the measurement.
                let queued = |line: usize| times.at(line) - times.at(line.saturating_sub(QUEUED_LINES));
                // A pace within 5 % of the plan is the plan (the status reports
                // and the link jitter that much over a short span).
                let noise = (queued(executed) + queued(l0)) / span + 0.05;
                let excess = (at - w0) / span - 1.0;
                let beyond = excess.signum() * (excess.abs() - noise).max(0.0);
                1.0 + beyond.clamp(-0.8, 19.0) * (span / (0.25 * total)).min(1.0)
            }
            _ => 1.0,
        };
        // Not moving for a while (a hold, a long line): what is left stays left.
        let eta = if wall - at > STALL_S { left * rate } else { (at + left * rate - wall).max(0.0) };
        let time_percent = if total > 0.0 { 100.0 * done / total } else { 0.0 };
        Estimate { planned_done: done, time_percent, eta_s: Some(eta) }
    }
}

/// Seconds without the executed line moving after which the machine counts as stopped.
const STALL_S: f64 = 2.0;

/// Lines a controller may hold between the executed-line bound and the line
/// it really runs: its planner blocks and step segments (Grbl 1.1: 15 + 5;
/// grblHAL holds more, and the bound allows for them).
const QUEUED_LINES: usize = 24;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_times_round_trip_and_carry_over_lines_without_a_time() {
        let times = LineTimes::from_ends([None, Some(1.0), None, Some(3.5), Some(10.0)].map(|t| (t, t.map(|t| [t, -t]))));
        assert_eq!(times.at(0), 0.0);
        assert_eq!(times.at(1), 0.0);
        assert_eq!(times.at(3), 1.0);
        assert_eq!(times.at(5), 10.0);
        assert_eq!(times.total(), 10.0);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("times.bin");
        times.write(&path).unwrap();
        assert_eq!(LineTimes::read(&path, 5), Some(times.clone()));
        // A file of another program's length is not this program's times.
        assert_eq!(LineTimes::read(&path, 6), None);
    }

    #[test]
    fn the_time_left_follows_the_plan_not_the_line_count() {
        // 100 quick lines (1 s in all), then 10 slow ones (99 s).
        let ends = (1..=100).map(|i| Some(i as f64 * 0.01)).chain((1..=10).map(|i| Some(1.0 + 9.9 * i as f64)));
        let times = LineTimes::from_ends(ends.map(|t| (t, None)));
        let mut eta = Eta::new(Some(times), 110, Some(100.0));
        // The machine runs as planned, 2 s late to start (the move to the start).
        eta.estimate(2.0, 0, 0, None);
        eta.estimate(2.5, 50, 50, None);
        let at_half = eta.estimate(2.0 + 50.5, 105, 105, None);
        assert!((at_half.time_percent - 50.5).abs() < 1e-3, "{at_half:?}");
        // By lines it would be 95 % done with 5 s left; by the plan, 49.5 s.
        assert!((at_half.eta_s.unwrap() - 49.5).abs() < 0.01, "{at_half:?}");
    }

    /// 10,000 lines of 10 ms each.
    fn even_lines() -> Eta {
        Eta::new(Some(LineTimes::from_ends((1..=10_000).map(|i| (Some(i as f64 * 0.01), Some([i as f64, 0.0]))))), 10_000, Some(100.0))
    }

    #[test]
    fn a_machine_slower_than_the_plan_stretches_the_time_left() {
        let mut eta = even_lines();
        eta.estimate(0.0, 1, 1, None);
        // Twice the planned time for the first half: the second half likewise.
        let e = eta.estimate(100.0, 5001, 5001, None);
        assert!((e.eta_s.unwrap() - 97.0).abs() < 1.0, "{e:?}");
        // Early on, the measured pace counts only in part.
        let mut eta = even_lines();
        eta.estimate(0.0, 1, 1, None);
        let e = eta.estimate(18.0, 1000, 1000, None);
        assert!(e.eta_s.unwrap() > 100.0 && e.eta_s.unwrap() < 170.0, "{e:?}");
    }

    #[test]
    fn a_lagging_executed_line_does_not_swing_the_estimate() {
        // The machine runs the plan exactly, 1.5 s late; the bound on the
        // executed line trails the true line by 0 to 20 lines, at random.
        let mut eta = even_lines();
        let mut rng = rand::rng();
        for step in 1..=1000 {
            let truly: usize = step * 10;
            let shown = truly.saturating_sub(rand::Rng::random_range(&mut rng, 0..=20));
            let wall = 1.5 + truly as f64 * 0.01;
            let e = eta.estimate(wall, shown, shown, None);
            let error = (wall + e.eta_s.unwrap() - 101.5).abs();
            assert!(error < 0.25, "at line {shown} the end is {error} s off: {e:?}");
        }
    }

    #[test]
    fn the_reported_position_places_the_machine_among_the_lines_it_may_be_running() {
        // Line i ends at X = i mm, 10 ms each: the machine is reported a
        // third of the way along line 130 while the bound says 100.
        let mut eta = even_lines();
        let e = eta.estimate(5.0, 100, 140, Some([129.0 + 1.0 / 3.0, 0.0]));
        assert!((e.planned_done - (1.29 + 0.01 / 3.0)).abs() < 1e-4, "{e:?}");
        // Not beyond what was sent, nor off the planned path.
        assert!((eta.estimate(5.0, 100, 120, Some([129.3, 0.0])).planned_done - 1.0).abs() < 1e-6);
        assert!((eta.estimate(5.0, 100, 140, Some([129.3, 1.0])).planned_done - 1.0).abs() < 1e-6);
    }

    #[test]
    fn without_line_times_it_is_prorated_by_lines() {
        let mut eta = Eta::new(None, 200, Some(100.0));
        let e = eta.estimate(10.0, 50, 50, None);
        assert_eq!(e.eta_s, Some(75.0));
        assert_eq!(e.time_percent, 25.0);
    }
}
