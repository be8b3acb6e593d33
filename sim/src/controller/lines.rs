//! Line bytes from the wire: the receive buffer (RX), taking a line out of it,
//! and working through what the line asks before its `ok`. Separate from the
//! realtime bytes, which never enter RX, and from motion, which the lines feed.
//!
//! A line's bytes stay in RX until the line has been fully handled; a motion
//! line waits there while the planner is full (its `ok` is delayed), a sync
//! command (G4, M2/M30, M0, spindle/coolant/offset changes) waits until motion
//! has stopped.

use super::system::StepOutcome;
use super::{AfterOk, Controller, Flavor, Knot, Pending, Step};

impl Controller {
    /// One byte from the wire at time `now`.
    pub fn receive(&mut self, now: f64, byte: u8) {
        self.advance(now);
        self.last_rx_t = self.now;
        let mut byte = byte;
        if self.cfg.flavor == Flavor::Grblhal {
            use crate::wire::realtime::*;
            byte = match byte {
                STATUS_ALT => STATUS,
                CYCLE_START_ALT => CYCLE_START,
                FEED_HOLD_ALT => FEED_HOLD,
                FULL_STATUS => {
                    if !self.critical {
                        let report = self.full_status_report();
                        let line = self.report_text(&report);
                        self.send(&line);
                    }
                    return;
                }
                b => b,
            };
        }
        if !crate::wire::realtime::is_realtime(byte) {
            self.bytes_received += 1;
            if self.cfg.faults.drop_byte == Some(self.bytes_received) {
                return;
            }
            if self.cfg.faults.corrupt_byte == Some(self.bytes_received) {
                byte = b'#';
            }
        }
        if crate::wire::realtime::is_realtime(byte) {
            self.realtime(byte);
        } else if byte >= 0x80 {
            // Undefined extended bytes are discarded, as Grbl does.
        } else if self.cfg.flavor == Flavor::Grblhal && self.hal_skips_line_end(byte) {
            // The second half of a CR LF (or LF CR) pair.
        } else if self.rx.len() >= self.rx_capacity() {
            self.stats.rx_overflows += 1;
        } else {
            self.rx.push_back(byte);
            if byte == b'\n' || byte == b'\r' {
                self.rx_lines += 1;
            } else if self.rx.len() >= self.rx_capacity() && self.rx_lines == 0 {
                let mut lb = self.carry.take().unwrap_or_else(|| self.line_builder());
                self.rx.drain(..).for_each(|b| lb.push(b));
                self.carry = Some(lb);
            }
        }
        self.process();
    }

    /// grblHAL ends a line at a CR or a LF alone, and skips a line end that
    /// comes while the line is still empty (no printable byte yet; realtime
    /// bytes and blanks do not count) right after a line ended by the other
    /// one, so that CR LF answers once (its protocol.c).
    pub(super) fn hal_skips_line_end(&mut self, byte: u8) -> bool {
        if byte != b'\n' && byte != b'\r' {
            self.hal_line_started |= byte > b' ';
            return false;
        }
        let skip = !self.hal_line_started && self.hal_eol != 0 && self.hal_eol != byte;
        self.hal_eol = if skip { 0 } else { byte };
        self.hal_line_started = false;
        skip
    }

    /// Bytes the receive buffer holds: Grbl's ring has a slot more than its
    /// size; grblHAL's keeps one unused, so a 1024-byte one holds 1023.
    pub(super) fn rx_capacity(&self) -> usize {
        match self.cfg.flavor {
            Flavor::Grbl => self.cfg.rx_buffer,
            Flavor::Grblhal => self.cfg.rx_buffer.saturating_sub(1),
        }
    }

    pub(super) fn process(&mut self) {
        // Lines run at `now`: a laser they switch at rest shows in the knots.
        self.watching_rest_laser(Controller::process_lines);
    }

    fn process_lines(&mut self) {
        loop {
            if self.pending.is_some() {
                if !self.progress_pending() {
                    break;
                }
            } else if self.startup_ready() {
                self.begin_startup();
            } else if self.rx_lines > 0 && !self.critical && !self.suspended() {
                // A critical alarm processes no lines until reset (reference §5).
                self.take_line();
            } else {
                break;
            }
        }
        self.auto_start();
    }

