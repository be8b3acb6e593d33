//! The GRBL 1.1 controller as a pure state machine driven by an external clock.
//!
//! Time is an `f64` in seconds handed in by the driver (`receive`, `advance`),
//! so the same machine runs in virtual time (tests, in-process simulation) and
//! in wall-clock time (the pty driver). Nothing in here sleeps or reads a clock.
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
//! # Lines and buffers
//! A line's bytes stay in RX until the line has been fully handled; a motion
//! line waits there while the planner is full (its `ok` is delayed), a sync
//! command (G4, M2/M30, M0, spindle/coolant/offset changes) waits until motion
//! has stopped.
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
//! the last byte received or, when the receive buffer had less room than a
//! line, from the `ok` that made room, whichever is later. A sender counting
//! characters waits for that `ok` (a `G4` holds its bytes and those behind it
//! until its `ok`, after the dwell), so a link quiet then is not the stream's end.
//! A feed hold (or a door) slows the program clock to a stop along the path,
//! laser off, within half of every axis' acceleration and jerk limit, then
//! reads `Hold:0`; `~` is taken only then, and ramps the clock up again.
//!
//! # The laser standing still
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
//!
//! # Starvation
//! `starved_s` counts the time the machine stood still with an empty planner
//! between two motion blocks, excluding dwells and feed holds. Idle time after
//! the last block is only counted once another block starts after it.

use std::collections::VecDeque;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::gcode::LineBuilder;
use crate::planner::{self, Kinematics, Planned, SegmentInput};
use crate::wire::{MachineState, StatusReport, BANNER, BANNER_HAL};

mod hold;
mod parser;
mod system;

use system::{Protocol, StepOutcome};

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct AxisConfig {
    pub letter: char,
    pub min: f64,
    pub max: f64,
    /// mm/s
    pub max_velocity: f64,
    /// mm/s²
    pub max_acceleration: f64,
    /// mm/s³
    pub max_jerk: f64,
}

impl AxisConfig {
    /// An axis with modest desktop-laser defaults (0..300 mm, 100 mm/s).
    pub fn new(letter: char) -> AxisConfig {
        AxisConfig {
            letter: letter.to_ascii_uppercase(),
            min: 0.0,
            max: 300.0,
            max_velocity: 100.0,
            max_acceleration: 1000.0,
            max_jerk: 20000.0,
        }
    }
}

