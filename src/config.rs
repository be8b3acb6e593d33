//! Machine configuration: the TOML file of `config/laserd.toml`, parsed and validated.
//!
//! Every check names the setting (`stage.max_velocity`) and the file, so an operator
//! can fix a bad value without reading code.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The values a numeric setting accepts, both bounds included, and its unit
/// for the error message.
#[derive(Debug, Clone, Copy)]
pub struct Range<T> {
    pub lo: T,
    pub hi: T,
    pub unit: &'static str,
}

impl<T: Setting> Range<T> {
    /// `name: must be between lo and hi unit, got v` unless `v` is within.
    pub fn check(&self, name: &str, v: T) -> std::result::Result<(), String> {
        in_range(name, v, self.lo, self.hi, self.unit)
    }
}

/// A number a setting holds: compared, and shown short in messages.
pub trait Setting: PartialOrd + Copy {
    fn shown(self) -> String;
}

impl Setting for f64 {
    /// Scientific notation where plain digits would run long (1e300, 1e-300).
    fn shown(self) -> String {
        let a = self.abs();
        if a != 0.0 && a.is_finite() && !(1e-3..1e7).contains(&a) {
            format!("{self:e}")
        } else {
            format!("{self}")
        }
    }
}

macro_rules! whole_setting {
    ($($t:ty),*) => {$(impl Setting for $t {
        fn shown(self) -> String {
            self.to_string()
        }
    })*};
}
whole_setting!(u32, u64, usize);

/// `v` within `lo..=hi` (NaN never is), else an error naming the setting,
/// the range and the value.
pub fn in_range<T: Setting>(name: &str, v: T, lo: T, hi: T, unit: &str) -> std::result::Result<(), String> {
    if lo <= v && v <= hi {
        return Ok(());
    }
    let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
    Err(format!("{name}: must be between {} and {}{unit}, got {}", lo.shown(), hi.shown(), v.shown()))
}

// Ranges shared by several settings (and the command line's flags). The
// physical ones lie far beyond any real machine and far below where the
// arithmetic of planning overflows or stops making progress.
/// Stage travel and other lengths on the table (mm): up to 100 m.
pub const TRAVEL: Range<f64> = Range { lo: 1.0, hi: 1e5, unit: "mm" };
/// The scanner's optical field (mm).
pub const FIELD: Range<f64> = Range { lo: 1.0, hi: 1000.0, unit: "mm" };
/// Speeds and velocity limits (mm/s): 0.1 mm/s to 100 m/s.
pub const VELOCITY: Range<f64> = Range { lo: 0.1, hi: 1e5, unit: "mm/s" };
/// Acceleration limits (mm/s²): galvos reach 1e7.
pub const ACCELERATION: Range<f64> = Range { lo: 1.0, hi: 1e9, unit: "mm/s²" };
/// Jerk limits (mm/s³): galvos reach about 4e11.
pub const JERK: Range<f64> = Range { lo: 1.0, hi: 1e14, unit: "mm/s³" };
/// Every tolerance of geometry and motion (mm).
pub const TOLERANCE: Range<f64> = Range { lo: 1e-4, hi: 10.0, unit: "mm" };
/// Shares of a limit (the margin, the stage's share on the fly).
pub const SHARE: Range<f64> = Range { lo: 0.1, hi: 1.0, unit: "" };
/// S value of full power (Grbl's $30; grblHAL takes larger ones).
pub const MAX_POWER: Range<f64> = Range { lo: 1.0, hi: 1e6, unit: "" };
/// Longest pierce accepted (s): far beyond any real pierce, well inside what a
/// controller's dwell counts (Grbl 1.1 counts G4 in 50 ms steps in 16 bits).
pub const PIERCE_TIME: Range<f64> = Range { lo: 0.0, hi: 60.0, unit: "s (0: no pierce)" };
/// The laser source's response times (s).
pub const LASER_DELAY: Range<f64> = Range { lo: 0.0, hi: 0.01, unit: "s" };
/// Serial link speeds (baud): 300 to USB full speed.
pub const BAUD: Range<u32> = Range { lo: 300, hi: 12_000_000, unit: "baud" };
/// Search time of the planners (s): up to a day.
pub const TIME_LIMIT: Range<f64> = Range { lo: 0.01, hi: 86_400.0, unit: "s" };
/// Weights of the galvo planners' directionality penalty.
pub const DIRECTION_WEIGHT: Range<f64> = Range { lo: 0.0, hi: 1000.0, unit: "" };
/// How often a layer is marked: each pass is a copy of its geometry in the plan.
pub const PASSES: Range<u32> = Range { lo: 1, hi: 1000, unit: "passes" };
/// Lead-in and lead-out lengths, overcut and closing gaps (mm).
pub const LEAD_LENGTH: Range<f64> = Range { lo: 0.0, hi: 100.0, unit: "mm" };
/// A lead's angle to its contour (degrees): a line from along it to straight at it.
pub const LEAD_ANGLE: Range<f64> = Range { lo: 1.0, hi: 180.0, unit: "degrees" };
/// Width of a cut (mm): a fibre laser's 0.02 to a plasma's few mm, with room.
/// Distance between hatch lines (mm): a fibre laser's 0.01 to a coarse 10.
pub const HATCH_SPACING: Range<f64> = Range { lo: 0.001, hi: 10.0, unit: "mm" };
pub const HATCH_ANGLE: Range<f64> = Range { lo: -360.0, hi: 360.0, unit: "degrees" };
pub const KERF: Range<f64> = Range { lo: 0.0, hi: 10.0, unit: "mm (0: cut on the line)" };

/// The default machine, shipped in the repository (for tests and tools run
/// in the checkout; an installed binary carries it as `DEFAULT_CONFIG_TEXT`).
pub const DEFAULT_CONFIG_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/laserd.toml");
/// The default machine, built into the binary: the last place the config
/// search looks, so that an installed `laserd` works with no file at all.
pub const DEFAULT_CONFIG_TEXT: &str = include_str!("../config/laserd.toml");
/// The machine PC's config, the service's (systemd/laserd.service).
pub const SYSTEM_CONFIG_PATH: &str = "/etc/laserd/laserd.toml";
/// The environment variable naming a config file.
pub const CONFIG_ENV: &str = "LASERD_CONFIG";

/// Where a command's machine config came from (reports carry it as `config`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "from", rename_all = "snake_case")]
pub enum ConfigSource {
    /// `--config FILE`.
    Option { path: PathBuf },
    /// `$LASERD_CONFIG`.
    Env { path: PathBuf },
    /// `/etc/laserd/laserd.toml`.
    System { path: PathBuf },
    /// `laserd/laserd.toml` in the user's config folder (`$XDG_CONFIG_HOME`, else `~/.config`).
    User { path: PathBuf },
    /// The default machine built into the binary (`config/laserd.toml`).
    Builtin,
}

impl ConfigSource {
    /// The file read; `None` for the built-in machine.
    pub fn path(&self) -> Option<&Path> {
        match self {
            ConfigSource::Option { path } | ConfigSource::Env { path } | ConfigSource::System { path } | ConfigSource::User { path } => Some(path),
            ConfigSource::Builtin => None,
        }
    }
}

impl std::fmt::Display for ConfigSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConfigSource::Option { path } => write!(f, "{} (--config)", path.display()),
            ConfigSource::Env { path } => write!(f, "{} (${CONFIG_ENV})", path.display()),
            ConfigSource::System { path } => write!(f, "{} (system)", path.display()),
            ConfigSource::User { path } => write!(f, "{} (user)", path.display()),
            ConfigSource::Builtin => write!(f, "the built-in default machine (config/laserd.toml)"),
        }
    }
}

/// The places a command looks for its machine config, in order: `--config`,
/// `$LASERD_CONFIG`, the system file, the user's file; the first that is
/// given (the first two) or exists (the last two) is used, and one that
/// cannot be read is an error, never skipped. None: the built-in machine.
#[derive(Debug, Clone)]
pub struct ConfigSearch {
    pub option: Option<PathBuf>,
    pub env: Option<PathBuf>,
    pub system: PathBuf,
    pub user: Option<PathBuf>,
}

/// A config as found: the machine, its text (the service hands it to its
/// planning processes) and where it came from.
#[derive(Debug, Clone)]
pub struct FoundConfig {
    pub machine: MachineConfig,
    pub text: String,
    pub source: ConfigSource,
}

impl ConfigSearch {
    /// The search of this process: `--config`, its environment, its user.
    pub fn new(option: Option<&Path>) -> ConfigSearch {
        ConfigSearch {
            option: option.map(Path::to_path_buf),
            env: std::env::var_os(CONFIG_ENV).filter(|v| !v.is_empty()).map(PathBuf::from),
            system: PathBuf::from(SYSTEM_CONFIG_PATH),
            user: dirs::config_dir().map(|d| d.join("laserd").join("laserd.toml")),
        }
    }

    /// The file to read and where it came from; `None`: no file, the built-in machine.
    fn locate(&self) -> Option<(PathBuf, ConfigSource)> {
        if let Some(path) = &self.option {
            return Some((path.clone(), ConfigSource::Option { path: path.clone() }));
        }
        if let Some(path) = &self.env {
            return Some((path.clone(), ConfigSource::Env { path: path.clone() }));
        }
        // A file that exists but cannot be read (permissions) is chosen, so
        // that reading it fails by name rather than another machine running.
        let exists = |p: &Path| p.symlink_metadata().is_ok();
        if exists(&self.system) {
            return Some((self.system.clone(), ConfigSource::System { path: self.system.clone() }));
        }
        self.user.as_ref().filter(|p| exists(p)).map(|p| (p.clone(), ConfigSource::User { path: p.clone() }))
    }

