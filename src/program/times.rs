//! A program's planned time read back from its words, line by line: what
//! `send` shows its progress and ETA by. laserd writes every motion block
//! with its time (G93: `F` = 1 / minutes; an arc in G94 at its feed over its
//! length; `G4 P` seconds), so a file it wrote carries its plan; a file with
//! a move whose time its words do not give (`G0`, `G1` at a feed in G94,
//! which the controller's acceleration lengthens) has no planned time.

use laserd_sim::gcode::{split_words, LineBuilder};

/// Lines between two kept sums: a file of any length in little memory.
const EVERY: usize = 64;

/// The planned time through each line of a program (1-based file lines).
#[derive(Debug, Clone)]
pub struct PlannedTimes {
    /// The time through line `k · EVERY`.
    sums: Vec<f64>,
    lines: usize,
    pub total_s: f64,
}

impl PlannedTimes {
    /// The planned times of the program `lines` (each file line, as read),
    /// or `None` where a move's time is not in its words or a line cannot
    /// be read.
    pub fn read<S: AsRef<str>>(lines: impl IntoIterator<Item = std::result::Result<S, crate::error::Error>>) -> Option<PlannedTimes> {
        let mut state = Modal::default();
        let mut sums = vec![0.0];
        let mut total = 0.0;
        let mut n = 0;
        for line in lines {
            total += state.line_time(line.ok()?.as_ref())?;
            n += 1;
            if n % EVERY == 0 {
                sums.push(total);
            }
        }
        (total > 0.0).then_some(PlannedTimes { sums, lines: n, total_s: total })
    }

    /// The planned time through line `line` (0: none run), linear between
    /// the kept sums.
    pub fn through(&self, line: usize) -> f64 {
        let line = line.min(self.lines);
        let k = line / EVERY;
        let before = self.sums[k];
        let after = self.sums.get(k + 1).copied().unwrap_or(self.total_s);
        let span = if k + 1 < self.sums.len() { EVERY } else { (self.lines - k * EVERY).max(1) };
        before + (after - before) * (line - k * EVERY) as f64 / span as f64
    }

    /// What is left of the job, s, with `line` the last line sent and
    /// `elapsed` seconds since the first: the plan's time minus the time
    /// run, which is the time since the start while the machine keeps to
    /// the plan, and never more than the plan up to the last line sent (a
    /// hold or a slower machine stops it there). The line count alone
    /// would misjudge it: lines are as short or long as the motion is.
    pub fn left(&self, line: usize, elapsed: f64) -> f64 {
        (self.total_s - elapsed.max(0.0).min(self.through(line))).max(0.0)
    }
}

/// What a line's time depends on from the lines before it.
#[derive(Default)]
struct Modal {
    inverse_time: bool,
    /// The motion mode: 0 to 3 (G0 to G3).
    motion: u8,
    feed: Option<f64>,
    position: [f64; 2],
}

