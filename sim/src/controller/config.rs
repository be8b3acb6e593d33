//! How the simulated machine is configured: axes, buffers, firmware flavour,
//! motion model, injected faults and the settings in EEPROM at power-up.
//! Separate from the state machine because it is plain data that tools and
//! tests build and (de)serialize; `sanitize` makes any config usable.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

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
    /// `$11` at power-up: the junction deviation (mm) of the `grbl` motion
    /// model's corners (Grbl's default 0.010).
    #[serde(default = "default_junction_deviation")]
    pub junction_deviation: f64,
}

/// Grbl 1.1's default `$11` (mm).
pub const JUNCTION_DEVIATION: f64 = 0.010;

fn default_junction_deviation() -> f64 {
    JUNCTION_DEVIATION
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
            junction_deviation: JUNCTION_DEVIATION,
        }
    }
}

/// Makes any config usable rather than failing later: the flavour's axes, positive
/// finite rates, min <= max, buffers of at least a few bytes/one block.
pub(super) fn sanitize(mut c: SimConfig) -> SimConfig {
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
    if !(c.junction_deviation.is_finite() && c.junction_deviation >= 0.0) {
        c.junction_deviation = JUNCTION_DEVIATION;
    }
    c.rx_buffer = c.rx_buffer.max(2);
    c.planner_blocks = c.planner_blocks.max(1);
    if !(c.laser_max_s.is_finite() && c.laser_max_s > 0.0) {
        c.laser_max_s = 1000.0;
    }
    c
}
