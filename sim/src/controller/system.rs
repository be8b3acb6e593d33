//! The protocol side of the controller apart from G-code (reference §3–§8):
//! `$` system commands (the settings themselves are in `settings.rs`), what
//! Grbl keeps in EEPROM (work offsets, G28/G30 positions, startup lines,
//! build info), feedback messages, the status report's `Pn:`/`A:`/`WCO:`
//! contents, the spindle stop override, probing results and homing outcomes.

use super::{AfterOk, Block, Controller, Flavor, Motion, Pending, SimConfig, Spindle, Step};
use super::settings::{parse_value, Kind};
use crate::wire::{fmt_num, MachineState, StatusReport};

/// Release and build date in Grbl 1.1h's `[VER:]`.
const VERSION: &str = "1.1h.20190830";
/// `[OPT:]` codes of the Grbl 1.1h build simulated: the default
/// configuration (variable spindle) with the safety door input pin.
const OPT_CODES: &str = "V+";
/// grblHAL's version and a build date of its core in `[VER:]`.
const VERSION_HAL: &str = "1.1f.20250731";
/// Longest text an EEPROM line (startup line, build info) holds: 79
/// characters and a terminator. A line never gets longer than that after
/// cleaning, so error 14 cannot actually occur here (nor in Grbl 1.1h).
const EEPROM_LINE: usize = 79;

/// Protocol state besides the modal G-code state. The first group is Grbl's
/// EEPROM: it survives soft resets (not a new `Controller`).
#[derive(Debug, Clone)]
pub(super) struct Protocol {
    /// The configuration as given: `$RST=$` returns the settings to it.
    pub(super) defaults: SimConfig,
    /// Origins of G54..G59 in machine coordinates.
    pub(super) coord: Vec<Vec<f64>>,
    /// G28.1 / G30.1 positions (machine coordinates).
    pub(super) g28: Vec<f64>,
    pub(super) g30: Vec<f64>,
    /// `$N0=` / `$N1=`.
    startup: [String; 2],
    /// `$I=`.
    build_info: String,

    /// G43.1 tool length offset (Z); cleared by a reset.
    pub(super) tlo: f64,
    /// Last probe position (machine) and whether it touched; cleared by a reset.
    probe: Vec<f64>,
    probe_ok: bool,
    /// The spindle stop override is engaged (only during a hold).
    pub(super) spindle_stop: bool,
    /// The startup lines are to run (after a reset that left no alarm; once a
    /// door open at the reset has been closed and resumed).
    startup_due: bool,
    /// Echo each received line as `[echo: ...]` (a Grbl compile option).
    echo: bool,

    /// Machine inputs. The probe touches the work (`Pn:P`).
    pub(super) probe_pin: bool,
    /// A limit switch held down since a hard limit tripped (`Pn:` + axis
    /// letter); the machine leaves it with its next move or homing.
    pub(super) limit_pin: Option<char>,
}

impl Protocol {
    pub(super) fn new(cfg: &SimConfig) -> Protocol {
        let n = cfg.axes.len();
        Protocol {
            defaults: cfg.clone(),
            coord: vec![vec![0.0; n]; coord_systems(cfg.flavor)],
            g28: vec![0.0; n],
            g30: vec![0.0; n],
            startup: Default::default(),
            build_info: String::new(),
            tlo: 0.0,
            probe: vec![0.0; n],
            probe_ok: false,
            spindle_stop: false,
            startup_due: false,
            echo: false,
            probe_pin: false,
            limit_pin: None,
        }
    }

    /// What a soft reset clears (reference §6).
    pub(super) fn reset(&mut self) {
        self.tlo = 0.0;
        self.probe.iter_mut().for_each(|p| *p = 0.0);
        self.probe_ok = false;
        self.spindle_stop = false;
    }
}

/// How a protocol step went, for the line handler.
pub(super) enum StepOutcome {
    /// Not yet: try again later.
    Wait,
    Done,
    /// Done; these steps come next.
    Then(Vec<Step>),
    /// The controller reset itself: the line is gone, no `ok`.
    Reset,
}

impl Controller {
    /// Echo every received line as `[echo: <line after cleaning>]`, as Grbl
    /// built with its echo option does (for debugging a link).
    pub fn set_echo(&mut self, on: bool) {
        self.proto.echo = on;
    }

