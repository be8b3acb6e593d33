//! Motion: the planner queue, when blocks start, their segments, knots and
//! the starvation bookkeeping. Separate from the line handling that fills the
//! queue and from the hold ramp (`hold.rs`) that slows the timed model.
//!
//! # Motion model (this version)
//! Every planner block executes at constant velocity along the straight line
//! from its start to its end. Its duration is
//! * G93 (inverse time): `60 / F` seconds (an arc's chords share that time
//!   equally);
//! * G94: `length / (F / 60)` with `length` the Euclidean length over all axes;
//! * G0: `max over axes |Δ| / max_velocity`.
//!
//! Like Grbl, a feed move is never faster than the axes allow: its duration is
//! at least the G0 duration of the same move. Overrides are applied when a
//! block starts. There is no acceleration: executed motion is piecewise linear
//! through the knots, and a reset or an alarm stops it at once. This is
//! deliberate, the limit checker in [`crate::limits`] judges what the *sender*
//! planned. A feed hold brakes within the limits (`hold.rs`).
//! Zero-length blocks are dropped (as Grbl does).
//!
//! # When blocks run
//! Grbl plans every queue to stop at its end, so a starved planner means a
//! controlled deceleration. With constant-velocity blocks the equivalent is to
//! run a block only when the queue holds a rest point after it: two *gentle*
//! blocks in a row (slow enough for their duration that the machine can stop
//! after the first and start into the second within its limits; see
//! `is_gentle`). Blocks also run when the planner is full, when the pending
//! line needs motion to end, or when the link has been silent for
//! `LINK_SILENCE_START` (a stream that never comes to rest must still run).
//! Silent means the sender could have sent and did not: the time counts from
//! the last byte received or, when the receive buffer had less room than the
//! longest line the controller takes, from the `ok` that made room, whichever
//! is later. A sender counting characters waits for that `ok` (a `G4` holds
//! its bytes and those behind it until its `ok`, after the dwell), so a link
//! quiet then is not the stream's end.
//! A feed hold (or a door) slows the program clock to a stop along the path,
//! laser off, within half of every axis' acceleration and jerk limit, then
//! reads `Hold:0`; `~` is taken only then, and ramps the clock up again.
//!
//! # Starvation
//! `starved_s` counts the time the machine stood still with an empty planner
//! between two motion blocks, excluding dwells and feed holds. Idle time after
//! the last block is only counted once another block starts after it.

use super::{Block, Controller, Exec, Knot, MotionModel, Step, LINK_SILENCE_START};
use crate::planner::{self, Planned, SegmentInput};

impl Controller {
    /// Stops the executing block where it is (reset or alarm), with a knot.
    pub(super) fn stop_motion_now(&mut self) {
        self.ramp = None;
        if let Some(e) = self.exec.take() {
            let p = interpolate(&e, self.now);
            if e.running {
                self.push_knot(Knot { t: self.now, pos: p.clone(), power: e.power, line: e.block.line });
                self.stats.last_motion_end_t = Some(self.now);
            }
            self.pos = p;
        }
    }

    pub(super) fn mark_idle(&mut self, t: f64) {
        if self.stats.first_motion_t.is_some() {
            self.starve_since = Some(t);
        }
    }

    pub(super) fn pause_starvation(&mut self) {
        if let Some(s) = self.starve_since.take() {
            self.starve_acc += (self.now - s).max(0.0);
        }
    }

    pub(super) fn reset_starvation(&mut self) {
        self.starve_since = None;
        self.starve_acc = 0.0;
    }

    pub(super) fn planner_full(&self) -> bool {
        self.planner.len() + usize::from(self.exec.is_some()) >= self.cfg.planner_blocks
    }

