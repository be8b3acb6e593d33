//! The G-code parser (reference §9) and `$J=` jogging. A block is checked
//! whole before anything changes; what is left to do (motion, syncs, pauses,
//! probing) comes back as steps for the line handler.

use super::arc::ArcInput;
use super::{dist, Block, Controller, Flavor, Motion, Spindle, Step, EPS_POS};
use crate::gcode::split_words;
use crate::wire::MachineState;

/// Non-modal commands (group 0).
#[derive(Debug, Clone, Copy, PartialEq)]
enum NonModal {
    /// G4
    Dwell,
    /// G10 L2 / L20
    SetCoord,
    /// G28 (0) / G30 (1)
    GoHome(usize),
    /// G28.1 (0) / G30.1 (1)
    SetHome(usize),
    /// G53
    Absolute,
    /// G92
    SetOffset,
    /// G92.1
    ClearOffset,
}

impl Controller {
    /// Parses and checks one G-code block; mutates state only on success.
    pub(super) fn gcode(&mut self, text: &str, line: u64) -> Result<Vec<Step>, u16> {
        let words = split_words(text)?;
        let naxes = self.cfg.axes.len();
        let mut groups = 0u32;
        let mut set_group = |g: u32| -> Result<(), u16> {
            if groups & (1 << g) != 0 {
                return Err(21);
            }
            groups |= 1 << g;
            Ok(())
        };
        let mut motion: Option<Motion> = None;
        let mut non_modal: Option<NonModal> = None;
        let (mut plane, mut units, mut distance_mode, mut feed_mode, mut coord) = (None, None, None, None, None);
        // Some(true): G43.1, Some(false): G49.
        let mut tool_length: Option<bool> = None;
        let mut spindle: Option<Spindle> = None;
        let mut coolant: Option<u32> = None;
        let mut stop: Option<u32> = None;
        let mut vals: [Option<f64>; 26] = [None; 26];
        let mut axes: Vec<Option<f64>> = vec![None; naxes];
        let hal = self.cfg.flavor == Flavor::Grblhal;
        // A command that uses the axis words is already in the block.
        let mut axis_command = false;

        for w in &words {
            let v = w.value;
            match w.letter {
                'G' | 'M' => {
                    if v < 0.0 {
                        return Err(20);
                    }
                    let int = v.trunc() as u32;
                    let mant = ((v - v.trunc()) * 100.0).round() as u32;
                    // Grbl checks a second command using the axis words (motion,
                    // G10/G28/G30/G92, G43.1/G49) before anything else of the word.
                    let uses_axes =
                        matches!(int, 0..=3 | 38 | 43 | 49) || (matches!(int, 10 | 28 | 30 | 92) && mant == 0);
                    if w.letter == 'G' && uses_axes {
                        if axis_command {
                            return Err(24);
                        }
                        axis_command = true;
                    }
                    if w.letter == 'M' {
                        if mant != 0 {
                            return Err(23);
                        }
                        match int {
                            // M1 (optional stop) is accepted and ignored, as in Grbl.
                            0 | 1 | 2 | 30 => {
                                set_group(20)?;
                                stop = Some(int);
                            }
                            3..=5 => {
                                set_group(21)?;
                                spindle = Some(match int {
                                    3 => Spindle::Cw,
                                    4 => Spindle::Ccw,
                                    _ => Spindle::Off,
                                });
                            }
                            // Grbl 1.1h as built by default has no M7 (mist).
                            7 if !hal => return Err(20),
                            7..=9 => {
                                set_group(22)?;
                                coolant = Some(int);
                            }
                            _ => return Err(20),
                        }
                        continue;
                    }
                    match (int, mant) {
                        (0..=3 | 80, 0) => {
                            set_group(1)?;
                            motion = Some(match int {
                                0 => Motion::Rapid,
                                1 => Motion::Linear,
                                2 => Motion::ArcCw,
                                3 => Motion::ArcCcw,
                                _ => Motion::None,
                            });
                        }
                        (38, 20 | 30 | 40 | 50) => {
                            set_group(1)?;
                            motion = Some(Motion::Probe { away: mant >= 40, no_error: mant == 30 || mant == 50 });
                        }
                        (4 | 10 | 53, 0) | (28 | 30 | 92, 0 | 10) => {
                            set_group(0)?;
                            non_modal = Some(match (int, mant) {
                                (4, _) => NonModal::Dwell,
                                (10, _) => NonModal::SetCoord,
                                (53, _) => NonModal::Absolute,
                                (28, 0) => NonModal::GoHome(0),
                                (30, 0) => NonModal::GoHome(1),
                                (28, _) => NonModal::SetHome(0),
                                (30, _) => NonModal::SetHome(1),
                                (92, 0) => NonModal::SetOffset,
                                _ => NonModal::ClearOffset,
                            });
                        }
                        (17..=19, 0) => {
                            set_group(2)?;
                            plane = Some(int as u8);
                        }
                        (90 | 91, 0) => {
                            set_group(3)?;
                            distance_mode = Some(int == 91);
                        }
                        (91, 10) => set_group(4)?,
                        (93 | 94, 0) => {
                            set_group(5)?;
                            feed_mode = Some(int == 93);
                        }
                        (20 | 21, 0) => {
                            set_group(6)?;
                            units = Some(int == 20);
                        }
                        (40, 0) => set_group(7)?,
                        (43, 10) | (49, 0) => {
                            set_group(8)?;
                            tool_length = Some(int == 43);
                        }
                        (54..=59, 0) => {
                            set_group(12)?;
                            coord = Some(int as u8);
                        }
                        // grblHAL's G59.1-G59.3 (Grbl 1.1h has none: a G59.x is
                        // a G59 with a fraction, error 23).
                        (59, 10 | 20 | 30) if hal => {
                            set_group(12)?;
                            coord = Some(59 + (mant / 10) as u8);
                        }
                        (61, 0) => set_group(13)?,
                        (0..=4 | 10 | 17..=21 | 40 | 49 | 53..=59 | 61 | 80 | 93 | 94, _) => return Err(23),
                        _ => return Err(20),
                    }
                }
                c @ ('F' | 'I' | 'J' | 'K' | 'L' | 'N' | 'P' | 'R' | 'S' | 'T') => {
                    let slot = &mut vals[(c as u8 - b'A') as usize];
                    if slot.is_some() {
                        return Err(25);
                    }
                    if matches!(c, 'F' | 'N' | 'P' | 'S' | 'T') && v < 0.0 {
                        return Err(4);
                    }
                    *slot = Some(v);
                }
                c => {
                    let i = self.axis_index(c).ok_or(20u16)?;
                    if axes[i].is_some() {
                        return Err(25);
                    }
                    axes[i] = Some(v);
                }
            }
        }
        let get = |c: char| vals[(c as u8 - b'A') as usize];
        let n_word = match get('N') {
            // Grbl's largest line number is 10,000,000 itself.
            Some(n) if n > 10_000_000.0 => return Err(27),
            Some(n) if n >= 1.0 => Some(n as u32),
            _ => None,
        };
        let tool = match get('T') {
            Some(t) if t > 255.0 => return Err(38),
            Some(t) => t as u32,
            None => self.modal.tool,
        };

        let m = &self.modal;
        let inches = units.unwrap_or(m.inches);
        let scale = if inches { 25.4 } else { 1.0 };
        let incremental = distance_mode.unwrap_or(m.incremental);
        let inverse = feed_mode.unwrap_or(m.inverse_time);
        let plane = plane.unwrap_or(m.plane);
        let mode = motion.unwrap_or(m.motion);
        let new_spindle = spindle.unwrap_or(m.spindle);
        let new_s = get('S').unwrap_or(m.s);
        // M7 and M8 add to each other; M9 stops both.
        let (new_flood, new_mist) = match coolant {
            Some(7) => (m.flood, true),
            Some(8) => (true, m.mist),
            Some(_) => (false, false),
            None => (m.flood, m.mist),
        };
        let new_coord = coord.unwrap_or(m.coord);
        let has_axes = axes.iter().any(|a| a.is_some());

        // Who uses the axis words: G10, G28/G30 (a via point), G92, G43.1, or motion.
        let nm_axes = matches!(non_modal, Some(NonModal::SetCoord | NonModal::GoHome(_) | NonModal::SetOffset));
        let takes_axes = nm_axes || tool_length == Some(true);
        let explicit_move = matches!(
            motion,
            Some(Motion::Rapid | Motion::Linear | Motion::ArcCw | Motion::ArcCcw | Motion::Probe { .. })
        );
        if (takes_axes && explicit_move) || (nm_axes && tool_length == Some(true)) {
            return Err(24);
        }
        if non_modal == Some(NonModal::SetOffset) && !has_axes {
            return Err(26);
        }
        if non_modal == Some(NonModal::SetCoord) {
            if !has_axes {
                return Err(26);
            }
            if get('L').is_none() && get('P').is_none() {
                return Err(28);
            }
            if get('P').is_some_and(|p| p.trunc() > self.proto.coord.len() as f64) {
                return Err(29);
            }
            if !matches!(get('L'), Some(l) if l == 2.0 || l == 20.0) || get('R').is_some() {
                return Err(20);
            }
        }
        if tool_length == Some(true) {
            // G43.1 takes exactly one axis word, the tool length axis (Z).
            let z = self.axis_index('Z');
            if z.is_none() || axes.iter().enumerate().any(|(i, a)| a.is_some() != (Some(i) == z)) {
                return Err(37);
            }
        }
        // Grbl's order from here: dwell, G53, then the motion mode's checks.
        let dwell = if non_modal == Some(NonModal::Dwell) { Some(get('P').ok_or(28u16)?) } else { None };
        let absolute = non_modal == Some(NonModal::Absolute);
        if absolute && !matches!(mode, Motion::Rapid | Motion::Linear) {
            return Err(30);
        }
        let motion_cmd = !takes_axes && (has_axes || explicit_move);
        if mode == Motion::None && has_axes && !takes_axes {
            return Err(31);
        }
        // Feed: Grbl keeps F across G94 blocks, requires it on every G93
        // motion block, and forgets it when leaving G93.
        let f_word = get('F');
        let feed = if inverse {
            f_word.unwrap_or(0.0)
        } else if m.inverse_time {
            f_word.map_or(0.0, |f| f * scale)
        } else {
            f_word.map_or(m.feed, |f| f * scale)
        };
        let feed_move = motion_cmd && !matches!(mode, Motion::Rapid | Motion::None);
        if feed_move && ((inverse && f_word.is_none()) || feed <= 0.0) {
            return Err(22);
        }
        let probe = match mode {
            Motion::Probe { away, no_error } if motion_cmd => Some((away, no_error)),
            _ => None,
        };
        if probe.is_some() && !has_axes {
            return Err(26);
        }
        let g10 = non_modal == Some(NonModal::SetCoord);
        if (dwell.is_none() && !g10 && get('P').is_some()) || (!g10 && get('L').is_some()) {
            return Err(36);
        }
        let is_arc = motion_cmd && matches!(mode, Motion::ArcCw | Motion::ArcCcw);
        if !is_arc && ['I', 'J', 'K', 'R'].iter().any(|c| get(*c).is_some() && !(g10 && *c == 'R')) {
            return Err(36);
        }

        // Targets in machine coordinates (mm): WPos + G54..G59 + G92 + TLO.
        let wcs = self.proto.coord[usize::from(new_coord - 54)].clone();
        let tlo_axis = self.axis_index('Z');
        let tlo = |i: usize, t: f64| if Some(i) == tlo_axis { t } else { 0.0 };
        let mut target = self.gc_pos.clone();
        let mut new_g92 = self.g92.clone();
        let mut new_tlo = if tool_length == Some(false) { 0.0 } else { self.proto.tlo };
        for (i, v) in axes.iter().enumerate() {
            let Some(v) = v else { continue };
            let mm = v * scale;
            match non_modal {
                Some(NonModal::SetOffset) => new_g92[i] = self.gc_pos[i] - wcs[i] - mm - tlo(i, self.proto.tlo),
                Some(NonModal::SetCoord) => {}
                _ if tool_length == Some(true) => new_tlo = mm,
                _ if absolute => target[i] = mm,
                _ if incremental => target[i] = self.gc_pos[i] + mm,
                _ => target[i] = mm + wcs[i] + self.g92[i] + tlo(i, self.proto.tlo),
            }
        }
        if non_modal == Some(NonModal::ClearOffset) {
            new_g92 = vec![0.0; naxes];
        }
        // G10: L2 sets the origin, L20 makes the present position read as given.
        let coord_write = g10.then(|| {
            let p = get('P').unwrap_or(0.0).trunc() as usize;
            let idx = if p == 0 { usize::from(new_coord - 54) } else { p - 1 };
            let mut data = self.proto.coord[idx].clone();
            for (i, v) in axes.iter().enumerate() {
                let Some(v) = v else { continue };
                let mm = v * scale;
                data[i] = if get('L') == Some(20.0) { self.gc_pos[i] - self.g92[i] - mm - tlo(i, self.proto.tlo) } else { mm };
            }
            (idx, data)
        });

        let laser_mode = self.setting(32) != 0.0;
        let fires = matches!(mode, Motion::Linear | Motion::ArcCw | Motion::ArcCcw)
            && new_spindle != Spindle::Off
            && new_s > 0.0;
        // Outside laser mode the spindle output runs at S whatever the motion.
        let spindle_on = !laser_mode && new_spindle != Spindle::Off;
        let power = if (fires && motion_cmd) || spindle_on { new_s.min(self.cfg.laser_max_s) } else { 0.0 };
        let mut rapid = mode == Motion::Rapid;
        let mut points: Vec<Vec<f64>> = Vec::new();
        if let Some(NonModal::GoHome(k)) = non_modal {
            // Via the given point (if any), then the given axes (all without
            // axis words) to the stored position, at rapid rate.
            let mut home = if k == 0 { self.proto.g28.clone() } else { self.proto.g30.clone() };
            if has_axes {
                for (i, a) in axes.iter().enumerate() {
                    if a.is_none() {
                        home[i] = self.gc_pos[i];
                    }
                }
                points.push(target.clone());
            }
            points.push(home);
            rapid = true;
        } else if motion_cmd && mode != Motion::None {
            if is_arc {
                let arc = ArcInput {
                    start: &self.gc_pos,
                    end: &target,
                    plane,
                    cw: mode == Motion::ArcCw,
                    ijk: [get('I'), get('J'), get('K')].map(|o| o.map(|v| v * scale)),
                    r: get('R').map(|v| v * scale),
                };
                points = self.arc_points(&arc, &axes)?;
            } else {
                if probe.is_some() && self.gc_pos.iter().zip(&target).all(|(a, b)| (a - b).abs() <= EPS_POS) {
                    return Err(33);
                }
                points.push(target.clone());
            }
        }

        // Soft limits, checked on every point before anything is queued.
        if self.soft_limits() && points.iter().any(|p| self.beyond_travel(p)) {
            if self.state() == MachineState::Run {
                // Grbl holds a running cycle to a controlled stop first.
                self.start_hold();
                return Ok(vec![Step::SoftLimit]);
            }
            self.soft_limit_alarm();
            return Err(9);
        }

        // Build the blocks.
        let mut blocks = Vec::new();
        let mut prev = self.gc_pos.clone();
        let nchords = points.len().max(1) as f64;
        for p in &points {
            let min_duration = self
                .cfg
                .axes
                .iter()
                .enumerate()
                .map(|(i, a)| (p[i] - prev[i]).abs() / a.max_velocity)
                .fold(0.0, f64::max);
            let len = dist(&prev, p);
            if prev.iter().zip(p).all(|(a, b)| (a - b).abs() <= EPS_POS) {
                prev = p.clone();
                continue;
            }
            let duration = match mode {
                _ if rapid => min_duration,
                // Grbl's mc_arc multiplies a G93 F by the segment count and
                // then runs the segments in units/min: each at F × segments
                // mm/min, whatever its length (Grbl 1.1h and grblHAL alike).
                _ if inverse && is_arc && points.len() > 1 => len / (feed * nchords / 60.0),
                _ if inverse => 60.0 / feed / nchords,
                _ => len / (feed / 60.0),
            }
            .max(min_duration);
            // M4 in laser mode: power follows the actual speed (grbl motion model).
            let dynamic_power = new_spindle == Spindle::Ccw && self.setting(32) != 0.0;
            blocks.push(Block { rapid, power, n_word, dynamic_power, ..Block::new(p.clone(), duration, min_duration, line) });
            prev = p.clone();
        }

        // Everything checked: commit and describe what is left to do.
        let wco_before = self.wco();
        let mut steps = Vec::new();
        let m = &self.modal;
        let accessories_change = new_spindle != m.spindle || new_flood != m.flood || new_mist != m.mist;
        let spindle_change = new_spindle != m.spindle;
        // Grbl's spindle syncs in laser mode (gcode.c, steps 4 and 7): any
        // M3/M4/M5 change, and under M3, in a line without motion, an S change
        // or a switch between G0 and a feed motion mode. Each waits for motion
        // to stop, then sets the laser at rest: M3 at S in G1/G2/G3 (G0 keeps
        // it off), M4 off (no motion, no power), M5 off. (Grbl also syncs on an
        // S change under M4; the laser stays off there, so only timing differs.)
        // Outside laser mode every S change of a running spindle syncs too,
        // and the output stands at S under M3 and M4 alike.
        let feed_mode = |mo: Motion| matches!(mo, Motion::Linear | Motion::ArcCw | Motion::ArcCcw);
        let in_motion = motion_cmd && has_axes;
        let mode_switch = laser_mode && feed_mode(m.motion) != feed_mode(mode);
        let laser_sync = new_spindle != m.spindle
            || (m.spindle == Spindle::Cw && !in_motion && (new_s != m.s || mode_switch))
            || (!laser_mode && m.spindle != Spindle::Off && new_s != m.s);
        let rest_power = match new_spindle {
            Spindle::Cw if laser_mode && feed_mode(mode) => new_s.min(self.cfg.laser_max_s),
            Spindle::Cw | Spindle::Ccw if !laser_mode => new_s.min(self.cfg.laser_max_s),
            _ => 0.0,
        };
        let sync = accessories_change
            || laser_sync
            || (new_spindle == Spindle::Cw && new_s != m.s && !motion_cmd)
            || new_coord != m.coord
            || tool_length.is_some()
            || matches!(
                non_modal,
                Some(NonModal::SetOffset | NonModal::ClearOffset | NonModal::SetCoord | NonModal::SetHome(_))
            );
        if sync {
            steps.push(Step::Sync);
        }
        if laser_sync && !self.check_mode {
            steps.push(Step::Laser { power: rest_power, line });
        }
        if (new_flood, new_mist) != (m.flood, m.mist) && !self.check_mode {
            steps.push(Step::Coolant { flood: new_flood, mist: new_mist });
        }
        if let Some(p) = dwell {
            steps.push(Step::Sync);
            if !self.check_mode {
                steps.push(Step::Dwell(p, line));
            }
        }
        match probe {
            Some((away, no_error)) if !self.check_mode => {
                if let Some(full) = blocks.pop() {
                    let (probe_steps, end) = self.probe_cycle(away, no_error, full);
                    steps.extend(probe_steps);
                    self.gc_pos = end;
                }
            }
            _ => {
                if let Some(last) = points.last() {
                    self.gc_pos = last.clone();
                }
                if !self.check_mode && !blocks.is_empty() {
                    // The machine moves off any switch it was pressing.
                    self.proto.limit_pin = None;
                    self.proto.probe_pin = false;
                    steps.extend(blocks.into_iter().map(Step::Queue));
                }
            }
        }
        if let Some(NonModal::SetHome(k)) = non_modal {
            let here = self.gc_pos.clone();
            if k == 0 {
                self.proto.g28 = here;
            } else {
                self.proto.g30 = here;
            }
        }
        if let Some((idx, data)) = coord_write {
            self.proto.coord[idx] = data;
        }
        let m = &mut self.modal;
        m.inches = inches;
        m.incremental = incremental;
        m.inverse_time = inverse;
        m.plane = plane;
        if !absolute {
            m.motion = mode;
        } else if let Some(mo) = motion {
            m.motion = mo;
        }
        m.spindle = new_spindle;
        m.s = new_s;
        m.flood = new_flood;
        m.mist = new_mist;
        m.coord = new_coord;
        m.tool = tool;
        m.feed = feed;
        self.g92 = new_g92;
        self.proto.tlo = new_tlo;
        match stop {
            Some(0) if !self.check_mode => steps.extend([Step::Sync, Step::Pause, Step::AwaitResume]),
            Some(2 | 30) => {
                // The program's end switches the spindle off: the laser too.
                steps.extend([Step::Sync, Step::Laser { power: 0.0, line }, Step::Coolant { flood: false, mist: false }, Step::ProgramEnd]);
                let m = &mut self.modal;
                m.motion = Motion::Linear;
                m.plane = 17;
                m.incremental = false;
                m.inverse_time = false;
                m.coord = 54;
                m.spindle = Spindle::Off;
                m.flood = false;
                m.mist = false;
            }
            _ => {}
        }
        if self.wco() != wco_before {
            self.wco_countdown = 0;
        }
        if spindle_change {
            // Grbl reports a spindle change at once (Ov: and A:); a coolant
            // change once it is made (`Step::Coolant`).
            self.ov_countdown = 0;
        }
        Ok(steps)
    }

