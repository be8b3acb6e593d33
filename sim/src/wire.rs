//! GRBL 1.1 wire definitions shared by the sender and the simulator.
//!
//! Both peers use these types so that what the simulator prints and what the
//! sender parses can never drift apart (one definition, tested by round trip).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Realtime command bytes (reference §3). They never enter the RX buffer.
pub mod realtime {
    pub const STATUS: u8 = b'?';
    pub const FEED_HOLD: u8 = b'!';
    pub const CYCLE_START: u8 = b'~';
    pub const SOFT_RESET: u8 = 0x18;
    pub const SAFETY_DOOR: u8 = 0x84;
    pub const JOG_CANCEL: u8 = 0x85;
    pub const FEED_OVR_RESET: u8 = 0x90;
    pub const FEED_OVR_COARSE_PLUS: u8 = 0x91;
    pub const FEED_OVR_COARSE_MINUS: u8 = 0x92;
    pub const FEED_OVR_FINE_PLUS: u8 = 0x93;
    pub const FEED_OVR_FINE_MINUS: u8 = 0x94;
    pub const RAPID_OVR_RESET: u8 = 0x95;
    pub const RAPID_OVR_MEDIUM: u8 = 0x96;
    pub const RAPID_OVR_LOW: u8 = 0x97;
    pub const SPINDLE_OVR_RESET: u8 = 0x99;
    pub const SPINDLE_OVR_COARSE_PLUS: u8 = 0x9A;
    pub const SPINDLE_OVR_COARSE_MINUS: u8 = 0x9B;
    pub const SPINDLE_OVR_FINE_PLUS: u8 = 0x9C;
    pub const SPINDLE_OVR_FINE_MINUS: u8 = 0x9D;
    pub const SPINDLE_OVR_STOP: u8 = 0x9E;
    pub const COOLANT_FLOOD_TOGGLE: u8 = 0xA0;
    pub const COOLANT_MIST_TOGGLE: u8 = 0xA1;

    /// grblHAL's non-printable aliases of `?`, `~` and `!`, and its full report.
    pub const STATUS_ALT: u8 = 0x80;
    pub const CYCLE_START_ALT: u8 = 0x81;
    pub const FEED_HOLD_ALT: u8 = 0x82;
    pub const FULL_STATUS: u8 = 0x87;

    /// True for the bytes Grbl 1.1h acts on in its RX interrupt.
    pub fn is_realtime(b: u8) -> bool {
        matches!(b, STATUS | FEED_HOLD | CYCLE_START | SOFT_RESET)
            || matches!(b, 0x84 | 0x85 | 0x90..=0x97 | 0x99..=0x9E | 0xA0 | 0xA1)
    }
}

/// Banner text (without the surrounding CR/LF) printed at power-up and reset.
pub const BANNER: &str = "Grbl 1.1h ['$' for help]";
/// grblHAL's banner.
pub const BANNER_HAL: &str = "GrblHAL 1.1f ['$' or '$HELP' for help]";

/// Errors from parsing wire text.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error("not a status report: {0:?}")]
    NotStatus(String),
    #[error("unknown machine state {0:?}")]
    BadState(String),
    #[error("bad number in field {0:?}")]
    BadNumber(String),
    #[error("status report has no MPos field")]
    MissingPosition,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub enum MachineState {
    Idle,
    Run,
    Hold(u8),
    Jog,
    Alarm,
    Door(u8),
    Check,
    Home,
    Sleep,
    /// grblHAL: a manual tool change is pending (jogging allowed).
    Tool,
}

impl MachineState {
    /// The state field as printed in a status report (`Hold:0`, `Idle`, ...).
    pub fn as_field(&self) -> String {
        match self {
            MachineState::Idle => "Idle".into(),
            MachineState::Run => "Run".into(),
            MachineState::Hold(n) => format!("Hold:{n}"),
            MachineState::Jog => "Jog".into(),
            MachineState::Alarm => "Alarm".into(),
            MachineState::Door(n) => format!("Door:{n}"),
            MachineState::Check => "Check".into(),
            MachineState::Home => "Home".into(),
            MachineState::Sleep => "Sleep".into(),
            MachineState::Tool => "Tool".into(),
        }
    }