    /// Starts the next queued block at `t`, entering it at `entry_speed` (grbl
    /// model; the timed model runs every block at its own constant speed).
    pub(super) fn start_next(&mut self, t: f64, from_rest: bool, entry_speed: f64) {
        let Some(block) = self.planner.pop_front() else { return };
        let power = if self.hold { 0.0 } else { self.block_power(&block) };
        if from_rest {
            // A knot closes the time the machine stood here, with the laser as
            // it was (on, after a pierce under M3), so that every knot's power
            // is that of the time ending at it.
            if self.last_knot_t.is_finite() && self.last_knot_t < t {
                let knot = Knot { t, pos: self.pos.clone(), power: self.rest_power(), line: self.rest_line };
                self.push_knot(knot);
            }
            // A restart at the instant the last block ended needs no knot of its own.
            if !self.knots.last().is_some_and(|k| k.t == t && k.pos == self.pos) {
                self.push_knot(Knot { t, pos: self.pos.clone(), power, line: block.line });
            }
            if let Some(s) = self.starve_since.take() {
                self.starve_acc += (t - s).max(0.0);
            }
            self.stats.starved_s += self.starve_acc;
            self.starve_acc = 0.0;
        }
        self.stats.first_motion_t.get_or_insert(t);
        let pos = self.pos.clone();
        self.exec = Some(Exec {
            origin: pos.clone(), start_t: t, end_t: t, start_pos: pos.clone(), end_pos: pos,
            done: 0.0, speed: entry_speed, running: false, power, block,
        });
        match self.cfg.motion {
            MotionModel::Timed => self.timed_segment(t),
            MotionModel::Grbl => self.next_segment(t),
        }
    }

    /// Laser S of a block after the spindle override.
    pub(super) fn block_power(&self, b: &Block) -> f64 {
        (b.power * self.ovr_spindle as f64 / 100.0).min(self.cfg.laser_max_s)
    }

    /// A block's speed now: the programmed one scaled by its override (feed,
    /// or rapid for G0; none for jogs and homing), never above what the axes allow.
    pub(super) fn nominal_speed(&self, b: &Block) -> f64 {
        let dur = self.block_time(b);
        if dur > 0.0 { b.kin.length / dur } else { b.kin.max_speed }
    }

    /// A block's duration at constant speed, after its override.
    pub(super) fn block_time(&self, b: &Block) -> f64 {
        let percent = if b.jog || b.homing {
            100
        } else if b.rapid {
            self.ovr_rapid
        } else {
            self.ovr_feed
        };
        (b.duration * 100.0 / percent as f64).max(b.min_duration)
    }

    /// Cuts and starts the next segment of the executing block (grbl model);
    /// finishes the block at its end, or stops in it when a hold has braked
    /// the machine to rest.
    pub(super) fn next_segment(&mut self, t: f64) {
        let Some(e) = self.exec.as_ref() else { return };
        let nominal = self.nominal_speed(&e.block);
        let queue = self.planner.iter().map(|b| Planned { nominal: self.nominal_speed(b), kin: &b.kin });
        let input = SegmentInput {
            speed: e.speed,
            remaining: e.block.kin.length - e.done,
            nominal,
            exit: planner::exit_speed(nominal, queue),
            acceleration: e.block.kin.acceleration,
            stopping: self.hold || self.jog_cancel,
        };
        let power = if self.hold { 0.0 } else { self.block_power(&e.block) };
        let programmed_speed = if e.block.duration > 0.0 { e.block.kin.length / e.block.duration } else { 0.0 };
        let Some(e) = self.exec.as_mut() else { return };
        match planner::next_segment(input) {
            Some(seg) => {
                // Grbl's M4 scales power by actual over programmed speed, per segment.
                let power = if e.block.dynamic_power && programmed_speed > 0.0 {
                    power * (seg.distance / seg.duration / programmed_speed).min(1.0)
                } else {
                    power
                };
                e.start_t = t;
                e.end_t = t + seg.duration;
                e.start_pos = std::mem::take(&mut e.end_pos);
                e.done += seg.distance;
                e.end_pos = if e.block.kin.length - e.done <= 1e-9 {
                    e.block.target.clone()
                } else {
                    e.origin.iter().zip(&e.block.kin.unit).map(|(o, u)| o + u * e.done).collect()
                };
                e.speed = seg.end_speed;
                e.running = true;
                e.power = power;
            }
            None if self.jog_cancel && input.remaining > 1e-9 => {
                e.start_pos = e.end_pos.clone();
                e.start_t = t;
                e.end_t = t;
                self.end_jog_cancel();
            }
            None if self.hold && input.remaining > 1e-9 => {
                // Braked to rest inside the block: Hold:0, the rest of it waits for `~`.
                e.running = false;
                e.speed = 0.0;
                e.start_t = t;
                e.end_t = t;
                e.start_pos = e.end_pos.clone();
            }
            None => self.finish_block(t),
        }
    }

