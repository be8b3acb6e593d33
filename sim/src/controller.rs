//! The GRBL 1.1 controller as a pure state machine driven by an external clock.
//!
//! Time is an `f64` in seconds handed in by the driver (`receive`, `advance`),
//! so the same machine runs in virtual time (tests, in-process simulation) and
//! in wall-clock time (the pty driver). Nothing in here sleeps or reads a clock.
//!
//! This file holds the state (`Controller`, its blocks and pending line), the
//! clock (`advance`, `next_event`) and what the driver reads back. The rest,
//! one `impl Controller` per seam:
//! * `config.rs`: `SimConfig` and its parts (axes, flavour, motion model,
//!   faults), and the sanitizing of a config;
//! * `lines.rs`: line bytes from the wire, the receive buffer, each line's
//!   steps up to its `ok`;
//! * `parser.rs`: G-code blocks and `$J=` jogs; `arc.rs`: arcs cut into chords;
//! * `system.rs`: `$` commands, EEPROM (offsets, stored positions, startup
//!   lines), homing, probing, feedback messages and the report's
//!   `Pn:`/`A:`/`WCO:` fields; `settings.rs`: the `$n` settings;
//! * `realtime.rs`: realtime bytes (`?`, `!`, `~`, door, jog cancel, overrides);
//! * `report.rs`: status reports and the `Bf:` buffer counts;
//! * `reset.rs`: soft and hardware resets, critical limit alarms;
//! * `motion.rs`: the planner queue, when blocks start, segments, starvation;
//! * `hold.rs`: the timed model's feed hold and resume (the program clock ramp);
//! * `laser.rs`: the laser at rest and the knots that record it.

use std::collections::VecDeque;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::gcode::LineBuilder;
use crate::planner::Kinematics;
use crate::wire::{MachineState, BANNER, BANNER_HAL};

mod arc;
mod config;
mod hold;
mod laser;
mod lines;
mod motion;
pub use motion::gentle_move;
mod parser;
mod realtime;
mod report;
mod reset;
mod settings;
mod system;

pub use config::{AxisConfig, Faults, Flavor, MotionModel, SimConfig, GRBL_AXES, JUNCTION_DEVIATION, STEPS_PER_MM};
use config::sanitize;
use motion::{dist, interpolate};
use system::Protocol;

/// A point of the executed, piecewise-linear motion.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema, PartialEq)]
pub struct Knot {
    pub t: f64,
    pub pos: Vec<f64>,
    /// Laser power (S) on the segment ending here, moving or standing still
    /// (on the first knot: on the segment starting there).
    pub power: f64,
    /// Received-line number (1-based count of lines received) of the block.
    pub line: u64,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize, JsonSchema)]
