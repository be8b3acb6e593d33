//! Resuming a program from a line after an interruption. The modal state the
//! program had built up before that line (units, distance mode, feed mode, work
//! coordinate system, G92 offset, laser mode and power, air assist (coolant),
//! feed rate, and where
//! the tool was) is re-established, and the tool moves to where that line
//! starts with the laser off, before the line itself is sent.
//!
//! G10 offsets need nothing: the controller keeps them in its EEPROM through
//! the reset that ended the interrupted run. Not restored: arcs' plane (G17 is
//! assumed, Grbl's default), and a G92 offset set where the tool's position
//! was unknown (after G28/G30/G53 moves, or before the first move).

use laserd_sim::gcode::{split_words, LineBuilder};

use crate::program::format_number;

/// Modal state of a G-code program at a point, as Grbl would hold it.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalState {
    letters: Vec<char>,
    pub inches: bool,
    pub incremental: bool,
    pub inverse_time: bool,
    /// 54..=59.
    pub coordinate_system: u8,
    /// M3 or M4 with the laser enabled, `None` after M5.
    pub laser: Option<u8>,
    pub power: f64,
    /// Coolant: flood (M8, laserd's air assist) and mist (M7); M9 ends both.
    pub flood: bool,
    pub mist: bool,
    pub feed: Option<f64>,
    /// Tool position per axis in program coordinates, where known.
    pub position: Vec<Option<f64>>,
    /// G92 offset per axis (program coordinates = work coordinates − offset);
    /// `None` where it was set at an unknown position.
    pub offset: Vec<Option<f64>>,
}

impl ModalState {
    /// Grbl's state after power-up: G21 G90 G94 G54 M5 S0, position unknown.
    pub fn new(axis_letters: &[char]) -> ModalState {
        ModalState {
            letters: axis_letters.to_vec(),
            inches: false,
            incremental: false,
            inverse_time: false,
            coordinate_system: 54,
            laser: None,
            power: 0.0,
            flood: false,
            mist: false,
            feed: None,
            position: vec![None; axis_letters.len()],
            offset: vec![Some(0.0); axis_letters.len()],
        }
    }

    /// Takes in one program line (comments, `$` lines and bad lines change nothing).
    pub fn apply(&mut self, raw: &str) {
        let mut clean = LineBuilder::default();
        raw.bytes().for_each(|b| clean.push(b));
        let Some(line) = clean.finish() else { return };
        if line.starts_with('$') {
            return;
        }
        let Ok(words) = split_words(&line) else { return };
        let has = |g: f64| words.iter().any(|w| w.letter == 'G' && w.value == g);
        let axis = |c: char| self.letters.iter().position(|l| *l == c);
        if has(92.1) {
            self.offset.iter_mut().for_each(|o| *o = Some(0.0));
        }
        if has(92.0) {
            // The tool's position now reads as the word's value: the offset
            // moves by the difference.
            for w in &words {
                if let Some(i) = axis(w.letter) {
                    self.offset[i] = match (self.offset[i], self.position[i]) {
                        (Some(o), Some(p)) => Some(o + p - w.value),
                        _ => None,
                    };
                    self.position[i] = Some(w.value);
                }
            }
            return;
        }
        if has(28.0) || has(30.0) {
            // To a stored position: where, in program coordinates, is unknown.
            self.position.iter_mut().for_each(|p| *p = None);
        }
        if has(53.0) {
            // Machine coordinates: the named axes end up somewhere unknown here.
            for w in &words {
                if let Some(i) = axis(w.letter) {
                    self.position[i] = None;
                }
            }
        }
        // Axis words here set offsets or name machine coordinates, not targets.
        let no_target = words.iter().any(|w| w.letter == 'G' && [4.0, 10.0, 28.0, 28.1, 30.0, 30.1, 53.0].contains(&w.value));
        for w in &words {
            match (w.letter, w.value) {
                ('G', g) if g == 20.0 || g == 21.0 => self.inches = g == 20.0,
                ('G', g) if g == 90.0 || g == 91.0 => self.incremental = g == 91.0,
                ('G', g) if g == 93.0 || g == 94.0 => self.inverse_time = g == 93.0,
                ('G', g) if (54.0..=59.0).contains(&g) && g.fract() == 0.0 => self.coordinate_system = g as u8,
                ('M', m) if m == 3.0 || m == 4.0 => self.laser = Some(m as u8),
                ('M', 5.0) => self.laser = None,
                ('M', 7.0) => self.mist = true,
                ('M', 8.0) => self.flood = true,
                ('M', 9.0) => (self.flood, self.mist) = (false, false),
                ('M', m) if m == 2.0 || m == 30.0 => {
                    self.incremental = false;
                    self.inverse_time = false;
                    self.coordinate_system = 54;
                    self.laser = None;
                    (self.flood, self.mist) = (false, false);
                }
                ('S', s) => self.power = s,
                ('F', f) => self.feed = Some(f),
                (c, v) if !no_target => {
                    if let Some(i) = self.letters.iter().position(|l| *l == c) {
                        self.position[i] = Some(if self.incremental { self.position[i].unwrap_or(0.0) + v } else { v });
                    }
                }
                _ => {}
            }
        }
    }

