//! The laser while the machine stands still, and the knots that record it.
//! Separate because every way into the controller (realtime bytes, lines, the
//! door switch) must leave the knots true about the power at rest.
//!
//! In laser mode (`$32=1`) the laser follows Grbl's rules while the machine
//! stands still (reference §9): a spindle sync (an M3/M4/M5 change, or under M3
//! an S change or a switch between G0 and G1/G2/G3 in a line without motion)
//! sets it once motion has stopped: M3 at S in a feed motion mode (off in G0),
//! M4 off (dynamic power: nothing moves), M5 off; after a block the laser stays
//! at the block's power under M3 and goes off under M4. So `M3 S500` then
//! `G4 P0.2` in G1 mode burns standing still for 0.2 s, and `M4 S500` with
//! `G4` does not. A hold, a door, a reset or an alarm switches it off, and in
//! laser mode a resume does not switch it on again (Grbl restores the laser
//! with the next motion). Knots record it: where the power at rest changes, a
//! knot closes the time before with the power it had and one at the same
//! instant opens the next; a dwell ends with a knot of its own line, and motion
//! that starts after a rest first closes that rest with a knot of its power.
//! A dwell's clock stops in a hold (Grbl dwells inside its realtime loop) and
//! runs on after `~`.

use super::{Controller, Knot};

impl Controller {
    /// Laser S while the machine stands still, after override: 0 in a door,
    /// an alarm, sleep, check mode or with the spindle stop override, and in
    /// laser mode in a hold. (Outside laser mode the output is a spindle's: it
    /// runs at S under M3 and M4, in a hold too, as Grbl's `FS:` shows.)
    pub(super) fn rest_power(&self) -> f64 {
        let held = self.hold && self.setting(32) != 0.0;
        let off = held || self.door || self.alarm || self.sleep || self.check_mode || self.proto.spindle_stop;
        if off || self.rest_s == 0.0 {
            0.0
        } else {
            (self.rest_s * self.ovr_spindle as f64 / 100.0).min(self.cfg.laser_max_s)
        }
    }

    /// Knots are where the machine is: Grbl's position plus where its zero
    /// has been since a hardware reset.
    pub(super) fn push_knot(&mut self, mut knot: Knot) {
        self.last_knot_t = knot.t;
        if self.power_up_shift.iter().any(|s| *s != 0.0) {
            knot.pos.iter_mut().zip(&self.power_up_shift).for_each(|(p, s)| *p += s);
        }
        self.knots.push(knot);
    }

    /// Runs `f`, then records in knots a change it made to the laser at rest.
    /// Every way in (a realtime byte, lines run at an instant, the door
    /// switch) goes through here, so resets and alarms need not.
    pub(super) fn watching_rest_laser<R>(&mut self, f: impl FnOnce(&mut Controller) -> R) -> R {
        let (before, line) = (self.rest_power(), self.rest_line);
        let r = f(self);
        self.rest_laser_changed(before, line);
        r
    }

    /// The laser at rest was `before` (set by `line`): if it changed while the
    /// machine stands still, a knot closes the time before (unless a knot is
    /// already here) and one opens the new state at the same instant.
    fn rest_laser_changed(&mut self, before: f64, line: u64) {
        let after = self.rest_power();
        if after == before || self.exec.is_some() {
            return;
        }
        let pos = self.pos.clone();
        if self.last_knot_t.is_finite() && self.last_knot_t < self.now {
            self.push_knot(Knot { t: self.now, pos: pos.clone(), power: before, line });
        }
        self.push_knot(Knot { t: self.now, pos, power: after, line: self.rest_line });
    }
}