    /// Reads and validates the config found; the built-in machine when no file is.
    pub fn find(&self) -> Result<FoundConfig> {
        match self.locate() {
            Some((path, source)) => {
                let (machine, text) = MachineConfig::load_with_text(Some(&path))?;
                Ok(FoundConfig { machine, text, source })
            }
            None => Ok(FoundConfig { machine: MachineConfig::builtin(), text: DEFAULT_CONFIG_TEXT.to_string(), source: ConfigSource::Builtin }),
        }
    }

    /// The config file found, for the service: it drives a real machine, so
    /// the built-in example machine is no fallback (its port, travel and
    /// limits are not this machine's).
    pub fn find_file(&self) -> Result<FoundConfig> {
        if self.locate().is_none() {
            return Err(Error::Config(format!(
                "no machine config: no --config, and none at {}; install one at {} \
                 (config/laserd.toml with [serial] port set to the controller's device)",
                self.places(),
                self.system.display()
            )));
        }
        self.find()
    }

    /// The places searched when `--config` is not given, for messages.
    pub fn places(&self) -> String {
        let user = self.user.as_ref().map(|p| format!(", {}", p.display())).unwrap_or_default();
        format!("${CONFIG_ENV}, {}{user}", self.system.display())
    }
}

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
    pub fill: FillConfig,
    #[serde(default)]
    pub service: ServiceConfig,
    #[serde(default)]
    pub job: JobConfig,
    /// The plate on the machine; none: parts are planned as if in empty space.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plate: Option<PlateConfig>,
    /// The cutting head's Z axis; none: the machine has X and Y only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub head: Option<HeadConfig>,
    /// The sheet's material, for thermal planning (`--thermal`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<MaterialConfig>,
    /// The plate heat model and the thermal planner (`--thermal`).
    #[serde(default)]
    pub thermal: ThermalConfig,
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
    #[serde(default = "default_true")]
    pub split_oversize: bool,
    pub mark_speed: f64,
    pub jump_speed: f64,
    pub max_acceleration: f64,
    pub max_jerk: f64,
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
    /// The source's optical output at `max_power`, W: the heat a cut puts
    /// into the plate (`[material] absorptivity` of it). Needed by `--thermal`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub watts: Option<f64>,
}

/// A sheet material and its thickness (`[material]`, seed 000's thermal
/// model): the constants of the plate heat model and the temperatures above
/// which a feature loses its quality. SI units, temperatures in °C.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MaterialConfig {
    /// What it is, for the report ("mild steel S235").
    #[serde(default)]
    pub name: String,
    /// Plate thickness, mm.
    pub thickness: f64,
    /// kg/m³.
    pub density: f64,
    /// J/(kg·K).
    pub specific_heat: f64,
    /// W/(m·K).
    pub conductivity: f64,
    /// Of the plate's faces, 0 to 1 (radiation).
    pub emissivity: f64,
    /// The share of the beam's power that stays in the plate as heat (the
    /// rest leaves with the molten kerf and the gas, or is reflected).
    pub absorptivity: f64,
    /// A pierce starting where the plate is hotter than this, °C, loses its quality.
    pub critical_pierce: f64,
    /// A cut running where the plate is hotter than this, °C.
    pub critical_cut: f64,
    /// A sharp corner cut where the plate is hotter than this burns off, °C.
    pub critical_corner: f64,
}

/// The plate heat model and the thermal planner (`[thermal]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ThermalConfig {
    /// Plan cutting routes that keep the plate below the material's critical
    /// temperatures, and report the heat (`--thermal` sets it).
    #[serde(default)]
    pub enabled: bool,
    /// Side of the model's square cells, mm.
    #[serde(default = "default_thermal_cell")]
    pub cell: f64,
    /// The air around the plate and the plate at the start, °C.
    #[serde(default = "default_ambient")]
    pub ambient: f64,
    /// Convection from the plate's top and bottom faces, W/(m²·K).
    #[serde(default = "default_convection_top")]
    pub convection_top: f64,
    #[serde(default = "default_convection_bottom")]
    pub convection_bottom: f64,
    /// How the machine handles a sharp corner (a turn sharper than
    /// `[cutting] corner_angle`): seconds the beam dwells there at cutting power.
    #[serde(default)]
    pub corner_dwell: f64,
    /// Seed 000's responsiveness (0 to 1): a violation adds to the penalty of
    /// the decision k places before it this power k of its size.
    #[serde(default = "default_responsiveness")]
    pub responsiveness: f64,
    /// A violation of its whole critical temperature adds this much to the
    /// penalty of the decision just before it, mm of air move.
    #[serde(default = "default_thermal_penalty")]
    pub penalty: f64,
    /// A violation raises the jumps into its path from every cut ending
    /// within this distance too (mm; 0: only the jump the route made): a
    /// neighbour of the heat is as hot a way in.
    #[serde(default = "default_thermal_reach")]
    pub reach: f64,
    /// Constructions (each searched, then judged by the heat model) before
    /// the planner gives up on a route without violations and waits instead.
    #[serde(default = "default_thermal_iterations")]
    pub iterations: u32,
    /// Constructions in a row that find no better route (fewer or shorter
    /// waits) end the search before `iterations`.
    #[serde(default = "default_thermal_stall")]
    pub stall: u32,
}

impl Default for ThermalConfig {
    fn default() -> Self {
        ThermalConfig {
            enabled: false,
            cell: default_thermal_cell(),
            ambient: default_ambient(),
            convection_top: default_convection_top(),
            convection_bottom: default_convection_bottom(),
            corner_dwell: 0.0,
            responsiveness: default_responsiveness(),
            penalty: default_thermal_penalty(),
            reach: default_thermal_reach(),
            iterations: default_thermal_iterations(),
            stall: default_thermal_stall(),
        }
    }
}

fn default_thermal_cell() -> f64 {
    5.0
}
fn default_ambient() -> f64 {
    20.0
}
// Still air over a hot horizontal plate: about 10-25 W/(m²·K) above, less
// below (a bed of slats shields it).
fn default_convection_top() -> f64 {
    15.0
}
fn default_convection_bottom() -> f64 {
    5.0
}
fn default_responsiveness() -> f64 {
    0.7
}
fn default_thermal_penalty() -> f64 {
    200.0
}
fn default_thermal_reach() -> f64 {
    80.0
}
fn default_thermal_iterations() -> u32 {
    40
}
fn default_thermal_stall() -> u32 {
    10
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
    /// The feed of a jog given without one (`laserd ctl jog X10`), mm/min.
    #[serde(default = "default_jog_feed")]
    pub jog_feed: f64,
    /// A Foxglove WebSocket server at this address (e.g. "127.0.0.1:8765")
    /// publishing the recording's topics live; none (the default): off.
    #[serde(default)]
    pub foxglove: Option<String>,
}

/// A laser head's jog: brisk, yet slow enough to stop by eye (50 mm/s).
fn default_jog_feed() -> f64 {
    3000.0
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
            jog_feed: default_jog_feed(),
            foxglove: None,
        }
    }
}

impl ServiceConfig {
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

    /// `foxglove` as an address to listen on, if set.
    pub fn foxglove_address(&self) -> std::result::Result<Option<std::net::SocketAddr>, String> {
        let Some(text) = &self.foxglove else { return Ok(None) };
        match text.parse::<std::net::SocketAddr>() {
            Ok(addr) if addr.port() != 0 => Ok(Some(addr)),
            Ok(_) => Err(format!("[service] foxglove = {text:?}: give a port (1 to 65535), such as \"127.0.0.1:8765\"")),
            Err(_) => Err(format!("[service] foxglove = {text:?}: not an IP address and port such as \"127.0.0.1:8765\"")),
        }
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
    /// Most elements a drawing may grow to once `<use>` and markers repeat
    /// what they refer to: bounds the time and memory of an import.
    #[serde(default = "default_max_elements")]
    pub max_elements: u64,
    /// Most points of the flattened drawing (and path segments before it).
    #[serde(default = "default_max_points")]
    pub max_points: u64,
    /// DXF: the unit the drawing is in, whatever its header says (`--units`);
    /// none: the header's `$INSUNITS` (mm when it names none).
    #[serde(default)]
    pub units: Option<DrawingUnit>,
}

/// The plate on the machine (`[plate]`, seed 000's "removing complexity"):
/// its rectangle, the skeleton and remnant cuts made in it besides the parts,
/// and the clamps that hold it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PlateConfig {
    /// The plate's lower-left corner on the machine, mm.
    #[serde(default)]
    pub x: f64,
    #[serde(default)]
    pub y: f64,
    pub width: f64,
    pub height: f64,
    /// Thickness, mm.
    #[serde(default = "default_plate_thickness")]
    pub thickness: f64,
    /// The skeleton (the waste left around the parts) is cut into pieces no
    /// larger than this on a side, mm; 0: left whole.
    #[serde(default)]
    pub skeleton_piece: f64,
    /// The remnant to keep, cut off the skeleton: "none", "auto" (the largest
    /// free rectangle at a corner of the plate whose sides are both at least
    /// `remnant_min`), or [x, y, width, height] in mm.
    #[serde(default)]
    #[schemars(with = "serde_json::Value")]
    pub remnant: RemnantSetting,
    /// The smallest side of a remnant worth keeping ("auto"), mm.
    #[serde(default = "default_remnant_min")]
    pub remnant_min: f64,
    /// What skeleton and remnant cuts keep clear of the parts, mm.
    #[serde(default = "default_plate_clearance")]
    pub clearance: f64,
    /// Skeleton and remnant cuts "in-route" (planned with the parts, seed
    /// 000) or "after" the parts.
    #[serde(default)]
    #[schemars(with = "String")]
    pub scrap_cuts: ScrapCuts,
    /// The layer that cuts skeleton and remnant; default: the first layer
    /// that pierces.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layer: Option<String>,
    /// Clamps holding the plate: the pieces of skeleton they touch never move.
    #[serde(default, rename = "clamp")]
    pub clamps: Vec<ClampConfig>,
    /// Spacing of the bed's support grid (slats or pins), mm. Pieces cut
    /// free that are smaller than twice it may tip, and the head lifts over
    /// them (`[head]`); none: nothing is taken to tip.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub support_grid: Option<f64>,
}