    /// `$J=`: a G1-like move with a mandatory F in units/min, one-shot G20/G21,
    /// G90/G91 and G53, nothing else (error 16); accepted only when idle or
    /// jogging (error 8); a target beyond travel answers error 15, no alarm. The
    /// parser's modal state is left alone. The laser stays off while jogging
    /// (Grbl would inherit the laser state; a simulator should not teach that).
    pub(super) fn jog(&mut self, text: &str, line: u64) -> Result<Vec<Step>, u16> {
        if !matches!(self.state(), crate::wire::MachineState::Idle | crate::wire::MachineState::Jog) {
            return Err(8);
        }
        let words = split_words(text)?;
        let mut axes: Vec<Option<f64>> = vec![None; self.cfg.axes.len()];
        let (mut inches, mut incremental, mut machine_coords) = (self.modal.inches, self.modal.incremental, false);
        let mut feed = None;
        for w in &words {
            match (w.letter, w.value) {
                ('G', g) if g == 20.0 || g == 21.0 => inches = g == 20.0,
                ('G', g) if g == 90.0 || g == 91.0 => incremental = g == 91.0,
                ('G', 53.0) => machine_coords = true,
                ('F', f) => {
                    if feed.replace(f).is_some() {
                        return Err(25);
                    }
                }
                ('N', _) => {}
                (c, v) => {
                    let i = self.axis_index(c).ok_or(16u16)?;
                    if axes[i].replace(v).is_some() {
                        return Err(25);
                    }
                }
            }
        }
        let scale = if inches { 25.4 } else { 1.0 };
        let feed = feed.ok_or(22u16)? * scale;
        if feed <= 0.0 {
            return Err(4);
        }
        if axes.iter().all(Option::is_none) {
            return Err(26);
        }
        let wco = self.wco();
        let mut target = self.gc_pos.clone();
        for (i, v) in axes.iter().enumerate() {
            let Some(v) = v else { continue };
            let mm = v * scale;
            target[i] = if machine_coords {
                mm
            } else if incremental {
                self.gc_pos[i] + mm
            } else {
                mm + wco[i]
            };
        }
        if self.soft_limits() && self.beyond_travel(&target) {
            return Err(15);
        }
        let len = dist(&self.gc_pos, &target);
        if len <= EPS_POS {
            return Ok(Vec::new());
        }
        let min_duration = self
            .cfg
            .axes
            .iter()
            .enumerate()
            .map(|(i, a)| (target[i] - self.gc_pos[i]).abs() / a.max_velocity)
            .fold(0.0, f64::max);
        let block = Block { ends_sequence: true, jog: true, ..Block::new(target.clone(), len / (feed / 60.0), min_duration, line) };
        self.gc_pos = target;
        self.proto.limit_pin = None;
        self.proto.probe_pin = false;
        Ok(vec![Step::Queue(block)])
    }