    pub(super) fn echo_line(&mut self, text: &str) {
        if self.proto.echo {
            // (report.c puts a blank after the colon.)
            self.send(&format!("[echo: {text}]"));
        }
    }

    // ----- report contents -----

    /// Work coordinate offset in force: active G54..G59 + G92 + TLO (on Z).
    pub(super) fn wco(&self) -> Vec<f64> {
        let wcs = &self.proto.coord[usize::from(self.modal.coord.saturating_sub(54)).min(self.proto.coord.len() - 1)];
        let z = self.axis_index('Z');
        (0..self.pos.len())
            .map(|i| wcs[i] + self.g92[i] + if Some(i) == z { self.proto.tlo } else { 0.0 })
            .collect()
    }

    /// Positions, offsets and feeds (mm, mm/min) in the units reports use:
    /// inches with `$13=1`.
    pub(super) fn report_units(&self, mm: &[f64]) -> Vec<f64> {
        let scale = if self.inch_reports() { 25.4 } else { 1.0 };
        mm.iter().map(|v| v / scale).collect()
    }

    /// `$13`: report in inches.
    fn inch_reports(&self) -> bool {
        self.setting(13) != 0.0
    }

    /// A status report as text, in the reporting units.
    pub(super) fn report_text(&self, report: &StatusReport) -> String {
        if self.inch_reports() {
            report.to_line_inches()
        } else {
            report.to_line()
        }
    }

    /// Axis values as `$#`, `[PRB:]` and `[TLO:]` print them: 3 decimals in
    /// mm, 4 in inches.
    pub(super) fn coord_text(&self, mm: &[f64]) -> String {
        let decimals = if self.inch_reports() { 4 } else { 3 };
        self.report_units(mm).iter().map(|x| fmt_num(*x, decimals)).collect::<Vec<_>>().join(",")
    }

    /// A feed as `$G` prints it: whole mm/min, or in/min with one decimal
    /// (`$13`, not the G20/G21 mode: the parser keeps feeds in mm/min).
    fn rate_text(&self, mm_per_min: f64) -> String {
        fmt_num(self.report_units(&[mm_per_min])[0], if self.inch_reports() { 1 } else { 0 })
    }

    /// `Pn:` letters: probe, limit switch, door.
    pub(super) fn pins(&self) -> Option<String> {
        let mut p = String::new();
        if self.proto.probe_pin {
            p.push('P');
        }
        if let Some(axis) = self.proto.limit_pin {
            p.push(axis);
        }
        if self.door_open {
            p.push('D');
        }
        (!p.is_empty()).then_some(p)
    }

    /// `A:` letters: what is actually on. A door or sleep switches spindle
    /// and coolant off, the spindle stop override the spindle.
    pub(super) fn accessories(&self) -> Option<String> {
        if self.door || self.sleep {
            return None;
        }
        let mut a = String::new();
        match self.modal.spindle {
            _ if self.proto.spindle_stop => {}
            Spindle::Cw => a.push('S'),
            Spindle::Ccw => a.push('C'),
            Spindle::Off => {}
        }
        if self.coolant_out[0] {
            a.push('F');
        }
        if self.coolant_out[1] {
            a.push('M');
        }
        (!a.is_empty()).then_some(a)
    }

    // ----- reset, startup lines -----

    /// What follows the banner (reference §6): the alarm lock message, a
    /// limit switch still pressed with hard limits on (which locks too), a door
    /// left open (Door state); otherwise the startup lines are due.
    pub(super) fn after_banner(&mut self) {
        let limit = self.proto.limit_pin.is_some() && self.setting(21) != 0.0;
        if limit {
            self.alarm = true;
        }
        if self.alarm {
            self.send("[MSG:'$H'|'$X' to unlock]");
        }
        if limit {
            self.send("[MSG:Check Limits]");
        }
        if !self.alarm && self.door_open {
            self.send("[MSG:Check Door]");
            self.door = true;
            self.hold = true;
        }
        self.proto.startup_due = !self.alarm;
    }

    /// Startup lines wait for the door to be closed and `~`, and never run
    /// in an alarm.
    pub(super) fn startup_ready(&self) -> bool {
        self.proto.startup_due && !self.alarm && !self.door && !self.sleep
    }