    fn take_line(&mut self) {
        let mut lb = self.carry.take().unwrap_or_else(|| self.line_builder());
        let mut len = 0;
        for &b in self.rx.iter() {
            len += 1;
            if b == b'\n' || b == b'\r' {
                break;
            }
            lb.push(b);
        }
        self.line_count += 1;
        self.stats.lines_received += 1;
        self.longest_line = self.longest_line.max(len);
        let n = self.line_count;
        if self.cfg.faults.reset_at_line == Some(n) {
            self.hardware_reset();
            return;
        }
        if self.cfg.faults.limit_alarm_at_line == Some(n) {
            self.drop_rx(len, 0);
            self.limit_alarm(1);
            return;
        }
        let result = if self.cfg.faults.error_on_line == Some(n) {
            Err(20)
        } else {
            match lb.finish() {
                None => Err(11),
                Some(text) => {
                    self.echo_line(&text);
                    self.execute_line(&text, n)
                }
            }
        };
        match result {
            Ok((steps, after)) => {
                if !steps.iter().any(|s| matches!(s, Step::Queue(_))) {
                    if let Some(last) = self.planner.back_mut() {
                        last.ends_sequence = true;
                    }
                }
                // A dwell's line is out of the receive buffer while it waits and
                // dwells (`Bf:` shows it free), as Grbl reads a line whole before
                // it executes it; its `ok` still comes at the dwell's end.
                let dwells = steps.iter().any(|s| matches!(s, Step::Dwell(..)));
                let taken = if dwells { self.take_rx(len) } else { 0 };
                self.pending = Some(Pending {
                    steps: steps.into(),
                    rx_len: len - taken,
                    taken,
                    dwell_until: None,
                    dwell_left: None,
                    after,
                    quiet: false,
                })
            }
            // Only a soft limit fails a line into a critical alarm: its
            // answer waits for the reset (see `ok_after_reset`).
            Err(_) if self.critical => {
                self.drop_rx(len, 0);
                self.ok_after_reset = true;
            }
            Err(code) => {
                self.drop_rx(len, 0);
                self.send_error(code);
            }
        }
    }

    /// A line is answered: `len` of its bytes leave RX, `taken` had left it
    /// before (the sender counts them in flight until the answer all the same).
    fn drop_rx(&mut self, len: usize, taken: usize) {
        // With room for a line as long as any the controller takes (or the
        // longest yet, were it longer), the sender was not waiting. Less room
        // than the longest line *so far* is not enough: the next may be longer
        // (an arc's line after those of a straight cut), and the sender waits.
        if self.rx_capacity().saturating_sub(self.rx.len() + taken) < self.longest_line.max(self.max_line() + 1) {
            self.last_room_t = self.now;
        }
        self.take_rx(len);
    }

    /// Removes the first `len` bytes of RX; how many there were.
    fn take_rx(&mut self, len: usize) -> usize {
        let len = len.min(self.rx.len());
        let removed_lines = self.rx.drain(..len).filter(|b| *b == b'\n' || *b == b'\r').count();
        self.rx_lines = self.rx_lines.saturating_sub(removed_lines);
        len
    }

