//! Resets and critical alarms: soft reset (`0x18`), hardware reset (a
//! brown-out), and the limit alarms that lock the machine until a reset.
//! Separate because they share one rule: what a reset clears and what
//! survives it (EEPROM), with the laser off afterwards.

use super::{Controller, Modal, Step};

impl Controller {
    pub(super) fn soft_reset(&mut self) {
        let moving = self.moving();
        // Grbl's dwell (and the wait for motion to end before it) gives up on
        // a reset, and the line it ran in is answered as done before the reboot.
        let dwell_cut_short = self.pending.as_ref().is_some_and(|p| !p.quiet && p.steps.iter().any(|s| matches!(s, Step::Dwell(..))));
        let homing = self.exec.as_ref().is_some_and(|e| e.block.homing);
        let ok_owed = std::mem::take(&mut self.ok_after_reset);
        self.clear_volatile_state();
        if self.sleep {
            // Leaving sleep always goes through Alarm (reference §7).
            self.sleep = false;
            self.alarm = true;
        }
        if moving {
            self.alarm = true;
            // A reset during homing fails the cycle (6); otherwise position is lost (3).
            let code = if homing { 6 } else { 3 };
            self.stats.alarms.push(code);
            self.send(&format!("ALARM:{code}"));
        }
        // A line cut short by the reset returns to Grbl's line loop with its
        // `ok` before the banner: the `$H` of a homing cycle, the line that
        // hit a soft limit, a dwell.
        if dwell_cut_short || homing || ok_owed {
            self.send("ok");
        }
        self.announce();
    }

    /// A hardware reset (a brown-out, the reset button): the controller
    /// reboots as at power-up. Only EEPROM survives (settings, work offsets,
    /// stored positions, startup lines); the machine stops where it is, and
    /// that place is the new zero, since the step counters start from zero.
    /// Nothing reports a lost position: the banner is all the host sees, and
    /// the lines it sends after it run in the power-up state.
    pub(super) fn hardware_reset(&mut self) {
        self.clear_volatile_state();
        for ((shift, p), g) in self.power_up_shift.iter_mut().zip(&mut self.pos).zip(&mut self.gc_pos) {
            *shift += *p;
            *p = 0.0;
            *g = 0.0;
        }
        self.sleep = false;
        // With homing enabled Grbl starts locked (its default build).
        self.alarm = self.setting(22) != 0.0;
        self.announce();
    }

    /// Banner, then what follows it.
    fn announce(&mut self) {
        let banner = self.banner();
        self.out.extend_from_slice(format!("\r\n{banner}\r\n").as_bytes());
        self.after_banner();
    }

    /// What any reset clears: motion stops where it is, everything queued
    /// and the parser's state are gone, the laser is off.
    fn clear_volatile_state(&mut self) {
        self.stop_motion_now();
        self.planner.clear();
        self.rx.clear();
        self.rx_lines = 0;
        self.carry = None;
        self.pending = None;
        self.modal = Modal::default();
        self.coolant_out = [false; 2];
        self.proto.reset();
        self.g92 = vec![0.0; self.pos.len()];
        self.gc_pos = self.pos.clone();
        self.ovr_feed = 100;
        self.ovr_rapid = 100;
        self.ovr_spindle = 100;
        self.wco_countdown = 0;
        self.ov_countdown = 1;
        self.check_mode = false;
        self.jog_cancel = false;
        self.hold = false;
        self.door = false;
        self.critical = false;
        self.ok_after_reset = false;
        self.reset_starvation();
        // Grbl's reset stops the spindle: the laser is off.
        self.rest_s = 0.0;
    }

    /// A critical limit alarm: motion stops where it is, laser off, everything
    /// locked until a reset (reference §5).
    pub(super) fn limit_alarm(&mut self, code: u16) {
        self.stop_motion_now();
        self.rest_s = 0.0;
        self.planner.clear();
        self.gc_pos = self.pos.clone();
        self.hold = false;
        self.alarm = true;
        self.critical = true;
        self.reset_starvation();
        if code == 1 {
            self.proto.limit_pin = self.cfg.axes.first().map(|a| a.letter);
        }
        self.stats.alarms.push(code);
        self.send(&format!("ALARM:{code}"));
        self.send("[MSG:Reset to continue]");
    }

    pub(super) fn soft_limit_alarm(&mut self) {
        self.limit_alarm(2);
    }
}