    /// Runs the startup lines as a line of their own that answers with
    /// `>line:ok` echoes instead of an `ok`.
    pub(super) fn begin_startup(&mut self) {
        self.proto.startup_due = false;
        let steps = self.startup_steps();
        if !steps.is_empty() {
            self.pending = Some(Pending { steps: steps.into(), rx_len: 0, taken: 0, dwell_until: None, dwell_left: None, after: AfterOk::Nothing, quiet: true });
        }
    }

    /// Each stored line executed as G-code, followed by its `>line:ok` or
    /// replaced by `>line:error:N`.
    fn startup_steps(&mut self) -> Vec<Step> {
        let mut steps = Vec::new();
        for text in self.proto.startup.clone().iter().filter(|l| !l.is_empty()) {
            match self.gcode(text, self.line_count) {
                Ok(s) => {
                    steps.extend(s);
                    steps.push(Step::Say(format!(">{text}:ok")));
                }
                Err(code) => steps.push(Step::Say(format!(">{text}:error:{code}"))),
            }
        }
        steps
    }

    // ----- holds, spindle stop, alarms -----

    /// A hold begins (`!` or M0). In laser mode Grbl stops the laser with its
    /// spindle stop override (build default), so resuming restores it: with
    /// the next motion, not while the machine stands still (a held dwell goes
    /// on dark after `~`).
    pub(super) fn hold_stops_laser(&mut self) {
        if self.setting(32) != 0.0 && self.modal.spindle != Spindle::Off {
            self.proto.spindle_stop = true;
            self.ov_countdown = 0;
        }
        if self.setting(32) != 0.0 {
            self.rest_s = 0.0;
        }
    }

    /// `0x9E` in Hold: stop the spindle, or restore it if stopped.
    pub(super) fn toggle_spindle_stop(&mut self) {
        if self.proto.spindle_stop {
            self.restore_spindle();
        } else if self.modal.spindle != Spindle::Off {
            self.proto.spindle_stop = true;
            self.ov_countdown = 0;
        }
    }

    /// Ends a spindle stop override (on `~` or a second `0x9E`). Grbl does
    /// not wait for spin-up in laser mode; this simulator never does.
    pub(super) fn restore_spindle(&mut self) {
        if std::mem::take(&mut self.proto.spindle_stop) {
            if self.modal.spindle != Spindle::Off {
                self.send("[MSG:Restoring spindle]");
            }
            self.ov_countdown = 0;
        }
    }

    /// A door turns spindle and coolant off itself and restores them on
    /// resume without a message: it supersedes the spindle stop override.
    pub(super) fn door_clears_spindle_stop(&mut self) {
        self.proto.spindle_stop = false;
    }

    /// A non-critical alarm (probe fail): locked until `$X`/`$H`, no reset.
    fn raise_alarm(&mut self, code: u16) {
        self.alarm = true;
        self.rest_s = 0.0;
        self.stats.alarms.push(code);
        self.send(&format!("ALARM:{code}"));
    }

    pub(super) fn homing_active(&self) -> bool {
        self.exec.as_ref().is_some_and(|e| e.block.homing) || self.planner.iter().any(|b| b.homing)
    }

    /// A failed homing cycle: the alarm, then Grbl resets itself (banner) and
    /// stays locked.
    pub(super) fn homing_fail(&mut self, code: u16) {
        self.stop_motion_now();
        self.planner.clear();
        self.stats.alarms.push(code);
        self.send(&format!("ALARM:{code}"));
        // Grbl's `$H` returns to its line loop before the reset is acted on:
        // the `ok` comes between the alarm and the banner.
        self.send("ok");
        self.alarm = true;
        self.soft_reset();
    }