    /// The segment running now has ended: a knot, then the next segment or block.
    pub(super) fn finish_segment(&mut self) {
        let Some(e) = self.exec.as_ref() else { return };
        let t = e.end_t;
        let knot = Knot { t, pos: e.end_pos.clone(), power: e.power, line: e.block.line };
        let block_done = e.block.kin.length - e.done <= 1e-9;
        self.push_knot(knot);
        self.stats.last_motion_end_t = Some(t);
        if block_done {
            self.finish_block(t);
        } else if self.cfg.motion == MotionModel::Timed {
            self.timed_segment(t);
        } else {
            self.next_segment(t);
        }
    }

    /// Grbl model: a hold or an override acts now, not at the end of a long
    /// cruise segment. The running segment is cut at the present position and
    /// the profile planned again from there. (A ramp segment, at most 10 ms,
    /// runs out, as Grbl's prepared segments do.)
    pub(super) fn replan_now(&mut self) {
        if self.cfg.motion == MotionModel::Grbl && self.exec.as_ref().is_some_and(|e| e.end_t - self.now > planner::SEGMENT_S) {
            self.cut_segment_now();
        }
    }

    fn finish_block(&mut self, t: f64) {
        let Some(e) = self.exec.take() else { return };
        self.pos = e.block.target.clone();
        // Should the machine stop here: Grbl's stepper leaves the laser at an M3
        // block's power and switches it off after an M4 (dynamic) one; a hold
        // has switched it off.
        // Outside laser mode the spindle runs on as its last sync set it.
        if self.setting(32) != 0.0 {
            self.rest_s = if self.hold || e.block.dynamic_power || e.block.power == 0.0 { 0.0 } else { e.block.power };
        }
        self.rest_line = e.block.line;
        self.stats.blocks_executed += 1;
        self.stats.last_motion_end_t = Some(t);
        if self.cfg.motion == MotionModel::Grbl {
            if self.jog_cancel && e.speed <= 1e-9 {
                self.end_jog_cancel();
            } else if self.hold && e.speed <= 1e-9 {
                // Braked to rest exactly at a block end: Hold:0.
            } else if !self.planner.is_empty() {
                self.start_next(t, false, e.speed);
            } else if !self.hold {
                self.mark_idle(t);
            }
            return;
        }
        if self.hold {
            // A braking hold goes on along the path into the next block until
            // it has stopped (then Hold:0; waiting for `~` is not starvation).
            if self.ramp.is_some_and(|r| r.braking) && !self.braked_to_rest(t) && !self.planner.is_empty() {
                self.start_next(t, false, 0.0);
            }
        } else if !self.planner.is_empty() && self.may_start(true) {
            self.start_next(t, false, 0.0);
        } else {
            self.mark_idle(t);
        }
    }

    pub(super) fn auto_start(&mut self) {
        if self.exec.is_none() && !self.hold && !self.alarm && !self.planner.is_empty() && self.may_start(false) {
            self.start_next(self.now, true, 0.0);
        }
    }

    /// Geometry, axis limits and junction speed of a block entering the planner
    /// behind what is queued. A block that finds the machine idle and the
    /// planner empty starts from rest (Grbl's rule).
    pub(super) fn plan_block(&self, b: &mut Block) {
        let before = match (self.planner.back(), &self.exec) {
            (Some(last), _) => Some(last),
            (None, Some(e)) => Some(&e.block),
            (None, None) => None,
        };
        let start = before.map_or(&self.pos, |p| &p.target);
        b.kin = planner::kinematics(start, &b.target, &self.cfg.axes);
        b.kin.max_junction = before.map_or(0.0, |p| planner::junction_speed(&p.kin.unit, &b.kin.unit, &self.cfg.axes, self.junction_deviation()));
    }

    /// `$11`, in mm.
    fn junction_deviation(&self) -> f64 {
        self.written_settings.get(&11).copied().unwrap_or(self.proto.defaults.junction_deviation)
    }