    /// A probing cycle G38.2–G38.5 (reference §9, alarms 4 and 5) along the
    /// already checked `full` move. Toward the work (G38.2/.3) the probe must
    /// start open, away (G38.4/.5) closed, else ALARM:4 once motion has stopped.
    /// The simulated probe changes state only where `Faults::probe_contact_mm`
    /// puts the work; there the move ends. Without a contact G38.2/.4 raise
    /// ALARM:5 at the target and G38.3/.5 just report. Returns the steps and
    /// where the parser's position ends up.
    fn probe_cycle(&mut self, away: bool, no_error: bool, full: Block) -> (Vec<Step>, Vec<f64>) {
        let start = self.gc_pos.clone();
        if self.proto.probe_pin != away {
            return (vec![Step::Sync, Step::Alarm(4)], start);
        }
        let len = dist(&start, &full.target);
        let contact = self.cfg.faults.probe_contact_mm.filter(|d| d.is_finite() && *d >= 0.0 && *d < len);
        let f = contact.map_or(1.0, |d| d / len);
        let end: Vec<f64> = start.iter().zip(&full.target).map(|(s, t)| s + (t - s) * f).collect();
        let mut steps = vec![Step::Sync];
        if dist(&start, &end) > EPS_POS {
            let (duration, min_duration) = (full.duration * f, full.min_duration * f);
            steps.push(Step::Queue(Block { target: end.clone(), duration, min_duration, ..full }));
        }
        let touched = contact.is_some();
        steps.extend([Step::Sync, Step::Probed { pos: end.clone(), touched, alarm: !touched && !no_error }]);
        (steps, end)
    }
}
