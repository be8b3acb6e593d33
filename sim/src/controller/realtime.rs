//! Realtime bytes, acted on the moment they arrive: status request, feed
//! hold, cycle start, safety door, jog cancel and the overrides (a soft reset
//! is in `reset.rs`). Separate from line handling: these never enter the
//! receive buffer and may come inside a line.

use super::report::REPORT_FORMAT_S;
use super::{Controller, Flavor, MotionModel};
use crate::wire::MachineState;

impl Controller {
    pub(super) fn realtime(&mut self, b: u8) {
        use crate::wire::realtime::*;
        let before = [self.ovr_feed, self.ovr_rapid, self.ovr_spindle];
        // A hold, a door, a reset or the spindle override changes the laser at rest.
        self.watching_rest_laser(|c| c.realtime_command(b));
        if b != SOFT_RESET && [self.ovr_feed, self.ovr_rapid, self.ovr_spindle] != before {
            // An override change shows in the next report.
            self.ov_countdown = 0;
        }
        if (FEED_OVR_RESET..=RAPID_OVR_LOW).contains(&b) {
            // A speed override takes effect now, not at the end of a long segment.
            self.replan_now();
        }
    }

    fn realtime_command(&mut self, b: u8) {
        use crate::wire::realtime::*;
        match b {
            SOFT_RESET => self.soft_reset(),
            // A critical alarm ignores everything but reset (reference §5).
            _ if self.critical => {}
            // No reports while homing (reference §3).
            // Grbl 1.1h prints the report, then clears the request: a `?`
            // arriving while it formats one is answered by that one.
            STATUS if self.cfg.flavor == Flavor::Grbl && self.now < self.report_busy_until => {}
            STATUS if !self.homing_active() => {
                self.report_busy_until = self.now + REPORT_FORMAT_S;
                let report = self.status_report();
                let line = self.report_text(&report);
                self.send(&line);
            }
            JOG_CANCEL => self.cancel_jog(),
            FEED_HOLD if self.jogging() => self.cancel_jog(),
            FEED_HOLD if !(self.alarm || self.check_mode || self.sleep || self.hold) => self.start_hold(),
            SAFETY_DOOR => self.door_event(),
            CYCLE_START if self.may_resume() => {
                self.restore_spindle();
                self.hold = false;
                self.door = false;
                self.begin_ramp_up();
                match &self.exec {
                    None if self.planner.is_empty() => self.mark_idle(self.now),
                    None => self.start_next(self.now, true, 0.0),
                    // Stopped inside a block: start again from rest there.
                    Some(e) if !e.running => self.resume_inside_block(),
                    Some(_) => {}
                }
            }
            FEED_OVR_RESET => self.ovr_feed = 100,
            FEED_OVR_COARSE_PLUS => self.ovr_feed = (self.ovr_feed + 10).min(200),
            FEED_OVR_COARSE_MINUS => self.ovr_feed = self.ovr_feed.saturating_sub(10).max(10),
            FEED_OVR_FINE_PLUS => self.ovr_feed = (self.ovr_feed + 1).min(200),
            FEED_OVR_FINE_MINUS => self.ovr_feed = self.ovr_feed.saturating_sub(1).max(10),
            RAPID_OVR_RESET => self.ovr_rapid = 100,
            RAPID_OVR_MEDIUM => self.ovr_rapid = 50,
            RAPID_OVR_LOW => self.ovr_rapid = 25,
            SPINDLE_OVR_RESET => self.ovr_spindle = 100,
            SPINDLE_OVR_COARSE_PLUS => self.ovr_spindle = (self.ovr_spindle + 10).min(200),
            SPINDLE_OVR_COARSE_MINUS => self.ovr_spindle = self.ovr_spindle.saturating_sub(10).max(10),
            SPINDLE_OVR_FINE_PLUS => self.ovr_spindle = (self.ovr_spindle + 1).min(200),
            SPINDLE_OVR_FINE_MINUS => self.ovr_spindle = self.ovr_spindle.saturating_sub(1).max(10),
            SPINDLE_OVR_STOP if matches!(self.state(), MachineState::Hold(_)) => self.toggle_spindle_stop(),
            // Coolant toggles act in Idle, Run and Hold, on the parser state (M7/M8/M9).
            // Grbl 1.1h has no mist coolant (M7) unless built with it.
            COOLANT_MIST_TOGGLE if self.cfg.flavor == Flavor::Grbl => {}
            COOLANT_FLOOD_TOGGLE | COOLANT_MIST_TOGGLE
                if matches!(self.state(), MachineState::Idle | MachineState::Run | MachineState::Hold(_)) =>
            {
                if b == COOLANT_FLOOD_TOGGLE {
                    self.modal.flood = !self.modal.flood;
                } else {
                    self.modal.mist = !self.modal.mist;
                }
                // The output switches at once, no sync.
                self.coolant_out = [self.modal.flood, self.modal.mist];
                self.ov_countdown = 0;
            }
            _ => {}
        }
    }