    /// Lines that bring a freshly reset controller into this state: modes, the
    /// move to the position with the laser off (in work coordinates, the G92
    /// offset cleared), the G92 offset set again there, then laser, feed and
    /// distance modes as the program had them.
    pub fn preamble(&self) -> Vec<String> {
        let mut lines = vec![
            format!("{}G90G94G{}", if self.inches { "G20" } else { "G21" }, self.coordinate_system),
            "M5".to_string(),
            "G92.1".to_string(),
        ];
        let mut rapid = String::from("G0");
        let mut g92 = String::from("G92");
        for ((letter, p), o) in self.letters.iter().zip(&self.position).zip(&self.offset) {
            if let Some(p) = p {
                rapid.push(*letter);
                rapid.push_str(&format_number(p + o.unwrap_or(0.0), 6));
                if o.is_some_and(|o| o != 0.0) {
                    g92.push(*letter);
                    g92.push_str(&format_number(*p, 6));
                }
            }
        }
        if rapid.len() > 2 {
            lines.push(rapid);
        }
        if g92.len() > 3 {
            lines.push(g92);
        }
        // Air assist on again where the job goes on, before the laser.
        if self.mist {
            lines.push("M7".into());
        }
        if self.flood {
            lines.push("M8".into());
        }
        if let Some(m) = self.laser {
            lines.push(format!("M{m}S{}", format_number(self.power, 3)));
        } else {
            lines.push(format!("S{}", format_number(self.power, 3)));
        }
        if self.inverse_time {
            lines.push("G93".into());
        } else if let Some(f) = self.feed {
            lines.push(format!("G1F{}", format_number(f, 3)));
        }
        if self.incremental {
            lines.push("G91".into());
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_follows_the_program_and_the_preamble_restores_it() {
        let mut s = ModalState::new(&['X', 'Y', 'U', 'V']);
        for l in ["G21 G90 G93 (set up)", "M4 S0", "G1 X10 Y5 S300 F6000", "G1 U1.5 V-2 F60000", "G91 G1 X1 F600 ; step", "$H"] {
            s.apply(l);
        }
        assert_eq!(s.laser, Some(4));
        assert_eq!(s.power, 300.0);
        assert!(s.inverse_time && s.incremental);
        assert_eq!(s.position, vec![Some(11.0), Some(5.0), Some(1.5), Some(-2.0)]);
        assert_eq!(s.preamble(), vec!["G21G90G94G54", "M5", "G92.1", "G0X11Y5U1.5V-2", "M4S300", "G93", "G91"]);
        // G92 X0 at X11: work X11 now reads 0; a later move to 4 is work X15.
        s.apply("G90 G92 X0");
        assert_eq!(s.position[0], Some(0.0));
        s.apply("G1 X4 F600");
        assert_eq!(s.offset[0], Some(11.0));
        let pre = s.preamble();
        assert_eq!(&pre[2..5], &["G92.1", "G0X15Y5U1.5V-2", "G92X4"], "{pre:?}");
        s.apply("G92.1");
        assert_eq!(s.offset[0], Some(0.0));
        // After G28 nothing is known of the position, so nothing moves on resume.
        s.apply("G28");
        assert!(s.position.iter().all(Option::is_none));
        assert!(!s.preamble().iter().any(|l| l.starts_with("G0")));
        s.apply("M5");
        s.apply("M2");
        assert_eq!(s.laser, None);
        assert!(!s.incremental);
    }

    #[test]
    fn air_assist_on_where_the_job_stopped_is_turned_on_again_before_the_laser() {
        let mut s = ModalState::new(&['X', 'Y']);
        for l in ["G21 G90 G93", "M4 S0", "M8", "G1 X10 Y5 S300 F6000"] {
            s.apply(l);
        }
        assert!(s.flood && !s.mist);
        let pre = s.preamble();
        let air = pre.iter().position(|l| l == "M8").unwrap_or_else(|| panic!("{pre:?}"));
        let laser = pre.iter().position(|l| l == "M4S300").unwrap();
        let moved = pre.iter().position(|l| l.starts_with("G0")).unwrap();
        assert!(moved < air && air < laser, "{pre:?}");
        // M9, or the program's end, leaves it off.
        s.apply("M9");
        assert!(!s.preamble().contains(&"M8".to_string()));
        s.apply("M8");
        s.apply("M2");
        assert!(!s.flood);
    }
}
