//! Conformance: the simulator walked through every realtime byte, machine
//! state and status field, every `$` command, every error and alarm path of
//! the reference (`shared/reference/grbl-protocol.md`) it can reach, each
//! checked against the exact text a Grbl 1.1 controller sends.
//!
//! A row is (machine, what comes before, input, exact answer to the input).
//! Every action is followed by 0.2 s of virtual time. In an expected status
//! report `MPos:*` stands for a position taken while moving (it depends on
//! the motion model, not on the protocol); everything else is exact.
//!
//! Not reachable, so not here: errors 7 (no EEPROM to fail), 12 (no step-rate
//! check), 14 (a cleaned line, at most 79 characters, always fits an EEPROM
//! line), 17 (built with a variable spindle); state `Door:3` (no parking).

mod common;

use common::{cfg, Sim};
use laserd_sim::controller::{Controller, Faults, Flavor, SimConfig};
use laserd_sim::wire::realtime;

/// Something done to the simulated machine.
#[derive(Clone, Copy)]
enum Act {
    /// A line; `\n` is added.
    L(&'static str),
    /// Raw bytes.
    B(&'static [u8]),
    /// One realtime byte.
    R(u8),
    /// The door switch opens (true) or closes.
    Door(bool),
    /// Done to the controller directly.
    Ctl(fn(&mut Controller)),
    /// Let this much more time pass.
    Wait(f64),
}
use Act::*;

const Q: Act = R(b'?');
const HOLD: Act = R(b'!');
const START: Act = R(b'~');
const RESET: Act = R(0x18);
const DOOR: Act = R(0x84);
const ECHO_ON: Act = Ctl(echo_on);
/// Soft limits on (they need homing on), then a move past them: a critical
/// ALARM:2 (Grbl's machine space is negative, so X1 is beyond it).
const TRIP: Act = B(b"$22=1\n$20=1\nG0X1\n");
const BANNER: &str = "Grbl 1.1h ['$' for help]";
const UNLOCK: &str = "[MSG:'$H'|'$X' to unlock]";
/// An idle report once the first two (with WCO, then Ov) have gone.
/// An idle report once the first two (with WCO, then Ov) have gone
/// (Grbl's default `$10=1`: MPos, no buffer state).
const IDLE: &str = "<Idle|MPos:0.000,0.000,0.000|FS:0,0>";
/// The same with `$10=3` (MPos and `Bf:`): every block and byte free.
const IDLE_BF: &str = "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>";

type Row = (fn() -> SimConfig, &'static [Act], &'static [Act], &'static [&'static str]);

fn echo_on(c: &mut Controller) {
    c.set_echo(true);
}

/// A 2-axis machine config; Grbl 1.1h still reports (and moves) X, Y and Z.
fn xy() -> SimConfig {
    cfg()
}

fn xyz() -> SimConfig {
    SimConfig::with_axes("XYZ")
}

fn faults(f: Faults) -> SimConfig {
    SimConfig { faults: f, ..cfg() }
}

/// The hard limit trips on the first line.
fn limit_1() -> SimConfig {
    faults(Faults { limit_alarm_at_line: Some(1), ..Default::default() })
}

/// The hard limit trips on the second line.
fn limit_2() -> SimConfig {
    faults(Faults { limit_alarm_at_line: Some(2), ..Default::default() })
}

/// Work 2 mm along every probing move.
fn probe_2mm() -> SimConfig {
    faults(Faults { probe_contact_mm: Some(2.0), ..Default::default() })
}

/// Grbl's own planner: a feed hold brakes within the acceleration limits.
fn grbl_motion() -> SimConfig {
    SimConfig { motion: laserd_sim::controller::MotionModel::Grbl, ..cfg() }
}

fn switch_missing() -> SimConfig {
    faults(Faults { homing_switch_missing: true, ..Default::default() })
}

fn pull_off_fails() -> SimConfig {
    faults(Faults { homing_pull_off_fails: true, ..Default::default() })
}

fn act(s: &mut Sim, a: Act) {
    let mut step = 0.2;
    match a {
        L(text) => s.send(&format!("{text}\n")),
        B(bytes) => s.link.push(s.t, bytes),
        R(b) => s.link.push(s.t, &[b]),
        Door(open) => s.ctl.set_door(open),
        Ctl(f) => f(&mut s.ctl),
        Wait(secs) => step = secs,
    }
    let t = s.t + step;
    s.run_until(t);
}

/// A status report with its position replaced by `*`.
fn mask_position(line: &str) -> String {
    for key in ["MPos:", "WPos:"] {
        if let Some(i) = line.find(key) {
            let start = i + key.len();
            let end = line[start..].find(['|', '>']).map_or(line.len(), |j| start + j);
            return format!("{}*{}", &line[..start], &line[end..]);
        }
    }
    line.to_string()
}

fn check(rows: &[Row]) {
    for (machine, before, input, expected) in rows {
        let mut s = Sim::new(machine());
        for a in *before {
            act(&mut s, *a);
        }
        let from = s.lines.len();
        for a in *input {
            act(&mut s, *a);
        }
        let got: Vec<String> = s.lines[from..]
            .iter()
            .zip(expected.iter().chain(std::iter::repeat(&"")))
            .map(|((_, l), e)| if e.contains("Pos:*") { mask_position(l) } else { l.clone() })
            .collect();
        assert_eq!(got, *expected, "after {} then {}", describe(before), describe(input));
    }
}

fn describe(acts: &[Act]) -> String {
    let one = |a: &Act| match a {
        L(t) => format!("{t:?}"),
        B(b) => format!("bytes {b:02x?}"),
        R(b) => format!("0x{b:02x}"),
        Door(o) => format!("door {}", if *o { "opens" } else { "closes" }),
        Ctl(_) => "(call)".into(),
        Wait(t) => format!("wait {t}s"),
    };
    format!("[{}]", acts.iter().map(one).collect::<Vec<_>>().join(", "))
}

/// Every realtime byte of `wire::realtime`, by its visible effect.
fn realtime_rows() -> Vec<Row> {
    vec![
        // `?`: WCO in the first report after a reset, Ov in the second, then neither.
        (xy, &[], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"]),
        (xy, &[Q], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        (xy, &[Q, Q], &[Q], &[IDLE]),
        // `!` feed hold: at rest at once; moving, Hold:1 until stopped.
        (xy, &[Q, Q], &[HOLD, Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, L("G1X100F600")], &[B(b"!?")], &["<Hold:1|MPos:*|FS:600,0>"]),
        (xy, &[Q, Q, L("G1X1F600"), HOLD, Wait(1.0)], &[Q], &["<Hold:0|MPos:1.000,0.000,0.000|FS:0,0>"]),
        // `~` cycle start: resumes a hold; otherwise nothing.
        (xy, &[Q, Q, HOLD], &[START, Q], &[IDLE]),
        (xy, &[Q, Q, L("G1X100F600"), HOLD], &[START, Q], &["<Run|MPos:*|FS:600,0>"]),
        (xy, &[Q, Q], &[START, Q], &[IDLE]),
        // 0x18 soft reset: banner; while moving the position is lost (ALARM:3).
        (xy, &[], &[RESET], &[BANNER]),
        (xy, &[L("G0X100F100")], &[RESET], &["ALARM:3", BANNER, UNLOCK]),
        (xy, &[L("G1X100F600")], &[B(b"!\x18")], &["ALARM:3", BANNER, UNLOCK]),
        (xy, &[L("G1X100F600"), HOLD, Q], &[RESET], &[BANNER]),
        (xy, &[Q, Q, R(0x91), R(0x96)], &[RESET, Q, Q], &[
            BANNER,
            "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>",
            "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>",
        ]),
        // 0x84 safety door: Door:2 stopping, Door:1 open (its switch), Door:0
        // closed; `~` resumes once closed. `0x84` alone leaves the switch closed.
        (xy, &[Q, Q], &[DOOR, Q], &["[MSG:Check Door]", "<Door:0|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, L("G1X100F600")], &[B(&[0x84, b'?'])], &["[MSG:Check Door]", "<Door:2|MPos:*|FS:600,0>"]),
        (xy, &[Q, Q, Door(true)], &[Door(false), Q], &["<Door:0|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, Door(true)], &[START, Q], &["<Door:1|MPos:0.000,0.000,0.000|FS:0,0|Pn:D>"]),
        (xy, &[Q, Q, Door(true), Door(false)], &[START, Q], &[IDLE]),
        (xy, &[Q, Q, DOOR], &[START, Q], &[IDLE]),
        (xy, &[Q, Q], &[Door(true), Q], &["[MSG:Check Door]", "<Door:1|MPos:0.000,0.000,0.000|FS:0,0|Pn:D>"]),
        // 0x85 jog cancel (and `!` while jogging): stop, drop the jog, Idle.
        (xy, &[Q, Q, L("$J=X100F600")], &[R(0x85), Q], &["<Idle|MPos:*|FS:0,0>"]),
        (xy, &[Q, Q, L("$J=X100F600"), L("$J=Y100F600")], &[HOLD, Q], &["<Idle|MPos:*|FS:0,0>"]),
        (xy, &[Q, Q], &[R(0x85), Q], &[IDLE]),
        // Feed override 0x90..0x94: 10..200 %, shown on a change.
        (xy, &[Q, Q], &[R(0x91), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:110,100,100>"]),
        (xy, &[Q, Q], &[R(0x92), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:90,100,100>"]),
        (xy, &[Q, Q], &[R(0x93), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:101,100,100>"]),
        (xy, &[Q, Q], &[R(0x94), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:99,100,100>"]),
        (xy, &[Q, Q, R(0x91), Q], &[R(0x90), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        (xy, &[Q, Q], &[R(0x90), Q], &[IDLE]),
        (xy, &[Q, Q], &[B(&[0x91; 12]), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:200,100,100>"]),
        (xy, &[Q, Q], &[B(&[0x92; 12]), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:10,100,100>"]),
        (xy, &[Q, Q], &[B(&[0x94; 200]), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:10,100,100>"]),
        // Rapid override 0x95..0x97: 100, 50, 25 %.
        (xy, &[Q, Q], &[R(0x96), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,50,100>"]),
        (xy, &[Q, Q], &[R(0x97), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,25,100>"]),
        (xy, &[Q, Q, R(0x97), Q], &[R(0x95), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        // Spindle override 0x99..0x9D: 10..200 %.
        (xy, &[Q, Q], &[R(0x9A), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,110>"]),
        (xy, &[Q, Q], &[R(0x9B), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,90>"]),
        (xy, &[Q, Q], &[R(0x9C), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,101>"]),
        (xy, &[Q, Q], &[R(0x9D), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,99>"]),
        (xy, &[Q, Q, R(0x9A), Q], &[R(0x99), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        (xy, &[Q, Q], &[B(&[0x9A; 12]), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,200>"]),
        // 0x9E spindle stop, only in Hold (here not in laser mode: the spindle
        // keeps turning in a hold until stopped); resuming restores it.
        (xy, &[L("$32=0"), L("M3S100"), HOLD, Q], &[Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,100|Ov:100,100,100|A:S>"]),
        (xy, &[L("$32=0"), L("M3S100"), HOLD, Q, Q], &[R(0x9E), Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        (xy, &[L("$32=0"), L("M3S100"), HOLD, Q, Q, R(0x9E), Q], &[R(0x9E), Q], &[
            "[MSG:Restoring spindle]",
            "<Hold:0|MPos:0.000,0.000,0.000|FS:0,100|Ov:100,100,100|A:S>",
        ]),
        (xy, &[L("$32=0"), L("M3S100"), HOLD, Q, Q, R(0x9E), Q], &[START, Q], &[
            "[MSG:Restoring spindle]",
            "<Idle|MPos:0.000,0.000,0.000|FS:0,100|Ov:100,100,100|A:S>",
        ]),
        (xy, &[L("M3S100"), Q, Q], &[R(0x9E), Q], &[IDLE]),
        // In laser mode ($32=1) a hold stops the laser by itself (the same
        // override), so `~` restores it and 0x9E in the hold turns it back on.
        (xy, &[L("M4S100"), Q, Q], &[HOLD, Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        (xy, &[L("M4S100"), Q, Q, HOLD, Q], &[START, Q], &[
            "[MSG:Restoring spindle]",
            "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:C>",
        ]),
        (xy, &[L("M4S100"), Q, Q, HOLD, Q], &[R(0x9E), Q], &[
            "[MSG:Restoring spindle]",
            "<Hold:0|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:C>",
        ]),
        // 0xA0 flood toggle (Idle, Run, Hold), as M8/M9 would; 0xA1 (mist)
        // is discarded by Grbl 1.1h as built (no M7).
        (xy, &[Q, Q], &[R(0xA0), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:F>"]),
        (xy, &[Q, Q], &[R(0xA1), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, R(0xA0)], &[R(0xA1), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:F>"]),
        (xy, &[Q, Q, R(0xA0), Q], &[R(0xA0), Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        (xy, &[L("M3S1"), Q, Q, HOLD], &[R(0xA0), Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:F>"]),
        (xy, &[R(0xA0), R(0xA1)], &[L("$G")], &["[GC:G0 G54 G17 G21 G90 G94 M5 M8 T0 F0 S0]", "ok"]),
        (xy, &[TRIP, RESET, Q, Q], &[R(0xA0), Q], &["<Alarm|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[L("$C"), Q, Q], &[R(0xA1), Q], &["<Check|MPos:0.000,0.000,0.000|FS:0,0>"]),
        // grblHAL's extra bytes (0x80-0x82 aliases, 0x87 full report): Grbl 1.1 discards them.
        (xy, &[Q, Q], &[R(0x80), R(0x87)], &[]),
        (xy, &[Q, Q], &[R(0x82), Q], &[IDLE]),
        (xy, &[Q, Q, HOLD], &[R(0x81), Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,0>"]),
    ]
}

#[test]
fn realtime_bytes() {
    check(&realtime_rows());
}

/// The realtime table has a row sending each byte Grbl acts on.
#[test]
fn every_realtime_byte_has_a_row() {
    let sent: Vec<u8> = realtime_rows()
        .iter()
        .flat_map(|r| r.2.iter())
        .flat_map(|a| match a {
            R(b) => vec![*b],
            B(bytes) => bytes.to_vec(),
            _ => vec![],
        })
        .collect();
    let missing: Vec<u8> = (0..=255u8).filter(|b| realtime::is_realtime(*b) && !sent.contains(b)).collect();
    assert!(missing.is_empty(), "no row for {missing:02x?}");
}

/// Every machine state and substate, every status field, the `$10` mask.
#[test]
fn states_and_status_fields() {
    let rows: &[Row] = &[
        (xy, &[Q, Q, L("G1X100F600")], &[Q], &["<Run|MPos:*|FS:600,0>"]),
        // No `Ln:`: Grbl 1.1h as built has no line numbers.
        (xy, &[Q, Q, L("N7G1X100F600")], &[Q], &["<Run|MPos:*|FS:600,0>"]),
        (xy, &[Q, Q, L("M3S250"), L("G1X100F600")], &[Q], &["<Run|MPos:*|FS:600,250|Ov:100,100,100|A:S>"]),
        (xy, &[Q, Q, L("$J=X100F600")], &[Q], &["<Jog|MPos:*|FS:600,0>"]),
        (xy, &[Q, Q, L("$C")], &[Q], &["<Check|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, L("$SLP")], &[Q], &["<Sleep|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, TRIP, RESET, Q, Q], &[Q], &["<Alarm|MPos:0.000,0.000,0.000|FS:0,0>"]),
        // Home: no reports while homing.
        (xy, &[L("$22=1"), L("G0X100"), Wait(1.5)], &[L("$H"), Q], &[]),
        // $10: bit 0 MPos (else WPos), bit 1 Bf; Grbl 1.1 has no other bits.
        (xy, &[L("$10=0"), Q, Q], &[Q], &["<Idle|WPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[L("$10=1"), Q, Q], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[L("$10=2"), Q, Q], &[Q], &["<Idle|WPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>"]),
        (xy, &[L("$10=3"), Q, Q], &[Q], &[IDLE_BF]),
        (xy, &[L("$10=255"), Q, Q], &[Q], &[IDLE_BF]),
        // WCO = G54..G59 + G92 + TLO, at once after a change; WPos = MPos - WCO.
        (xy, &[Q, Q, L("G10L2P1X10Y5")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:10.000,5.000,0.000>"]),
        (xy, &[L("$10=0"), L("G10L2P1X10Y5"), Q, Q], &[Q], &["<Idle|WPos:-10.000,-5.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, L("G10L2P2X10"), L("G55G0X1"), Wait(0.5)], &[Q], &["<Idle|MPos:11.000,0.000,0.000|FS:0,0|WCO:10.000,0.000,0.000>"]),
        (xy, &[Q, Q, L("G0X3"), L("G92X1")], &[Q], &["<Idle|MPos:3.000,0.000,0.000|FS:0,0|WCO:2.000,0.000,0.000>"]),
        (xy, &[Q, Q, L("G0X3"), L("G92X1"), Q], &[L("G92.1"), Q], &["ok", "<Idle|MPos:3.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"]),
        (xyz, &[Q, Q, L("G43.1Z2")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,2.000>"]),
        (xyz, &[Q, Q, L("G43.1Z2"), Q], &[L("G49"), Q], &["ok", "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"]),
        // Pn: D door, X limit switch (after a hard limit), P probe.
        (limit_1, &[L("G0X1"), RESET, Q, Q], &[Q], &["<Alarm|MPos:0.000,0.000,0.000|FS:0,0|Pn:X>"]),
        (limit_1, &[L("G0X1"), RESET, Q, Q, L("$X"), L("G0X1"), Wait(0.5)], &[Q], &["<Idle|MPos:1.000,0.000,0.000|FS:0,0>"]),
        (probe_2mm, &[Q, Q, L("G38.2X10F600"), Wait(0.5)], &[Q], &["<Idle|MPos:2.000,0.000,0.000|FS:0,0|Pn:P>"]),
        (xy, &[Q, Q, Door(true), Door(false), START, Door(true), DOOR], &[Q], &["<Door:1|MPos:0.000,0.000,0.000|FS:0,0|Pn:D>"]),
        // A: S (M3), C (M4), F (flood), in the report with Ov.
        (xy, &[Q, Q, L("M3S1"), L("M8")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:SF>"]),
        (xy, &[Q, Q, L("M4S1"), L("M8")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:CF>"]),
        (xy, &[Q, Q, L("M4S1"), L("M8"), Q], &[L("M9"), L("M5"), Q], &["ok", "ok", "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        // Flood (a laser's air assist) through a feed hold: on (Grbl stops
        // coolant for a door or sleep, not a hold); a soft reset stops it
        // (its mc_reset stops spindle and coolant), the report after the
        // WCO one has Ov: without A:, and $G says M9.
        (xy, &[Q, Q, L("M8"), L("G1X100F600"), HOLD, Wait(1.0)], &[Q], &["<Hold:0|MPos:*|FS:0,0|Ov:100,100,100|A:F>"]),
        (xy, &[L("M8"), RESET, Q], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"]),
        // M8 after a move waits for it to end (Grbl's coolant sync): no A:
        // while it runs, A:F in the report right after.
        (xy, &[Q, Q, L("G1X10F600"), L("M8")], &[Q], &["<Run|MPos:*|FS:600,0>"]),
        (xy, &[Q, Q, L("G1X1F600"), L("M8"), Wait(1.0)], &[Q], &["<Idle|MPos:1.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:F>"]),
        (xy, &[L("M8"), RESET], &[L("$G")], &["[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]),
        // FS: the laser standing still in laser mode: M3 burns at S in G1 (in
        // G0 it stays dark, rows above), M4 is dark (no motion, no power).
        (xy, &[Q, Q, L("G1F100"), L("M3S500")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,500|Ov:100,100,100|A:S>"]),
        (xy, &[Q, Q, L("G1F100"), L("M4S500")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100|A:C>"]),
    ];
    check(rows);
}

/// The full default `$$` listing of the XY machine (with Grbl's Z), `changes` applied.
fn listing(changes: &[(&str, &str)]) -> Vec<String> {
    let defaults = [
        ("0", "10"), ("1", "25"), ("2", "0"), ("3", "0"), ("4", "0"), ("5", "0"), ("6", "0"),
        ("10", "1"), ("11", "0.010"), ("12", "0.002"), ("13", "0"),
        ("20", "0"), ("21", "0"), ("22", "0"), ("23", "0"), ("24", "25.000"), ("25", "500.000"),
        ("26", "250"), ("27", "1.000"), ("30", "1000"), ("31", "0"), ("32", "1"),
        ("100", "250.000"), ("101", "250.000"), ("102", "250.000"),
        ("110", "6000.000"), ("111", "6000.000"), ("112", "6000.000"),
        ("120", "1000.000"), ("121", "1000.000"), ("122", "1000.000"),
        ("130", "300.000"), ("131", "300.000"), ("132", "300.000"),
    ];
    let mut out: Vec<String> = defaults
        .iter()
        .map(|(n, v)| format!("${n}={}", changes.iter().find(|c| c.0 == *n).map_or(*v, |c| c.1)))
        .collect();
    out.push("ok".into());
    out
}

fn leak(v: Vec<String>) -> &'static [&'static str] {
    v.into_iter().map(|s| &*s.leak()).collect::<Vec<&'static str>>().leak()
}

/// Every `$` command of the reference.
#[test]
fn system_commands() {
    let mut rows: Vec<Row> = vec![
        (xy, &[], &[L("$")], &["[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]", "ok"]),
        (xy, &[L("G1X100F600")], &[L("$$")], &["error:8"]),
        // (Right behind the `!`, while the hold brakes: once it has stopped,
        // Grbl reads no line until `~`.)
        (xy, &[L("G1X100F600")], &[B(b"!$$\n")], &["error:8"]),
        // $x=value: written values read back (integers truncated, booleans 0/1) and survive a reset.
        (xy, &[], &[L("$110=600.5")], &["ok"]),
        (xy, &[], &[L("$10=abc")], &["error:2"]),
        (xy, &[], &[L("$10")], &["error:3"]),
        (xy, &[], &[L("$999=1")], &["error:3"]),
        (xy, &[L("G1X100F600")], &[L("$110=600")], &["error:8"]),
        (xy, &[TRIP, RESET], &[L("$110=600"), L("$X")], &["ok", "[MSG:Caution: Unlocked]", "ok"]),
        // $#: G54..G59 and G28/G30 (kept like EEPROM), G92, TLO, the last probe.
        (xy, &[], &[L("$#")], &[
            "[G54:0.000,0.000,0.000]", "[G55:0.000,0.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:0.000,0.000,0.000]", "[G28:0.000,0.000,0.000]", "[G30:0.000,0.000,0.000]",
            "[G92:0.000,0.000,0.000]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]", "ok",
        ]),
        (xy, &[L("G10L2P2X5Y6"), L("G10L2P6X-1"), L("G0X1Y2"), L("G28.1"), L("G0X3Y4"), L("G30.1"), L("G92X0")], &[L("$#")], &[
            "[G54:0.000,0.000,0.000]", "[G55:5.000,6.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:-1.000,0.000,0.000]", "[G28:1.000,2.000,0.000]", "[G30:3.000,4.000,0.000]",
            "[G92:3.000,0.000,0.000]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]", "ok",
        ]),
        (xy, &[L("G10L2P2X5Y6"), L("G0X1Y2"), L("G28.1"), L("G92X0"), RESET], &[L("$#")], &[
            "[G54:0.000,0.000,0.000]", "[G55:5.000,6.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:0.000,0.000,0.000]", "[G28:1.000,2.000,0.000]", "[G30:0.000,0.000,0.000]",
            "[G92:0.000,0.000,0.000]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]", "ok",
        ]),
        (xyz, &[L("G43.1Z-1.5")], &[L("$#")], &[
            "[G54:0.000,0.000,0.000]", "[G55:0.000,0.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:0.000,0.000,0.000]", "[G28:0.000,0.000,0.000]", "[G30:0.000,0.000,0.000]",
            "[G92:0.000,0.000,0.000]", "[TLO:-1.500]", "[PRB:0.000,0.000,0.000:0]", "ok",
        ]),
        (xy, &[L("G1X100F600")], &[L("$#")], &["error:8"]),
        // $G in any state.
        (xy, &[], &[L("$G")], &["[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]),
        (xy, &[L("G91 G93 M4 S250")], &[L("$G")], &["[GC:G0 G54 G17 G21 G91 G93 M4 M9 T0 F0 S250]", "ok"]),
        (xy, &[L("G1F100"), L("G55G20G18"), L("M8"), L("T5"), L("S300")], &[L("$G")], &["[GC:G1 G55 G18 G20 G90 G94 M5 M8 T5 F100 S300]", "ok"]),
        (xy, &[L("G38.3X5F100"), Wait(4.0)], &[L("$G")], &["[GC:G38.3 G54 G17 G21 G90 G94 M5 M9 T0 F100 S0]", "ok"]),
        (xy, &[L("G1X100F600")], &[L("$G")], &["[GC:G1 G54 G17 G21 G90 G94 M5 M9 T0 F600 S0]", "ok"]),
        // $I, $I=.
        (xy, &[], &[L("$I")], &["[VER:1.1h.20190830:]", "[OPT:V+,15,128]", "ok"]),
        (xy, &[L("$I=My Laser")], &[L("$I")], &["[VER:1.1h.20190830:MYLASER]", "[OPT:V+,15,128]", "ok"]),
        (xy, &[L("$I=My Laser"), RESET], &[L("$I")], &["[VER:1.1h.20190830:MYLASER]", "[OPT:V+,15,128]", "ok"]),
        (xy, &[L("G1X100F600")], &[L("$I")], &["error:8"]),
        // $N, $Nx=: validated by executing, run after each reset without an alarm.
        (xy, &[], &[L("$N")], &["$N0=", "$N1=", "ok"]),
        (xy, &[], &[L("$N0=G21 G54")], &["ok"]),
        (xy, &[L("$N0=G21 G54"), L("$N1=G20")], &[L("$N")], &["$N0=G21G54", "$N1=G20", "ok"]),
        (xy, &[L("$N0=G21 G54"), L("$N1=G20")], &[RESET], &[BANNER, ">G21G54:ok", ">G20:ok"]),
        (xy, &[L("$N1=G20"), RESET], &[L("$G")], &["[GC:G0 G54 G17 G20 G90 G94 M5 M9 T0 F0 S0]", "ok"]),
        (xy, &[L("G1F100"), L("$N0=G1X1"), Wait(1.0)], &[RESET], &[BANNER, ">G1X1:error:22"]),
        (xy, &[], &[L("$N1=G5")], &["error:20"]),
        (xy, &[L("$N1=G5")], &[L("$N")], &["$N0=", "$N1=", "ok"]),
        (xy, &[], &[L("$N2=G20")], &["error:3"]),
        (xy, &[], &[L("$N0")], &["error:3"]),
        (xy, &[TRIP, RESET], &[L("$N0=G20")], &["error:8"]),
        (xy, &[TRIP, RESET], &[L("$N")], &["$N0=", "$N1=", "ok"]),
        (xy, &[L("$N0=G20"), TRIP], &[RESET], &["ok", BANNER, UNLOCK]),
        (xy, &[L("$N0=G20"), TRIP, RESET], &[L("$X")], &["[MSG:Caution: Unlocked]", "ok"]),
        (xy, &[L("$N0=G20"), Door(true)], &[RESET, Q], &[BANNER, "[MSG:Check Door]", "<Door:1|MPos:0.000,0.000,0.000|FS:0,0|Pn:D|WCO:0.000,0.000,0.000>"]),
        (xy, &[L("$N0=G20"), Door(true), RESET, Door(false)], &[START], &[">G20:ok"]),
        (xy, &[L("$22=1"), L("$N0=G20")], &[L("$H")], &[">G20:ok", "ok"]),
        // $C check mode.
        (xy, &[], &[L("$C")], &["[MSG:Enabled]", "ok"]),
        (xy, &[L("$C")], &[L("$C")], &["[MSG:Disabled]", "ok", BANNER]),
        (xy, &[L("$C")], &[L("G1X10F100"), L("G4P5"), Q], &["ok", "ok", "<Check|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"]),
        (xy, &[TRIP, RESET], &[L("$C")], &["error:8"]),
        // $X.
        (xy, &[], &[L("$X")], &["ok"]),
        (xy, &[TRIP, RESET], &[L("$X")], &["[MSG:Caution: Unlocked]", "ok"]),
        (xy, &[TRIP, RESET, Door(true)], &[L("$X")], &["error:13"]),
        // $H.
        (xy, &[], &[L("$H")], &["error:5"]),
        (xy, &[L("$22=1"), L("$25=600"), L("G0X10"), Wait(0.5)], &[L("$H"), Wait(1.0)], &["ok"]),
        (xy, &[TRIP, RESET, Door(true)], &[L("$H")], &["error:13"]),
        (xy, &[L("$22=1")], &[L("$HX")], &["error:3"]),
        (xy, &[L("$22=1"), L("G1X100F600")], &[L("$H")], &["error:8"]),
        // $J=.
        (xy, &[], &[L("$J=X1F100"), Wait(0.5)], &["ok"]),
        (xy, &[], &[L("$J")], &["error:3"]),
        (xy, &[TRIP, RESET], &[L("$J=X1F100")], &["error:8"]),
        (xy, &[L("$C")], &[L("$J=X1F100")], &["error:8"]),
        // $SLP: only a reset leaves it, into Alarm.
        (xy, &[L("$SLP")], &[RESET], &[BANNER, UNLOCK]),
        (xy, &[L("G1X100F600")], &[L("$SLP")], &["error:8"]),
        // $RST=$ / # / *: then a reset (startup lines run after it).
        (xy, &[], &[L("$RST=$")], &["[MSG:Restoring defaults]", "ok", BANNER]),
        (xy, &[L("$N0=G20")], &[L("$RST=$")], &["[MSG:Restoring defaults]", "ok", BANNER, ">G20:ok"]),
        (xy, &[L("G10L2P1X5"), L("G0X1"), L("G28.1"), L("$RST=#")], &[L("$#")], &[
            "[G54:0.000,0.000,0.000]", "[G55:0.000,0.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:0.000,0.000,0.000]", "[G28:0.000,0.000,0.000]", "[G30:0.000,0.000,0.000]",
            "[G92:0.000,0.000,0.000]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]", "ok",
        ]),
        (xy, &[L("$N0=G20"), L("$I=X1"), L("$RST=*")], &[L("$N"), L("$I")], &["$N0=", "$N1=", "ok", "[VER:1.1h.20190830:]", "[OPT:V+,15,128]", "ok"]),
        (xy, &[], &[L("$RST=x")], &["error:3"]),
        (xy, &[L("G1X100F600")], &[L("$RST=*")], &["error:8"]),
        (xy, &[], &[L("$Q")], &["error:2"]),
        // [echo: ] (a build option): the line after cleaning.
        (xy, &[ECHO_ON], &[L("g0 x1 (move)"), L("")], &["[echo: G0X1]", "ok", "[echo: ]", "ok"]),
    ];
    // $$ listings: defaults, written values kept across a reset, $RST=$.
    rows.push((xy, &[], &[L("$$")], leak(listing(&[]))));
    rows.push((
        xy,
        &[L("$110=600.5"), L("$26=300.7"), L("$13=5"), L("$22=1"), L("$20=0"), L("$10=0"), RESET],
        &[L("$$")],
        leak(listing(&[("10", "0"), ("13", "1"), ("20", "0"), ("22", "1"), ("26", "300"), ("110", "600.500")])),
    ));
    rows.push((xy, &[L("$22=0")], &[L("$$")], leak(listing(&[("20", "0")]))));
    rows.push((xy, &[L("$110=600"), L("$22=1"), L("$RST=$")], &[L("$$")], leak(listing(&[]))));
    rows.push((xy, &[TRIP, RESET], &[L("$$")], leak(listing(&[("20", "1"), ("22", "1")]))));
    check(&rows);
}

/// Every error code the simulator can produce, each on a path of the reference.
#[test]
fn error_codes() {
    let rows: &[Row] = &[
        (xy, &[], &[L("1")], &["error:1"]),
        (xy, &[], &[L("X")], &["error:2"]),
        (xy, &[], &[L("$10=-")], &["error:2"]),
        (xy, &[], &[L("$Q")], &["error:2"]),
        (xy, &[], &[L("$RST=")], &["error:3"]),
        (xy, &[], &[L("F-1")], &["error:4"]),
        (xy, &[], &[L("$11=-1")], &["error:4"]),
        (xy, &[], &[L("$H")], &["error:5"]),
        (xy, &[], &[L("$0=2")], &["error:6"]),
        (xy, &[L("G1X100F600")], &[L("$$")], &["error:8"]),
        (xy, &[TRIP, RESET], &[L("$C")], &["error:8"]),
        (xy, &[TRIP, RESET], &[L("G0X1")], &["error:9"]),
        (xy, &[L("$J=X100F600")], &[L("G0X1")], &["error:9"]),
        (xy, &[], &[L("$20=1")], &["error:10"]),
        (xy, &[L("$22=1")], &[L("$20=1")], &["ok"]),
        (xy, &[], &[B(b"G0 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1 X1\n")], &["error:11"]),
        (xy, &[TRIP, RESET, Door(true)], &[L("$X")], &["error:13"]),
        (xy, &[L("$22=1"), L("$20=1")], &[L("$J=X1F100")], &["error:15"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$20=0")], &[L("$J=X1F100"), Wait(0.5)], &["ok"]),
        (xy, &[], &[L("$J=X1S5F100")], &["error:16"]),
        (xy, &[], &[L("$J=G1X1F100")], &["error:16"]),
        (xy, &[], &[L("G5X1")], &["error:20"]),
        (xy, &[], &[L("M6")], &["error:20"]),
        (xy, &[], &[L("A1")], &["error:20"]),
        (xy, &[], &[L("G90.1")], &["error:20"]),
        (xy, &[], &[L("G38.1X1F100")], &["error:20"]),
        (xy, &[], &[L("G10L3P1X0")], &["error:20"]),
        (xy, &[], &[L("M7")], &["error:20"]),
        (xy, &[], &[L("G0G80")], &["error:21"]),
        (xy, &[], &[L("M8M9")], &["error:21"]),
        (xy, &[], &[L("G1X1")], &["error:22"]),
        (xy, &[], &[L("G93G1X1")], &["error:22"]),
        (xy, &[], &[L("G38.2X1")], &["error:22"]),
        (xy, &[], &[L("G1.5X1")], &["error:23"]),
        (xy, &[], &[L("M3.1")], &["error:23"]),
        (xy, &[], &[L("G0G92X0")], &["error:24"]),
        (xy, &[], &[L("G1G28X1F100")], &["error:24"]),
        (xyz, &[], &[L("G0G43.1Z1")], &["error:24"]),
        (xy, &[], &[L("X1X2")], &["error:25"]),
        (xy, &[], &[L("G92")], &["error:26"]),
        (xy, &[], &[L("G10L2P1")], &["error:26"]),
        (xy, &[], &[L("G38.2F100")], &["error:26"]),
        (xy, &[], &[L("N10000001G0X1")], &["error:27"]),
        (xy, &[], &[L("G4")], &["error:28"]),
        (xy, &[], &[L("G10X1")], &["error:28"]),
        (xy, &[], &[L("G10L2P7X1")], &["error:29"]),
        (xy, &[L("G80")], &[L("G53")], &["error:30"]),
        (xy, &[], &[L("G80X1")], &["error:31"]),
        (xy, &[], &[L("G2I1F100")], &["error:32"]),
        (xyz, &[], &[L("G2Z5I1F100")], &["error:32"]),
        (xy, &[], &[L("G2X0Y0R1F100")], &["error:33"]),
        (xy, &[], &[L("G2X10I1F100")], &["error:33"]),
        (xy, &[], &[L("G38.2X0F100")], &["error:33"]),
        (xy, &[], &[L("G2X5R1F100")], &["error:34"]),
        (xy, &[], &[L("G2X5F100")], &["error:35"]),
        (xy, &[], &[L("G0X1P1")], &["error:36"]),
        (xy, &[], &[L("G0X1I1")], &["error:36"]),
        (xy, &[], &[L("G1X1L2F100")], &["error:36"]),
        (xyz, &[], &[L("G43.1X1")], &["error:37"]),
        (xyz, &[], &[L("G43.1")], &["error:37"]),
        (xyz, &[], &[L("G43.1Z1X1")], &["error:37"]),
        (xy, &[], &[L("T256")], &["error:38"]),
    ];
    check(rows);
}

/// Every alarm path, with what follows it.
#[test]
fn alarms() {
    let rows: &[Row] = &[
        // 1: hard limit (critical: nothing but a reset is heard).
        (limit_1, &[], &[L("G0X1")], &["ALARM:1", "[MSG:Reset to continue]"]),
        (limit_1, &[L("G0X1")], &[L("G0X2"), L("$X"), Q], &[]),
        (limit_1, &[L("G0X1")], &[RESET], &[BANNER, UNLOCK]),
        (limit_2, &[L("$21=1"), L("G0X1")], &[RESET], &[BANNER, UNLOCK, "[MSG:Check Limits]"]),
        // 2: soft limit (critical): see `homing_and_soft_limits`.
        (xy, &[TRIP, RESET], &[L("G0X-1")], &["error:9"]),
        (xy, &[TRIP, RESET], &[L("$X")], &["[MSG:Caution: Unlocked]", "ok"]),
        (xy, &[L("$22=1"), L("$20=1"), L("G0X-290"), Wait(3.0)], &[L("G28X-310")], &["ALARM:2", "[MSG:Reset to continue]"]),
        // 3: reset while moving.
        (xy, &[L("G0X100F100")], &[RESET], &["ALARM:3", BANNER, UNLOCK]),
        // 4: probe not in its expected state at the start.
        (xy, &[], &[L("G38.4X5F600")], &["ALARM:4", "ok"]),
        (xy, &[], &[L("G38.5X5F600")], &["ALARM:4", "ok"]),
        (probe_2mm, &[L("G38.2X10F600"), Wait(0.5)], &[L("G38.2X20F600")], &["ALARM:4", "ok"]),
        (xy, &[L("G38.4X5F600")], &[L("G0X1")], &["error:9"]),
        // 5: no contact (G38.2/.4); the no-error forms just report.
        (xy, &[], &[L("G38.2X5F600"), Wait(1.0)], &["ALARM:5", "[PRB:0.000,0.000,0.000:0]", "ok"]),
        (xy, &[], &[L("G38.3X5F600"), Wait(1.0)], &["[PRB:5.000,0.000,0.000:0]", "ok"]),
        (probe_2mm, &[L("G38.2X10F600"), Wait(0.5)], &[L("G38.4X1F600"), Wait(0.5)], &["ALARM:5", "[PRB:2.000,0.000,0.000:0]", "ok"]),
        (probe_2mm, &[L("G38.2X10F600"), Wait(0.5)], &[L("G38.5X1F600"), Wait(0.5)], &["[PRB:1.000,0.000,0.000:0]", "ok"]),
        (xy, &[L("G38.2X5F600"), Wait(1.0)], &[L("G0X1")], &["error:9"]),
        // ...and with contact: [PRB:...:1], also in $#.
        (probe_2mm, &[], &[L("G38.2X10F600"), Wait(0.5)], &["[PRB:2.000,0.000,0.000:1]", "ok"]),
        (probe_2mm, &[L("G38.2X10F600"), Wait(0.5)], &[L("G38.4X10F600"), Wait(0.5)], &["[PRB:4.000,0.000,0.000:1]", "ok"]),
        (probe_2mm, &[L("G38.2X10F600"), Wait(0.5)], &[L("$#")], &[
            "[G54:0.000,0.000,0.000]", "[G55:0.000,0.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:0.000,0.000,0.000]", "[G28:0.000,0.000,0.000]", "[G30:0.000,0.000,0.000]",
            "[G92:0.000,0.000,0.000]", "[TLO:0.000]", "[PRB:2.000,0.000,0.000:1]", "ok",
        ]),
        (xy, &[L("$C")], &[L("G38.2X5F600")], &["ok"]),
        // 6: reset during homing; 7: door opened during homing.
        (xy, &[L("$22=1"), L("G0X50"), Wait(1.0)], &[L("$H"), RESET], &["ALARM:6", "ok", BANNER, UNLOCK]),
        (xy, &[L("$22=1"), L("G0X50"), Wait(1.0)], &[L("$H"), DOOR], &["ALARM:7", "ok", BANNER, UNLOCK]),
        (xy, &[L("$22=1"), L("G0X50"), Wait(1.0), L("$H"), DOOR], &[Q], &["<Alarm|MPos:*|FS:0,0|WCO:0.000,0.000,0.000>"]),
        (xy, &[L("$22=1"), L("G0X50"), Wait(1.0), L("$H"), Door(true)], &[Q], &["<Alarm|MPos:*|FS:0,0|Pn:D|WCO:0.000,0.000,0.000>"]),
        // 8: the pull-off does not clear the switch; 9: no switch found.
        // (8 and 9: see `homing_and_soft_limits`.)
    ];
    check(rows);
}

/// The G-code side of the reference's feedback: offsets, stored positions,
/// program flow.
#[test]
fn gcode_feedback() {
    let rows: &[Row] = &[
        (xy, &[], &[L("M2")], &["[MSG:Pgm End]", "ok"]),
        (xy, &[], &[L("M30")], &["[MSG:Pgm End]", "ok"]),
        (xy, &[L("G91G55M8"), L("M2")], &[L("$G")], &["[GC:G1 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]),
        // M0 pauses (Hold) and answers once resumed (its 3 bytes stay in RX
        // until answered, as every line's do here); M1 is ignored.
        (xy, &[Q, Q], &[L("M0"), Q], &["<Hold:0|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, &[L("M0")], &[START], &["ok"]),
        (xy, &[L("M0"), L("G0X1")], &[START, Wait(0.5)], &["ok", "ok"]),
        (xy, &[], &[L("M1")], &["ok"]),
        (xy, &[], &[L("M0M1")], &["error:21"]),
        // G28/G30: to the stored position, via a given point with only its axes.
        (xy, &[Q, Q, L("G0X5Y5"), L("G28.1"), L("G0X20Y1"), Wait(0.5)], &[L("G28"), Wait(0.5), Q], &["ok", "<Idle|MPos:5.000,5.000,0.000|FS:0,0>"]),
        (xy, &[Q, Q, L("G0X5Y5"), L("G30.1"), L("G0X20Y1"), Wait(0.5)], &[L("G30X10"), Wait(0.5), Q], &["ok", "<Idle|MPos:5.000,1.000,0.000|FS:0,0>"]),
        // G10 L20: the present position reads as given.
        (xy, &[Q, Q, L("G0X5"), L("G10L20P1X1")], &[Q], &["<Idle|MPos:5.000,0.000,0.000|FS:0,0|WCO:4.000,0.000,0.000>"]),
        (xy, &[L("G0X5"), L("G10L20P0X1"), L("$10=0"), Q, Q], &[L("G0X0"), Wait(0.5), Q], &["ok", "<Idle|WPos:0.000,0.000,0.000|FS:0,0>"]),
    ];
    check(rows);
}

/// Dwells and the buffer state (issue 17, rows 18-20): `$10` defaults to 1
/// (no `Bf:`); during a `G4` the machine is Idle, the dwell's line is out of
/// the receive buffer and its `ok` comes at the dwell's end, or before the
/// banner when a reset cuts it short; `Bf:` counts planner blocks only, so a
/// block whose last step segment is prepared (within 5 segments of 10 ms)
/// no longer counts though it still runs.
#[test]
fn dwells_and_buffer_state() {
    let rows: &[Row] = &[
        // Row 19: the default report has no `Bf:`; `$10=3` adds it.
        (xy, &[Q, Q], &[Q], &[IDLE]),
        (xy, &[L("$10=3"), Q, Q], &[Q], &[IDLE_BF]),
        // Row 18: Idle during the dwell, its line out of the buffer, no `ok` yet.
        (xy, &[Q, Q, L("$10=3"), L("G4P1")], &[Q], &[IDLE_BF]),
        (xy, &[Q, Q, L("G4P1")], &[Q], &[IDLE]),
        (xy, &[Q, Q, L("$10=3"), L("G4P1")], &[Wait(1.0)], &["ok"]),
        // The lines behind it wait in the buffer.
        (xy, &[Q, Q, L("$10=3"), B(b"G4P1\nG0X1\n")], &[Q], &["<Idle|MPos:0.000,0.000,0.000|Bf:15,123|FS:0,0>"]),
        // Row 20: a reset ends the dwell; its line is answered, then the banner.
        (xy, &[L("G4P2")], &[RESET], &["ok", BANNER]),
        (xy, &[L("G1X100F600"), L("G4P1")], &[RESET], &["ALARM:3", "ok", BANNER, UNLOCK]),
        // `Bf:` while moving: a block with more than 5 segments (50 ms) to run counts...
        (xy, &[Q, Q, L("$10=3"), B(b"N7G1X3F600\nN8G1X6\n")], &[Q], &["<Run|MPos:*|Bf:13,128|FS:600,0>"]),
        // ...one with 4 left is out of the planner: `Bf:` shows it free.
        (xy, &[Q, Q, L("$10=3"), B(b"N7G1X3F600\nN8G1X6\n"), Wait(0.07)], &[Q], &["<Run|MPos:*|Bf:14,128|FS:600,0>"]),
        (grbl_motion, &[Q, Q, L("$10=3"), B(b"N7G1X3F600\nN8G1X6\n")], &[Q], &["<Run|MPos:*|Bf:13,128|FS:600,0>"]),
        (grbl_motion, &[Q, Q, L("$10=3"), B(b"N7G1X3F600\nN8G1X6\n"), Wait(0.07)], &[Q], &["<Run|MPos:*|Bf:14,128|FS:600,0>"]),
        // The last block prepared: the planner is empty while it runs.
        (xy, &[Q, Q, L("$10=3"), B(b"N7G1X3F600\nN8G1X3.6\n"), Wait(0.13)], &[Q], &["<Run|MPos:*|Bf:15,128|FS:600,0>"]),
    ];
    check(rows);
}

/// A grblHAL board with Grbl's three axes, its 1024-byte receive buffer and 100 blocks.
fn hal() -> SimConfig {
    SimConfig { flavor: Flavor::Grblhal, rx_buffer: 1024, planner_blocks: 100, ..SimConfig::with_axes("XYZ") }
}

/// A 4-axis config (a galvo's X Y U V) under the `grbl` flavour: Grbl 1.1h
/// still has X, Y and Z only (laserd's config refuses this; see `flavor_error`).
fn xyuv() -> SimConfig {
    SimConfig::with_axes("XYUV")
}

/// Issue 17's "simulator against Grbl 1.1h" rows 5-10, 14, 15, 17 and 21:
/// report requests, report units, parser errors, jogging, what a hold and
/// sleep do to lines, the spindle at rest, Grbl's axes, grblHAL's line ends,
/// G59.1-G59.3, `$I` and banner. Reports are asked with `$10=3` set.
#[test]
fn grbl_1_1h_parser_and_reports() {
    let rows: &[Row] = &[
        // 5: a `?` while the last one's report is being formatted gets no
        // report of its own (protocol.c prints, then clears the request); one
        // a moment later does.
        (xy, &[L("$10=3"), Q, Q], &[B(b"??")], &["<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>"]),
        (xy, &[L("$10=3"), Q, Q], &[Q, Q], &[
            "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>",
            "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>",
        ]),
        // 6: `$13=1` reports positions, offsets and the feed in inches (4 and 1 decimals).
        (xy, &[L("$10=3"), L("$13=1"), L("G0X25.4Y2.54"), Wait(0.5), Q, Q], &[Q], &["<Idle|MPos:1.0000,0.1000,0.0000|Bf:15,128|FS:0.0,0>"]),
        (xy, &[L("$10=3"), L("$13=1"), Q, Q, L("G1X100F254")], &[Q], &["<Run|MPos:*|Bf:14,128|FS:10.0,0>"]),
        (xy, &[L("$10=0"), L("$13=1"), L("G10L2P1X25.4"), Q, Q], &[Q], &["<Idle|WPos:-1.0000,0.0000,0.0000|FS:0.0,0>"]),
        (xy, &[L("$10=3"), L("$13=1"), L("G10L2P1X25.4")], &[Q], &["<Idle|MPos:0.0000,0.0000,0.0000|Bf:15,128|FS:0.0,0|WCO:1.0000,0.0000,0.0000>"]),
        (xy, &[L("$13=1"), L("G10L2P2X25.4"), L("G43.1Z2.54")], &[L("$#")], &[
            "[G54:0.0000,0.0000,0.0000]", "[G55:1.0000,0.0000,0.0000]", "[G56:0.0000,0.0000,0.0000]",
            "[G57:0.0000,0.0000,0.0000]", "[G58:0.0000,0.0000,0.0000]", "[G59:0.0000,0.0000,0.0000]",
            "[G28:0.0000,0.0000,0.0000]", "[G30:0.0000,0.0000,0.0000]", "[G92:0.0000,0.0000,0.0000]",
            "[TLO:0.1000]", "[PRB:0.0000,0.0000,0.0000:0]", "ok",
        ]),
        (xy, &[L("$13=1"), L("G1F254")], &[L("$G")], &["[GC:G1 G54 G17 G21 G90 G94 M5 M9 T0 F10.0 S0]", "ok"]),
        // 7: the parser keeps feeds in mm/min; `$G` prints them so unless `$13=1`.
        (xy, &[L("G20F50")], &[L("$G")], &["[GC:G0 G54 G17 G20 G90 G94 M5 M9 T0 F1270 S0]", "ok"]),
        // 8: errors in Grbl's order: a second axis command (24) before the
        // modal group (21); G59.x is a G59 with a fraction (23); G53 before
        // the feed (30); `$` and no number (2); N up to 10,000,000.
        (xy, &[], &[L("G1G0X1")], &["error:24"]),
        (xy, &[], &[L("G28G28")], &["error:24"]),
        (xy, &[], &[L("G59.1")], &["error:23"]),
        (xy, &[], &[L("G53G2X1")], &["error:30"]),
        (xy, &[], &[L("$Z")], &["error:2"]),
        (xy, &[], &[L("N10000000G0X0")], &["ok"]),
        // 9: G-code while jogging, also right behind the jog in one write.
        (xy, &[], &[B(b"$J=X10F1000\nG0X1\n")], &["ok", "error:9"]),
        // 10: a completed hold suspends Grbl: no line is read until `~`.
        (xy, &[L("$10=3"), Q, Q, HOLD], &[L("$G"), L("$#"), L("$$"), L("$I"), Q], &["<Hold:0|MPos:0.000,0.000,0.000|Bf:15,116|FS:0,0>"]),
        (xy, &[HOLD, L("$G"), L("$I")], &[START], &[
            "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok", "[VER:1.1h.20190830:]", "[OPT:V+,15,128]", "ok",
        ]),
        (xy, &[L("$10=3"), Q, Q, L("G1X2F600"), HOLD, Wait(1.0)], &[L("G0X0"), Q], &["<Hold:0|MPos:*|Bf:14,123|FS:0,0>"]),
        // 14: `$SLP` answers, then sleeps: later lines get no answer until a reset.
        (xy, &[], &[L("$SLP")], &["ok", "[MSG:Sleeping]"]),
        (xy, &[L("$10=3"), Q, Q, L("$SLP")], &[L("G0X1"), L("$$"), Q], &["<Sleep|MPos:0.000,0.000,0.000|Bf:15,120|FS:0,0>"]),
        (xy, &[L("$SLP"), L("G0X1")], &[RESET, L("$X")], &[BANNER, UNLOCK, "[MSG:Caution: Unlocked]", "ok"]),
        // 15: outside laser mode (`$32=0`, Grbl's default) `M3 S500` runs the
        // output at S standing still; in laser mode M3 lights it in G1-G3 only
        // (`M3S500` after `G1F100` above), not in G0 (gcode.c passes 0 there).
        (xy, &[L("$10=3"), L("$32=0"), Q, Q], &[L("M3S500"), Q], &["ok", "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,500|Ov:100,100,100|A:S>"]),
        (xy, &[L("$10=3"), L("$32=0"), L("M3S500"), Q, Q], &[L("S200"), Q], &["ok", "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,200>"]),
        // 17: Grbl 1.1h always has X, Y and Z.
        (xy, &[L("$10=3"), Q, Q, L("G0Z1"), Wait(0.5)], &[Q], &["<Idle|MPos:0.000,0.000,1.000|Bf:15,128|FS:0,0>"]),
        (xyuv, &[L("$10=3"), Q, Q], &[L("G0U1"), Q], &["error:20", "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>"]),
        (xyuv, &[], &[L("$I")], &["[VER:1.1h.20190830:]", "[OPT:V+,15,128]", "ok"]),
        // 21: grblHAL: CR or LF alone ends a line; the second of a CR LF pair
        // is skipped only while the line is still empty (blanks do not count).
        (hal, &[], &[B(b"G21\r")], &["ok"]),
        (hal, &[], &[B(b"\r\r")], &["ok", "ok"]),
        (hal, &[B(b"G21\n")], &[B(b" \r")], &[]),
        (hal, &[B(b"G21\n")], &[B(b"G90\r")], &["ok"]),
        // ...G59.1-G59.3 (P7-P9)...
        (hal, &[], &[L("G59.1"), L("G59.3"), L("G10L2P8X1")], &["ok", "ok", "ok"]),
        // ...its `$I` (at compatibility level 0) and its banner.
        (hal, &[], &[L("$I")], &[
            "[VER:1.1f.20250731:]", "[OPT:VNM+,100,1024,3,0]", "[AXS:3:XYZ]", "[NEWOPT:ENUMS,RT+]", "[FIRMWARE:grblHAL]",
            "[DRIVER:laserd-sim]", concat!("[DRIVER VERSION:", env!("CARGO_PKG_VERSION"), "]"), "ok",
        ]),
        (hal, &[], &[RESET], &["GrblHAL 1.1f ['$' or '$HELP' for help]"]),
    ];
    check(rows);
    // G59.1 moves the work origin: G0 X0 there goes to its X.
    let mut s = common::Sim::new(hal());
    for a in [L("G10L2P7X5"), L("G59.1"), L("G0X0"), Wait(1.0)] {
        act(&mut s, a);
    }
    assert_eq!(s.ctl.position()[0], 5.0, "{:?}", s.texts());
}

/// Arcs as Grbl 1.1h's `mc_arc` cuts them: `floor(arc length / chord)`
/// segments for chords of sagitta `$12` (so a quarter circle of radius 1 at
/// the default 0.002 mm is 12 planner blocks, not the 13 that keep every
/// chord within `$12`); in G93 each segment runs at F × segments mm/min
/// (Grbl multiplies F by the count and drops inverse time); gcode.c's radius
/// check: start and end radii within 0.005 mm, or within 0.1 % of the radius
/// up to 0.5 mm.
#[test]
fn arcs_as_grbl_1_1h_segments_and_times_them() {
    let rows: &[Row] = &[
        (xy, &[L("$10=3"), Q, Q], &[L("G3X-1Y1I-1F6"), Q], &["ok", "<Run|MPos:*|Bf:3,128|FS:6,0>"]),
        (xy, &[L("$10=3"), L("$12=0.02"), Q, Q], &[L("G3X-1Y1I-1F6"), Q], &["ok", "<Run|MPos:*|Bf:12,128|FS:6,0>"]),
        (xy, &[L("$10=3"), Q, Q], &[L("G93G3X-1Y1I-1F6"), Q], &["ok", "<Run|MPos:*|Bf:5,128|FS:72,0>"]),
        // An arc shorter than one chord is one straight block, in G93 in 1/F minutes.
        (xy, &[L("$10=3"), Q, Q], &[L("G93G2X0.1Y-0.001J-5F60"), Q], &["ok", "<Run|MPos:*|Bf:14,128|FS:6,0>"]),
        // (Coarse `$12` so that the planner queue takes the whole arc at once.)
        (xy, &[L("$12=0.1")], &[L("G2X10.004Y0I5F600")], &["ok"]),
        (xy, &[], &[L("G2X10.006Y0I5F600")], &["error:33"]),
        (xy, &[L("$12=10")], &[L("G2X1200.4Y0I600F600")], &["ok"]),
        (xy, &[], &[L("G2X1200.55Y0I600F600")], &["error:33"]),
    ];
    check(rows);
}

/// Homing and soft limits as Grbl 1.1h has them: its default settings (no
/// homing, no soft limits), its negative machine space (homing to the
/// positive end by default, `$23` turning an axis round, the pull-off `$27`
/// inside the switch), the critical soft-limit alarm and its silence until a
/// reset, and the order of a failed homing cycle's answers.
#[test]
fn homing_and_soft_limits() {
    let rows: &[Row] = &[
        // Grbl's defaults ($20=0, $22=0): no soft limits, so nothing is beyond travel.
        (xy, &[], &[L("G0X-1"), Wait(0.5)], &["ok"]),
        (xy, &[], &[L("$J=X-1F100"), Wait(0.5)], &["ok"]),
        // After `$H`: each axis at minus the pull-off, at the positive end.
        (xy, &[L("$10=1"), L("$22=1"), L("$H"), Wait(0.5), Q, Q], &[Q], &["<Idle|MPos:-1.000,-1.000,-1.000|FS:0,0>"]),
        (xy, &[L("$10=1"), L("$22=1"), L("$27=5"), L("$H"), Wait(1.0), Q, Q], &[Q], &["<Idle|MPos:-5.000,-5.000,-5.000|FS:0,0>"]),
        // $23 bit 0: X homes to its negative end, pull-off inside it.
        (xy, &[L("$10=1"), L("$22=1"), L("$23=1"), L("$25=6000"), L("$H"), Wait(3.5), Q, Q], &[Q], &["<Idle|MPos:-299.000,-1.000,-1.000|FS:0,0>"]),
        // Soft limits: -$130 <= MPos <= 0 on every axis, however it homes.
        (xy, &[L("$22=1"), L("$20=1"), L("$H"), Wait(0.5)], &[L("$J=G91X10F600")], &["error:15"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$H"), Wait(0.5)], &[L("$J=G91X-10F600"), Wait(1.5)], &["ok"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$23=3"), L("$25=6000"), L("$H"), Wait(3.5)], &[L("$J=G91X-0.5F600"), Wait(0.5)], &["ok"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$23=3"), L("$25=6000"), L("$H"), Wait(3.5)], &[L("$J=G91X-1.5F600")], &["error:15"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$130=100"), L("$H"), Wait(0.5)], &[L("$J=X-100F6000"), Wait(1.5)], &["ok"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$130=100"), L("$H"), Wait(0.5)], &[L("$J=X-100.1F6000")], &["error:15"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$H"), Wait(0.5)], &[L("G0X-300Y-300"), Wait(3.5)], &["ok"]),
        // A move past them: the critical ALARM:2, then nothing (not even
        // status reports) until a reset; the line's `ok` comes with the
        // reset, before the banner.
        (xy, &[L("$22=1"), L("$20=1")], &[L("G0X1")], &["ALARM:2", "[MSG:Reset to continue]"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$H"), Wait(0.5)], &[L("G0X-301")], &["ALARM:2", "[MSG:Reset to continue]"]),
        (xy, &[L("$22=1"), L("$20=1"), L("G0X1")], &[Q, L("G0X-1"), L("$X"), Wait(1.0)], &[]),
        (xy, &[L("$22=1"), L("$20=1"), L("G0X1"), Q, L("G0X-1")], &[RESET], &["ok", BANNER, UNLOCK]),
        (xy, &[L("$22=1"), L("$20=1"), L("G0X-100"), Wait(0.1)], &[L("G0X5"), Wait(1.5)], &["ALARM:2", "[MSG:Reset to continue]"]),
        (xy, &[L("$22=1"), L("$20=1"), L("G0X-100"), Wait(0.1), L("G0X5"), Wait(1.5)], &[RESET], &["ok", BANNER, UNLOCK]),
        // A running cycle is first held to a controlled stop (Grbl's motion
        // model brakes within its acceleration), still reporting; then the alarm.
        (grbl_motion, &[L("$10=1"), L("$22=1"), L("$20=1"), Q, Q, L("G1X-100F600"), Wait(0.5), Q], &[B(b"G0X5\n?"), Q], &["<Hold:1|MPos:*|FS:300,0>", "ALARM:2", "[MSG:Reset to continue]"]),
        (grbl_motion, &[L("$10=1"), L("$22=1"), L("$20=1"), L("G1X-100F600"), Wait(0.5)], &[L("G0X5"), Wait(0.5), Q], &["ALARM:2", "[MSG:Reset to continue]"]),
        (grbl_motion, &[L("$22=1"), L("$20=1"), L("G1X-100F600"), Wait(0.5), L("G0X5"), Wait(0.5)], &[RESET], &["ok", BANNER, UNLOCK]),
        // Check mode checks soft limits too.
        (xy, &[L("$22=1"), L("$20=1"), L("$C")], &[L("G0X1")], &["ALARM:2", "[MSG:Reset to continue]"]),
        (xy, &[L("$22=1"), L("$20=1"), L("$C")], &[L("G0X-1")], &["ok"]),
        // A failed homing cycle: the alarm, the `$H` line's `ok`, then the
        // reset Grbl does itself (banner) into Alarm.
        (pull_off_fails, &[L("$22=1")], &[L("$H"), Wait(0.5)], &["ALARM:8", "ok", BANNER, UNLOCK]),
        (switch_missing, &[L("$22=1"), L("G0X-50"), Wait(1.0)], &[L("$H"), Wait(8.0)], &["ALARM:9", "ok", BANNER, UNLOCK]),
        (switch_missing, &[L("$22=1"), L("$H"), Wait(0.5)], &[L("$H"), Wait(0.5)], &["ALARM:9", "ok", BANNER, UNLOCK]),
        (switch_missing, &[L("$22=1"), L("$H"), Wait(0.5)], &[L("$X")], &["[MSG:Caution: Unlocked]", "ok"]),
    ];
    check(rows);
}

/// The machine reboots on its 4th line (a brown-out, the reset button).
fn reboot_4() -> SimConfig {
    faults(Faults { reset_at_line: Some(4), ..Default::default() })
}

/// Stopping and resetting as Grbl 1.1h does: a feed hold brakes to `Hold:0`;
/// a safety door (`0x84`) says so, stops (`Door:2`), reads closed once
/// stopped (`Door:0`: only the switch holds it open) and resumes on `~`; the
/// spindle stop override acts only in a hold; a hardware reset is a reboot
/// (banner only, power-up state, the lines after it run). Reports at `$10=1`.
#[test]
fn holds_doors_and_resets() {
    const MOVING: &[Act] = &[L("$10=1"), Q, Q, L("G1X100F600")];
    const IDLE1: &str = "<Idle|MPos:0.000,0.000,0.000|FS:0,0>";
    let rows: &[Row] = &[
        // 1: a hold brakes (timed model) to Hold:0; `~` is ignored until then.
        (xy, MOVING, &[HOLD, Q], &["<Hold:0|MPos:*|FS:0,0>"]),
        (xy, MOVING, &[B(b"!?")], &["<Hold:1|MPos:*|FS:600,0>"]),
        (xy, MOVING, &[B(b"!~"), Q], &["<Hold:0|MPos:*|FS:0,0>"]),
        (xy, &[L("$10=1"), Q, Q, L("G1X100F600"), HOLD], &[START, Q], &["<Run|MPos:*|FS:600,0>"]),
        // 2: the door.
        (xy, &[L("$10=1"), Q, Q], &[DOOR, Q], &["[MSG:Check Door]", "<Door:0|MPos:0.000,0.000,0.000|FS:0,0>"]),
        (xy, MOVING, &[B(&[0x84, b'?'])], &["[MSG:Check Door]", "<Door:2|MPos:*|FS:600,0>"]),
        (xy, MOVING, &[DOOR, Q], &["[MSG:Check Door]", "<Door:0|MPos:*|FS:0,0>"]),
        (xy, &[L("$10=1"), Q, Q, L("G1X100F600"), DOOR], &[START, Q], &["<Run|MPos:*|FS:600,0>"]),
        (xy, &[L("$10=1"), Q, Q, L("G1X100F600")], &[B(&[0x84, b'~']), Q], &["[MSG:Check Door]", "<Door:0|MPos:*|FS:0,0>"]),
        (xy, &[L("$10=1"), DOOR, Q, Q], &[RESET, Q], &[BANNER, "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"]),
        (xy, &[L("$10=1"), Q, Q], &[Door(true), START, Q], &["[MSG:Check Door]", "<Door:1|MPos:0.000,0.000,0.000|FS:0,0|Pn:D>"]),
        (xy, &[L("$10=1"), Q, Q, Door(true)], &[RESET, Q], &[BANNER, "[MSG:Check Door]", "<Door:1|MPos:0.000,0.000,0.000|FS:0,0|Pn:D|WCO:0.000,0.000,0.000>"]),
        (xy, &[L("$10=1"), Q, Q, Door(true), Door(false)], &[START, Q], &[IDLE1]),
        (xy, &[L("$C")], &[DOOR], &[]),
        // 11: 0x9E outside a hold is ignored: a later hold keeps the laser
        // off, `~` brings it back with the motion.
        (xy, &[L("$10=1"), L("M3S500"), L("G1X100F600"), Q, Q], &[R(0x9E), Q], &["<Run|MPos:*|FS:600,500>"]),
        (xy, &[L("$10=1"), L("M3S500"), L("G1X100F600"), Q, Q, R(0x9E)], &[HOLD, Q], &["<Hold:0|MPos:*|FS:0,0|Ov:100,100,100>"]),
        (xy, &[L("$10=1"), L("M3S500"), L("G1X100F600"), Q, Q, R(0x9E), HOLD, Q], &[START, Q], &["[MSG:Restoring spindle]", "<Run|MPos:*|FS:600,500|Ov:100,100,100|A:S>"]),
        // 16: a hardware reset: the banner only (no ALARM:3 though moving),
        // position 0 where it stopped, G90 again; the next line runs.
        (reboot_4, &[L("$10=1"), L("G91"), L("G1X50F600")], &[L("G0X1"), Q], &[BANNER, "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"]),
        (reboot_4, &[L("$10=1"), L("G91"), L("G1X50F600"), L("G0X1")], &[L("G0X1"), Wait(0.5), Q, L("$G")], &[
            "ok",
            "<Idle|MPos:1.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>",
            "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]",
            "ok",
        ]),
        (reboot_4, &[L("$22=1"), L("$10=1"), L("G10L2P1X7")], &[L("G0X1"), Q, L("$#")], &[
            BANNER, UNLOCK, "<Alarm|MPos:0.000,0.000,0.000|FS:0,0|WCO:7.000,0.000,0.000>",
            "[G54:7.000,0.000,0.000]", "[G55:0.000,0.000,0.000]", "[G56:0.000,0.000,0.000]", "[G57:0.000,0.000,0.000]",
            "[G58:0.000,0.000,0.000]", "[G59:0.000,0.000,0.000]", "[G28:0.000,0.000,0.000]", "[G30:0.000,0.000,0.000]",
            "[G92:0.000,0.000,0.000]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]", "ok",
        ]),
    ];
    check(rows);
}

/// A hold in the default (timed) motion model stops within a fraction of a
/// second, within every axis limit, laser off from the hold on; `~` goes on
/// along the path within the limits too, and the move ends where programmed.
#[test]
fn a_timed_hold_brakes_within_the_limits_and_resumes() {
    let mut s = Sim::new(cfg());
    for line in ["$10=1", "M3S500", "G1X20Y10F1200", "G1X40Y10", "G1X60Y30"] {
        s.send(&format!("{line}\n"));
    }
    s.run_until(0.5);
    let moving = s.ctl.position();
    s.realtime(b'!');
    let hold_t = s.t;
    s.run_until(0.6);
    s.realtime(b'?');
    s.run_until(0.61);
    let report = s.texts().last().unwrap().to_string();
    assert!(report.starts_with("<Hold:0|"), "{report}");
    let stopped = s.ctl.position();
    let braked = ((stopped[0] - moving[0]).powi(2) + (stopped[1] - moving[1]).powi(2)).sqrt();
    assert!(braked > 0.0 && braked < 1.0, "braked over {braked} mm");
    s.run_until(1.5);
    assert_eq!(s.ctl.position(), stopped, "held still");
    s.realtime(b'~');
    s.run_until(6.0);
    assert_eq!(s.ctl.position(), vec![60.0, 30.0, 0.0]);
    let mut checker = laserd_sim::limits::LimitChecker::new(&s.ctl.config().axes);
    s.knots.iter().for_each(|k| checker.push(k));
    let report = checker.finish();
    assert_eq!(report.violations, 0, "{:?}", report.first_violation);
    // Dark from the hold until the resume.
    assert!(s.knots.iter().filter(|k| k.t > hold_t + 1e-9 && k.t < 1.5).all(|k| k.power == 0.0));
    assert!(s.knots.iter().any(|k| k.t > 1.6 && k.power == 500.0), "lit again after `~`");
}