/// The cutting head's Z axis (`[head]`, seed 000's lift moves): 0 is the
/// cutting height, up is positive. Air moves that would pass over a piece
/// that may have tipped lift the head to `lift_height` on the way.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HeadConfig {
    /// The Z travel above the cutting height, mm.
    pub travel_z: f64,
    /// h_max: the height that clears a tipped piece, mm.
    pub lift_height: f64,
    pub max_velocity: f64,
    pub max_acceleration: f64,
    pub max_jerk: f64,
    /// How far around a piece that may have tipped the head is up, mm.
    #[serde(default = "default_lift_clearance")]
    pub clearance: f64,
    /// Lift over pieces that may have tipped (false: the head stays down;
    /// the dry-run still counts the collisions).
    #[serde(default = "default_true")]
    pub lift_moves: bool,
}

fn default_lift_clearance() -> f64 {
    2.0
}

fn default_true() -> bool {
    true
}

fn default_plate_thickness() -> f64 {
    1.0
}

fn default_remnant_min() -> f64 {
    100.0
}

fn default_plate_clearance() -> f64 {
    3.0
}

/// `[plate] remnant`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(try_from = "toml::Value", into = "toml::Value")]
pub enum RemnantSetting {
    #[default]
    None,
    Auto,
    /// x, y, width, height (mm).
    At([f64; 4]),
}

impl TryFrom<toml::Value> for RemnantSetting {
    type Error = String;
    fn try_from(v: toml::Value) -> std::result::Result<Self, String> {
        let bad = || format!("'{v}' is no remnant: \"none\", \"auto\" or [x, y, width, height] in mm");
        match &v {
            toml::Value::String(s) if s == "none" => Ok(RemnantSetting::None),
            toml::Value::String(s) if s == "auto" => Ok(RemnantSetting::Auto),
            toml::Value::Array(a) if a.len() == 4 => {
                let mut r = [0.0; 4];
                for (x, item) in r.iter_mut().zip(a) {
                    *x = item.as_float().or_else(|| item.as_integer().map(|i| i as f64)).ok_or_else(bad)?;
                }
                Ok(RemnantSetting::At(r))
            }
            _ => Err(bad()),
        }
    }
}

impl From<RemnantSetting> for toml::Value {
    fn from(r: RemnantSetting) -> toml::Value {
        match r {
            RemnantSetting::None => "none".into(),
            RemnantSetting::Auto => "auto".into(),
            RemnantSetting::At(a) => toml::Value::Array(a.iter().map(|&x| toml::Value::Float(x)).collect()),
        }
    }
}

/// `[plate] scrap_cuts`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScrapCuts {
    #[default]
    InRoute,
    After,
}

/// A clamp (`[[plate.clamp]]`): where it holds the plate, and how far it reaches.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ClampConfig {
    pub x: f64,
    pub y: f64,
    #[serde(default = "default_clamp_radius")]
    pub radius: f64,
}

fn default_clamp_radius() -> f64 {
    10.0
}

/// Where a job goes on the machine.
#[derive(Debug, Clone, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JobConfig {
    /// `drawing` (where the drawing puts it: an SVG document's bottom-left
    /// corner, a DXF drawing's origin, at the machine origin), `origin` (the
    /// job's bounds' lower-left corner at the machine origin), `center`
    /// (centred on the bed), or `X,Y` (the bounds' lower-left corner there,
    /// mm). `--place` sets it for one run.
    #[serde(default)]
    #[schemars(with = "String")]
    pub anchor: Anchor,
}

/// `[job] anchor` / `--place`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Anchor {
    #[default]
    Drawing,
    Origin,
    Center,
    At(f64, f64),
}

impl std::str::FromStr for Anchor {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Anchor, String> {
        let bad = || format!("'{s}' is no placement: drawing, origin, center, or X,Y in mm (such as 10,20)");
        match s.trim().to_ascii_lowercase().as_str() {
            "drawing" => Ok(Anchor::Drawing),
            "origin" => Ok(Anchor::Origin),
            "center" | "centre" => Ok(Anchor::Center),
            other => {
                let (x, y) = other.split_once(',').ok_or_else(bad)?;
                let (x, y): (f64, f64) = (x.trim().parse().map_err(|_| bad())?, y.trim().parse().map_err(|_| bad())?);
                if !(x.is_finite() && y.is_finite()) || x.abs() > 1e6 || y.abs() > 1e6 {
                    return Err(bad());
                }
                Ok(Anchor::At(x, y))
            }
        }
    }
}

impl TryFrom<String> for Anchor {
    type Error = String;

    fn try_from(s: String) -> std::result::Result<Anchor, String> {
        s.parse()
    }
}

impl From<Anchor> for String {
    fn from(a: Anchor) -> String {
        match a {
            Anchor::Drawing => "drawing".into(),
            Anchor::Origin => "origin".into(),
            Anchor::Center => "center".into(),
            Anchor::At(x, y) => format!("{x},{y}"),
        }
    }
}

/// A length unit a drawing may be made in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DrawingUnit {
    Mm,
    Cm,
    Inch,
}

impl DrawingUnit {
    pub const ALL: [DrawingUnit; 3] = [DrawingUnit::Mm, DrawingUnit::Cm, DrawingUnit::Inch];

    pub fn mm(self) -> f64 {
        match self {
            DrawingUnit::Mm => 1.0,
            DrawingUnit::Cm => 10.0,
            DrawingUnit::Inch => 25.4,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            DrawingUnit::Mm => "mm",
            DrawingUnit::Cm => "cm",
            DrawingUnit::Inch => "inch",
        }
    }
}

fn default_max_elements() -> u64 {
    200_000
}

fn default_max_points() -> u64 {
    5_000_000
}

fn default_max_file_mb() -> f64 {
    128.0
}

impl Default for ImportConfig {
    fn default() -> Self {
        ImportConfig {
            tolerance: 0.01,
            svg_dpi: 96.0,
            max_file_mb: default_max_file_mb(),
            max_elements: default_max_elements(),
            max_points: default_max_points(),
            units: None,
        }
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
    /// A wall-clock cap on the planning step (s); `--time-limit` overrides
    /// it. None by default: the search ends on its budget of work, which
    /// grows with the job, and plans the same whatever the machine's load.
    /// A cap that ends the search first may change the plan (the report
    /// says `search_stopped_by: "time-limit"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_limit: Option<f64>,
    /// "ils" (iterated local search, the default) or "tabu" (seed 001's).
    #[serde(default, with = "search_kind")]
    #[schemars(with = "String")]
    pub search: SearchKind,
    /// Bridges (seed 000): where a cut ends at most this far (mm) from where
    /// the next one starts with a pierce, cut straight across the waste to it
    /// if that is faster than the air move and the pierce; 0: no bridges.
    #[serde(default)]
    pub bridge_max: f64,
    /// Pre-cuts (seed 000): a cut that would start with a pierce on a
    /// junction the route passed through earlier is started this far (mm)
    /// into its element and back when the head passes there, then later
    /// started in that kerf without a pierce, where that is faster; 0: none.
    #[serde(default)]
    pub precut_length: f64,
    /// What the machine's handling of a turn sharper than `corner_angle` (a
    /// sharp-angle macro: a loop, a slow-down, a dwell) costs, in mm of air
    /// move as `pierce_cost`: the cutting planner charges it where a cut
    /// goes on through such a turn, and pre-cuts at a junction go in the
    /// order with the fewest of them.
    #[serde(default)]
    pub sharp_angle_cost: f64,
    /// What the search minimises: `length` (air moves plus pierce costs, the
    /// default), `time` (each air move's machine time, rest to rest, the axes
    /// at their limits), or a weighted sum of the two; `--objective` sets it.
    #[serde(default = "default_route_objective")]
    pub objective: String,
}

/// Which search improves the cutting planner's construction (`[cutting] search`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SearchKind {
    /// Iterated local search with relaxed starts (`plan::ecp::ils`), the default.
    #[default]
    Ils,
    /// Seed 001's tabu search (`plan::ecp::tabu`), the reference.
    Tabu,
}

impl FromStr for SearchKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "ils" => Ok(SearchKind::Ils),
            "tabu" => Ok(SearchKind::Tabu),
            _ => Err(format!("unknown search '{s}' (available: ils, tabu)")),
        }
    }
}

impl SearchKind {
    pub fn name(self) -> &'static str {
        match self {
            SearchKind::Ils => "ils",
            SearchKind::Tabu => "tabu",
        }
    }
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
    /// A wall-clock cap on the planning step (s) of both galvo planners;
    /// `--time-limit` overrides it. None by default: the searches end on
    /// their budgets of work (kicks, generations) and plan the same whatever
    /// the machine's load; a cap that ends one first may change the plan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_limit: Option<f64>,
    /// Seed of the planners' random choices; `--seed` overrides it.
    #[serde(default = "default_galvo_seed")]
    pub seed: u64,
    /// What the route minimises: `length` (idle stroke, the default), `time`
    /// (the job's machine time: routes from several seeds, each judged by
    /// its planned motion), or a weighted sum of the two; `--objective` sets it.
    #[serde(default = "default_route_objective")]
    pub objective: String,
}