    /// Only a hold that has come to rest resumes (Grbl ignores `~` while it
    /// still decelerates), a door's once it is closed.
    fn may_resume(&self) -> bool {
        let door_open = self.door && self.door_open;
        self.hold && !self.alarm && !self.moving() && !door_open
    }

    /// Feed hold: the machine brakes to a stop, laser off.
    pub(super) fn start_hold(&mut self) {
        self.hold = true;
        self.hold_stops_laser();
        self.pause_starvation();
        self.replan_now();
        self.begin_braking();
    }

    /// The safety door switch (an input of the machine, not a byte on the link):
    /// opening it holds the machine with the laser off, as `0x84` does; after
    /// closing it, `~` resumes.
    pub fn set_door(&mut self, open: bool) {
        self.watching_rest_laser(|c| {
            c.door_open = open;
            if open {
                c.door_event();
            }
        });
    }

    /// The door opened (its switch) or `0x84` came. Grbl acts on both alike;
    /// only the switch holds the door open: after `0x84` alone the door reads
    /// closed as soon as the machine has stopped (`Door:0`), and `~` resumes.
    fn door_event(&mut self) {
        if self.homing_active() {
            // The door fails a homing cycle (reference §3).
            self.homing_fail(7);
            return;
        }
        if self.alarm || self.check_mode {
            return;
        }
        // Grbl says so on every door event it acts on, sleeping included.
        self.send("[MSG:Check Door]");
        if self.sleep {
            return;
        }
        self.door_clears_spindle_stop();
        if self.setting(32) != 0.0 {
            // The door switches the laser off; in laser mode Grbl brings it
            // back with the next motion, not while standing still.
            self.rest_s = 0.0;
        }
        if self.jogging() {
            self.cancel_jog();
        }
        self.door = true;
        self.hold = true;
        self.pause_starvation();
        self.replan_now();
        self.begin_braking();
    }

    /// Jog cancel: stop the jog and drop every queued jog block.
    /// Jog cancel. The timed model stops at once; the grbl model brakes at the
    /// jog's acceleration (across queued jog blocks if need be, still in Jog)
    /// and drops the rest of the jog once stopped.
    fn cancel_jog(&mut self) {
        if !self.jogging() {
            return;
        }
        if self.cfg.motion == MotionModel::Grbl && self.moving() {
            self.jog_cancel = true;
            self.replan_now();
            return;
        }
        self.stop_motion_now();
        self.end_jog_cancel();
    }

    /// The machine has stopped: drop what is left of the jog.
    pub(super) fn end_jog_cancel(&mut self) {
        if let Some(e) = self.exec.take() {
            self.pos = e.end_pos;
        }
        self.jog_cancel = false;
        self.planner.retain(|b| !b.jog);
        self.gc_pos = self.pos.clone();
        self.mark_idle(self.now);
    }
}