impl Modal {
    /// The time of `line`, s; `None` for a move whose time its words do not give.
    fn line_time(&mut self, line: &str) -> Option<f64> {
        let mut cleaned = LineBuilder::with_max(laserd_sim::gcode::MAX_LINE_HAL);
        line.bytes().for_each(|b| cleaned.push(b));
        let text = cleaned.finish()?;
        // System commands and program marks take no machine time.
        if text.is_empty() || text.starts_with(['$', '%']) {
            return Some(0.0);
        }
        let words = split_words(&text).ok()?;
        let (mut dwell, mut target, mut centre, mut moved) = (false, self.position, [0.0; 2], false);
        let mut p = None;
        let mut feed = None;
        for w in &words {
            match (w.letter, w.value) {
                ('G', 93.0) => self.inverse_time = true,
                ('G', 94.0) => self.inverse_time = false,
                ('G', 4.0) => dwell = true,
                ('G', g) if (0.0..=3.0).contains(&g) && g.fract() == 0.0 => self.motion = g as u8,
                ('X', v) => (target[0], moved) = (v, true),
                ('Y', v) => (target[1], moved) = (v, true),
                ('I', v) => centre[0] = v,
                ('J', v) => centre[1] = v,
                ('P', v) => p = Some(v),
                ('F', v) => feed = Some(v),
                // Other axes (Z, the scanner's) move within the block's time.
                (letter, _) if letter.is_ascii_alphabetic() && !"GMSNTLR".contains(letter) => moved = true,
                _ => {}
            }
        }
        if !self.inverse_time {
            self.feed = feed.or(self.feed);
        }
        if dwell {
            return Some(p.unwrap_or(0.0));
        }
        if !moved {
            return Some(0.0);
        }
        let from = std::mem::replace(&mut self.position, target);
        match (self.motion, self.inverse_time) {
            (1..=3, true) => feed.filter(|&f| f > 0.0).map(|f| 60.0 / f),
            (2 | 3, false) => {
                let radius = centre[0].hypot(centre[1]);
                let c = [from[0] + centre[0], from[1] + centre[1]];
                let angle = |p: [f64; 2]| (p[1] - c[1]).atan2(p[0] - c[0]);
                let mut sweep = angle(target) - angle(from);
                // G2 turns clockwise, G3 counter-clockwise; ending where it starts is a full circle.
                if self.motion == 2 {
                    sweep = -sweep;
                }
                let sweep = if sweep.abs() < 1e-12 { std::f64::consts::TAU } else { sweep.rem_euclid(std::f64::consts::TAU) };
                self.feed.filter(|&f| f > 0.0).map(|f| 60.0 * radius * sweep / f)
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Option<PlannedTimes> {
        PlannedTimes::read(text.lines().map(Ok::<_, crate::error::Error>))
    }

    #[test]
    fn inverse_time_arcs_and_dwells_give_the_time_and_g0_none() {
        // 1 s, a half circle of radius 10 at 600 mm/min (3.14 s), 0.5 s standing, 0.25 s.
        let times = read("G21G90G93\nG1X10Y0F60\nG94G3X-10Y0I-10J0F600\nG4P0.5\nG93G1X0A1F240 (scanner)\nM5\n").unwrap();
        let half = std::f64::consts::PI * 10.0 / 10.0;
        assert!((times.total_s - (1.0 + half + 0.5 + 0.25)).abs() < 1e-9, "{}", times.total_s);
        assert_eq!(times.through(6), times.total_s);
        // From (10, 0) to (0, 10) round the origin: a quarter counter-clockwise, three quarters clockwise.
        let quarter = read("G93G1X10F60\nG94G3X0Y10I-10J0F600\n").unwrap();
        assert!((quarter.total_s - 1.0 - half / 2.0).abs() < 1e-9, "{quarter:?}");
        let clockwise = read("%\nG93G1X10F60\nG94G2X0Y10I-10J0F600\n").unwrap();
        assert!((clockwise.total_s - 1.0 - 1.5 * half).abs() < 1e-9, "{clockwise:?}");
        assert!(read("G90G94\nG0X10\nG1X20F600\n").is_none(), "a G0 or a G94 feed move has no planned time");
    }

    #[test]
    fn what_is_left_follows_the_clock_but_never_runs_ahead_of_the_lines_sent() {
        let mut text = String::from("G21G90G93\n");
        for k in 1..=1000 {
            text.push_str(&format!("G1X{k}F6000\n"));
        }
        let times = read(&text).unwrap();
        assert!((times.total_s - 10.0).abs() < 1e-9);
        // Every line 10 ms: line 501 is 5 s in, wherever the kept sums fall.
        assert!((times.through(501) - 5.0).abs() < 1e-9);
        assert!((times.through(641) - 6.4).abs() < 1e-9);
        assert!((times.left(501, 4.9) - 5.1).abs() < 1e-9, "on time: by the clock");
        assert!((times.left(501, 7.0) - 5.0).abs() < 1e-9, "held: no less than the lines not yet sent");
        assert_eq!(times.left(1001, 11.0), 0.0);
    }
}