/// What the planners minimise, and the fill planner's genetic search
/// (seed 004).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FillConfig {
    /// The objective: `length` (laser-off travel), `time` (machine time),
    /// `turns`, `heat`, or a weighted sum (`time+0.2*turns`); `--objective`
    /// overrides it.
    #[serde(default = "default_objective")]
    pub objective: String,
    /// `heat`: marks whose middles lie closer than this share heat (mm) ...
    #[serde(default = "default_heat_radius")]
    pub heat_radius: f64,
    /// ... when made less than this apart (s).
    #[serde(default = "default_cooling_time")]
    pub cooling_time: f64,
    /// Routes in each generation of the fill planner's genetic search.
    #[serde(default = "default_population")]
    pub population: usize,
    /// Generations without a better route before it stops.
    #[serde(default = "default_stall_generations")]
    pub stall_generations: usize,
}

fn default_objective() -> String {
    "time".into()
}
fn default_route_objective() -> String {
    "length".into()
}
fn default_heat_radius() -> f64 {
    1.0
}
fn default_cooling_time() -> f64 {
    0.5
}
fn default_population() -> usize {
    25
}
fn default_stall_generations() -> usize {
    30
}

impl Default for FillConfig {
    fn default() -> Self {
        FillConfig {
            objective: default_objective(),
            heat_radius: default_heat_radius(),
            cooling_time: default_cooling_time(),
            population: default_population(),
            stall_generations: default_stall_generations(),
        }
    }
}

/// The terms an objective may weigh (`plan::objective` gives each its meaning).
pub const OBJECTIVE_TERMS: [&str; 4] = ["length", "time", "turns", "heat"];

/// The terms the cutting and galvo searches can weigh: the others price a
/// route by its neighbouring marks' turns and heat, which a fill has.
pub const ROUTE_OBJECTIVE_TERMS: [&str; 2] = ["length", "time"];

/// A cutting or galvo objective's weighted terms: `length`, `time`, `time+0.5*length`.
pub fn route_objective_terms(s: &str) -> std::result::Result<Vec<(f64, &'static str)>, String> {
    let terms = objective_terms(s)?;
    match terms.iter().find(|(_, t)| !ROUTE_OBJECTIVE_TERMS.contains(t)) {
        Some((_, t)) => Err(format!("objective '{s}': '{t}' orders fills only (the cutting and galvo searches weigh length and time)")),
        None => Ok(terms),
    }
}

/// A cutting or galvo objective's weights of length and of time.
pub fn route_objective_weights(s: &str) -> std::result::Result<(f64, f64), String> {
    let terms = route_objective_terms(s)?;
    let weight = |term: &str| terms.iter().filter(|(_, t)| *t == term).map(|(w, _)| w).sum::<f64>();
    Ok((weight("length"), weight("time")))
}

/// An objective's weighted terms: `time`, `time+0.2*turns`, `0.5*time+2*heat`.
pub fn objective_terms(s: &str) -> std::result::Result<Vec<(f64, &'static str)>, String> {
    let known = "length, time, turns, heat, or a weighted sum such as time+0.2*turns";
    let mut terms = Vec::new();
    for part in s.split('+').map(str::trim) {
        let (weight, name) = match part.split_once('*') {
            Some((w, n)) => (w.trim().parse::<f64>().map_err(|_| format!("objective '{s}': '{}' is not a weight ({known})", w.trim()))?, n.trim()),
            None => (1.0, part),
        };
        if !(weight.is_finite() && (0.0..=1e6).contains(&weight)) {
            return Err(format!("objective '{s}': weight {weight} is outside 0 to 1e6"));
        }
        let Some(term) = OBJECTIVE_TERMS.iter().find(|t| **t == name) else {
            return Err(format!("objective '{s}': unknown term '{name}' ({known})"));
        };
        terms.push((weight, *term));
    }
    if terms.iter().all(|&(w, _)| w == 0.0) {
        return Err(format!("objective '{s}': every weight is 0"));
    }
    Ok(terms)
}

fn default_direction_weight() -> f64 {
    0.5
}
fn default_direction_weight_single_field() -> f64 {
    0.1
}
fn default_galvo_seed() -> u64 {
    1
}

