//! Machine configuration: the TOML file of `config/laserd.toml`, parsed and validated.
//!
//! Every check names the setting (`stage.max_velocity`) and the file, so an operator
//! can fix a bad value without reading code.

use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Longest pierce accepted (s): far beyond any real pierce, well inside what a
/// controller's dwell counts (Grbl 1.1 counts G4 in 50 ms steps in 16 bits).
pub const MAX_PIERCE_TIME: f64 = 60.0;

/// The default machine, shipped in the repository.
pub const DEFAULT_CONFIG_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/laserd.toml");

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MachineConfig {
    pub stage: StageConfig,
    #[serde(default)]
    pub scanner: Option<ScannerConfig>,
    pub laser: LaserConfig,
    pub serial: SerialConfig,
    #[serde(default)]
    pub import: ImportConfig,
    #[serde(default)]
    pub motion: MotionConfig,
    #[serde(default)]
    pub program: ProgramConfig,
    #[serde(default)]
    pub simulator: SimulatorConfig,
    #[serde(default)]
    pub cutting: CuttingConfig,
    #[serde(default)]
    pub galvo: GalvoConfig,
    #[serde(default)]
    pub service: ServiceConfig,
    pub default_layer: String,
    #[serde(rename = "layer")]
    pub layers: Vec<LayerConfig>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    pub travel_x: f64,
    pub travel_y: f64,
    pub max_velocity: f64,
    pub max_acceleration: f64,
    pub max_jerk: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ScannerConfig {
    pub axis_letters: [String; 2],
    pub field_x: f64,
    pub field_y: f64,
    pub usable_half_field: f64,
    /// A geometry larger than the usable field is split at field borders into
    /// pieces marked one after another (true), or fails the job (false).
    #[serde(default = "default_split_oversize")]
    pub split_oversize: bool,
    pub mark_speed: f64,
    pub jump_speed: f64,
    pub max_acceleration: f64,
    pub max_jerk: f64,
}

fn default_split_oversize() -> bool {
    true
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum LaserMode {
    M3,
    M4,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LaserConfig {
    pub max_power: f64,
    pub mode: LaserMode,
    /// Seconds the head stands still over the start of every path with the
    /// laser on before the cut begins (0: no pierce); a layer may set its own.
    #[serde(default)]
    pub pierce_time: f64,
    /// S value of the pierce; a layer may set its own. None: each layer's `power`.
    #[serde(default)]
    pub pierce_power: Option<f64>,
    /// The laser source's response times (s): it is switched on this long
    /// before a mark begins and off this long before it ends, so that it
    /// emits exactly along the mark.
    #[serde(default)]
    pub on_delay: f64,
    #[serde(default)]
    pub off_delay: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SerialConfig {
    pub port: String,
    pub baud: u32,
    pub rx_buffer: usize,
    #[serde(default = "default_status_hz")]
    pub status_hz: f64,
}

fn default_status_hz() -> f64 {
    5.0
}

/// `laserd serve`: where the control API listens, and what the service keeps.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ServiceConfig {
    /// The API's Unix socket (mode 0660, the service's group); a relative
    /// path is under the runtime directory (`/run/laserd`).
    #[serde(default = "default_socket")]
    pub socket: String,
    /// Also listen on TCP at this address (e.g. "127.0.0.1:7125"); every
    /// request must then carry `Authorization: Bearer <token>`.
    #[serde(default)]
    pub tcp: Option<String>,
    /// File holding the bearer token (required with `tcp`).
    #[serde(default)]
    pub token_file: Option<String>,
    /// Finished jobs kept with their programs and recordings; older ones are deleted.
    #[serde(default = "default_keep_jobs")]
    pub keep_jobs: usize,
    /// Folders on the machine PC from which a job may be submitted by path
    /// (`{"path": …}`), symbolic links resolved; none (the default): only uploads.
    #[serde(default)]
    pub job_folders: Vec<String>,
    /// A job still planning after this long fails (s).
    #[serde(default = "default_plan_timeout")]
    pub plan_timeout: f64,
    /// Memory a job's planning may take (MB); beyond it the job fails alone.
    #[serde(default = "default_plan_memory_mb")]
    pub plan_memory_mb: f64,
}

fn default_plan_timeout() -> f64 {
    600.0
}

fn default_plan_memory_mb() -> f64 {
    4096.0
}

fn default_socket() -> String {
    "laserd.sock".into()
}

fn default_keep_jobs() -> usize {
    100
}

impl Default for ServiceConfig {
    fn default() -> Self {
        ServiceConfig {
            socket: default_socket(),
            tcp: None,
            token_file: None,
            keep_jobs: default_keep_jobs(),
            job_folders: Vec::new(),
            plan_timeout: default_plan_timeout(),
            plan_memory_mb: default_plan_memory_mb(),
        }
    }
}

impl ServiceConfig {
    /// The service's own limits, each in a range a machine PC can keep.
    fn validate(&self) -> std::result::Result<(), String> {
        for (name, v, lo, hi, unit) in [
            ("service.plan_timeout", self.plan_timeout, 1.0, 86400.0, "s"),
            ("service.plan_memory_mb", self.plan_memory_mb, 256.0, 1048576.0, "MB"),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("{name}: must be between {lo} and {hi} {unit}, got {v}"));
            }
        }
        for folder in &self.job_folders {
            if !std::path::Path::new(folder).is_absolute() {
                return Err(format!("service.job_folders: {folder:?} is not an absolute path"));
            }
        }
        Ok(())
    }

    /// The bearer token for TCP clients, from `token_file`.
    pub fn token(&self) -> Result<String> {
        let file = self.token_file.as_deref().ok_or_else(|| Error::Config("[service] tcp needs token_file: a TCP API without a token is refused".into()))?;
        let token = std::fs::read_to_string(file).map_err(|e| Error::Config(format!("[service] token_file = {file:?}: cannot read: {e}")))?;
        let token = token.trim().to_string();
        if token.len() < 16 {
            return Err(Error::Config(format!("[service] token_file = {file:?}: the token must be at least 16 characters")));
        }
        Ok(token)
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ImportConfig {
    pub tolerance: f64,
    pub svg_dpi: f64,
    /// Largest job file read (MB): by `plan` and `dry-run`, uploaded to the
    /// service or submitted to it by path.
    #[serde(default = "default_max_file_mb")]
    pub max_file_mb: f64,
}

fn default_max_file_mb() -> f64 {
    128.0
}

impl Default for ImportConfig {
    fn default() -> Self {
        ImportConfig { tolerance: 0.01, svg_dpi: 96.0, max_file_mb: default_max_file_mb() }
    }
}

impl ImportConfig {
    /// The largest job file read, in bytes.
    pub fn max_file_bytes(&self) -> usize {
        (self.max_file_mb * 1e6) as usize
    }
}

/// The cutting planner (`--planner ecp`).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CuttingConfig {
    /// What a pierce costs, in mm of air move: a contour is left and finished
    /// later only where that saves more air than this.
    #[serde(default = "default_pierce_cost")]
    pub pierce_cost: f64,
    /// Boundaries of two parts closer than this (mm) are one common cut, cut once.
    #[serde(default = "default_common_cut_tolerance")]
    pub common_cut_tolerance: f64,
    /// A turn sharper than this (degrees) is a corner, where a cut may start.
    #[serde(default = "default_corner_angle")]
    pub corner_angle: f64,
    /// How long the search may run (s); `--time-limit` overrides it. Small
    /// jobs finish earlier, once the search long finds nothing better.
    #[serde(default = "default_cutting_time_limit")]
    pub time_limit: f64,
    /// "ils" (iterated local search, the default) or "tabu" (seed 001's).
    #[serde(default, with = "search_kind")]
    #[schemars(with = "String")]
    pub search: crate::plan::ecp::SearchKind,
}

/// The galvo planners (`--planner hha`, `--planner hga`).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct GalvoConfig {
    /// Weight of seed 003's directionality penalty (Eq. 7) with several fields.
    #[serde(default = "default_direction_weight")]
    pub direction_weight: f64,
    /// The same when the job fits one field.
    #[serde(default = "default_direction_weight_single_field")]
    pub direction_weight_single_field: f64,
    /// How long the HGA may run (s); `--time-limit` overrides it.
    #[serde(default = "default_galvo_time_limit")]
    pub time_limit: f64,
    /// Seed of the planners' random choices; `--seed` overrides it.
    #[serde(default = "default_galvo_seed")]
    pub seed: u64,
}

fn default_direction_weight() -> f64 {
    0.5
}
fn default_direction_weight_single_field() -> f64 {
    0.1
}
fn default_galvo_time_limit() -> f64 {
    30.0
}
fn default_galvo_seed() -> u64 {
    1
}

impl Default for GalvoConfig {
    fn default() -> Self {
        GalvoConfig {
            direction_weight: default_direction_weight(),
            direction_weight_single_field: default_direction_weight_single_field(),
            time_limit: default_galvo_time_limit(),
            seed: default_galvo_seed(),
        }
    }
}

fn default_pierce_cost() -> f64 {
    10.0
}
fn default_common_cut_tolerance() -> f64 {
    0.01
}
fn default_corner_angle() -> f64 {
    30.0
}
fn default_cutting_time_limit() -> f64 {
    10.0
}

impl Default for CuttingConfig {
    fn default() -> Self {
        CuttingConfig {
            pierce_cost: default_pierce_cost(),
            common_cut_tolerance: default_common_cut_tolerance(),
            corner_angle: default_corner_angle(),
            time_limit: default_cutting_time_limit(),
            search: Default::default(),
        }
    }
}

mod search_kind {
    use crate::plan::ecp::SearchKind;
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(kind: &SearchKind, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(kind.name())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<SearchKind, D::Error> {
        let name = String::deserialize(d)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MotionConfig {
    pub limit_margin: f64,
    /// How far a blended corner may cut inside the programmed corner (mm).
    #[serde(default = "default_corner_tolerance")]
    pub corner_tolerance: f64,
    /// Vertices closer than this to the line through their neighbours are
    /// dropped before planning (mm).
    #[serde(default = "default_line_tolerance")]
    pub line_tolerance: f64,
    /// Share of the stage's limits its on-the-fly moves use; the rest is
    /// headroom for the rounding of coordinates in the program.
    #[serde(default = "default_stage_share")]
    pub stage_share: f64,
}

fn default_corner_tolerance() -> f64 {
    0.01
}

fn default_line_tolerance() -> f64 {
    0.001
}

fn default_stage_share() -> f64 {
    0.8
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            limit_margin: 0.98,
            corner_tolerance: default_corner_tolerance(),
            line_tolerance: default_line_tolerance(),
            stage_share: default_stage_share(),
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ProgramConfig {
    pub tolerance: f64,
    /// The same for laser-off moves, where only the machine's own limits matter.
    #[serde(default = "default_jump_tolerance")]
    pub jump_tolerance: f64,
    pub decimals: usize,
    /// Decimal places of the scanner's coordinates (its moves are short and
    /// its limits high: micrometres are finer than a galvo resolves).
    #[serde(default = "default_scanner_decimals")]
    pub scanner_decimals: usize,
}

fn default_scanner_decimals() -> usize {
    4
}

fn default_jump_tolerance() -> f64 {
    0.5
}

impl Default for ProgramConfig {
    fn default() -> Self {
        ProgramConfig { tolerance: 0.01, jump_tolerance: default_jump_tolerance(), decimals: 6, scanner_decimals: default_scanner_decimals() }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SimulatorConfig {
    pub planner_blocks: usize,
    /// How the simulated controller executes blocks: `timed` (each in its
    /// programmed time) or `grbl` (Grbl 1.1's trapezoids and junction speeds).
    #[serde(default)]
    pub motion: laserd_sim::controller::MotionModel,
    /// Which firmware the simulated controller answers as: `grbl` or `grblhal`.
    #[serde(default)]
    pub flavor: laserd_sim::controller::Flavor,
}

impl Default for SimulatorConfig {
    fn default() -> Self {
        SimulatorConfig { planner_blocks: 15, motion: Default::default(), flavor: Default::default() }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LayerConfig {
    pub name: String,
    #[serde(default)]
    pub stroke: Option<String>,
    #[serde(default)]
    pub id: Option<String>,
    pub speed: f64,
    pub power: f64,
    #[serde(default = "one")]
    pub passes: u32,
    /// The layer's pierce time (s); None: `laser.pierce_time`.
    #[serde(default)]
    pub pierce_time: Option<f64>,
    /// The layer's pierce power (S); None: `laser.pierce_power`, else `power`.
    #[serde(default)]
    pub pierce_power: Option<f64>,
}

fn one() -> u32 {
    1
}

/// What happens at the entry of every path of a layer before it is cut: the head
/// stands still there with the laser on at `power` for `time` seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pierce {
    pub power: f64,
    pub time: f64,
}

impl Pierce {
    /// Whether there is a pierce at all (a time of 0 means none).
    pub fn active(&self) -> bool {
        self.time > 0.0
    }
}

/// Kinematic limits of one group of axes, per axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Limits {
    pub velocity: f64,
    pub acceleration: f64,
    pub jerk: f64,
}

impl Limits {
    pub fn scaled(self, factor: f64) -> Limits {
        Limits { velocity: self.velocity * factor, acceleration: self.acceleration * factor, jerk: self.jerk * factor }
    }
}

impl MachineConfig {
    /// Reads and validates a config file; `None` reads the shipped default machine.
    pub fn load(path: Option<&Path>) -> Result<MachineConfig> {
        Self::load_with_text(path).map(|(config, _)| config)
    }

    /// The config and its text as read (the service hands the same text to
    /// its planning processes).
    pub fn load_with_text(path: Option<&Path>) -> Result<(MachineConfig, String)> {
        let path: PathBuf = path.map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from(DEFAULT_CONFIG_PATH));
        let text = std::fs::read_to_string(&path)
            .map_err(|e| Error::Config(format!("{}: cannot read: {e}", path.display())))?;
        Ok((Self::parse(&text, &path.display().to_string())?, text))
    }

    /// Parses and validates config text; `origin` names the file in error messages.
    pub fn parse(text: &str, origin: &str) -> Result<MachineConfig> {
        let config: MachineConfig = toml::from_str(text).map_err(|e| {
            // toml's message spans several lines with a source excerpt; keep the first
            // line and the position so the error stays one line.
            let mut msg = e.message().to_string();
            if let Some(span) = e.span() {
                let line = text[..span.start.min(text.len())].lines().count().max(1);
                msg = format!("line {line}: {msg}");
            }
            Error::Config(format!("{origin}: {msg}"))
        })?;
        config.validate().map_err(|e| Error::Config(format!("{origin}: {e}")))?;
        Ok(config)
    }

    fn validate(&self) -> std::result::Result<(), String> {
        fn positive(name: &str, v: f64) -> std::result::Result<(), String> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{name}: must be a positive number, got {v}"))
            }
        }
        let s = &self.stage;
        positive("stage.travel_x", s.travel_x)?;
        positive("stage.travel_y", s.travel_y)?;
        positive("stage.max_velocity", s.max_velocity)?;
        positive("stage.max_acceleration", s.max_acceleration)?;
        positive("stage.max_jerk", s.max_jerk)?;
        if let Some(sc) = &self.scanner {
            positive("scanner.field_x", sc.field_x)?;
            positive("scanner.field_y", sc.field_y)?;
            positive("scanner.usable_half_field", sc.usable_half_field)?;
            if sc.usable_half_field > sc.field_x.min(sc.field_y) / 2.0 {
                return Err(format!(
                    "scanner.usable_half_field: {} exceeds half the field ({})",
                    sc.usable_half_field,
                    sc.field_x.min(sc.field_y) / 2.0
                ));
            }
            positive("scanner.mark_speed", sc.mark_speed)?;
            positive("scanner.jump_speed", sc.jump_speed)?;
            if sc.mark_speed > sc.jump_speed {
                return Err("scanner.mark_speed: must not exceed scanner.jump_speed".into());
            }
            positive("scanner.max_acceleration", sc.max_acceleration)?;
            positive("scanner.max_jerk", sc.max_jerk)?;
            for (i, l) in sc.axis_letters.iter().enumerate() {
                let ok = l.len() == 1 && "ZABCUVW".contains(l.as_str());
                if !ok {
                    return Err(format!("scanner.axis_letters[{i}]: '{l}' is not one of Z A B C U V W"));
                }
            }
            if sc.axis_letters[0] == sc.axis_letters[1] {
                return Err("scanner.axis_letters: the two letters must differ".into());
            }
        }
        positive("laser.max_power", self.laser.max_power)?;
        let max_power = self.laser.max_power;
        let power_in_range = |name: &str, v: f64| -> std::result::Result<(), String> {
            if v.is_finite() && (0.0..=max_power).contains(&v) {
                Ok(())
            } else {
                Err(format!("{name}: must be between 0 and laser.max_power ({max_power}), got {v}"))
            }
        };
        let time_ok = |name: &str, v: f64| -> std::result::Result<(), String> {
            if v.is_finite() && (0.0..=MAX_PIERCE_TIME).contains(&v) {
                Ok(())
            } else {
                Err(format!("{name}: must be between 0 (no pierce) and {MAX_PIERCE_TIME} s, got {v}"))
            }
        };
        time_ok("laser.pierce_time", self.laser.pierce_time)?;
        if let Some(p) = self.laser.pierce_power {
            power_in_range("laser.pierce_power", p)?;
        }
        if self.serial.baud == 0 {
            return Err("serial.baud: must be positive".into());
        }
        if self.serial.rx_buffer < 16 {
            return Err(format!("serial.rx_buffer: {} is too small (at least 16 bytes)", self.serial.rx_buffer));
        }
        positive("serial.status_hz", self.serial.status_hz)?;
        positive("import.tolerance", self.import.tolerance)?;
        positive("import.svg_dpi", self.import.svg_dpi)?;
        let m = self.motion.limit_margin;
        if !(m.is_finite() && m > 0.0 && m <= 1.0) {
            return Err(format!("motion.limit_margin: must be in (0, 1], got {m}"));
        }
        positive("program.tolerance", self.program.tolerance)?;
        positive("program.jump_tolerance", self.program.jump_tolerance)?;
        positive("motion.corner_tolerance", self.motion.corner_tolerance)?;
        if !(self.motion.line_tolerance.is_finite() && self.motion.line_tolerance >= 0.0) {
            return Err(format!("motion.line_tolerance: must be 0 or more mm, got {}", self.motion.line_tolerance));
        }
        let share = self.motion.stage_share;
        if !(share.is_finite() && share > 0.0 && share <= 1.0) {
            return Err(format!("motion.stage_share: must be in (0, 1], got {share}"));
        }
        for (name, v) in [("laser.on_delay", self.laser.on_delay), ("laser.off_delay", self.laser.off_delay)] {
            if !(v.is_finite() && (0.0..=0.01).contains(&v)) {
                return Err(format!("{name}: must be between 0 and 0.01 s, got {v}"));
            }
        }
        if !(2..=9).contains(&self.program.decimals) {
            return Err(format!("program.decimals: must be 2 to 9, got {}", self.program.decimals));
        }
        if !(2..=7).contains(&self.program.scanner_decimals) {
            return Err(format!("program.scanner_decimals: must be 2 to 7, got {}", self.program.scanner_decimals));
        }
        let c = &self.cutting;
        if !(c.pierce_cost.is_finite() && c.pierce_cost >= 0.0) {
            return Err(format!("cutting.pierce_cost: must be 0 or a positive number of mm, got {}", c.pierce_cost));
        }
        positive("cutting.common_cut_tolerance", c.common_cut_tolerance)?;
        if !(c.corner_angle.is_finite() && c.corner_angle > 0.0 && c.corner_angle <= 180.0) {
            return Err(format!("cutting.corner_angle: must be in (0, 180] degrees, got {}", c.corner_angle));
        }
        positive("cutting.time_limit", c.time_limit)?;
        let g = &self.galvo;
        for (name, w) in [("galvo.direction_weight", g.direction_weight), ("galvo.direction_weight_single_field", g.direction_weight_single_field)] {
            if !(w.is_finite() && w >= 0.0) {
                return Err(format!("{name}: must be 0 or a positive number, got {w}"));
            }
        }
        positive("galvo.time_limit", g.time_limit)?;
        self.service.validate()?;
        let mb = self.import.max_file_mb;
        if !(mb.is_finite() && (0.001..=4096.0).contains(&mb)) {
            return Err(format!("import.max_file_mb: must be between 0.001 and 4096 MB, got {mb}"));
        }
        if self.simulator.planner_blocks == 0 {
            return Err("simulator.planner_blocks: must be at least 1".into());
        }
        if self.layers.is_empty() {
            return Err("layer: at least one [[layer]] is needed".into());
        }
        for (i, l) in self.layers.iter().enumerate() {
            positive(&format!("layer[{i}] ({}).speed", l.name), l.speed)?;
            power_in_range(&format!("layer[{i}] ({}).power", l.name), l.power)?;
            if let Some(t) = l.pierce_time {
                time_ok(&format!("layer[{i}] ({}).pierce_time", l.name), t)?;
            }
            if let Some(p) = l.pierce_power {
                power_in_range(&format!("layer[{i}] ({}).pierce_power", l.name), p)?;
            }
            if l.passes == 0 {
                return Err(format!("layer[{i}] ({}).passes: must be at least 1", l.name));
            }
            if let Some(c) = &l.stroke {
                if parse_hex_colour(c).is_none() {
                    return Err(format!("layer[{i}] ({}).stroke: '{c}' is not a #rrggbb colour", l.name));
                }
            }
        }
        if !self.layers.iter().any(|l| l.name == self.default_layer) {
            return Err(format!("default_layer: no [[layer]] is named '{}'", self.default_layer));
        }
        Ok(())
    }

    /// The same machine running `k` (≥ 1) times slower: every velocity
    /// limit and speed divided by k, accelerations by k², jerks by k³, so a
    /// trajectory planned with it is the time-stretched one. Times (laser
    /// delays, pierces) stay as they are.
    pub fn slowed(&self, k: f64) -> MachineConfig {
        let mut m = self.clone();
        let (v, a, j) = (1.0 / k, 1.0 / (k * k), 1.0 / (k * k * k));
        m.stage.max_velocity *= v;
        m.stage.max_acceleration *= a;
        m.stage.max_jerk *= j;
        if let Some(s) = &mut m.scanner {
            s.mark_speed *= v;
            s.jump_speed *= v;
            s.max_acceleration *= a;
            s.max_jerk *= j;
        }
        m.layers.iter_mut().for_each(|l| l.speed *= v);
        m
    }

    pub fn stage_limits(&self) -> Limits {
        Limits {
            velocity: self.stage.max_velocity,
            acceleration: self.stage.max_acceleration,
            jerk: self.stage.max_jerk,
        }
    }

    /// Scanner limits with the jump speed as the velocity limit (the scanner's own cap).
    pub fn scanner_limits(&self) -> Option<Limits> {
        self.scanner.as_ref().map(|s| Limits {
            velocity: s.jump_speed,
            acceleration: s.max_acceleration,
            jerk: s.max_jerk,
        })
    }

    /// The pierce of the layer named `layer`: its own settings, else those of
    /// `[laser]`, the power falling back to the layer's own. An unknown layer
    /// gets `[laser]`'s (power: its pierce power, else full power).
    pub fn pierce(&self, layer: &str) -> Pierce {
        let l = self.layers.iter().find(|l| l.name == layer);
        let time = l.and_then(|l| l.pierce_time).unwrap_or(self.laser.pierce_time);
        let power = l
            .and_then(|l| l.pierce_power)
            .or(self.laser.pierce_power)
            .or(l.map(|l| l.power))
            .unwrap_or(self.laser.max_power);
        Pierce { power, time }
    }

    /// Index of the default layer in `layers` (validated to exist).
    pub fn default_layer_index(&self) -> usize {
        self.layers.iter().position(|l| l.name == self.default_layer).unwrap_or(0)
    }

    /// Axis letters of the controller: X Y, then the scanner's if there is one.
    pub fn axis_letters(&self) -> Vec<char> {
        let mut letters = vec!['X', 'Y'];
        if let Some(s) = &self.scanner {
            letters.extend(s.axis_letters.iter().filter_map(|l| l.chars().next()));
        }
        letters
    }
}

/// `#rrggbb` (or `#rgb`) to RGB bytes.
pub fn parse_hex_colour(s: &str) -> Option<[u8; 3]> {
    let hex = s.strip_prefix('#')?;
    let expand = |c: &str| u8::from_str_radix(c, 16).ok();
    match hex.len() {
        6 => Some([expand(&hex[0..2])?, expand(&hex[2..4])?, expand(&hex[4..6])?]),
        3 => {
            let d: Vec<u8> = hex.chars().map(|c| c.to_digit(16).map(|v| (v * 17) as u8)).collect::<Option<_>>()?;
            Some([d[0], d[1], d[2]])
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default_text() -> String {
        std::fs::read_to_string(DEFAULT_CONFIG_PATH).unwrap()
    }

    #[test]
    fn default_config_is_valid_and_has_a_scanner() {
        let c = MachineConfig::load(None).unwrap();
        assert_eq!(c.axis_letters(), vec!['X', 'Y', 'U', 'V']);
        assert_eq!(c.stage.travel_x, 300.0);
        assert_eq!(c.scanner.as_ref().unwrap().usable_half_field, 32.0);
        assert!(c.scanner.as_ref().unwrap().split_oversize);
    }

    #[test]
    fn split_oversize_defaults_to_true_and_can_be_turned_off() {
        let text = default_text();
        assert!(text.contains("split_oversize = true\n"));
        let absent = MachineConfig::parse(&text.replace("split_oversize = true\n", ""), "t.toml").unwrap();
        assert!(absent.scanner.unwrap().split_oversize);
        let off = MachineConfig::parse(&text.replace("split_oversize = true", "split_oversize = false"), "t.toml").unwrap();
        assert!(!off.scanner.unwrap().split_oversize);
    }

    #[test]
    fn scanner_section_is_optional() {
        let text = default_text();
        let start = text.find("\n[scanner]").unwrap();
        let end = text.find("\n[laser]").unwrap();
        let stage_only = format!("{}{}", &text[..start], &text[end..]);
        let c = MachineConfig::parse(&stage_only, "t.toml").unwrap();
        assert!(c.scanner.is_none());
        assert_eq!(c.axis_letters(), vec!['X', 'Y']);
    }

    #[test]
    fn bad_value_names_the_setting() {
        let text = default_text().replace("max_velocity = 500.0", "max_velocity = -5.0");
        let err = MachineConfig::parse(&text, "t.toml").unwrap_err().to_string();
        assert!(err.contains("stage.max_velocity"), "{err}");
        assert!(err.contains("t.toml"), "{err}");
    }

    #[test]
    fn unknown_key_and_nan_are_rejected_with_position() {
        let text = default_text().replace("travel_x = 300.0", "travel_x = 300.0\ntravle_y = 1");
        let err = MachineConfig::parse(&text, "t.toml").unwrap_err().to_string();
        assert!(err.contains("travle_y") && err.contains("line"), "{err}");
        let text = default_text().replace("max_jerk = 250000.0", "max_jerk = nan");
        let err = MachineConfig::parse(&text, "t.toml").unwrap_err().to_string();
        assert!(err.contains("stage.max_jerk"), "{err}");
    }

    #[test]
    fn pierce_defaults_to_none_and_layers_inherit_from_laser() {
        let c = MachineConfig::load(None).unwrap();
        assert_eq!(c.laser.pierce_time, 0.0, "the shipped machine marks: no pierce");
        for l in &c.layers {
            assert!(!c.pierce(&l.name).active(), "{}", l.name);
        }
        // [laser] sets the default; a layer its own; without a power anywhere a
        // layer pierces at its own power.
        let text = default_text()
            .replace("pierce_time = 0.0\n", "pierce_time = 0.2\n")
            .replace("name = \"cut\"\n", "name = \"cut\"\npierce_time = 0.5\npierce_power = 900.0\n");
        let c = MachineConfig::parse(&text, "t.toml").unwrap();
        assert_eq!(c.pierce("cut"), Pierce { power: 900.0, time: 0.5 });
        assert_eq!(c.pierce("mark"), Pierce { power: 300.0, time: 0.2 });
        let text = text.replace("# pierce_power = 1000.0", "pierce_power = 650.0");
        let c = MachineConfig::parse(&text, "t.toml").unwrap();
        assert_eq!(c.pierce("mark"), Pierce { power: 650.0, time: 0.2 });
        assert_eq!(c.pierce("cut").power, 900.0);
    }

    #[test]
    fn bad_pierce_values_name_the_setting() {
        let cases = [
            ("pierce_time = 0.0\n", "pierce_time = -0.1\n", "laser.pierce_time"),
            ("pierce_time = 0.0\n", "pierce_time = nan\n", "laser.pierce_time"),
            ("pierce_time = 0.0\n", "pierce_time = inf\n", "laser.pierce_time"),
            ("pierce_time = 0.0\n", "pierce_time = 61.0\n", "laser.pierce_time"),
            ("# pierce_power = 1000.0", "pierce_power = 1000.5", "laser.pierce_power"),
            ("# pierce_power = 1000.0", "pierce_power = -1.0", "laser.pierce_power"),
            ("# pierce_power = 1000.0", "pierce_power = nan", "laser.pierce_power"),
            ("name = \"cut\"\n", "name = \"cut\"\npierce_time = -2.0\n", "layer[1] (cut).pierce_time"),
            ("name = \"cut\"\n", "name = \"cut\"\npierce_time = nan\n", "layer[1] (cut).pierce_time"),
            ("name = \"cut\"\n", "name = \"cut\"\npierce_power = 2000.0\n", "layer[1] (cut).pierce_power"),
            ("name = \"cut\"\n", "name = \"cut\"\npierce_power = -0.5\n", "layer[1] (cut).pierce_power"),
        ];
        for (from, to, setting) in cases {
            let text = default_text();
            assert!(text.contains(from), "{from}");
            let err = MachineConfig::parse(&text.replacen(from, to, 1), "t.toml").unwrap_err().to_string();
            assert!(err.contains(setting) && err.contains("t.toml"), "{to}: {err}");
        }
        // The edges are fine.
        let text = default_text().replace("pierce_time = 0.0\n", "pierce_time = 60.0\n").replace("# pierce_power = 1000.0", "pierce_power = 0.0");
        assert!(MachineConfig::parse(&text, "t.toml").is_ok());
    }

    #[test]
    fn hex_colours() {
        assert_eq!(parse_hex_colour("#ff0000"), Some([255, 0, 0]));
        assert_eq!(parse_hex_colour("#0f0"), Some([0, 255, 0]));
        assert_eq!(parse_hex_colour("red"), None);
    }
}