#[derive(Debug, Clone, Default, Serialize, Deserialize, JsonSchema)]
pub struct Faults {
    /// The n-th received line (1-based, empty lines included) answers
    /// `error:20` and is not executed.
    pub error_on_line: Option<u64>,
    /// The n-th line byte arriving on the wire (1-based; realtime bytes, which
    /// never enter the receive buffer, are not counted) is lost, as on a noisy
    /// line or an overrun UART.
    #[serde(default)]
    pub drop_byte: Option<u64>,
    /// The n-th line byte arriving on the wire is garbled (arrives as `#`).
    #[serde(default)]
    pub corrupt_byte: Option<u64>,
    /// From the n-th received line on, the controller transmits nothing (a dead
    /// TX line or a wedged USB bridge); it still receives and moves.
    #[serde(default)]
    pub mute_from_line: Option<u64>,
    /// The controller reboots on receiving the n-th line (a brown-out, the
    /// reset button): banner only, everything queued lost, the power-up
    /// state (EEPROM kept, zero where the machine stands); the lines sent
    /// after it run from there.
    #[serde(default)]
    pub reset_at_line: Option<u64>,
    /// A hard limit switch (the first axis') trips on receiving the n-th
    /// line: `ALARM:1`. It stays pressed (`Pn:`) until the machine next moves
    /// or homes.
    #[serde(default)]
    pub limit_alarm_at_line: Option<u64>,
    /// The link itself closes (pseudo-terminal closed, USB unplugged) once the
    /// controller has received n lines. Acted on by the drivers, not here.
    #[serde(default)]
    pub close_link_at_line: Option<u64>,
    /// Work for the probe this many mm along every probing move (G38.x):
    /// toward it the probe closes there, away from it it opens there, and the
    /// move stops. None: the probe never changes state (G38.2/.4 then fail).
    #[serde(default)]
    pub probe_contact_mm: Option<f64>,
    /// Homing finds no switch: `$H` ends in `ALARM:9` (the search is cut
    /// short at the home position, so the machine stays within travel).
    #[serde(default)]
    pub homing_switch_missing: bool,
    /// The homing switch stays pressed after the pull-off: `ALARM:8`.
    #[serde(default)]
    pub homing_pull_off_fails: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SimConfig {
    /// Grbl: X, Y, Z (a missing one is added); grblHAL: 1..=8 axes.
    pub axes: Vec<AxisConfig>,
    pub rx_buffer: usize,
    pub planner_blocks: usize,
    /// `$30`: S value for full laser power.
    pub laser_max_s: f64,
    /// How the controller executes its blocks.
    #[serde(default)]
    pub motion: MotionModel,
    /// Which firmware the controller answers as.
    #[serde(default)]
    pub flavor: Flavor,
    #[serde(default)]
    pub faults: Faults,
    /// Settings in the controller's EEPROM at power-up, `$n=value` as its
    /// owner wrote them (e.g. `(10, 3.0)`: reports with `Bf:`); one Grbl
    /// would refuse is left out.
    #[serde(default)]
    pub settings: Vec<(u32, f64)>,
}

/// The firmware the simulated controller is: its banner, build info, line
/// length, realtime aliases, axes and the receive buffer it reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Flavor {
    /// Grbl 1.1h as built from its source with a safety door input: always
    /// the axes X, Y and Z (a Z the config lacks is added, and nothing uses
    /// it), no other axis, no line numbers (`Ln:`), no mist coolant (M7).
    #[default]
    Grbl,
    /// grblHAL: 256-character lines, CR LF as one line end, `0x80`–`0x82`
    /// and `0x87`, up to 8 axes of any letters, G59.1–G59.3, line numbers,
    /// mist coolant, `[AXS:]`, `[NEWOPT:]`, `[FIRMWARE:]` and driver lines in
    /// `$I`; set `rx_buffer` (1024) and `planner_blocks` (100) to match a board.
    Grblhal,
}

/// Grbl 1.1h's axes, always all three.
pub const GRBL_AXES: [char; 3] = ['X', 'Y', 'Z'];

/// How planner blocks turn into motion.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum MotionModel {
    /// Every block runs at constant velocity in exactly its programmed time (a
    /// controller that keeps G93 timing, as laserd's programs assume); the limit
    /// checker then judges what the sender planned.
    #[default]
    Timed,
    /// Grbl 1.1's planner: trapezoidal speed profiles at each block's
    /// acceleration, junction speeds from the junction deviation (`$11`),
    /// the queue always planned to stop at its end, feed hold decelerating.
    Grbl,
}

/// `$100`…: steps per mm of every axis unless set otherwise.
pub const STEPS_PER_MM: f64 = 250.0;

impl SimConfig {
    /// Why this config cannot be the firmware it names, if it cannot: Grbl
    /// 1.1h has the axes X, Y and Z and no other (grblHAL has up to 8).
    pub fn flavor_error(&self) -> Option<String> {
        let foreign: String = self.axes.iter().map(|a| a.letter.to_ascii_uppercase()).filter(|l| !GRBL_AXES.contains(l)).collect();
        match self.flavor {
            Flavor::Grbl if !foreign.is_empty() => Some(format!(
                "Grbl 1.1h has only the axes X, Y and Z, not {foreign}: use the grblhal flavor for a machine with other axes"
            )),
            Flavor::Grblhal if self.axes.len() > 8 => Some(format!("grblHAL has at most 8 axes, not {}", self.axes.len())),
            _ => None,
        }
    }

    /// The longest step of any axis (mm), from the steps per mm in force at
    /// power-up.
    pub fn step_mm(&self) -> f64 {
        (0..self.axes.len() as u32)
            .map(|i| self.settings.iter().rev().find(|(n, v)| *n == 100 + i && v.is_finite() && *v > 0.0).map_or(STEPS_PER_MM, |(_, v)| *v))
            .map(|steps| 1.0 / steps)
            .fold(0.0, f64::max)
    }

