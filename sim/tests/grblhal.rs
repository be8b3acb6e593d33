//! The grblHAL flavour: what a sender sees differently from Grbl 1.1 (banner,
//! build info, line length, CR LF, realtime aliases, full report, 8 axes,
//! larger buffers), each against the reference's text.

mod common;

use common::Sim;
use laserd_sim::controller::{Flavor, SimConfig};
use laserd_sim::wire::{realtime, MachineState, StatusReport, BANNER_HAL};

/// A grblHAL board with 8 axes, a 1024-byte receive buffer and 100 blocks.
fn hal() -> SimConfig {
    SimConfig { flavor: Flavor::Grblhal, rx_buffer: 1024, planner_blocks: 100, ..SimConfig::with_axes("XYZABCUV") }
}

fn exchange(s: &mut Sim, input: &str) -> Vec<String> {
    let before = s.lines.len();
    s.send(input);
    let t = s.t;
    s.run_until(t + 0.5);
    s.lines[before..].iter().map(|(_, l)| l.clone()).collect()
}

#[test]
fn banner_build_info_and_buffers() {
    let mut s = Sim::new(hal());
    assert_eq!(s.texts(), vec![BANNER_HAL]);
    assert_eq!(
        exchange(&mut s, "$I\n"),
        vec![
            "[VER:1.1f.20250731:]",
            "[OPT:VNM+,100,1024,8,0]",
            "[AXS:8:XYZABCUV]",
            "[NEWOPT:ENUMS,RT+]",
            "[FIRMWARE:grblHAL]",
            "[DRIVER:laserd-sim]",
            concat!("[DRIVER VERSION:", env!("CARGO_PKG_VERSION"), "]"),
            "ok"
        ]
    );
    // The ring keeps one byte unused: an idle board reports 1023 free.
    let st = s.status();
    assert_eq!(st.buffer, Some((100, 1023)));
    assert_eq!(st.mpos.len(), 8);
}

#[test]
fn cr_lf_is_one_line_end_and_lines_may_be_long() {
    let mut s = Sim::new(hal());
    s.run_until(0.1);
    assert_eq!(exchange(&mut s, "G21\r\n"), vec!["ok"], "one answer for CR LF");
    assert_eq!(exchange(&mut s, "G21\n\rG90\r\n"), vec!["ok", "ok"], "LF CR too");
    // 256 characters after stripping pass, 257 do not (error 11).
    let long = |n: usize| format!("G1X1F100{}\n", "0".repeat(n - 8));
    assert_eq!(exchange(&mut s, &long(256)), vec!["ok"]);
    assert_eq!(exchange(&mut s, &long(257)), vec!["error:11"]);
    // Grbl 1.1 answers both ends of a CR LF, and stops at 79 characters.
    let mut g = Sim::new(SimConfig::with_axes("XY"));
    g.run_until(0.1);
    assert_eq!(exchange(&mut g, "G21\r\n"), vec!["ok", "ok"]);
    assert_eq!(exchange(&mut g, &long(80)), vec!["error:11"]);
}

#[test]
fn realtime_aliases_and_the_full_report() {
    let mut s = Sim::new(hal());
    s.run_until(0.1);
    let before = s.lines.len();
    s.realtime(realtime::STATUS_ALT);
    assert!(s.lines[before].1.starts_with("<Idle|MPos:"), "{:?}", s.lines[before]);
    s.send("G1A100F6000\n");
    s.run_until(0.2);
    s.realtime(realtime::FEED_HOLD_ALT);
    s.run_until(0.3);
    assert_eq!(s.status().state, MachineState::Hold(0));
    s.realtime(realtime::CYCLE_START_ALT);
    s.run_until(0.35);
    assert_eq!(s.status().state, MachineState::Run);
    let before = s.lines.len();
    s.realtime(realtime::FULL_STATUS);
    let full = StatusReport::parse(&s.lines[before].1).unwrap();
    assert_eq!(full.firmware.as_deref(), Some("grblHAL"));
    assert!(full.wco.is_some() && full.overrides.is_some() && full.buffer.is_some(), "{full:?}");
    s.run_until(5.0);
    assert!((s.ctl.position()[3] - 100.0).abs() < 1e-9, "the A axis moved");
}

#[test]
fn the_deeper_planner_takes_100_blocks_before_delaying_an_ok() {
    let mut s = Sim::new(hal());
    s.run_until(0.1);
    // 120 slow 1 mm moves (10 s each) of 11 bytes, 1320 bytes: more than the receive buffer
    // holds, so send them in two halves.
    s.send(&"G91G1X1F06\n".repeat(60));
    s.run_until(1.0);
    s.send(&"G91G1X1F06\n".repeat(60));
    s.run_until(2.0);
    let oks = s.texts().iter().filter(|l| **l == "ok").count();
    assert_eq!(oks, 100, "100 blocks queued (one executing), the rest wait");
    assert_eq!(s.status().buffer.unwrap().0, 0);
}

/// grblHAL's 1024-byte ring holds 1023 bytes (`[OPT:]` says 1024, `Bf:` 1023).
#[test]
fn the_receive_ring_holds_one_byte_less_than_its_size() {
    let mut s = Sim::new(hal());
    s.send("$10=3\n");
    s.run_until(0.1);
    // A dwell's line leaves the ring while it dwells; 1020 bytes held behind
    // it, then 4 more: one too many.
    s.send("G4P5\n");
    s.send(&"G21\n".repeat(255));
    s.send("M05\n");
    s.run_until(1.0);
    assert_eq!(s.ctl.stats().rx_overflows, 1);
    assert_eq!(s.status().buffer, Some((100, 0)));
}

/// Grbl 1.1h has the axes X, Y and Z and no other: a config with more is a
/// grblHAL board, and saying otherwise is an error naming the way out.
#[test]
fn only_grblhal_has_axes_beyond_xyz() {
    let galvo = SimConfig::with_axes("XYUV");
    let e = galvo.flavor_error().expect("Grbl with U and V");
    assert!(e.contains("UV") && e.contains("grblhal"), "{e}");
    assert_eq!(SimConfig { flavor: Flavor::Grblhal, ..galvo }.flavor_error(), None);
    assert_eq!(SimConfig::with_axes("XY").flavor_error(), None, "Z is added");
    assert!(SimConfig { flavor: Flavor::Grblhal, ..SimConfig::with_axes("XYZABCUVW") }.flavor_error().is_some());
}