    /// The protocol's own steps of a pending line.
    pub(super) fn protocol_step(&mut self, step: &Step) -> StepOutcome {
        match step {
            Step::Say(text) => self.send(text),
            Step::Alarm(code) => {
                if *code == 4 {
                    // A probing cycle that cannot start has not succeeded either.
                    self.proto.probe_ok = false;
                }
                self.raise_alarm(*code);
            }
            Step::AwaitResume if self.hold => return StepOutcome::Wait,
            Step::Probed { pos, touched, alarm } => {
                if *touched {
                    // Toward the work it now touches, away from it it has left.
                    self.proto.probe_pin = !self.proto.probe_pin;
                    self.proto.probe = pos.clone();
                } else if !*alarm {
                    self.proto.probe = pos.clone();
                }
                // A failed G38.2/.4 leaves the last probe position as it was
                // (Grbl records the position only on contact or in the
                // no-error variants) and reports that.
                self.proto.probe_ok = *touched;
                if *alarm {
                    self.raise_alarm(5);
                }
                let prb = format!("[PRB:{}:{}]", self.coord_text(&self.proto.probe), u8::from(*touched));
                self.send(&prb);
            }
            Step::HomingDone => {
                let f = &self.cfg.faults;
                let fail = if f.homing_switch_missing {
                    Some(9)
                } else if f.homing_pull_off_fails {
                    Some(8)
                } else {
                    None
                };
                if let Some(code) = fail {
                    self.homing_fail(code);
                    return StepOutcome::Reset;
                }
                self.proto.limit_pin = None;
                return StepOutcome::Then(self.startup_steps());
            }
            _ => {}
        }
        StepOutcome::Done
    }

    // ----- `$` commands -----