    /// Parses a state field; a missing substate of Hold/Door reads as 0 and
    /// grblHAL's `Alarm:<code>` / `Run:<n>` substates are accepted and dropped.
    pub fn parse_field(s: &str) -> Result<MachineState, WireError> {
        let (name, sub) = match s.split_once(':') {
            Some((n, sub)) => (n, Some(sub)),
            None => (s, None),
        };
        let sub_num = || -> Result<u8, WireError> {
            match sub {
                None => Ok(0),
                Some(v) => v.parse().map_err(|_| WireError::BadState(s.to_string())),
            }
        };
        Ok(match name {
            "Idle" => MachineState::Idle,
            "Run" => MachineState::Run,
            "Hold" => MachineState::Hold(sub_num()?),
            "Jog" => MachineState::Jog,
            "Alarm" => MachineState::Alarm,
            "Door" => MachineState::Door(sub_num()?),
            "Check" => MachineState::Check,
            "Home" => MachineState::Home,
            "Sleep" => MachineState::Sleep,
            "Tool" => MachineState::Tool,
            _ => return Err(WireError::BadState(s.to_string())),
        })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct StatusReport {
    pub state: MachineState,
    pub mpos: Vec<f64>,
    /// `Bf:` free planner blocks, free RX bytes.
    pub buffer: Option<(u32, u32)>,
    /// `Ln:` line number (N word) of the executing block.
    pub line: Option<u32>,
    /// `FS:`/`F:` feed in units/min.
    pub feed: Option<f64>,
    /// `FS:` spindle speed / laser S.
    pub spindle: Option<f64>,
    /// `WPos:` when the controller reports work positions instead (`$10` bit 0
    /// clear); `mpos` is then empty.
    #[serde(default)]
    pub wpos: Option<Vec<f64>>,
    /// `WCO:` work coordinate offset (sent now and then: cache the last one).
    #[serde(default)]
    pub wco: Option<Vec<f64>>,
    /// `Ov:` feed, rapid and spindle overrides in percent.
    #[serde(default)]
    pub overrides: Option<[u32; 3]>,
    /// `Pn:` input pins triggered (letters).
    #[serde(default)]
    pub pins: Option<String>,
    /// `A:` accessories on (`S` M3, `C` M4, `F` flood, `M` mist).
    #[serde(default)]
    pub accessories: Option<String>,
    /// grblHAL's `FW:` (in a full report, `0x87`).
    #[serde(default)]
    pub firmware: Option<String>,
}

/// Formats with a fixed number of decimals; avoids printing `-0.000`.
pub fn fmt_num(x: f64, decimals: usize) -> String {
    let s = format!("{:.*}", decimals, x);
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

impl StatusReport {
    /// A report with the state and machine position only.
    pub fn new(state: MachineState, mpos: Vec<f64>) -> StatusReport {
        StatusReport {
            state,
            mpos,
            buffer: None,
            line: None,
            feed: None,
            spindle: None,
            wpos: None,
            wco: None,
            overrides: None,
            pins: None,
            accessories: None,
            firmware: None,
        }
    }

    /// The reported position: machine position, or work position when the
    /// controller reports that instead.
    pub fn position(&self) -> &[f64] {
        match (&self.wpos, self.mpos.is_empty()) {
            (Some(w), true) => w,
            _ => &self.mpos,
        }
    }

    /// `<Run|MPos:1.000,2.000|Bf:15,128|Ln:3|FS:500,0|WCO:0.000,0.000>` without
    /// CR/LF, fields in Grbl's order.
    pub fn to_line(&self) -> String {
        self.format(3, 0)
    }

    /// The same with positions and feed in inches (`$13=1`): 4 decimals for
    /// positions, 1 for the feed (the values are already in inches).
    pub fn to_line_inches(&self) -> String {
        self.format(4, 1)
    }

    fn format(&self, pos_decimals: usize, feed_decimals: usize) -> String {
        let join = |v: &[f64]| v.iter().map(|x| fmt_num(*x, pos_decimals)).collect::<Vec<_>>().join(",");
        let mut s = match (&self.wpos, self.mpos.is_empty()) {
            (Some(w), true) => format!("<{}|WPos:{}", self.state.as_field(), join(w)),
            _ => format!("<{}|MPos:{}", self.state.as_field(), join(&self.mpos)),
        };
        if let Some((b, r)) = self.buffer {
            s.push_str(&format!("|Bf:{b},{r}"));
        }
        if let Some(n) = self.line {
            s.push_str(&format!("|Ln:{n}"));
        }
        match (self.feed, self.spindle) {
            (None, None) => {}
            (Some(f), None) => s.push_str(&format!("|F:{}", fmt_num(f, feed_decimals))),
            (f, sp) => s.push_str(&format!(
                "|FS:{},{}",
                fmt_num(f.unwrap_or(0.0), feed_decimals),
                fmt_num(sp.unwrap_or(0.0), 0)
            )),
        }
        if let Some(p) = &self.pins {
            s.push_str(&format!("|Pn:{p}"));
        }
        if let Some(w) = &self.wco {
            s.push_str(&format!("|WCO:{}", join(w)));
        }
        if let Some([f, r, sp]) = self.overrides {
            s.push_str(&format!("|Ov:{f},{r},{sp}"));
        }
        if let Some(a) = &self.accessories {
            s.push_str(&format!("|A:{a}"));
        }
        if let Some(f) = &self.firmware {
            s.push_str(&format!("|FW:{f}"));
        }
        s.push('>');
        s
    }

    /// Parses `<...>`; fields may come in any order, unknown ones are ignored.
    /// `MPos` is required (WPos is a different frame and is not converted).
    pub fn parse(line: &str) -> Result<StatusReport, WireError> {
        let t = line.trim();
        let inner = t
            .strip_prefix('<')
            .and_then(|r| r.strip_suffix('>'))
            .ok_or_else(|| WireError::NotStatus(t.to_string()))?;
        let mut fields = inner.split('|');
        let state = MachineState::parse_field(fields.next().unwrap_or(""))?;
        let mut rep = StatusReport::new(state, Vec::new());
        let mut have_pos = false;
        for field in fields {
            let Some((key, val)) = field.split_once(':') else { continue };
            let bad = || WireError::BadNumber(field.to_string());
            let nums = || -> Result<Vec<f64>, WireError> {
                val.split(',').map(|v| v.trim().parse::<f64>().map_err(|_| bad())).collect()
            };
            match key {
                "MPos" => {
                    rep.mpos = nums()?;
                    have_pos = true;
                }
                "Bf" => {
                    let v = nums()?;
                    if v.len() != 2 || v.iter().any(|x| *x < 0.0) {
                        return Err(bad());
                    }
                    rep.buffer = Some((v[0] as u32, v[1] as u32));
                }
                "Ln" => rep.line = Some(val.trim().parse().map_err(|_| bad())?),
                "FS" => {
                    let v = nums()?;
                    if v.len() < 2 {
                        return Err(bad());
                    }
                    rep.feed = Some(v[0]);
                    rep.spindle = Some(v[1]);
                }
                "F" => rep.feed = Some(val.trim().parse().map_err(|_| bad())?),
                "WPos" => {
                    rep.wpos = Some(nums()?);
                    have_pos = true;
                }
                "WCO" => rep.wco = Some(nums()?),
                "Ov" => {
                    let v = nums()?;
                    if v.len() != 3 || v.iter().any(|x| *x < 0.0) {
                        return Err(bad());
                    }
                    rep.overrides = Some([v[0] as u32, v[1] as u32, v[2] as u32]);
                }
                "Pn" => rep.pins = Some(val.to_string()),
                "A" => rep.accessories = Some(val.to_string()),
                "FW" => rep.firmware = Some(val.to_string()),
                _ => {}
            }
        }
        if !have_pos {
            return Err(WireError::MissingPosition);
        }
        Ok(rep)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub enum Response {
    Ok,
    Error(u16),
    Alarm(u16),
    Status(StatusReport),
    /// The whole banner line, e.g. `Grbl 1.1h ['$' for help]`.
    Banner(String),
    /// Text inside `[MSG:...]`.
    Message(String),
    /// Any other `[...]` line, whole (e.g. `[GC:G0 G54 ...]`).
    Feedback(String),
    Other(String),
}

impl Response {
    /// Classifies one received line (CR/LF optional). Never fails.
    pub fn parse(line: &str) -> Response {
        let t = line.trim_end_matches(['\r', '\n']).trim();
        if t == "ok" {
            return Response::Ok;
        }
        if let Some(n) = t.strip_prefix("error:") {
            return n.parse().map(Response::Error).unwrap_or_else(|_| Response::Other(t.to_string()));
        }
        if let Some(n) = t.strip_prefix("ALARM:") {
            return n.parse().map(Response::Alarm).unwrap_or_else(|_| Response::Other(t.to_string()));
        }
        if t.starts_with('<') {
            return StatusReport::parse(t).map(Response::Status).unwrap_or_else(|_| Response::Other(t.to_string()));
        }
        if t.starts_with("Grbl ") || t.starts_with("GrblHAL ") {
            return Response::Banner(t.to_string());
        }
        if t.starts_with('[') && t.ends_with(']') {
            if let Some(m) = t.strip_prefix("[MSG:").and_then(|r| r.strip_suffix(']')) {
                return Response::Message(m.to_string());
            }
            return Response::Feedback(t.to_string());
        }
        Response::Other(t.to_string())
    }
}

/// Meaning of `error:N` (reference §5).
pub fn error_message(code: u16) -> &'static str {
    match code {
        1 => "word has no letter (expected command letter)",
        2 => "bad or missing numeric value",
        3 => "$ command not recognised or malformed",
        4 => "negative value where a positive one is required",
        5 => "homing not enabled",
        6 => "step pulse time must be at least 3 us",
        7 => "EEPROM read failed; defaults restored",
        8 => "$ command needs Idle state",
        9 => "G-code locked out in Alarm or Jog state",
        10 => "soft limits need homing enabled",
        11 => "line too long",
        12 => "setting would exceed max step rate",
        13 => "safety door open",
        14 => "build info or startup line too long",
        15 => "jog target beyond machine travel",
        16 => "invalid jog command",
        17 => "laser mode needs variable spindle",
        20 => "unsupported or invalid G/M command",
        21 => "two commands of the same modal group in one block",
        22 => "feed rate undefined",
        23 => "command needs an integer value",
        24 => "two commands in one block both need axis words",
        25 => "a word repeated in the block",
        26 => "command needs axis words, none given",
        27 => "line number too large",
        28 => "required P or L word missing",
        29 => "unsupported work coordinate system",
        30 => "G53 requires G0 or G1 motion mode",
        31 => "axis words present but unused",
        32 => "G2/G3 without axis words in the active plane",
        33 => "invalid motion target",
        34 => "arc radius maths failed",
        35 => "G2/G3 offset form without I/J/K in the plane",
        36 => "leftover unused value words",
        37 => "G43.1 on an axis other than the tool length axis",
        38 => "tool number above maximum",
        _ => "unknown error",
    }
}

/// Meaning of `ALARM:N` (Grbl 1.1h table).
pub fn alarm_message(code: u16) -> &'static str {
    match code {
        1 => "hard limit hit",
        2 => "soft limit: target beyond travel",
        3 => "reset during motion",
        4 => "probe fail: probe not in expected initial state",
        5 => "probe fail: no contact within travel",
        6 => "homing fail: reset during homing",
        7 => "homing fail: door opened during homing",
        8 => "homing fail: pull-off did not clear switch",
        9 => "homing fail: switch not found",
        10 => "homing fail: second switch of dual axis not found",
        _ => "unknown alarm",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_round_trip() {
        let r = StatusReport {
            buffer: Some((15, 128)),
            line: Some(7),
            feed: Some(500.0),
            spindle: Some(0.0),
            ..StatusReport::new(MachineState::Run, vec![1.0, 2.0, -0.0001, 300.5])
        };
        let s = r.to_line();
        assert_eq!(s, "<Run|MPos:1.000,2.000,0.000,300.500|Bf:15,128|Ln:7|FS:500,0>");
        let mut back = StatusReport::parse(&s).unwrap();
        back.mpos[2] = -0.0001; // 3 decimals lose this; everything else must match
        assert_eq!(back, r);
        let h = StatusReport { state: MachineState::Hold(1), line: None, ..r };
        assert_eq!(StatusReport::parse(&h.to_line()).unwrap().state, MachineState::Hold(1));
        // grblHAL's extra state and substates.
        assert_eq!(StatusReport::parse("<Tool|MPos:0,0>").unwrap().state, MachineState::Tool);
        assert_eq!(StatusReport::parse("<Alarm:10|MPos:0,0>").unwrap().state, MachineState::Alarm);
        assert_eq!(StatusReport::parse("<Run:2|MPos:0,0,0,0,0,0,0,0>").unwrap().mpos.len(), 8);
    }

    #[test]
    fn status_any_order_and_unknown_fields() {
        let r = StatusReport::parse("<Idle|WCO:0,0,0|FS:0,0|Pn:X|Bf:14,100|MPos:1.5,2.25,3>\r\n").unwrap();
        assert_eq!(r.state, MachineState::Idle);
        assert_eq!(r.mpos, vec![1.5, 2.25, 3.0]);
        assert_eq!(r.buffer, Some((14, 100)));
        assert_eq!(r.feed, Some(0.0));
        assert!(StatusReport::parse("<Bogus|MPos:0>").is_err());
        let w = StatusReport::parse("<Idle|WPos:1,2|WCO:0.5,0|Ov:100,50,110|A:CF|Pn:XZ>").unwrap();
        assert_eq!((w.mpos.len(), w.position()), (0, &[1.0, 2.0][..]));
        assert_eq!(w.wco, Some(vec![0.5, 0.0]));
        assert_eq!(w.overrides, Some([100, 50, 110]));
        assert_eq!((w.accessories.as_deref(), w.pins.as_deref()), (Some("CF"), Some("XZ")));
        assert_eq!(StatusReport::parse(&w.to_line()).unwrap(), w);
        assert!(StatusReport::parse("<Idle|Bf:1,2>").is_err(), "a position is required");
        assert!(StatusReport::parse("<Idle|MPos:a,0>").is_err());
        assert!(StatusReport::parse("Idle|MPos:0").is_err());
    }

    #[test]
    fn response_parse() {
        assert_eq!(Response::parse("ok\r\n"), Response::Ok);
        assert_eq!(Response::parse("error:20"), Response::Error(20));
        assert_eq!(Response::parse("ALARM:2\r\n"), Response::Alarm(2));
        assert_eq!(Response::parse(&format!("{BANNER}\r\n")), Response::Banner(BANNER.to_string()));
        // grblHAL's banner as its report.c prints it (compatibility level 0),
        // and at a higher level, where it names itself Grbl.
        assert_eq!(BANNER_HAL, "GrblHAL 1.1f ['$' or '$HELP' for help]");
        assert_eq!(Response::parse(BANNER_HAL), Response::Banner(BANNER_HAL.to_string()));
        assert!(matches!(Response::parse("Grbl 1.1f ['$' for help]"), Response::Banner(_)));
        assert_eq!(Response::parse("[MSG:Pgm End]"), Response::Message("Pgm End".into()));
        assert_eq!(Response::parse("[GC:G0 G54]"), Response::Feedback("[GC:G0 G54]".into()));
        assert_eq!(Response::parse("error:x"), Response::Other("error:x".into()));
        assert_eq!(Response::parse("$10=3"), Response::Other("$10=3".into()));
        assert!(matches!(Response::parse("<Idle|MPos:0.000|Bf:15,128|FS:0,0>"), Response::Status(_)));
    }

    #[test]
    fn tables() {
        assert_eq!(error_message(22), "feed rate undefined");
        assert_eq!(error_message(99), "unknown error");
        assert_eq!(alarm_message(2), "soft limit: target beyond travel");
        assert!(realtime::is_realtime(b'?') && realtime::is_realtime(0x18) && !realtime::is_realtime(b'G'));
    }
}