impl Default for GalvoConfig {
    fn default() -> Self {
        GalvoConfig {
            direction_weight: default_direction_weight(),
            direction_weight_single_field: default_direction_weight_single_field(),
            time_limit: None,
            seed: default_galvo_seed(),
            objective: default_route_objective(),
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

impl Default for CuttingConfig {
    fn default() -> Self {
        CuttingConfig {
            pierce_cost: default_pierce_cost(),
            common_cut_tolerance: default_common_cut_tolerance(),
            corner_angle: default_corner_angle(),
            time_limit: None,
            search: Default::default(),
            bridge_max: 0.0,
            precut_length: 0.0,
            sharp_angle_cost: 0.0,
            objective: default_route_objective(),
        }
    }
}

mod search_kind {
    use super::SearchKind;
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
    /// Share of the stage's limits its on-the-fly bursts use; the rest is
    /// headroom for the rounding of coordinates in the program (a stage
    /// flowing through the fields uses all of them within `limit_margin`).
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
    /// Stage-only marks: runs of blocks on one circle as one G2/G3 (fewer
    /// lines on the link) where the controller's chords stay within `tolerance`.
    #[serde(default = "default_true")]
    pub arcs: bool,
}

fn default_scanner_decimals() -> usize {
    4
}

fn default_jump_tolerance() -> f64 {
    0.5
}

impl Default for ProgramConfig {
    fn default() -> Self {
        ProgramConfig { tolerance: 0.01, jump_tolerance: default_jump_tolerance(), decimals: 6, scanner_decimals: default_scanner_decimals(), arcs: default_true() }
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
    /// Which firmware the simulated controller answers as: `grbl` (Grbl 1.1h:
    /// X, Y, Z only, so no scanner) or `grblhal`.
    #[serde(default)]
    pub flavor: laserd_sim::controller::Flavor,
    /// Settings in the simulated controller's EEPROM at power-up, as
    /// `[[10, 3]]` (`$10=3`: status reports with `Bf:`); by default Grbl's own.
    #[serde(default)]
    pub settings: Vec<(u32, f64)>,
    /// The simulated controller's junction deviation (`$11`, mm) at
    /// power-up: how fast the `grbl` motion model takes a corner (default
    /// Grbl's own, 0.010; `bench motion --vs-grbl` sets it to
    /// `[motion] corner_tolerance`). A `[11, ...]` in `settings` overrides it.
    #[serde(default = "default_junction_deviation")]
    pub junction_deviation: f64,
}

fn default_junction_deviation() -> f64 {
    laserd_sim::controller::JUNCTION_DEVIATION
}

impl Default for SimulatorConfig {
    fn default() -> Self {
        SimulatorConfig {
            planner_blocks: 15,
            motion: Default::default(),
            flavor: Default::default(),
            settings: Vec::new(),
            junction_deviation: default_junction_deviation(),
        }
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
    /// DXF: the drawing layer whose entities take this layer (case
    /// insensitive, as DXF names are); without it, a drawing layer of this
    /// layer's own name does.
    #[serde(default)]
    pub dxf_layer: Option<String>,
    /// DXF: the AutoCAD colour index (1 to 255) whose entities take this
    /// layer (a DXF true colour matches `stroke`).
    #[serde(default)]
    pub color: Option<u16>,
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
    /// The width of the cut (mm): closed contours are cut half of it into
    /// the waste (parts outward, holes inward) so parts come out as drawn;
    /// 0: cut on the drawn line.
    #[serde(default)]
    pub kerf: f64,
    /// How an offset contour goes round a part's outer corner: on an arc
    /// about it ("round") or out to the point of the corner ("sharp").
    #[serde(default)]
    pub kerf_corners: KerfCorners,
    /// How a cut that starts with a pierce gets onto its contour: from a
    /// pierce in the waste along a line or an arc ("none": pierce on it).
    #[serde(default)]
    pub lead_in: LeadKind,
    /// The lead-in's length (mm).
    #[serde(default = "lead_length")]
    pub lead_in_length: f64,
    /// Line: its angle to the contour (90: straight at it); arc: how far
    /// it turns before it runs along the contour (degrees).
    #[serde(default = "lead_angle")]
    pub lead_in_angle: f64,
    /// Where on a closed contour the lead-in goes: where the planner enters
    /// it ("entry"), the corner nearest to that ("corner"), or the middle of
    /// its longest straight side ("longest").
    #[serde(default)]
    pub lead_in_at: LeadAt,
    /// How a cut leaves its contour into the waste at its end.
    #[serde(default)]
    pub lead_out: LeadKind,
    #[serde(default = "lead_length")]
    pub lead_out_length: f64,
    #[serde(default = "lead_angle")]
    pub lead_out_angle: f64,
    /// How far a closed contour is cut past its start (mm): the pierce's
    /// mark and the start are cut twice, so nothing holds the part.
    #[serde(default)]
    pub overcut: f64,
    /// How much of a closed contour is left uncut before its start (mm), so
    /// that the part stays in the sheet (taken out by hand later).
    #[serde(default)]
    pub closing_gap: f64,
    /// Micro-joints on every part outline of the layer: this many, evenly
    /// spaced (0: none) ...
    #[serde(default)]
    pub tabs: u32,
    /// ... or one every this many mm of outline (0: by count).
    #[serde(default)]
    pub tab_spacing: f64,
    /// The length of outline each tab leaves uncut (mm).
    #[serde(default = "tab_width")]
    pub tab_width: f64,
    /// What is marked of the layer's shapes: their outlines ("line"), the
    /// area inside them hatched ("fill"), or both, the fill first ("fill+line").
    #[serde(default)]
    pub mode: LayerMode,
    /// Fill: the distance between hatch lines (mm).
    #[serde(default = "hatch_spacing")]
    pub hatch_spacing: f64,
    /// Fill: the hatch lines' angle to the X axis (degrees, counter-clockwise).
    #[serde(default)]
    pub hatch_angle: f64,
    /// Fill: a second hatch at right angles to the first.
    #[serde(default)]
    pub cross_hatch: bool,
    /// Fill: hatch lines marked either way (else each in the hatch angle's direction).
    #[serde(default = "default_true")]
    pub bidirectional: bool,
    /// Fill: every hatch line entered and left at its speed, the laser off
    /// while the machine turns round outside the shape (a stage's overscan;
    /// a scanner's skywriting). Off: hatch lines start and end as other marks.
    #[serde(default = "default_true")]
    pub overscan: bool,
    /// Air assist (coolant flood, M8) on before this layer's first pierce
    /// or mark, off (M9) at the program's end and on every stop.
    #[serde(default)]
    pub air: bool,
}

fn hatch_spacing() -> f64 {
    0.1
}

/// What a layer marks of its shapes (`[[layer]] mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
pub enum LayerMode {
    /// The outlines, as drawn.
    #[default]
    #[serde(rename = "line")]
    Line,
    /// The area inside the closed shapes, hatched.
    #[serde(rename = "fill")]
    Fill,
    /// The area hatched, then the outlines.
    #[serde(rename = "fill+line")]
    FillLine,
}

impl LayerMode {
    pub fn fills(self) -> bool {
        self != LayerMode::Line
    }
    pub fn lines(self) -> bool {
        self != LayerMode::Fill
    }
}

fn tab_width() -> f64 {
    0.5
}

fn lead_length() -> f64 {
    2.0
}

fn lead_angle() -> f64 {
    90.0
}

/// The shape of a lead-in or lead-out (`[[layer]] lead_in`, `lead_out`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum LeadKind {
    #[default]
    None,
    Line,
    Arc,
}

/// Where a closed contour's lead-in goes (`[[layer]] lead_in_at`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum LeadAt {
    /// Where the planner enters the contour.
    #[default]
    Entry,
    /// The contour's corner nearest to the planner's entry.
    Corner,
    /// The middle of the contour's longest straight side.
    Longest,
}

/// How a kerf offset goes round a convex corner (`[[layer]] kerf_corners`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum KerfCorners {
    /// An arc of half the kerf about the corner: the beam's edge touches the
    /// corner all the way round (the offset every CAM tool makes first).
    #[default]
    Round,
    /// The two offset sides extended until they meet (a miter).
    Sharp,
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
    /// Reads and validates a config file; `None` is the built-in default
    /// machine (no search: commands find theirs with `ConfigSearch`).
    pub fn load(path: Option<&Path>) -> Result<MachineConfig> {
        match path {
            Some(path) => Self::load_with_text(Some(path)).map(|(config, _)| config),
            None => Ok(Self::builtin()),
        }
    }

    /// The config and its text as read (the service hands the same text to
    /// its planning processes); `None` is the built-in default machine.
    pub fn load_with_text(path: Option<&Path>) -> Result<(MachineConfig, String)> {
        let Some(path) = path else { return Ok((Self::builtin(), DEFAULT_CONFIG_TEXT.to_string())) };
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::Config(format!("{}: cannot read: {e}", path.display())))?;
        Ok((Self::parse(&text, &path.display().to_string())?, text))
    }

    /// A config that came from elsewhere than a file (a recording's, which
    /// is untrusted), checked as a file's is; `origin` names it in errors.
    pub fn checked(self, origin: &str) -> Result<MachineConfig> {
        self.validate().map_err(|e| Error::Config(format!("{origin}: {e}")))?;
        Ok(self)
    }

    /// The default machine built into the binary (`config/laserd.toml`).
    pub fn builtin() -> MachineConfig {
        // Checked by the tests (default_config_is_valid_and_has_a_scanner):
        // the shipped file always parses.
        Self::parse(DEFAULT_CONFIG_TEXT, "the built-in config/laserd.toml").expect("the built-in config/laserd.toml is valid")
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
        for warning in config.warnings() {
            tracing::warn!("{origin}: {warning}");
        }
        Ok(config)
    }

    /// Settings that are valid but unlikely on a real machine, each naming
    /// them: the command goes on, the log says so. A scanner field wider than
    /// the stage's travel can be planned (the scanner then reaches past the
    /// travel), but a stage that carries the scanner less far than the lens
    /// reaches is more often a travel or field in the wrong unit.
    pub fn warnings(&self) -> Vec<String> {
        let Some(sc) = &self.scanner else { return vec![] };
        [("x", sc.field_x, self.stage.travel_x), ("y", sc.field_y, self.stage.travel_y)]
            .into_iter()
            .filter(|(_, field, travel)| field > travel)
            .map(|(axis, field, travel)| {
                format!("scanner.field_{axis} = {field} mm is larger than stage.travel_{axis} = {travel} mm: is one of them in the wrong unit?")
            })
            .collect()
    }

    fn validate(&self) -> std::result::Result<(), String> {
        let s = &self.stage;
        TRAVEL.check("stage.travel_x", s.travel_x)?;
        TRAVEL.check("stage.travel_y", s.travel_y)?;
        VELOCITY.check("stage.max_velocity", s.max_velocity)?;
        ACCELERATION.check("stage.max_acceleration", s.max_acceleration)?;
        JERK.check("stage.max_jerk", s.max_jerk)?;
        if let Some(sc) = &self.scanner {
            FIELD.check("scanner.field_x", sc.field_x)?;
            FIELD.check("scanner.field_y", sc.field_y)?;
            in_range("scanner.usable_half_field", sc.usable_half_field, 0.5, sc.field_x.min(sc.field_y) / 2.0, "mm (half the field)")?;
            VELOCITY.check("scanner.mark_speed", sc.mark_speed)?;
            VELOCITY.check("scanner.jump_speed", sc.jump_speed)?;
            if sc.mark_speed > sc.jump_speed {
                return Err("scanner.mark_speed: must not exceed scanner.jump_speed".into());
            }
            ACCELERATION.check("scanner.max_acceleration", sc.max_acceleration)?;
            JERK.check("scanner.max_jerk", sc.max_jerk)?;
            for (i, l) in sc.axis_letters.iter().enumerate() {
                let ok = l.len() == 1 && "ZABCUVW".contains(l.as_str());
                if !ok {
                    return Err(format!("scanner.axis_letters[{i}]: '{l}' is not one of Z A B C U V W"));
                }
            }
            if sc.axis_letters[0] == sc.axis_letters[1] {
                return Err("scanner.axis_letters: the two letters must differ".into());
            }
            // Grbl 1.1h has X, Y and Z only: two scanner axes beside the stage's
            // take a grblHAL board.
            if self.simulator.flavor == laserd_sim::controller::Flavor::Grbl {
                return Err(format!(
                    "[simulator] flavor: \"grbl\" is Grbl 1.1h, which has only the axes X, Y and Z, not the scanner's {}: \
                     use flavor = \"grblhal\" (and its buffers: serial.rx_buffer = 1024, simulator.planner_blocks = 100)",
                    sc.axis_letters.join(" ")
                ));
            }
        }
        let laser = &self.laser;
        MAX_POWER.check("laser.max_power", laser.max_power)?;
        let power = |name: &str, v: f64| in_range(name, v, 0.0, laser.max_power, "(laser.max_power)");
        PIERCE_TIME.check("laser.pierce_time", laser.pierce_time)?;
        if let Some(p) = laser.pierce_power {
            power("laser.pierce_power", p)?;
        }
        LASER_DELAY.check("laser.on_delay", laser.on_delay)?;
        LASER_DELAY.check("laser.off_delay", laser.off_delay)?;
        BAUD.check("serial.baud", self.serial.baud)?;
        in_range("serial.rx_buffer", self.serial.rx_buffer, 16, 65_536, "bytes")?;
        in_range("serial.status_hz", self.serial.status_hz, 0.1, 100.0, "Hz")?;
        TOLERANCE.check("import.tolerance", self.import.tolerance)?;
        in_range("import.svg_dpi", self.import.svg_dpi, 10.0, 10_000.0, "dpi")?;
        let m = &self.motion;
        SHARE.check("motion.limit_margin", m.limit_margin)?;
        TOLERANCE.check("motion.corner_tolerance", m.corner_tolerance)?;
        in_range("motion.line_tolerance", m.line_tolerance, 0.0, TOLERANCE.hi, TOLERANCE.unit)?;
        SHARE.check("motion.stage_share", m.stage_share)?;
        let p = &self.program;
        TOLERANCE.check("program.tolerance", p.tolerance)?;
        TOLERANCE.check("program.jump_tolerance", p.jump_tolerance)?;
        in_range("program.decimals", p.decimals, 2, 9, "")?;
        in_range("program.scanner_decimals", p.scanner_decimals, 2, 7, "")?;
        in_range("simulator.planner_blocks", self.simulator.planner_blocks, 1, 10_000, "blocks")?;
        in_range("simulator.junction_deviation", self.simulator.junction_deviation, 0.0, TOLERANCE.hi, TOLERANCE.unit)?;
        let c = &self.cutting;
        in_range("cutting.pierce_cost", c.pierce_cost, 0.0, TRAVEL.hi, TRAVEL.unit)?;
        TOLERANCE.check("cutting.common_cut_tolerance", c.common_cut_tolerance)?;
        in_range("cutting.corner_angle", c.corner_angle, 1.0, 180.0, "degrees")?;
        in_range("cutting.bridge_max", c.bridge_max, 0.0, 1000.0, "mm (0: no bridges)")?;
        in_range("cutting.precut_length", c.precut_length, 0.0, 100.0, "mm (0: no pre-cuts)")?;
        in_range("cutting.sharp_angle_cost", c.sharp_angle_cost, 0.0, 1000.0, "mm")?;
        if let Some(t) = c.time_limit {
            TIME_LIMIT.check("cutting.time_limit", t)?;
        }
        let g = &self.galvo;
        DIRECTION_WEIGHT.check("galvo.direction_weight", g.direction_weight)?;
        DIRECTION_WEIGHT.check("galvo.direction_weight_single_field", g.direction_weight_single_field)?;
        route_objective_terms(&c.objective).map_err(|e| format!("cutting.objective: {e}"))?;
        route_objective_terms(&g.objective).map_err(|e| format!("galvo.objective: {e}"))?;
        let f = &self.fill;
        objective_terms(&f.objective).map_err(|e| format!("fill.objective: {e}"))?;
        in_range("fill.heat_radius", f.heat_radius, 0.001, 1000.0, "mm")?;
        in_range("fill.cooling_time", f.cooling_time, 0.001, 3600.0, "s")?;
        in_range("fill.population", f.population, 2, 1000, "routes")?;
        in_range("fill.stall_generations", f.stall_generations, 1, 100_000, "generations")?;
        if let Some(t) = g.time_limit {
            TIME_LIMIT.check("galvo.time_limit", t)?;
        }
        in_range("import.max_file_mb", self.import.max_file_mb, 0.001, 4096.0, "MB")?;
        in_range("import.max_elements", self.import.max_elements, 1, 100_000_000, "elements")?;
        in_range("import.max_points", self.import.max_points, 1_000, 1_000_000_000, "points")?;
        in_range("service.keep_jobs", self.service.keep_jobs, 0, 1_000_000, "jobs")?;
        in_range("service.plan_timeout", self.service.plan_timeout, 1.0, 86_400.0, "s")?;
        in_range("service.plan_memory_mb", self.service.plan_memory_mb, 256.0, 1_048_576.0, "MB")?;
        in_range("service.jog_feed", self.service.jog_feed, 1.0, 60_000.0, "mm/min")?;
        if let Some(plate) = &self.plate {
            self.validate_plate(plate)?;
        }
        self.validate_head()?;
        self.validate_thermal()?;
        self.service.foxglove_address()?;
        if let Some(folder) = self.service.job_folders.iter().find(|f| !Path::new(f).is_absolute()) {
            return Err(format!("service.job_folders: {folder:?} is not an absolute path"));
        }
        if self.layers.is_empty() {
            return Err("layer: at least one [[layer]] is needed".into());
        }
        for (i, l) in self.layers.iter().enumerate() {
            let name = |setting: &str| format!("layer[{i}] ({}).{setting}", l.name);
            VELOCITY.check(&name("speed"), l.speed)?;
            power(&name("power"), l.power)?;
            if let Some(t) = l.pierce_time {
                PIERCE_TIME.check(&name("pierce_time"), t)?;
            }
            if let Some(p) = l.pierce_power {
                power(&name("pierce_power"), p)?;
            }
            PASSES.check(&name("passes"), l.passes)?;
            KERF.check(&name("kerf"), l.kerf)?;
            LEAD_LENGTH.check(&name("lead_in_length"), l.lead_in_length)?;
            LEAD_LENGTH.check(&name("lead_out_length"), l.lead_out_length)?;
            LEAD_ANGLE.check(&name("lead_in_angle"), l.lead_in_angle)?;
            LEAD_ANGLE.check(&name("lead_out_angle"), l.lead_out_angle)?;
            LEAD_LENGTH.check(&name("overcut"), l.overcut)?;
            LEAD_LENGTH.check(&name("closing_gap"), l.closing_gap)?;
            for (kind, length, setting) in [(l.lead_in, l.lead_in_length, "lead_in_length"), (l.lead_out, l.lead_out_length, "lead_out_length")] {
                if kind != LeadKind::None {
                    in_range(&name(setting), length, 0.05, LEAD_LENGTH.hi, "mm (a lead needs a length)")?;
                }
            }
            in_range(&name("tabs"), l.tabs, 0, 1000, "tabs per outline")?;
            in_range(&name("tab_spacing"), l.tab_spacing, 0.0, TRAVEL.hi, "mm (0: by count)")?;
            in_range(&name("tab_width"), l.tab_width, 0.01, 50.0, "mm")?;
            HATCH_SPACING.check(&name("hatch_spacing"), l.hatch_spacing)?;
            HATCH_ANGLE.check(&name("hatch_angle"), l.hatch_angle)?;
            if l.mode.fills() && self.pierce(&l.name).active() {
                return Err(format!("{}: a layer that pierces (cuts through) cannot fill; fill on a marking layer (pierce_time = 0)", name("mode")));
            }
            if l.overcut > 0.0 && l.closing_gap > 0.0 {
                return Err(format!("{}: a contour is either cut past its start (overcut) or left short of it (closing_gap), not both", name("closing_gap")));
            }
            if let Some(c) = l.color.filter(|c| !(1..=255).contains(c)) {
                return Err(format!("{}: {c} is not an AutoCAD colour index (1 to 255)", name("color")));
            }
            if let Some(c) = &l.stroke {
                if parse_hex_colour(c).is_none() {
                    return Err(format!("{}: '{c}' is not a #rrggbb colour", name("stroke")));
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

    /// The head's Z limits, where it has a Z axis.
    pub fn head_limits(&self) -> Option<Limits> {
        self.head.as_ref().map(|h| Limits { velocity: h.max_velocity, acceleration: h.max_acceleration, jerk: h.max_jerk })
    }

    /// The support grid's spacing where pieces cut free may tip and the
    /// head lifts over them.
    pub fn support_grid(&self) -> Option<f64> {
        self.plate.as_ref().and_then(|p| p.support_grid)
    }

    pub fn stage_limits(&self) -> Limits {
        Limits {
            velocity: self.stage.max_velocity,
            acceleration: self.stage.max_acceleration,
            jerk: self.stage.max_jerk,
        }
    }

    /// The longest a stop from full speed takes (s): over the stage and the
    /// scanner, top speed over deceleration, plus the time the jerk limit
    /// takes to bring the deceleration in and out.
    pub fn stop_time_s(&self) -> f64 {
        let stop = |l: Limits| l.velocity / l.acceleration + if l.jerk > 0.0 { l.acceleration / l.jerk } else { 0.0 };
        self.scanner_limits().map_or(0.0, stop).max(stop(self.stage_limits()))
    }

    /// Scanner limits with the jump speed as the velocity limit (the scanner's own cap).
    pub fn scanner_limits(&self) -> Option<Limits> {
        self.scanner.as_ref().map(|s| Limits {
            velocity: s.jump_speed,
            acceleration: s.max_acceleration,
            jerk: s.max_jerk,
        })
    }

    /// The `[[layer]]` named `name`.
    pub fn layer(&self, name: &str) -> Option<&LayerConfig> {
        self.layers.iter().find(|l| l.name == name)
    }

    /// Whether the fill of the layer named `layer` is overscanned (unknown: not).
    pub fn overscans(&self, layer: &str) -> bool {
        self.layer(layer).is_some_and(|l| l.overscan)
    }

    /// The pierce of the layer named `layer`: its own settings, else those of
    /// `[laser]`, the power falling back to the layer's own. An unknown layer
    /// gets `[laser]`'s (power: its pierce power, else full power).
    pub fn pierce(&self, layer: &str) -> Pierce {
        let l = self.layer(layer);
        // A fill marks; it pierces only where its own layer says so (refused).
        let inherited = if l.is_some_and(|l| l.mode.fills()) { 0.0 } else { self.laser.pierce_time };
        let time = l.and_then(|l| l.pierce_time).unwrap_or(inherited);
        let power = l
            .and_then(|l| l.pierce_power)
            .or(self.laser.pierce_power)
            .or(l.map(|l| l.power))
            .unwrap_or(self.laser.max_power);
        Pierce { power, time }
    }

    /// Whether `layer`'s closed contours cut parts out of the sheet (it
    /// pierces, or sets a kerf or leads): they decide what is a part, a
    /// hole, and the waste.
    pub fn cuts_parts(&self, layer: &str) -> bool {
        let l = self.layer(layer);
        self.pierce(layer).active() || l.is_some_and(|l| l.kerf > 0.0 || l.lead_in != LeadKind::None || l.lead_out != LeadKind::None)
    }

    fn validate_thermal(&self) -> std::result::Result<(), String> {
        if let Some(w) = self.laser.watts {
            in_range("laser.watts", w, 0.1, 1e6, "W")?;
        }
        let t = &self.thermal;
        in_range("thermal.cell", t.cell, 0.5, 100.0, "mm")?;
        in_range("thermal.ambient", t.ambient, -50.0, 100.0, "°C")?;
        in_range("thermal.convection_top", t.convection_top, 0.0, 1e4, "W/(m²·K)")?;
        in_range("thermal.convection_bottom", t.convection_bottom, 0.0, 1e4, "W/(m²·K)")?;
        in_range("thermal.corner_dwell", t.corner_dwell, 0.0, 10.0, "s")?;
        in_range("thermal.responsiveness", t.responsiveness, 0.01, 1.0, "")?;
        in_range("thermal.penalty", t.penalty, 0.0, 1e6, "mm")?;
        in_range("thermal.reach", t.reach, 0.0, 10_000.0, "mm")?;
        in_range("thermal.iterations", t.iterations, 1, 10_000, "constructions")?;
        in_range("thermal.stall", t.stall, 1, 10_000, "constructions")?;
        if let Some(m) = &self.material {
            in_range("material.thickness", m.thickness, 0.01, 500.0, "mm")?;
            in_range("material.density", m.density, 10.0, 30_000.0, "kg/m³")?;
            in_range("material.specific_heat", m.specific_heat, 10.0, 10_000.0, "J/(kg·K)")?;
            in_range("material.conductivity", m.conductivity, 0.01, 2_000.0, "W/(m·K)")?;
            in_range("material.emissivity", m.emissivity, 0.0, 1.0, "")?;
            in_range("material.absorptivity", m.absorptivity, 0.0, 1.0, "")?;
            // Above the air it cools to, or nothing could ever be cut after a wait.
            let critical = |name: &str, v: f64| in_range(name, v, t.ambient + 1.0, 3_000.0, "°C (above thermal.ambient)");
            critical("material.critical_pierce", m.critical_pierce)?;
            critical("material.critical_cut", m.critical_cut)?;
            critical("material.critical_corner", m.critical_corner)?;
        }
        Ok(())
    }

    fn validate_head(&self) -> std::result::Result<(), String> {
        let grid = self.plate.as_ref().and_then(|p| p.support_grid);
        if let Some(g) = grid {
            in_range("plate.support_grid", g, 1.0, 1000.0, "mm")?;
        }
        let Some(h) = &self.head else {
            return match grid {
                Some(_) => Err("plate.support_grid: lifting over pieces that may tip needs the head's Z axis: add [head]".into()),
                None => Ok(()),
            };
        };
        in_range("head.travel_z", h.travel_z, 1.0, 1000.0, "mm")?;
        in_range("head.lift_height", h.lift_height, 0.1, h.travel_z, "mm (up to head.travel_z)")?;
        VELOCITY.check("head.max_velocity", h.max_velocity)?;
        ACCELERATION.check("head.max_acceleration", h.max_acceleration)?;
        JERK.check("head.max_jerk", h.max_jerk)?;
        in_range("head.clearance", h.clearance, 0.0, 100.0, "mm")?;
        if self.scanner.is_some() {
            return Err("head: a Z axis beside a scanner is not supported (lift moves are for stage-only cutters); remove [head] or [scanner]".into());
        }
        Ok(())
    }

    fn validate_plate(&self, p: &PlateConfig) -> std::result::Result<(), String> {
        let place = |name: &str, v: f64| in_range(name, v, -TRAVEL.hi, TRAVEL.hi, TRAVEL.unit);
        place("plate.x", p.x)?;
        place("plate.y", p.y)?;
        TRAVEL.check("plate.width", p.width)?;
        TRAVEL.check("plate.height", p.height)?;
        in_range("plate.thickness", p.thickness, 0.01, 500.0, "mm")?;
        if p.skeleton_piece != 0.0 {
            in_range("plate.skeleton_piece", p.skeleton_piece, 10.0, TRAVEL.hi, "mm (0: the skeleton left whole)")?;
        }
        in_range("plate.remnant_min", p.remnant_min, 1.0, TRAVEL.hi, TRAVEL.unit)?;
        in_range("plate.clearance", p.clearance, 0.0, 100.0, "mm")?;
        if let RemnantSetting::At([x, y, w, h]) = p.remnant {
            place("plate.remnant x", x)?;
            place("plate.remnant y", y)?;
            TRAVEL.check("plate.remnant width", w)?;
            TRAVEL.check("plate.remnant height", h)?;
        }
        in_range("plate.clamp count", p.clamps.len(), 0, 256, "clamps")?;
        for (i, c) in p.clamps.iter().enumerate() {
            place(&format!("plate.clamp[{i}].x"), c.x)?;
            place(&format!("plate.clamp[{i}].y"), c.y)?;
            in_range(&format!("plate.clamp[{i}].radius"), c.radius, 0.1, 1000.0, "mm")?;
        }
        if let Some(layer) = &p.layer {
            if !self.layers.iter().any(|l| &l.name == layer) {
                return Err(format!("plate.layer: no [[layer]] is named '{layer}'"));
            }
            if !self.pierce(layer).active() {
                return Err(format!("plate.layer: layer '{layer}' does not pierce (pierce_time 0), so it cuts nothing through"));
            }
        } else if !self.layers.iter().any(|l| self.pierce(&l.name).active()) {
            return Err("plate: no layer pierces, so nothing cuts the plate; set a layer's pierce_time".into());
        }
        Ok(())
    }

    /// The layer that cuts `plate`'s skeleton and remnant: its `layer`, else
    /// the first layer that pierces.
    pub fn plate_layer<'a>(&'a self, plate: &'a PlateConfig) -> Option<&'a str> {
        plate.layer.as_deref().or_else(|| self.layers.iter().map(|l| l.name.as_str()).find(|l| self.pierce(l).active()))
    }

    /// Index of the default layer in `layers` (validated to exist).
    pub fn default_layer_index(&self) -> usize {
        self.layers.iter().position(|l| l.name == self.default_layer).unwrap_or(0)
    }

    /// Axis letters of the controller: X Y, then the scanner's if there is one.
    pub fn axis_letters(&self) -> Vec<char> {
        let mut letters = vec!['X', 'Y'];
        if self.head.is_some() {
            letters.push('Z');
        }
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

    /// The search order: --config, $LASERD_CONFIG, the system file, the
    /// user's, the built-in machine; a named file that cannot be read is an
    /// error, not skipped. (Temporary files stand for /etc and the user's folder.)
    #[test]
    fn config_search_takes_the_first_place_that_has_a_config() {
        let dir = tempfile::tempdir().unwrap();
        let file = |name: &str| {
            let path = dir.path().join(name);
            std::fs::write(&path, default_text().replace("travel_x = 300.0", &format!("travel_x = {}.0", 100 + name.len()))).unwrap();
            path
        };
        let mut search = ConfigSearch { option: None, env: None, system: dir.path().join("etc.toml"), user: Some(dir.path().join("user.toml")) };
        let found = search.find().unwrap();
        assert_eq!(found.source, ConfigSource::Builtin);
        assert_eq!(found.machine.stage.travel_x, 300.0);
        assert!(search.find_file().unwrap_err().to_string().contains("no machine config"));
        // Places filled from the last searched to the first: each takes over.
        let user = file("user.toml");
        assert_eq!(search.find().unwrap().source, ConfigSource::User { path: user });
        let system = file("etc.toml");
        assert_eq!(search.find().unwrap().source, ConfigSource::System { path: system });
        search.env = Some(file("environment.toml"));
        assert_eq!(search.find().unwrap().source, ConfigSource::Env { path: dir.path().join("environment.toml") });
        search.option = Some(file("option-given.toml"));
        let found = search.find().unwrap();
        assert_eq!(found.source, ConfigSource::Option { path: dir.path().join("option-given.toml") });
        // The file found is the file read (each has its own travel).
        assert_eq!(found.machine.stage.travel_x, 117.0);
        assert!(found.text.contains("travel_x = 117.0"));
        // Named but missing: an error naming it, not the next place.
        search.option = None;
        search.env = Some(dir.path().join("missing.toml"));
        let err = search.find().unwrap_err().to_string();
        assert!(err.contains("missing.toml: cannot read"), "{err}");
    }

    /// Issue 17, point 6: a field larger than the travel is said, naming both settings.
    #[test]
    fn a_scanner_field_larger_than_the_travel_is_named() {
        assert!(MachineConfig::builtin().warnings().is_empty());
        let text = default_text().replace("travel_y = 300.0", "travel_y = 50.0").replace("field_y = 70.0", "field_y = 120.0");
        let warnings = MachineConfig::parse(&text, "t.toml").unwrap().warnings();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("scanner.field_y = 120") && warnings[0].contains("stage.travel_y = 50"), "{warnings:?}");
    }

    #[test]
    fn the_built_in_machine_is_the_shipped_file() {
        assert_eq!(DEFAULT_CONFIG_TEXT, default_text());
    }

    #[test]
    fn default_config_is_valid_and_has_a_scanner() {
        let c = MachineConfig::load(None).unwrap();
        assert_eq!(c.axis_letters(), vec!['X', 'Y', 'U', 'V']);
        assert_eq!(c.stage.travel_x, 300.0);
        assert_eq!(c.scanner.as_ref().unwrap().usable_half_field, 32.0);
        assert!(c.scanner.as_ref().unwrap().split_oversize);
    }

    /// Grbl 1.1h has X, Y and Z only: the galvo's U and V take grblHAL,
    /// and the error says where and what instead.
    #[test]
    fn a_scanner_needs_the_grblhal_flavour() {
        let text = default_text();
        assert!(text.contains("flavor = \"grblhal\"\n"));
        let err = MachineConfig::parse(&text.replace("flavor = \"grblhal\"\n", "flavor = \"grbl\"\n"), "t.toml").unwrap_err().to_string();
        assert!(err.contains("t.toml: [simulator] flavor:") && err.contains("U V") && err.contains("flavor = \"grblhal\""), "{err}");
        // The default flavour is grbl: leaving it out with a scanner is the same error.
        assert!(MachineConfig::parse(&text.replace("flavor = \"grblhal\"\n", ""), "t.toml").is_err());
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

    /// The shipped config with one value set: `path` is `section.key`, or
    /// `layer.N.key` for the N-th layer.
    fn with_value(path: &str, value: toml::Value) -> String {
        let mut doc: toml::Table = toml::from_str(&default_text()).unwrap();
        let parts: Vec<&str> = path.split('.').collect();
        // Sections the default machine leaves out, complete and valid.
        if parts[0] == "material" {
            let steel = "thickness = 6.0\ndensity = 7832.0\nspecific_heat = 434.0\nconductivity = 63.9\nemissivity = 0.79\nabsorptivity = 0.3\ncritical_pierce = 70.0\ncritical_cut = 80.0\ncritical_corner = 60.0";
            doc.insert("material".into(), toml::Value::Table(toml::from_str(steel).unwrap()));
        }
        if parts[0] == "thermal" {
            doc.entry("thermal").or_insert(toml::Value::Table(toml::Table::new()));
        }
        let table = match parts[..] {
            [section, _] => doc.get_mut(section).and_then(|s| s.as_table_mut()).unwrap(),
            ["layer", n, _] => doc["layer"].as_array_mut().unwrap()[n.parse::<usize>().unwrap()].as_table_mut().unwrap(),
            _ => panic!("{path}"),
        };
        table.insert(parts[parts.len() - 1].to_string(), value);
        toml::to_string(&doc).unwrap()
    }

    /// Issue 16, findings 10 and 11: values that passed validation and then
    /// panicked, hung or overflowed planning are refused, each naming the
    /// setting and its range; every numeric setting has both ends.
    #[test]
    fn every_numeric_setting_is_refused_outside_its_range_by_name() {
        use toml::Value::{Float as F, Integer as I};
        let cases: Vec<(&str, toml::Value)> = vec![
            // The reported ones.
            ("serial.status_hz", F(1e-300)),
            ("serial.status_hz", F(1e300)),
            ("import.tolerance", F(1e-300)),
            ("cutting.time_limit", F(1e30)),
            ("cutting.time_limit", F(1e19)),
            ("galvo.time_limit", F(1e30)),
            ("galvo.time_limit", F(1e19)),
            ("layer.0.passes", I(4_294_967_295)),
            ("stage.max_velocity", F(1e-300)),
            ("layer.1.speed", F(5e-324)),
            ("stage.max_velocity", F(1e308)),
            ("stage.max_acceleration", F(1e308)),
            ("stage.max_jerk", F(1e308)),
            ("stage.travel_x", F(1e308)),
            // Every other number, one end or the other.
            ("stage.travel_y", F(0.5)),
            ("stage.max_acceleration", F(0.1)),
            ("stage.max_jerk", F(0.5)),
            ("scanner.field_x", F(1e6)),
            ("scanner.field_y", F(0.1)),
            ("scanner.usable_half_field", F(0.01)),
            ("scanner.usable_half_field", F(36.0)),
            ("scanner.mark_speed", F(1e-9)),
            ("scanner.jump_speed", F(1e9)),
            ("scanner.max_acceleration", F(1e12)),
            ("scanner.max_jerk", F(1e20)),
            ("laser.max_power", F(1e300)),
            ("laser.max_power", F(0.0)),
            ("laser.on_delay", F(1.0)),
            ("laser.off_delay", F(-1e-3)),
            ("serial.baud", I(0)),
            ("serial.baud", I(4_000_000_000)),
            ("serial.rx_buffer", I(8)),
            ("serial.rx_buffer", I(1 << 40)),
            ("import.tolerance", F(100.0)),
            ("import.svg_dpi", F(1e-300)),
            ("import.svg_dpi", F(1e9)),
            ("motion.limit_margin", F(1e-300)),
            ("motion.limit_margin", F(1.5)),
            ("motion.corner_tolerance", F(1e-9)),
            ("motion.line_tolerance", F(1e300)),
            ("motion.stage_share", F(1e-9)),
            ("program.tolerance", F(1e-9)),
            ("program.jump_tolerance", F(1e300)),
            ("program.decimals", I(12)),
            ("program.scanner_decimals", I(1)),
            ("simulator.planner_blocks", I(0)),
            ("simulator.planner_blocks", I(1 << 40)),
            ("simulator.junction_deviation", F(-0.01)),
            ("simulator.junction_deviation", F(1e300)),
            ("cutting.pierce_cost", F(1e300)),
            ("cutting.pierce_cost", F(-1.0)),
            ("cutting.common_cut_tolerance", F(1e-300)),
            ("cutting.corner_angle", F(1e-300)),
            ("cutting.corner_angle", F(720.0)),
            ("cutting.bridge_max", F(-1.0)),
            ("cutting.bridge_max", F(1e4)),
            ("cutting.precut_length", F(-1.0)),
            ("cutting.precut_length", F(1e3)),
            ("cutting.sharp_angle_cost", F(f64::NAN)),
            ("cutting.sharp_angle_cost", F(1e4)),
            ("cutting.time_limit", F(1e-300)),
            ("galvo.direction_weight", F(1e300)),
            ("galvo.direction_weight_single_field", F(-0.5)),
            ("service.keep_jobs", I(1 << 40)),
            ("service.plan_timeout", F(1e30)),
            ("service.plan_memory_mb", F(1.0)),
            ("service.jog_feed", F(0.0)),
            ("service.jog_feed", F(1e6)),
            ("import.max_file_mb", F(1e9)),
            ("layer.0.speed", F(1e300)),
            ("layer.0.power", F(1e300)),
            ("layer.0.passes", I(0)),
            ("layer.2.pierce_time", F(1e300)),
            ("layer.2.pierce_power", F(-1.0)),
            ("layer.1.kerf", F(-0.1)),
            ("layer.1.kerf", F(f64::NAN)),
            ("layer.1.kerf", F(11.0)),
            ("layer.1.lead_in_length", F(-1.0)),
            ("layer.1.lead_out_length", F(1e9)),
            ("layer.1.lead_in_angle", F(0.0)),
            ("layer.1.lead_out_angle", F(181.0)),
            ("layer.1.overcut", F(f64::NAN)),
            ("layer.1.closing_gap", F(-0.5)),
            ("layer.1.tabs", I(1001)),
            ("layer.1.tab_spacing", F(-1.0)),
            ("layer.1.tab_width", F(0.0)),
            ("layer.1.hatch_spacing", F(0.0)),
            ("layer.1.hatch_spacing", F(11.0)),
            ("layer.1.hatch_angle", F(400.0)),
            ("laser.watts", F(0.0)),
            ("thermal.cell", F(0.1)),
            ("thermal.ambient", F(500.0)),
            ("thermal.convection_top", F(-1.0)),
            ("thermal.convection_bottom", F(1e9)),
            ("thermal.corner_dwell", F(100.0)),
            ("thermal.responsiveness", F(0.0)),
            ("thermal.penalty", F(f64::NAN)),
            ("thermal.iterations", I(0)),
            ("thermal.stall", I(0)),
            ("thermal.reach", F(-1.0)),
            ("material.thickness", F(0.0)),
            ("material.density", F(1e9)),
            ("material.specific_heat", F(1.0)),
            ("material.conductivity", F(1e5)),
            ("material.emissivity", F(1.5)),
            ("material.absorptivity", F(-0.1)),
            ("material.critical_pierce", F(20.0)),
            ("material.critical_cut", F(1e4)),
            ("material.critical_corner", F(f64::NAN)),
        ];
        for (path, value) in cases {
            let shown = value.to_string();
            let err = MachineConfig::parse(&with_value(path, value), "t.toml").unwrap_err().to_string();
            let setting = match path.strip_prefix("layer.") {
                Some(rest) => {
                    let (n, key) = rest.split_once('.').unwrap();
                    let layer = ["mark", "cut", "engrave"][n.parse::<usize>().unwrap()];
                    format!("layer[{n}] ({layer}).{key}")
                }
                None => path.to_string(),
            };
            assert!(err.contains(&format!("t.toml: {setting}: must be between ")), "{path} = {shown}: {err}");
            assert!(err.len() < 200, "short, in scientific notation: {err}");
        }
    }

    #[test]
    fn range_errors_show_the_range_and_value_short() {
        let err = MachineConfig::parse(&with_value("serial.status_hz", toml::Value::Float(1e300)), "t.toml").unwrap_err().to_string();
        assert!(err.ends_with("t.toml: serial.status_hz: must be between 0.1 and 100 Hz, got 1e300"), "{err}");
        let err = MachineConfig::parse(&with_value("stage.max_velocity", toml::Value::Float(f64::NAN)), "t.toml").unwrap_err().to_string();
        assert!(err.ends_with("stage.max_velocity: must be between 0.1 and 100000 mm/s, got NaN"), "{err}");
    }

    #[test]
    fn the_ends_of_every_range_are_accepted() {
        use toml::Value::{Float as F, Integer as I};
        for (path, value) in [
            ("serial.status_hz", F(0.1)),
            ("serial.status_hz", F(100.0)),
            ("import.tolerance", F(1e-4)),
            ("cutting.time_limit", F(86_400.0)),
            ("galvo.time_limit", F(0.01)),
            ("layer.0.passes", I(1000)),
            ("stage.max_velocity", F(0.1)),
            ("stage.max_jerk", F(1e14)),
            ("scanner.max_acceleration", F(1e9)),
            ("serial.baud", I(300)),
            ("serial.baud", I(12_000_000)),
            ("motion.line_tolerance", F(0.0)),
            ("service.keep_jobs", I(0)),
            ("service.plan_timeout", F(1.0)),
            ("service.jog_feed", F(1.0)),
            ("service.jog_feed", F(60_000.0)),
            ("import.max_file_mb", F(4096.0)),
        ] {
            let shown = value.to_string();
            assert!(MachineConfig::parse(&with_value(path, value), "t.toml").is_ok(), "{path} = {shown}");
        }
    }

    /// `[service] foxglove` is an IP address and a port, or an error naming it.
    #[test]
    fn a_bad_foxglove_address_is_refused_naming_the_setting() {
        let text = |addr: &str| with_value("service.foxglove", toml::Value::String(addr.into()));
        for bad in ["localhost", "127.0.0.1", "127.0.0.1:0", "127.0.0.1:99999", "not an address", ""] {
            let e = MachineConfig::parse(&text(bad), "t.toml").unwrap_err().to_string();
            assert!(e.contains("[service] foxglove") && e.contains(&format!("{bad:?}")), "{bad}: {e}");
        }
        for good in ["127.0.0.1:8765", "[::1]:8765", "0.0.0.0:1"] {
            let machine = MachineConfig::parse(&text(good), "t.toml").unwrap();
            assert_eq!(machine.service.foxglove_address(), Ok(Some(good.parse().unwrap())), "{good}");
        }
        assert_eq!(MachineConfig::parse(&default_text(), "t.toml").unwrap().service.foxglove_address(), Ok(None));
    }

    #[test]
    fn hex_colours() {
        assert_eq!(parse_hex_colour("#ff0000"), Some([255, 0, 0]));
        assert_eq!(parse_hex_colour("#0f0"), Some([0, 255, 0]));
        assert_eq!(parse_hex_colour("red"), None);
    }
}