    /// A `$` line (without the `$`; `$J=` is handled by the jog parser).
    /// Ok(steps before the `ok`, what follows the `ok`) or Err(code), in the
    /// order Grbl's system.c checks them.
    pub(super) fn system_command(&mut self, cmd: &str) -> Result<(Vec<Step>, AfterOk), u16> {
        let done = Ok((Vec::new(), AfterOk::Nothing));
        let state = self.state();
        let idle_or_alarm = matches!(state, MachineState::Idle | MachineState::Alarm);
        match cmd {
            "" => self.send("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"),
            "$" => {
                if matches!(state, MachineState::Run | MachineState::Hold(_)) {
                    return Err(8);
                }
                for (n, kind, v) in self.settings() {
                    let text = match kind {
                        Kind::Float => fmt_num(v, 3),
                        _ => fmt_num(v, 0),
                    };
                    self.send(&format!("${n}={text}"));
                }
            }
            "G" => {
                let gc = self.gc_line();
                self.send(&gc);
            }
            "C" => {
                if self.check_mode {
                    self.send("[MSG:Disabled]");
                    return Ok((Vec::new(), AfterOk::Reset));
                }
                if state != MachineState::Idle {
                    return Err(8);
                }
                self.check_mode = true;
                self.send("[MSG:Enabled]");
            }
            "X" => {
                if self.alarm {
                    if self.door_open {
                        return Err(13);
                    }
                    self.alarm = false;
                    self.send("[MSG:Caution: Unlocked]");
                }
            }
            // `$J` without `=`.
            _ if cmd.starts_with('J') => {
                return Err(if matches!(state, MachineState::Idle | MachineState::Jog) { 3 } else { 8 });
            }
            // `$$`, `$G`, `$C`, `$X` followed by anything.
            _ if cmd.starts_with(['$', 'G', 'C', 'X']) => return Err(3),
            // Everything else needs Idle or Alarm.
            _ if !idle_or_alarm => return Err(8),
            "#" => {
                let mut lines: Vec<String> = (54..)
                    .zip(&self.proto.coord)
                    .map(|(n, c)| format!("[G{}:{}]", coord_name(n), self.coord_text(c)))
                    .collect();
                lines.push(format!("[G28:{}]", self.coord_text(&self.proto.g28)));
                lines.push(format!("[G30:{}]", self.coord_text(&self.proto.g30)));
                lines.push(format!("[G92:{}]", self.coord_text(&self.g92)));
                lines.push(format!("[TLO:{}]", self.coord_text(&[self.proto.tlo])));
                lines.push(format!("[PRB:{}:{}]", self.coord_text(&self.proto.probe), u8::from(self.proto.probe_ok)));
                lines.iter().for_each(|l| self.send(l));
            }
            "H" => return self.home(),
            // `$HX` and the like: checked as `$H` is, then refused (Grbl 1.1h
            // as built has no single-axis homing).
            _ if cmd.starts_with('H') => {
                return Err(if self.setting(22) == 0.0 {
                    5
                } else if self.door_open {
                    13
                } else {
                    3
                });
            }
            // Grbl answers `ok`, then sleeps (and reads no line until a reset).
            "SLP" => return Ok((Vec::new(), AfterOk::Sleep)),
            "I" => match self.cfg.flavor {
                Flavor::Grbl => {
                    let ver = format!("[VER:{VERSION}:{}]", self.proto.build_info);
                    self.send(&ver);
                    let opt = format!("[OPT:{OPT_CODES},{},{}]", self.cfg.planner_blocks, self.cfg.rx_buffer);
                    self.send(&opt);
                }
                Flavor::Grblhal => {
                    // grblHAL's `$I` at its default compatibility level:
                    // the receive buffer's size (its ring holds one byte less,
                    // as `Bf:` shows), axes and tools in `[OPT:]`, then
                    // the axes, the extended options (enumerations, printable
                    // realtime characters on), the firmware and the driver.
                    let letters: String = self.cfg.axes.iter().map(|a| a.letter).collect();
                    let ver = format!("[VER:{VERSION_HAL}:{}]", self.proto.build_info);
                    self.send(&ver);
                    let opt = format!(
                        "[OPT:VNM+,{},{},{},0]",
                        self.cfg.planner_blocks,
                        self.cfg.rx_buffer,
                        letters.len()
                    );
                    self.send(&opt);
                    self.send(&format!("[AXS:{}:{letters}]", letters.len()));
                    self.send("[NEWOPT:ENUMS,RT+]");
                    self.send("[FIRMWARE:grblHAL]");
                    self.send("[DRIVER:laserd-sim]");
                    self.send(&format!("[DRIVER VERSION:{}]", env!("CARGO_PKG_VERSION")));
                }
            },
            "N" => {
                for (i, text) in self.proto.startup.clone().iter().enumerate() {
                    self.send(&format!("$N{i}={text}"));
                }
            }
            "RST=$" | "RST=#" | "RST=*" => {
                if cmd != "RST=#" {
                    self.restore_settings();
                }
                if cmd != "RST=$" {
                    let n = self.pos.len();
                    self.proto.coord = vec![vec![0.0; n]; coord_systems(self.cfg.flavor)];
                    self.proto.g28 = vec![0.0; n];
                    self.proto.g30 = vec![0.0; n];
                }
                if cmd == "RST=*" {
                    self.proto.startup = Default::default();
                    self.proto.build_info.clear();
                }
                self.send("[MSG:Restoring defaults]");
                return Ok((Vec::new(), AfterOk::Reset));
            }
            // `$#`, `$S…`, `$R…` and `$I…` not as above.
            _ if cmd.starts_with(['#', 'S', 'R']) || (cmd.starts_with('I') && !cmd.starts_with("I=")) => return Err(3),
            _ => {
                if let Some(text) = cmd.strip_prefix("I=") {
                    if text.len() > EEPROM_LINE {
                        return Err(14);
                    }
                    self.proto.build_info = text.to_string();
                } else if let Some(rest) = cmd.strip_prefix('N') {
                    return self.store_startup_line(rest);
                } else {
                    // `$n=value`: a number (else error 2, as for `$Z`), `=`
                    // (else 3), a value; written like Grbl's EEPROM, kept
                    // across resets.
                    let end = cmd.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(cmd.len());
                    let n = parse_value(&cmd[..end]).ok_or(2u16)?;
                    let v = cmd[end..].strip_prefix('=').ok_or(3u16)?;
                    let v = parse_value(v).ok_or(2u16)?;
                    if n > 255.0 {
                        return Err(3);
                    }
                    self.write_setting(n.trunc() as u32, v)?;
                }
            }
        }
        done
    }

    /// `$Nx=line`: Idle only; the line is executed (and must be valid) before
    /// it is stored.
    fn store_startup_line(&mut self, rest: &str) -> Result<(Vec<Step>, AfterOk), u16> {
        if self.state() != MachineState::Idle {
            return Err(8);
        }
        let (idx, text) = rest.split_once('=').ok_or(3u16)?;
        let idx = match idx {
            "0" => 0,
            "1" => 1,
            _ => return Err(3),
        };
        if text.len() > EEPROM_LINE {
            return Err(14);
        }
        let steps = self.gcode(text, self.line_count)?;
        self.proto.startup[idx] = text.to_string();
        Ok((steps, AfterOk::Nothing))
    }