pub struct SimStats {
    pub lines_received: u64,
    pub blocks_executed: u64,
    pub first_motion_t: Option<f64>,
    pub last_motion_end_t: Option<f64>,
    pub starved_s: f64,
    pub alarms: Vec<u16>,
    pub rx_overflows: u64,
    pub errors_sent: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Motion {
    Rapid,
    Linear,
    ArcCw,
    ArcCcw,
    /// G38.2 (toward, alarm on no contact), G38.3, G38.4 (away), G38.5.
    Probe { away: bool, no_error: bool },
    None,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Spindle {
    Off,
    Cw,
    Ccw,
}

/// G-code modal state (reset values are Grbl's power-up defaults).
#[derive(Debug, Clone)]
struct Modal {
    motion: Motion,
    plane: u8,
    inches: bool,
    incremental: bool,
    inverse_time: bool,
    coord: u8,
    spindle: Spindle,
    flood: bool,
    mist: bool,
    /// mm/min in G94; the raw inverse-time value after a G93 block.
    feed: f64,
    s: f64,
    tool: u32,
}

impl Default for Modal {
    fn default() -> Self {
        Modal {
            motion: Motion::Rapid,
            plane: 17,
            inches: false,
            incremental: false,
            inverse_time: false,
            coord: 54,
            spindle: Spindle::Off,
            flood: false,
            mist: false,
            feed: 0.0,
            s: 0.0,
            tool: 0,
        }
    }
}

#[derive(Debug, Clone)]
struct Block {
    target: Vec<f64>,
    /// Commanded duration (s), already at least `min_duration`.
    duration: f64,
    /// Duration at the axes' max velocities.
    min_duration: f64,
    rapid: bool,
    /// Laser S while executing, before the spindle override.
    power: f64,
    line: u64,
    n_word: Option<u32>,
    /// Slow enough for its duration that the machine may stop after it or
    /// start into it from rest within its limits (set when it enters the planner).
    gentle: bool,
    /// The program ends its motion here: the next line was not a motion line.
    ends_sequence: bool,
    /// A `$J=` jog block.
    jog: bool,
    /// A `$H` homing move.
    homing: bool,
    /// Geometry and limits, set when the block enters the planner.
    kin: Kinematics,
    /// Laser power scales with actual over programmed speed (M4, laser mode).
    dynamic_power: bool,
}

impl Block {
    /// A feed or rapid move to `target` taking `duration` seconds (at least
    /// `min_duration`, the time at the axes' max velocities), laser off.
    fn new(target: Vec<f64>, duration: f64, min_duration: f64, line: u64) -> Block {
        Block {
            target,
            duration: duration.max(min_duration),
            min_duration,
            rapid: false,
            power: 0.0,
            line,
            n_word: None,
            gentle: false,
            ends_sequence: false,
            jog: false,
            homing: false,
            kin: Kinematics::default(),
            dynamic_power: false,
        }
    }
}

/// The block executing now and the constant-speed segment of it that runs:
/// from `start_pos` at `start_t` to `end_pos` at `end_t`. In the timed model
/// the segment is the whole block.
#[derive(Debug, Clone)]
struct Exec {
    block: Block,
    /// Where the block started.
    origin: Vec<f64>,
    start_t: f64,
    end_t: f64,
    start_pos: Vec<f64>,
    end_pos: Vec<f64>,
    /// Distance along the block at the segment's end.
    done: f64,
    /// Speed of the profile at the segment's end.
    speed: f64,
    /// False when a feed hold has stopped the machine inside the block.
    running: bool,
    power: f64,
}

/// What is left to do for a parsed line before its `ok`.
#[derive(Debug, Clone)]
enum Step {
    /// Wait until the planner is empty and motion stopped.
    Sync,
    /// Wait this many seconds (after a Sync); the line of the `G4`.
    Dwell(f64, u64),
    /// A spindle sync has set the laser power at rest (S before override).
    Laser { power: f64, line: u64 },
    /// A coolant sync: the outputs switch once motion has stopped (flood, mist).
    Coolant { flood: bool, mist: bool },
    /// Queue a block once the planner has room.
    Queue(Block),
    /// M0: enter feed hold.
    Pause,
    /// M2/M30 after motion ends.
    ProgramEnd,
    /// M0: wait for the `~` that ends the pause (Grbl answers M0 then).
    AwaitResume,
    /// Raise this non-critical alarm now (probe fails).
    Alarm(u16),
    /// A probing move ended here: record it, report `[PRB:]`, maybe ALARM:5.
    Probed { pos: Vec<f64>, touched: bool, alarm: bool },
    /// `$H` reached home: fail (a fault) or run the startup lines.
    HomingDone,
    /// A line past the soft limits while a cycle runs: once the hold it
    /// started has stopped the machine, the critical ALARM:2 (Grbl keeps the
    /// position so); the line is answered at the reset.
    SoftLimit,
    /// Send this line (startup line echoes).
    Say(String),
}

/// What a line sets off once its `ok` has gone.
#[derive(Debug, Clone, Copy, PartialEq)]
enum AfterOk {
    Nothing,
    /// A soft reset (`$C` off, `$RST=`).
    Reset,
    /// Sleep (`$SLP`): Grbl answers the line, then enters its sleep loop.
    Sleep,
}

#[derive(Debug)]
struct Pending {
    steps: VecDeque<Step>,
    /// Bytes of the line (incl. terminator) still in RX.
    rx_len: usize,
    /// Bytes of the line already out of RX though not yet answered (a `G4`:
    /// Grbl has read the line into its line buffer; the sender still counts them).
    taken: usize,
    dwell_until: Option<f64>,
    /// What was left of the dwell when a hold stopped its clock.
    dwell_left: Option<f64>,
    /// What happens once the `ok` has gone.
    after: AfterOk,
    /// No `ok` at the end (startup lines, which echo `>line:ok` instead).
    quiet: bool,
}

pub struct Controller {
    cfg: SimConfig,
    now: f64,
    out: Vec<u8>,
    rx: VecDeque<u8>,
    rx_lines: usize,
    /// Start of a line that overflowed RX without a terminator (Grbl keeps
    /// reading such a line into its line buffer, so RX must not stall).
    carry: Option<LineBuilder>,
    pending: Option<Pending>,
    planner: VecDeque<Block>,
    exec: Option<Exec>,
    /// Machine position when not executing (= last block end).
    pos: Vec<f64>,
    /// Parser position: end of the last queued block.
    gc_pos: Vec<f64>,
    g92: Vec<f64>,
    modal: Modal,
    hold: bool,
    /// A safety-door hold is in force (until the door is closed and `~`).
    door: bool,
    /// The door switch: open or closed.
    door_open: bool,
    alarm: bool,
    /// Soft-limit alarm before reset: everything is locked out.
    critical: bool,
    /// The line that hit a soft limit is answered `ok` once the reset comes
    /// (Grbl's parser finishes it after leaving its alarm loop).
    ok_after_reset: bool,
    check_mode: bool,
    sleep: bool,
    ovr_feed: u32,
    ovr_rapid: u32,
    ovr_spindle: u32,
    line_count: u64,
    knots: Vec<Knot>,
    stats: SimStats,
    starve_since: Option<f64>,
    starve_acc: f64,
    /// When the last byte arrived.
    last_rx_t: f64,
    /// When an answered line last made room in an RX too full for another
    /// line of the longest length the controller takes: a sender waiting
    /// for room may send again from then.
    last_room_t: f64,
    /// Longest line received so far (bytes, terminator included).
    longest_line: usize,
    /// Bytes arrived on the wire so far (for fault injection).
    bytes_received: u64,
    /// Status reports until WCO and Ov are included again.
    wco_countdown: u32,
    ov_countdown: u32,
    /// `$n=value` writes: kept across soft resets, as Grbl keeps its EEPROM.
    written_settings: std::collections::BTreeMap<u32, f64>,
    /// grblHAL: the byte (CR or LF) that ended the last line, 0 once the
    /// other one of a pair has been skipped; and whether a printable byte has
    /// come since (see `hal_skips_line_end`).
    hal_eol: u8,
    hal_line_started: bool,
    /// A jog cancel is braking the machine (grbl model).
    jog_cancel: bool,
    /// Work offsets, stored positions, startup lines, probe, pins, ...
    proto: Protocol,
    /// Laser S (before override) while the machine stands still, and the line
    /// that set it (see "The laser standing still").
    rest_s: f64,
    rest_line: u64,
    /// Time of the last knot (-inf before the first), also once taken.
    last_knot_t: f64,
    /// Until when a status report is being formatted (see `REPORT_FORMAT_S`).
    report_busy_until: f64,
    /// Timed model: a hold braking the program clock, or a resume ramping it up.
    ramp: Option<hold::Ramp>,
    /// Where the machine's zero is since a hardware reset (it restarts
    /// counting where it stood).
    power_up_shift: Vec<f64>,
    /// The coolant outputs (flood, mist): M7/M8/M9 switch them only once
    /// motion has stopped (Grbl's coolant sync), `A:` reports them.
    coolant_out: [bool; 2],
}

const EPS_POS: f64 = 1e-9;
/// Time the link must stay silent (no byte received, no line answered) before
/// queued blocks start even though the queue holds no rest point (a stream
/// that never comes to rest). Long enough that a sender's scheduling hiccup on
/// a busy host is not mistaken for the end of the stream.
pub const LINK_SILENCE_START: f64 = 0.1;

impl Controller {
    pub fn new(config: SimConfig) -> Controller {
        let cfg = sanitize(config);
        let n = cfg.axes.len();
        let proto = Protocol::new(&cfg);
        let mut c = Controller {
            cfg,
            now: 0.0,
            out: Vec::new(),
            rx: VecDeque::new(),
            rx_lines: 0,
            carry: None,
            pending: None,
            planner: VecDeque::new(),
            exec: None,
            pos: vec![0.0; n],
            gc_pos: vec![0.0; n],
            g92: vec![0.0; n],
            modal: Modal::default(),
            hold: false,
            door: false,
            door_open: false,
            alarm: false,
            critical: false,
            ok_after_reset: false,
            check_mode: false,
            sleep: false,
            ovr_feed: 100,
            ovr_rapid: 100,
            ovr_spindle: 100,
            line_count: 0,
            knots: Vec::new(),
            stats: SimStats::default(),
            starve_since: None,
            starve_acc: 0.0,
            last_rx_t: 0.0,
            last_room_t: 0.0,
            longest_line: 0,
            bytes_received: 0,
            wco_countdown: 0,
            ov_countdown: 1,
            written_settings: std::collections::BTreeMap::new(),
            hal_eol: 0,
            hal_line_started: false,
            jog_cancel: false,
            proto,
            rest_s: 0.0,
            rest_line: 0,
            last_knot_t: f64::NEG_INFINITY,
            report_busy_until: f64::NEG_INFINITY,
            ramp: None,
            power_up_shift: vec![0.0; n],
            coolant_out: [false; 2],
        };
        for (n, v) in c.cfg.settings.clone() {
            let _ = c.write_setting(n, v);
        }
        let banner = c.banner();
        c.out.extend_from_slice(format!("\r\n{banner}\r\n").as_bytes());
        c
    }

    fn banner(&self) -> &'static str {
        match self.cfg.flavor {
            Flavor::Grbl => BANNER,
            Flavor::Grblhal => BANNER_HAL,
        }
    }

    /// An empty line buffer of the firmware's size.
    fn line_builder(&self) -> LineBuilder {
        LineBuilder::with_max(self.max_line())
    }

    /// The longest line (cleaned, without its terminator) the flavor takes.
    fn max_line(&self) -> usize {
        match self.cfg.flavor {
            Flavor::Grbl => crate::gcode::MAX_LINE,
            Flavor::Grblhal => crate::gcode::MAX_LINE_HAL,
        }
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Time of the last `advance`/`receive`.
    pub fn now(&self) -> f64 {
        self.now
    }

    pub fn stats(&self) -> SimStats {
        self.stats.clone()
    }

    pub fn take_output(&mut self) -> Vec<u8> {
        let out = std::mem::take(&mut self.out);
        if self.cfg.faults.mute_from_line.is_some_and(|n| self.line_count >= n) {
            return Vec::new();
        }
        out
    }

    pub fn take_knots(&mut self) -> Vec<Knot> {
        std::mem::take(&mut self.knots)
    }

    pub fn state(&self) -> MachineState {
        if self.sleep {
            MachineState::Sleep
        } else if self.alarm {
            MachineState::Alarm
        } else if self.door {
            // 2: stopping, 1: stopped with the door open, 0: closed, ready to resume.
            MachineState::Door(if self.moving() { 2 } else if self.door_open { 1 } else { 0 })
        } else if self.hold {
            MachineState::Hold(if self.moving() { 1 } else { 0 })
        } else if self.check_mode {
            MachineState::Check
        } else if self.exec.as_ref().is_some_and(|e| e.block.homing) {
            MachineState::Home
        } else if self.jogging() {
            MachineState::Jog
        } else if self.exec.is_some() {
            MachineState::Run
        } else {
            MachineState::Idle
        }
    }

    /// Machine position now (interpolated inside the executing block).
    pub fn position(&self) -> Vec<f64> {
        match &self.exec {
            Some(e) => self.on_ramp().map_or_else(|| interpolate(e, self.now), |r| r.0),
            None => self.pos.clone(),
        }
    }

    /// Laser S in effect now, after override: the running block's, or what
    /// the laser holds while the machine stands still (0 when off).
    pub fn laser_power(&self) -> f64 {
        match self.exec.as_ref().filter(|e| e.running) {
            Some(e) => e.power,
            None => self.rest_power(),
        }
    }

    /// Coolant actually on (flood M8 or mist M7: a laser's air assist), as
    /// the status report's `A:` shows it: a reset, M9 or M2 turns it off, a
    /// feed hold does not, a door or sleep does for as long as they last.
    pub fn coolant_on(&self) -> bool {
        self.accessories().is_some_and(|a| a.contains(['F', 'M']))
    }

    /// A segment of motion is running.
    fn moving(&self) -> bool {
        self.exec.as_ref().is_some_and(|e| e.running)
    }

    /// Earliest time at which `advance` has work to do without new input.
    pub fn next_event(&self) -> Option<f64> {
        let a = self.exec.as_ref().filter(|e| e.running).map(|e| e.end_t);
        // A hold stops a dwell's clock.
        let b = self.pending.as_ref().and_then(|p| p.dwell_until).filter(|_| !self.hold);
        // Blocks waiting for a stop point start when the link falls silent.
        let c = (self.exec.is_none() && !self.hold && !self.alarm && !self.planner.is_empty())
            .then(|| (self.link_quiet_since() + LINK_SILENCE_START).max(self.now));
        [a, b, c].into_iter().flatten().reduce(f64::min)
    }

    /// Runs motion, parser and planner up to `now`. Earlier times are ignored.
    pub fn advance(&mut self, now: f64) {
        let now = if now.is_finite() { now.max(self.now) } else { self.now };
        loop {
            self.process();
            match self.next_event() {
                Some(t) if t <= now => {
                    self.now = t.max(self.now);
                    if self.exec.as_ref().is_some_and(|e| e.running && e.end_t <= self.now) {
                        self.finish_segment();
                    }
                }
                _ => break,
            }
        }
        self.now = now;
    }

    fn send(&mut self, s: &str) {
        self.out.extend_from_slice(s.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    fn send_error(&mut self, code: u16) {
        self.stats.errors_sent += 1;
        self.send(&format!("error:{code}"));
    }

    fn jogging(&self) -> bool {
        self.exec.as_ref().is_some_and(|e| e.block.jog) || self.planner.iter().any(|b| b.jog)
    }

    fn axis_index(&self, letter: char) -> Option<usize> {
        self.cfg.axes.iter().position(|a| a.letter == letter)
    }
}