    /// Whether the machine may stop after `b` (coming after what is queued), or
    /// start into it from rest, within its limits (`gentle_move`). The first
    /// and last blocks of a planned rest-to-rest move pass; a block in the
    /// middle of a fast move does not.
    pub(super) fn is_gentle(&self, b: &Block) -> bool {
        let start = match (self.planner.back(), &self.exec) {
            (Some(last), _) => &last.target,
            (None, Some(e)) => &e.block.target,
            (None, None) => &self.pos,
        };
        self.cfg.axes.iter().enumerate().all(|(i, ax)| gentle_move(b.target[i] - start[i], b.duration, ax.max_acceleration, ax.max_jerk))
    }

    /// Grbl plans every queue to come to a stop at its end. Here blocks run at
    /// constant velocity, so the equivalent rule is: run the next block only when
    /// the queue holds a rest point after it (two gentle blocks in a row: the
    /// machine can stop between them and start again; or the end of the
    /// program's motion, where a line without motion follows). Otherwise wait for more
    /// blocks, unless the planner is full, the pending line needs motion to end
    /// (M2, M5, G4, ...), or the link has fallen silent (a stream that never
    /// comes to rest must still run). A block that has `just_finished` still
    /// counts as filling the planner: were it full, Grbl's stepper goes on into
    /// the next block at once, and the line waiting for that slot takes it
    /// within microseconds; stopping there would be a stop Grbl never makes.
    fn may_start(&self, just_finished: bool) -> bool {
        if self.cfg.motion == MotionModel::Grbl {
            // Grbl starts a cycle as soon as it has parsed everything received,
            // which the simulator does the moment a line arrives.
            return true;
        }
        let queued: Vec<bool> = self.planner.iter().map(|b| b.gentle).collect();
        queued.windows(2).any(|w| w[0] && w[1])
            || self.planner.iter().any(|b| b.ends_sequence)
            || self.planner.len() + usize::from(self.exec.is_some() || just_finished) >= self.cfg.planner_blocks
            || self.pending.as_ref().is_some_and(|p| !matches!(p.steps.front(), None | Some(Step::Queue(_))))
            || self.now - self.link_quiet_since() >= LINK_SILENCE_START - 1e-9
    }

    /// Since when the link has been silent: the last byte received, or the
    /// last answer that made room in a receive buffer too full for another
    /// line (of the longest length the controller takes: the controller
    /// cannot know how long the sender's next line is), whichever came
    /// later. A sender counting characters that finds the buffer full waits for an `ok` (a `G4` keeps its bytes, and those of
    /// the lines behind it, there until its `ok`, after the dwell), so a link
    /// quiet while the controller holds its buffer is waiting, not done. Were
    /// this counted from the last byte only, the few blocks that fit behind a
    /// dwell would start at its end without a rest point queued after them,
    /// and the controller, fed a line at a time, would stop inside the cut.
    pub(super) fn link_quiet_since(&self) -> f64 {
        self.last_rx_t.max(self.last_room_t)
    }
}

/// Whether a block moving an axis by `delta` in `duration` seconds at
/// constant velocity v is slow enough to stop after, or to start into from
/// rest, next to another such block. Judged as the limit checker judges it:
/// a stop of no length between blocks 1 and 2 shows as an acceleration of
/// 2·v/T at the knot and a jerk of 6·(v₁/T₁ + v₂/T₂) / (T₁ + T₂), within
/// `acceleration` and `jerk` when each block keeps v/T ≤ A/2 and
/// v/T² ≤ J/6. (With J/2, a stop between two such blocks could show as
/// 3 × the jerk limit.) The timed controller's rest points, and the
/// sender's model of them, use this one rule.
pub fn gentle_move(delta: f64, duration: f64, acceleration: f64, jerk: f64) -> bool {
    if duration <= 0.0 {
        return true;
    }
    let v = delta.abs() / duration;
    v / duration <= 0.5 * acceleration && v / (duration * duration) <= jerk / 6.0
}

pub(super) fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (y - x) * (y - x)).sum::<f64>().sqrt()
}

pub(super) fn interpolate(e: &Exec, t: f64) -> Vec<f64> {
    let dur = e.end_t - e.start_t;
    let f = if e.running && dur > 0.0 { ((t - e.start_t) / dur).clamp(0.0, 1.0) } else { 1.0 };
    e.start_pos.iter().zip(&e.end_pos).map(|(s, g)| s + (g - s) * f).collect()
}