    /// Works through the pending line's steps; true when it completed.
    fn progress_pending(&mut self) -> bool {
        let stopped = self.exec.is_none() && self.planner.is_empty();
        let Some(mut p) = self.pending.take() else { return true };
        while let Some(step) = p.steps.front() {
            match step {
                Step::Sync => {
                    // Checked live: a block this same line queued must finish too.
                    if self.exec.is_some() || !self.planner.is_empty() {
                        break;
                    }
                }
                Step::Dwell(secs, line) => {
                    let line = *line;
                    if self.hold {
                        // Grbl dwells inside its realtime loop: a hold suspends it
                        // there, and the dwell's clock stands until `~`.
                        if let Some(until) = p.dwell_until.take() {
                            p.dwell_left = Some((until - self.now).max(0.0));
                        }
                        break;
                    }
                    if let Some(left) = p.dwell_left.take() {
                        p.dwell_until = Some(self.now + left);
                    }
                    match p.dwell_until {
                        None => {
                            if !stopped {
                                break;
                            }
                            self.pause_starvation();
                            p.dwell_until = Some(self.now + secs);
                            // The time before the dwell ends here, with the laser as it was.
                            if self.last_knot_t.is_finite() && self.last_knot_t < self.now {
                                let knot = Knot { t: self.now, pos: self.pos.clone(), power: self.rest_power(), line: self.rest_line };
                                self.push_knot(knot);
                            }
                            continue;
                        }
                        Some(until) if self.now >= until => {
                            p.dwell_until = None;
                            self.mark_idle(self.now);
                            // The dwell, standing still with the laser as it is, ends here.
                            if self.last_knot_t.is_finite() && self.last_knot_t < self.now {
                                let knot = Knot { t: self.now, pos: self.pos.clone(), power: self.rest_power(), line };
                                self.push_knot(knot);
                            }
                        }
                        Some(_) => break,
                    }
                }
                Step::Coolant { flood, mist } => {
                    // As the laser: Grbl syncs the planner before it switches coolant.
                    if self.exec.is_some() || !self.planner.is_empty() {
                        break;
                    }
                    self.coolant_out = [*flood, *mist];
                    // Grbl reports a coolant change at once (Ov: and A:).
                    self.ov_countdown = 0;
                }
                Step::Laser { power, line } => {
                    // Checked live: Grbl syncs the planner before it sets the laser.
                    if self.exec.is_some() || !self.planner.is_empty() {
                        break;
                    }
                    self.rest_s = *power;
                    self.rest_line = *line;
                }
                Step::Queue(_) => {
                    if self.planner_full() {
                        break;
                    }
                    if let Some(Step::Queue(mut b)) = p.steps.pop_front() {
                        b.gentle = self.is_gentle(&b);
                        self.plan_block(&mut b);
                        self.planner.push_back(b);
                    }
                    continue;
                }
                Step::Pause => {
                    if !stopped {
                        break;
                    }
                    self.hold = true;
                    self.hold_stops_laser();
                    self.pause_starvation();
                }
                Step::ProgramEnd => {
                    if !stopped {
                        break;
                    }
                    self.reset_starvation();
                    self.send("[MSG:Pgm End]");
                }
                Step::SoftLimit => {
                    if self.moving() {
                        break;
                    }
                    self.drop_rx(p.rx_len, p.taken);
                    self.soft_limit_alarm();
                    self.ok_after_reset = true;
                    return true;
                }
                other => match self.protocol_step(other) {
                    StepOutcome::Wait => break,
                    StepOutcome::Done => {}
                    StepOutcome::Then(more) => {
                        p.steps.pop_front();
                        for s in more.into_iter().rev() {
                            p.steps.push_front(s);
                        }
                        continue;
                    }
                    // The controller reset itself: the line is gone.
                    StepOutcome::Reset => return true,
                },
            }
            p.steps.pop_front();
        }
        if !p.steps.is_empty() {
            self.pending = Some(p);
            return false;
        }
        self.drop_rx(p.rx_len, p.taken);
        if !p.quiet {
            self.send("ok");
        }
        match p.after {
            AfterOk::Nothing => {}
            AfterOk::Reset => self.soft_reset(),
            AfterOk::Sleep => {
                self.sleep = true;
                self.send("[MSG:Sleeping]");
            }
        }
        true
    }

    /// Executes a cleaned line. Ok(steps still to do before `ok`, what follows
    /// the ok) or Err(Grbl error code); on error nothing has changed.
    fn execute_line(&mut self, text: &str, line: u64) -> Result<(Vec<Step>, AfterOk), u16> {
        if text.is_empty() {
            return Ok((Vec::new(), AfterOk::Nothing));
        }
        if let Some(jog) = text.strip_prefix("$J=") {
            return self.jog(jog, line).map(|s| (s, AfterOk::Nothing));
        }
        if let Some(cmd) = text.strip_prefix('$') {
            return self.system_command(cmd);
        }
        if self.alarm || self.sleep || self.jogging() {
            return Err(9);
        }
        self.gcode(text, line).map(|s| (s, AfterOk::Nothing))
    }

    /// Grbl reads no line while it is suspended: from the moment a feed hold,
    /// a door or M0 has the machine standing still until `~` resumes it
    /// (protocol.c's suspend loop), and in sleep until a reset.
    fn suspended(&self) -> bool {
        self.sleep || ((self.hold || self.door) && !self.moving())
    }
}
