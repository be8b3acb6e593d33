//! Bytes on the wire → the simulated controller (its line buffer, G-code and
//! `$` parser, realtime bytes, planner and motion), paced at 115200 baud as the
//! sim tests drive it, then run on in virtual time. The first byte picks the
//! firmware flavour, the motion model, the axes and a probe. Every report line
//! the controller sends must parse, and its knots go through the limit checker.
#![no_main]

use laserd_sim::controller::{Controller, Flavor, MotionModel, SimConfig};
use laserd_sim::limits::LimitChecker;
use laserd_sim::wire::{Response, StatusReport};
use libfuzzer_sys::fuzz_target;

const BYTE: f64 = 10.0 / 115200.0;
/// Virtual time the machine runs on after the last byte: enough for a queue
/// of moves across the default travel, bounded so a huge move cannot hang.
const RUN_ON_S: f64 = 30.0;

fn check_output(ctl: &mut Controller, partial: &mut Vec<u8>) {
    partial.extend(ctl.take_output());
    while let Some(end) = partial.iter().position(|&b| b == b'\n') {
        let line: Vec<u8> = partial.drain(..=end).collect();
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.starts_with('<') {
            assert!(StatusReport::parse(text).is_ok(), "the simulator sent a status report it cannot parse: {text:?}");
            assert!(matches!(Response::parse(text), Response::Status(_)));
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&setup, bytes)) = data.split_first() else { return };
    let mut config = SimConfig::with_axes(if setup & 4 == 0 { "XY" } else { "XYUV" });
    config.flavor = if setup & 1 == 0 { Flavor::Grbl } else { Flavor::Grblhal };
    config.motion = if setup & 2 == 0 { MotionModel::Timed } else { MotionModel::Grbl };
    if setup & 8 != 0 {
        config.faults.probe_contact_mm = Some(1.5);
    }
    let mut checker = LimitChecker::new(&config.axes);
    let mut ctl = Controller::new(config);
    let mut partial = Vec::new();
    let mut t = 0.0;
    for &b in bytes {
        t += BYTE;
        ctl.receive(t, b);
        check_output(&mut ctl, &mut partial);
        for k in ctl.take_knots() {
            checker.push(&k);
        }
    }
    ctl.advance(t + RUN_ON_S);
    check_output(&mut ctl, &mut partial);
    for k in ctl.take_knots() {
        checker.push(&k);
    }
    let _ = checker.finish();
    let _ = ctl.stats();
});