    /// `$H`. There are no switches to seek: X, Y and Z (Grbl's homing
    /// cycles) move at the seek rate (`$25`) straight to where Grbl's cycle
    /// leaves them, the `ok` comes when they are there, and the startup lines
    /// run. `Faults` can make the cycle fail there (ALARM:8/9).
    ///
    /// Where: Grbl's machine space is negative, the switch at 0 for an axis
    /// homing toward plus (the default) and at minus its max travel for one
    /// whose `$23` bit is set; the pull-off (`$27`) leaves it that far inside.
    fn home(&mut self) -> Result<(Vec<Step>, AfterOk), u16> {
        if self.setting(22) == 0.0 {
            return Err(5);
        }
        if self.door_open {
            return Err(13);
        }
        // A successful cycle clears the alarm (the state reads Home meanwhile).
        self.alarm = false;
        let seek = self.setting(25).max(1e-3) / 60.0;
        let dir_mask = self.setting(23) as u32;
        let pull_off = self.setting(27);
        let home: Vec<f64> = (0..self.pos.len() as u32)
            .map(|i| match self.cfg.axes[i as usize].letter {
                'X' | 'Y' | 'Z' if dir_mask & (1 << i) != 0 => -self.setting(130 + i) + pull_off,
                'X' | 'Y' | 'Z' => -pull_off,
                // Axes Grbl's cycles do not home (a scanner's) stay.
                _ => self.pos[i as usize],
            })
            .collect();
        let duration = self.pos.iter().zip(&home).map(|(p, h)| (p - h).abs() / seek).fold(0.0, f64::max);
        self.gc_pos = home.clone();
        if duration <= 0.0 {
            return Ok((vec![Step::HomingDone], AfterOk::Nothing));
        }
        let block = Block { rapid: true, ends_sequence: true, homing: true, ..Block::new(home, duration, 0.0, self.line_count) };
        Ok((vec![Step::Queue(block), Step::Sync, Step::HomingDone], AfterOk::Nothing))
    }

    /// `[GC:...]`: the parser's modal state (reference §7).
    fn gc_line(&self) -> String {
        let m = &self.modal;
        let motion = match m.motion {
            Motion::Rapid => "G0",
            Motion::Linear => "G1",
            Motion::ArcCw => "G2",
            Motion::ArcCcw => "G3",
            Motion::Probe { away: false, no_error: false } => "G38.2",
            Motion::Probe { away: false, no_error: true } => "G38.3",
            Motion::Probe { away: true, no_error: false } => "G38.4",
            Motion::Probe { away: true, no_error: true } => "G38.5",
            Motion::None => "G80",
        };
        let spindle = match m.spindle {
            Spindle::Off => "M5",
            Spindle::Cw => "M3",
            Spindle::Ccw => "M4",
        };
        let coolant = match (m.mist, m.flood) {
            (false, false) => "M9",
            (true, false) => "M7",
            (false, true) => "M8",
            (true, true) => "M7 M8",
        };
        // The parser's feed (mm/min, or G93's inverse time) as reports print rates.
        let feed = self.rate_text(m.feed);
        format!(
            "[GC:{motion} G{} G{} {} {} {} {spindle} {coolant} T{} F{feed} S{}]",
            coord_name(m.coord),
            m.plane,
            if m.inches { "G20" } else { "G21" },
            if m.incremental { "G91" } else { "G90" },
            if m.inverse_time { "G93" } else { "G94" },
            m.tool,
            fmt_num(m.s, 0),
        )
    }
}

/// Work coordinate systems: G54-G59, and grblHAL's G59.1-G59.3.
fn coord_systems(flavor: Flavor) -> usize {
    match flavor {
        Flavor::Grbl => 6,
        Flavor::Grblhal => 9,
    }
}

/// `54`..`59`, then `59.1`..`59.3` for the systems after G59.
fn coord_name(n: u8) -> String {
    if n <= 59 {
        n.to_string()
    } else {
        format!("59.{}", n - 59)
    }
}