    /// Default config with the given axis letters, e.g. `"XYUV"`.
    pub fn with_axes(letters: &str) -> SimConfig {
        SimConfig {
            axes: letters.chars().filter(|c| c.is_ascii_alphabetic()).map(AxisConfig::new).collect(),
            ..SimConfig::default()
        }
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            axes: vec![AxisConfig::new('X'), AxisConfig::new('Y')],
            rx_buffer: 128,
            planner_blocks: 15,
            laser_max_s: 1000.0,
            motion: MotionModel::default(),
            flavor: Flavor::default(),
            faults: Faults::default(),
            settings: Vec::new(),
        }
    }
}

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
    /// line: a sender waiting for room may send again from then.
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
}

const EPS_POS: f64 = 1e-9;
/// Time the link must stay silent (no byte received, no line answered) before
/// queued blocks start even though the queue holds no rest point (a stream
/// that never comes to rest). Long enough that a sender's scheduling hiccup on
/// a busy host is not mistaken for the end of the stream.
pub const LINK_SILENCE_START: f64 = 0.1;
/// How long an AVR takes to format a status report (some hundred
/// microseconds of float printing; taken as 1 ms). Two `?` closer together
/// than that get one report from Grbl 1.1h.
const REPORT_FORMAT_S: f64 = 0.001;

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
        LineBuilder::with_max(match self.cfg.flavor {
            Flavor::Grbl => crate::gcode::MAX_LINE,
            Flavor::Grblhal => crate::gcode::MAX_LINE_HAL,
        })
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

    /// Laser S while the machine stands still, after override: 0 in a door,
    /// an alarm, sleep, check mode or with the spindle stop override, and in
    /// laser mode in a hold. (Outside laser mode the output is a spindle's: it
    /// runs at S under M3 and M4, in a hold too, as Grbl's `FS:` shows.)
    fn rest_power(&self) -> f64 {
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
    fn push_knot(&mut self, mut knot: Knot) {
        self.last_knot_t = knot.t;
        if self.power_up_shift.iter().any(|s| *s != 0.0) {
            knot.pos.iter_mut().zip(&self.power_up_shift).for_each(|(p, s)| *p += s);
        }
        self.knots.push(knot);
    }

    /// Runs `f`, then records in knots a change it made to the laser at rest.
    /// Every way in (a realtime byte, lines run at an instant, the door
    /// switch) goes through here, so resets and alarms need not.
    fn watching_rest_laser<R>(&mut self, f: impl FnOnce(&mut Controller) -> R) -> R {
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
    fn hal_skips_line_end(&mut self, byte: u8) -> bool {
        if byte != b'\n' && byte != b'\r' {
            self.hal_line_started |= byte > b' ';
            return false;
        }
        let skip = !self.hal_line_started && self.hal_eol != 0 && self.hal_eol != byte;
        self.hal_eol = if skip { 0 } else { byte };
        self.hal_line_started = false;
        skip
    }

    // ----- output helpers -----

    fn send(&mut self, s: &str) {
        self.out.extend_from_slice(s.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    fn send_error(&mut self, code: u16) {
        self.stats.errors_sent += 1;
        self.send(&format!("error:{code}"));
    }

    /// Bytes the receive buffer holds: Grbl's ring has a slot more than its
    /// size; grblHAL's keeps one unused, so a 1024-byte one holds 1023.
    fn rx_capacity(&self) -> usize {
        match self.cfg.flavor {
            Flavor::Grbl => self.cfg.rx_buffer,
            Flavor::Grblhal => self.cfg.rx_buffer.saturating_sub(1),
        }
    }

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
        let segments = |secs: f64| (secs / planner::SEGMENT_S - 1e-9).ceil().max(1.0) as usize;
        let mut used = segments(e.end_t - self.now);
        let mut prepared = 0;
        let blocks = std::iter::once(&e.block).chain(self.planner.iter());
        if self.cfg.motion == MotionModel::Timed {
            // Each block at its own constant speed.
            for (i, b) in blocks.enumerate() {
                if i > 0 {
                    used += segments(self.block_time(b));
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
                used += segments(seg.duration);
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

    fn status_report(&mut self) -> StatusReport {
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
    fn full_status_report(&mut self) -> StatusReport {
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

    // ----- realtime -----

    fn realtime(&mut self, b: u8) {
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

    fn soft_reset(&mut self) {
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
    fn hardware_reset(&mut self) {
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

    /// Stops the executing block where it is (reset or alarm), with a knot.
    fn stop_motion_now(&mut self) {
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

    // ----- starvation bookkeeping -----

    fn mark_idle(&mut self, t: f64) {
        if self.stats.first_motion_t.is_some() {
            self.starve_since = Some(t);
        }
    }

    fn pause_starvation(&mut self) {
        if let Some(s) = self.starve_since.take() {
            self.starve_acc += (self.now - s).max(0.0);
        }
    }

    fn reset_starvation(&mut self) {
        self.starve_since = None;
        self.starve_acc = 0.0;
    }

    // ----- motion -----

    fn planner_full(&self) -> bool {
        self.planner.len() + usize::from(self.exec.is_some()) >= self.cfg.planner_blocks
    }

    /// Starts the next queued block at `t`, entering it at `entry_speed` (grbl
    /// model; the timed model runs every block at its own constant speed).
    fn start_next(&mut self, t: f64, from_rest: bool, entry_speed: f64) {
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
    fn block_power(&self, b: &Block) -> f64 {
        (b.power * self.ovr_spindle as f64 / 100.0).min(self.cfg.laser_max_s)
    }

    /// A block's speed now: the programmed one scaled by its override (feed,
    /// or rapid for G0; none for jogs and homing), never above what the axes allow.
    fn nominal_speed(&self, b: &Block) -> f64 {
        let dur = self.block_time(b);
        if dur > 0.0 { b.kin.length / dur } else { b.kin.max_speed }
    }

    /// A block's duration at constant speed, after its override.
    fn block_time(&self, b: &Block) -> f64 {
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
    fn next_segment(&mut self, t: f64) {
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
    fn finish_segment(&mut self) {
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
    fn replan_now(&mut self) {
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
        } else if !self.planner.is_empty() && self.may_start() {
            self.start_next(t, false, 0.0);
        } else {
            self.mark_idle(t);
        }
    }

    fn auto_start(&mut self) {
        if self.exec.is_none() && !self.hold && !self.alarm && !self.planner.is_empty() && self.may_start() {
            self.start_next(self.now, true, 0.0);
        }
    }

    /// Geometry, axis limits and junction speed of a block entering the planner
    /// behind what is queued. A block that finds the machine idle and the
    /// planner empty starts from rest (Grbl's rule).
    fn plan_block(&self, b: &mut Block) {
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
        self.written_settings.get(&11).copied().unwrap_or(0.010)
    }

    /// Whether the machine may stop after `b` (coming after what is queued), or
    /// start into it from rest, within half of every axis' acceleration and jerk
    /// limit, judged as the limit checker would: a stop from velocity v after a
    /// block of duration T shows as an acceleration v/T and a jerk of about v/T².
    /// The first and last blocks of a planned rest-to-rest move pass; a block in
    /// the middle of a fast move does not.
    fn is_gentle(&self, b: &Block) -> bool {
        let start = match (self.planner.back(), &self.exec) {
            (Some(last), _) => &last.target,
            (None, Some(e)) => &e.block.target,
            (None, None) => &self.pos,
        };
        let t = b.duration;
        if t <= 0.0 {
            return true;
        }
        self.cfg.axes.iter().enumerate().all(|(i, ax)| {
            let v = (b.target[i] - start[i]).abs() / t;
            v / t <= 0.5 * ax.max_acceleration && v / (t * t) <= 0.5 * ax.max_jerk
        })
    }

    /// Grbl plans every queue to come to a stop at its end. Here blocks run at
    /// constant velocity, so the equivalent rule is: run the next block only when
    /// the queue holds a rest point after it (two gentle blocks in a row: the
    /// machine can stop between them and start again; or the end of the
    /// program's motion, where a line without motion follows). Otherwise wait for more
    /// blocks, unless the planner is full, the pending line needs motion to end
    /// (M2, M5, G4, ...), or the link has fallen silent (a stream that never
    /// comes to rest must still run).
    fn may_start(&self) -> bool {
        if self.cfg.motion == MotionModel::Grbl {
            // Grbl starts a cycle as soon as it has parsed everything received,
            // which the simulator does the moment a line arrives.
            return true;
        }
        let queued: Vec<bool> = self.planner.iter().map(|b| b.gentle).collect();
        queued.windows(2).any(|w| w[0] && w[1])
            || self.planner.iter().any(|b| b.ends_sequence)
            || self.planner_full()
            || self.pending.as_ref().is_some_and(|p| !matches!(p.steps.front(), None | Some(Step::Queue(_))))
            || self.now - self.link_quiet_since() >= LINK_SILENCE_START - 1e-9
    }

    /// Since when the link has been silent: the last byte received, or the
    /// last answer that made room in a receive buffer too full for another
    /// line, whichever came later. A sender counting characters that finds
    /// the buffer full waits for an `ok` (a `G4` keeps its bytes, and those of
    /// the lines behind it, there until its `ok`, after the dwell), so a link
    /// quiet while the controller holds its buffer is waiting, not done. Were
    /// this counted from the last byte only, the few blocks that fit behind a
    /// dwell would start at its end without a rest point queued after them,
    /// and the controller, fed a line at a time, would stop inside the cut.
    fn link_quiet_since(&self) -> f64 {
        self.last_rx_t.max(self.last_room_t)
    }

    // ----- line handling -----

    fn process(&mut self) {
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
        // (Room for another line of the longest yet: the sender was not waiting.)
        if self.rx_capacity().saturating_sub(self.rx.len() + taken) < self.longest_line {
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

    fn jogging(&self) -> bool {
        self.exec.as_ref().is_some_and(|e| e.block.jog) || self.planner.iter().any(|b| b.jog)
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
    fn end_jog_cancel(&mut self) {
        if let Some(e) = self.exec.take() {
            self.pos = e.end_pos;
        }
        self.jog_cancel = false;
        self.planner.retain(|b| !b.jog);
        self.gc_pos = self.pos.clone();
        self.mark_idle(self.now);
    }

    fn axis_index(&self, letter: char) -> Option<usize> {
        self.cfg.axes.iter().position(|a| a.letter == letter)
    }

    fn soft_limit_alarm(&mut self) {
        self.limit_alarm(2);
    }

    /// Feed hold: the machine brakes to a stop, laser off.
    fn start_hold(&mut self) {
        self.hold = true;
        self.hold_stops_laser();
        self.pause_starvation();
        self.replan_now();
        self.begin_braking();
    }

    /// A critical limit alarm: motion stops where it is, laser off, everything
    /// locked until a reset (reference §5).
    fn limit_alarm(&mut self, code: u16) {
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

}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (y - x) * (y - x)).sum::<f64>().sqrt()
}

fn interpolate(e: &Exec, t: f64) -> Vec<f64> {
    let dur = e.end_t - e.start_t;
    let f = if e.running && dur > 0.0 { ((t - e.start_t) / dur).clamp(0.0, 1.0) } else { 1.0 };
    e.start_pos.iter().zip(&e.end_pos).map(|(s, g)| s + (g - s) * f).collect()
}

/// Makes any config usable rather than failing later: the flavour's axes, positive
/// finite rates, min <= max, buffers of at least a few bytes/one block.
fn sanitize(mut c: SimConfig) -> SimConfig {
    for a in &mut c.axes {
        a.letter = a.letter.to_ascii_uppercase();
    }
    match c.flavor {
        // Exactly X, Y, Z in this order, each as configured or a default one
        // (`SimConfig::flavor_error` names any other axis; it is dropped here).
        Flavor::Grbl => {
            c.axes = GRBL_AXES
                .iter()
                .map(|l| c.axes.iter().find(|a| a.letter == *l).cloned().unwrap_or_else(|| AxisConfig::new(*l)))
                .collect()
        }
        Flavor::Grblhal => c.axes.truncate(8),
    }
    if c.axes.is_empty() {
        c.axes.push(AxisConfig::new('X'));
    }
    for a in &mut c.axes {
        if !a.min.is_finite() {
            a.min = 0.0;
        }
        if !a.max.is_finite() {
            a.max = a.min;
        }
        if a.min > a.max {
            std::mem::swap(&mut a.min, &mut a.max);
        }
        if !(a.max_velocity.is_finite() && a.max_velocity > 0.0) {
            a.max_velocity = 1.0;
        }
        if !(a.max_acceleration.is_finite() && a.max_acceleration > 0.0) {
            a.max_acceleration = 1.0;
        }
    }
    c.rx_buffer = c.rx_buffer.max(2);
    c.planner_blocks = c.planner_blocks.max(1);
    if !(c.laser_max_s.is_finite() && c.laser_max_s > 0.0) {
        c.laser_max_s = 1000.0;
    }
    c
}
