//! Status reports (`?`, grblHAL's `0x87`): what the machine shows of itself,
//! including `Bf:` free buffers as Grbl counts them (blocks already cut into
//! step segments are out of the planner). Separate because the report's
//! contents follow Grbl's bookkeeping, not the simulator's own.

use super::{dist, Controller, Flavor, MotionModel};
use crate::planner::{self, Planned, SegmentInput};
use crate::wire::StatusReport;

/// How long an AVR takes to format a status report (some hundred
/// microseconds of float printing; taken as 1 ms). Two `?` closer together
/// than that get one report from Grbl 1.1h.
pub(super) const REPORT_FORMAT_S: f64 = 0.001;

impl Controller {
    /// `Bf:` free planner blocks and receive-buffer bytes. Blocks already
    /// cut into the step-segment buffer are out of the planner.
    fn free_buffers(&self) -> (u32, u32) {
        let used = self.planner.len() + usize::from(self.exec.is_some()) - self.prepared_blocks();
        (self.cfg.planner_blocks.saturating_sub(used) as u32, self.rx_capacity().saturating_sub(self.rx.len()) as u32)
    }

    /// How many blocks, from the executing one on, have every segment in
    /// the step-segment buffer. Grbl cuts the block at the planner's head into
    /// segments of at most 10 ms (`ACCELERATION_TICKS_PER_SECOND` 100; one
    /// ends where its block ends) ahead of the steppers and discards the block
    /// from its planner once its last segment is prepared: `Bf:` no longer
    /// counts it and `Ln:` names the block after it while the machine still
    /// has it to run. The segment ring holds 6 on Grbl 1.1h (10 on grblHAL)
    /// with one slot kept open, the running segment's included. A block that
    /// a hold brakes to rest inside is kept.
    fn prepared_blocks(&self) -> usize {
        let Some(e) = self.exec.as_ref().filter(|e| e.running) else { return 0 };
        let slots = match self.cfg.flavor {
            Flavor::Grbl => 5,
            Flavor::Grblhal => 9,
        };
        // A block of absurd length (a fuzzed G93 feed) needs more segments
        // than a usize counts: the cast saturates, and so do the sums.
        let segments = |secs: f64| (secs / planner::SEGMENT_S - 1e-9).ceil().max(1.0) as usize;
        let mut used = segments(e.end_t - self.now);
        let mut prepared = 0;
        let blocks = std::iter::once(&e.block).chain(self.planner.iter());
        if self.cfg.motion == MotionModel::Timed {
            // Each block at its own constant speed.
            for (i, b) in blocks.enumerate() {
                if i > 0 {
                    used = used.saturating_add(segments(self.block_time(b)));
                }
                if used > slots {
                    break;
                }
                prepared += 1;
            }
            return prepared;
        }
        // The profile as Grbl's segment generator cuts it from here on.
        let (mut speed, mut remaining) = (e.speed, e.block.kin.length - e.done);
        for (i, b) in blocks.enumerate() {
            if i > 0 {
                remaining = b.kin.length;
            }
            let nominal = self.nominal_speed(b);
            let queue = self.planner.iter().skip(i).map(|q| Planned { nominal: self.nominal_speed(q), kin: &q.kin });
            let input = SegmentInput {
                speed,
                remaining,
                nominal,
                exit: planner::exit_speed(nominal, queue),
                acceleration: b.kin.acceleration,
                stopping: self.hold || self.jog_cancel,
            };
            while used <= slots {
                let Some(seg) = planner::next_segment(SegmentInput { speed, remaining, ..input }) else { break };
                used = used.saturating_add(segments(seg.duration));
                speed = seg.end_speed;
                remaining -= seg.distance;
            }
            if used > slots || remaining > 1e-9 {
                break;
            }
            prepared += 1;
        }
        prepared
    }

    pub(super) fn status_report(&mut self) -> StatusReport {
        let used = self.planner.len() + usize::from(self.exec.is_some());
        let feed = match &self.exec {
            Some(e) => {
                let len = dist(&e.start_pos, &e.end_pos);
                let dur = e.end_t - e.start_t;
                let speed = match self.on_ramp() {
                    Some((_, speed)) => speed,
                    None if e.running && dur > 0.0 => len / dur,
                    None => 0.0,
                };
                speed * 60.0
            }
            None => 0.0,
        };
        // `Ln:` is the line of the block at the planner's head; Grbl 1.1h as
        // built by default has no line numbers (no `N` in `[OPT:]`).
        let line = self
            .exec
            .iter()
            .map(|e| &e.block)
            .chain(self.planner.iter())
            .nth(self.prepared_blocks())
            .and_then(|b| b.n_word)
            .filter(|_| self.cfg.flavor == Flavor::Grblhal);
        // WCO comes in the first report after a reset or an offset change, then
        // every 10th (idle) / 30th (busy); Ov in the second, on a change, then
        // every 10th / 20th, a report later when WCO takes its turn (reference §4).
        let busy = used > 0;
        let wco = if self.wco_countdown == 0 {
            self.wco_countdown = if busy { 29 } else { 9 };
            Some(self.report_units(&self.wco()))
        } else {
            self.wco_countdown -= 1;
            None
        };
        let overrides = if self.ov_countdown == 0 && wco.is_none() {
            self.ov_countdown = if busy { 19 } else { 9 };
            Some([self.ovr_feed, self.ovr_rapid, self.ovr_spindle])
        } else {
            self.ov_countdown = self.ov_countdown.saturating_sub(1);
            None
        };
        let accessories = overrides.and_then(|_| self.accessories());
        let mask = self.status_mask();
        let position = self.position();
        let (mpos, wpos) = if mask & 1 == 1 {
            (self.report_units(&position), None)
        } else {
            // WPos = MPos - WCO.
            let wpos: Vec<f64> = position.iter().zip(&self.wco()).map(|(p, o)| p - o).collect();
            (Vec::new(), Some(self.report_units(&wpos)))
        };
        StatusReport {
            buffer: (mask & 2 == 2).then(|| self.free_buffers()),
            line,
            feed: Some(self.report_units(&[feed])[0]),
            spindle: Some(self.laser_power()),
            wpos,
            wco,
            overrides,
            accessories,
            pins: self.pins(),
            ..StatusReport::new(self.state(), mpos)
        }
    }

    /// grblHAL's `0x87`: every optional field, whatever `$10` and the report
    /// counters say, and the firmware's name.
    pub(super) fn full_status_report(&mut self) -> StatusReport {
        self.wco_countdown = 0;
        let mut r = self.status_report();
        r.wco = Some(self.report_units(&self.wco()));
        r.overrides = Some([self.ovr_feed, self.ovr_rapid, self.ovr_spindle]);
        r.accessories = self.accessories();
        if r.buffer.is_none() {
            r.buffer = Some(self.free_buffers());
        }
        r.firmware = Some("grblHAL".into());
        r
    }
}
