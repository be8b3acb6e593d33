//! Controller behaviour in virtual time, driven through a paced 115200 link.

mod common;

use common::{cfg, close, Sim, BYTE};
use laserd_sim::controller::{AxisConfig, Faults, Flavor, Knot, SimConfig, LINK_SILENCE_START};
use laserd_sim::wire::{realtime, MachineState, Response, StatusReport, BANNER};

/// `$10=3`: reports carry `Bf:` (Grbl's default `$10=1` leaves it out);
/// what the controller said so far is forgotten.
fn with_buffer_state(s: &mut Sim) {
    s.send("$10=3\n");
    s.run_until(0.01);
    s.lines.clear();
}

#[test]
fn banner_and_idle_status() {
    let mut s = Sim::new(cfg());
    assert_eq!(s.texts(), vec![BANNER]);
    let st = s.status();
    assert_eq!(s.lines.last().unwrap().1, "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>", "WCO in the first report after reset");
    assert_eq!(st.state, MachineState::Idle);
}

#[test]
fn g93_program_knots_and_oks() {
    let mut s = Sim::new(cfg());
    let prog = ["G21 G90 G93", "M3 S500", "G1 X1 F600", "N7 G1 X1 Y2 F300", "G0 X0 Y0", "M5", "M2"];
    let text: String = prog.iter().map(|l| format!("{l}\n")).collect();
    s.send(&text);
    s.run_until(5.0);
    let oks = s.responses();
    assert_eq!(oks.len(), prog.len());
    assert!(oks.iter().all(|(_, r)| *r == Response::Ok));
    assert!(s.texts().contains(&"[MSG:Pgm End]"));
    // Motion starts once the queue holds a rest point: blocks 3 and 4 are both
    // gentle, so when line 4's newline has arrived.
    let bytes4: usize = prog[..4].iter().map(|l| l.len() + 1).sum();
    let t0 = bytes4 as f64 * BYTE;
    let expect = [
        (t0, [0.0, 0.0], 500.0, 3),
        (t0 + 0.1, [1.0, 0.0], 500.0, 3),
        (t0 + 0.3, [1.0, 2.0], 500.0, 4),
        (t0 + 0.32, [0.0, 0.0], 0.0, 5),
    ];
    assert_eq!(s.knots.len(), expect.len(), "{:?}", s.knots);
    for (k, (t, p, pw, line)) in s.knots.iter().zip(expect) {
        assert!(close(k.t, t), "{k:?} vs t={t}");
        assert_eq!(k.pos, [&p[..], &[0.0]].concat(), "Grbl's Z stays at 0");
        assert_eq!((k.power, k.line), (pw, line));
    }
    // M5 and M2 wait for motion: their oks come at the end of motion.
    assert!(close(oks[5].0, t0 + 0.32) && close(oks[6].0, t0 + 0.32));
    let st = s.ctl.stats();
    assert_eq!((st.lines_received, st.blocks_executed), (7, 3));
    assert_eq!(st.starved_s, 0.0);
    assert!(close(st.last_motion_end_t.unwrap(), t0 + 0.32));
    assert!(s.ctl.stats().alarms.is_empty());
    // M2 reset the modal state.
    s.send("$G\n");
    s.run_until(6.0);
    assert!(s.texts().iter().any(|l| l.starts_with("[GC:G1 G54 G17 G21 G90 G94 M5 M9 T0 F")), "{:?}", s.texts());
}

#[test]
fn planner_full_delays_ok() {
    let mut s = Sim::new(cfg());
    with_buffer_state(&mut s);
    s.send("G93\n");
    let mut text = String::new();
    for i in 1..=20 {
        text.push_str(&format!("G1X{i}F600\n"));
    }
    s.send(&text);
    s.run_until(0.05);
    // 1 (G93) + 15 blocks acknowledged, the 16th waits in RX.
    assert_eq!(s.responses().len(), 16);
    let st = s.status();
    let waiting = text.len() - 15 * "G1XnF600\n".len() - 6; // 6 two-digit numbers among the first 15
    assert_eq!(st.buffer, Some((0, (128 - waiting) as u32)));
    assert_eq!(st.state, MachineState::Run);
    let first_start = s.knots[0].t;
    s.run_until(10.0);
    let oks = s.responses();
    assert_eq!(oks.len(), 21);
    assert!(close(oks[16].0, first_start + 0.1), "ok of block 16 at {} not at end of block 1", oks[16].0);
    assert!(close(s.knots.last().unwrap().t, first_start + 2.0));
    assert_eq!(s.ctl.position(), vec![20.0, 0.0, 0.0]);
}

#[test]
fn rx_overflow_when_overfilled() {
    let mut s = Sim::new(cfg());
    let text: String = (1..=60).map(|i| format!("G93G1X{i}F6\n")).collect();
    s.send(&text);
    s.run_until(1.0);
    assert!(s.ctl.stats().rx_overflows > 0);
}

#[test]
fn error_on_line_fault() {
    let c = SimConfig { faults: Faults { error_on_line: Some(2), ..Default::default() }, ..cfg() };
    let mut s = Sim::new(c);
    s.send("G1 X1 F600\nG1 X2\nG1 X3\n");
    s.run_until(2.0);
    let r: Vec<Response> = s.responses().into_iter().map(|x| x.1).collect();
    assert_eq!(r, vec![Response::Ok, Response::Error(20), Response::Ok]);
    let xs: Vec<f64> = s.knots.iter().map(|k| k.pos[0]).collect();
    assert!(!xs.contains(&2.0) && xs.contains(&3.0));
    assert_eq!(s.ctl.stats().errors_sent, 1);
}

#[test]
fn soft_limit_alarm_and_recovery() {
    let mut s = Sim::new(cfg());
    // Soft limits need homing on; Grbl's machine space is -300..0 here.
    s.send("$22=1\n$20=1\nG0 X-400\nG0 X-1\n$X\n");
    s.run_until(1.0);
    let t = s.texts();
    // Critical: the lines after the alarming one are not even read; the reset drops them.
    assert_eq!(&t[1..], &["ok", "ok", "ALARM:2", "[MSG:Reset to continue]"]);
    assert_eq!(s.ctl.state(), MachineState::Alarm);
    let n = s.lines.len();
    s.realtime(realtime::STATUS); // ignored until reset
    assert_eq!(s.lines.len(), n);
    s.realtime(realtime::SOFT_RESET);
    // The alarming line's `ok` comes with the reset.
    assert_eq!(&s.texts()[n..], &["ok", BANNER, "[MSG:'$H'|'$X' to unlock]"]);
    s.send("G0 X-1\n$X\nG0 X-1\n");
    s.run_until(2.0);
    assert_eq!(&s.texts()[n + 3..], &["error:9", "[MSG:Caution: Unlocked]", "ok", "ok"]);
    assert_eq!(s.ctl.position(), vec![-1.0, 0.0, 0.0]);
    assert_eq!(s.ctl.stats().alarms, vec![2]);
    assert!(s.knots.iter().all(|k| (-300.0..=0.0).contains(&k.pos[0])));
}

#[test]
fn soft_reset_while_moving_and_idle() {
    let mut s = Sim::new(cfg());
    with_buffer_state(&mut s);
    s.send("M3 S100\nG1 X100 F600\nG1 X200\n");
    s.run_until(1.0);
    assert_eq!(s.ctl.state(), MachineState::Run);
    assert!(s.ctl.laser_power() == 100.0);
    let n = s.lines.len();
    s.realtime(realtime::SOFT_RESET);
    assert_eq!(&s.texts()[n..], &["ALARM:3", BANNER, "[MSG:'$H'|'$X' to unlock]"]);
    assert_eq!(s.ctl.state(), MachineState::Alarm);
    assert_eq!(s.ctl.laser_power(), 0.0);
    let last = s.knots.last().unwrap();
    assert!(close(last.t, 1.0));
    let start = s.knots[0].t;
    assert!((last.pos[0] - (1.0 - start) * 10.0).abs() < 1e-9);
    assert_eq!(s.ctl.stats().alarms, vec![3]);
    assert_eq!(s.ctl.next_event(), None);
    let st = s.status();
    assert_eq!(st.buffer, Some((15, 128)));
    // Reset while idle: banner only, no alarm.
    s.send("$X\n");
    s.run_until(2.0);
    let n = s.lines.len();
    s.realtime(realtime::SOFT_RESET);
    assert_eq!(&s.texts()[n..], &[BANNER]);
    assert_eq!(s.ctl.state(), MachineState::Idle);
}

#[test]
fn starvation_counts_only_gaps_between_blocks() {
    let mut s = Sim::new(cfg());
    s.send("G93 G1 X1 F600\n");
    s.run_until(1.0);
    assert_eq!(s.ctl.stats().starved_s, 0.0);
    let end1 = s.knots[1].t;
    s.send("G1 X2 F600\n");
    s.run_until(3.0);
    // A lone block has no rest point after it: it starts when the link falls silent.
    let restart = 1.0 + "G1 X2 F600\n".len() as f64 * BYTE + LINK_SILENCE_START;
    let st = s.ctl.stats();
    assert!(close(st.starved_s, restart - end1), "{} vs {}", st.starved_s, restart - end1);
    // The rest is explicit in the knots: end, then restart at the same place.
    assert!(close(s.knots[2].t, restart) && s.knots[2].pos == s.knots[1].pos);
    s.run_until(10.0);
    assert!(close(s.ctl.stats().starved_s, restart - end1), "idle after the last block is not starvation");
}

#[test]
fn dwell_waits_for_motion_and_is_not_starvation() {
    let mut s = Sim::new(cfg());
    s.send("G93 G1 X1 F600\nG4 P0.5\nG1 X2 F600\n");
    s.run_until(3.0);
    let k = &s.knots;
    assert_eq!(k.len(), 4, "{k:?}");
    assert!(close(k[2].t, k[1].t + 0.5));
    assert_eq!(s.ctl.stats().starved_s, 0.0);
    let oks = s.responses();
    assert!(close(oks[1].0, k[1].t + 0.5), "dwell ok after the dwell");
}

#[test]
fn feed_hold_brakes_inside_the_block_then_resumes() {
    let mut s = Sim::new(cfg());
    s.send("M3 S300\nG93 G1 X1 F60\nG1 X2 F60\n");
    s.run_until(0.5);
    let at_hold = s.ctl.position()[0];
    s.realtime(realtime::FEED_HOLD);
    assert_eq!(s.ctl.state(), MachineState::Hold(1));
    assert_eq!(s.status().state, MachineState::Hold(1));
    // `~` while it still brakes is ignored, as Grbl does.
    s.realtime(realtime::CYCLE_START);
    assert_eq!(s.ctl.state(), MachineState::Hold(1));
    s.run_until(0.6);
    assert_eq!(s.ctl.state(), MachineState::Hold(0));
    assert_eq!(s.ctl.laser_power(), 0.0);
    // At 1 mm/s it stops within 0.02 mm (in 0.02 s), inside the first block.
    let stopped = s.ctl.position()[0];
    assert!(stopped > at_hold && stopped < at_hold + 0.02, "{at_hold} -> {stopped}");
    s.run_until(3.0);
    assert_eq!(s.ctl.position()[0], stopped);
    s.realtime(realtime::CYCLE_START);
    assert_eq!(s.ctl.state(), MachineState::Run);
    assert_eq!(s.ctl.laser_power(), 300.0);
    s.run_until(5.0);
    assert_eq!(s.ctl.position(), vec![2.0, 0.0, 0.0]);
    // The 1.5 s of program left run after 3.0, plus half the ramp up.
    let end = s.knots.last().unwrap().t;
    assert!(end > 4.5 && end < 4.6, "{end}");
    assert_eq!(s.ctl.stats().starved_s, 0.0, "a hold is not starvation");
}

#[test]
fn arcs_are_chords_within_tolerance() {
    let mut s = Sim::new(cfg());
    // Quarter circle radius 10 around (10,0) from (0,0) to (10,10), CW.
    s.send("G0 X0 Y0\nM3 S200\nG2 X10 Y10 I10 J0 F600\nG3 X20 Y0 R10\n");
    s.run_until(10.0);
    assert_eq!(s.responses().len(), 4);
    assert!(s.responses().iter().all(|r| r.1 == Response::Ok));
    let arc: Vec<&Knot> = s.knots.iter().filter(|k| k.line == 3).collect();
    assert!(arc.len() > 20, "{}", arc.len());
    // Grbl's floor(arc / chord) = floor(39.27) = 39 segments: a sagitta of
    // 0.002 x (39.27 / 39)^2, a little over `$12`; its small-angle rotation
    // (corrected every 12 segments) keeps points on the circle within 1e-4.
    assert_eq!(arc.len(), 39 + 1, "the knot before the arc and one per segment");
    for w in arc.windows(2) {
        let (a, b) = (&w[0].pos, &w[1].pos);
        for p in [a, b] {
            assert!(((p[0] - 10.0).hypot(p[1]) - 10.0).abs() < 1e-4);
        }
        // Sagitta of the chord.
        let chord = (b[0] - a[0]).hypot(b[1] - a[1]);
        let sagitta = 10.0 - (100.0 - chord * chord / 4.0).sqrt();
        assert!(sagitta > 0.002 && sagitta < 0.00204, "{sagitta}");
        assert!(w[0].pos[1] <= w[1].pos[1], "CW from (0,0) goes up");
    }
    assert_eq!(arc.last().unwrap().pos, vec![10.0, 10.0, 0.0]);
    let r_arc: Vec<&Knot> = s.knots.iter().filter(|k| k.line == 4).collect();
    for k in &r_arc {
        assert!(((k.pos[0] - 20.0).hypot(k.pos[1] - 10.0) - 10.0).abs() < 1e-4, "{k:?}");
    }
    assert_eq!(s.ctl.position(), vec![20.0, 0.0, 0.0]);
}

#[test]
fn error_codes() {
    let cases = [
        ("G1 X1", 22),
        ("G93 G1 X1", 22),
        ("G1 X1 X2 F1", 25),
        ("G0 G1 X1", 24),
        ("G0 G80", 21),
        ("A1", 20),
        ("G1.5 X1", 23),
        ("M3.1", 23),
        ("X", 2),
        ("1", 1),
        ("G2 X5 R1 F100", 34),
        ("G2 X5 F100", 35),
        ("G0 G92 X0", 24),
        ("G92", 26),
        ("G4", 28),
        ("G38.2 X1", 22),
        ("F-1", 4),
        ("$Q", 2),
        ("$H", 5),
        ("$999=1", 3),
        ("$0=2", 6),
        ("$11=-1", 4),
    ];
    for (line, code) in cases {
        let mut s = Sim::new(cfg());
        s.send(&format!("{line}\n"));
        s.run_until(1.0);
        assert_eq!(s.responses().into_iter().map(|r| r.1).collect::<Vec<_>>(), vec![Response::Error(code)], "{line}");
    }
    let mut s = Sim::new(cfg());
    s.send(&format!("G0{}\n", " X1".repeat(40)));
    s.send(&format!("(a long comment {} ) G0 X1\n\n", "x".repeat(120)));
    s.run_until(1.0);
    let r: Vec<Response> = s.responses().into_iter().map(|r| r.1).collect();
    assert_eq!(r, vec![Response::Error(11), Response::Ok, Response::Ok]);
    assert_eq!(s.ctl.position(), vec![1.0, 0.0, 0.0]);
}

#[test]
fn units_distance_and_offsets() {
    let mut s = Sim::new(cfg());
    s.send("G20 G91 G0 X1\nG21 G0 X1\nG92 X0\nG90 G0 X5\nG53 G0 X1\n");
    s.run_until(5.0);
    assert!(s.responses().iter().all(|r| r.1 == Response::Ok));
    let mut xs: Vec<f64> = s.knots.iter().filter(|k| k.t > s.knots[0].t).map(|k| k.pos[0]).collect();
    xs.dedup(); // G92 syncs, so there is a rest (two knots at 26.4)
    assert!(close(xs[0], 25.4) && close(xs[1], 26.4) && close(xs[2], 31.4) && close(xs[3], 1.0), "{xs:?}");
}

#[test]
fn system_commands() {
    // Axes beyond X, Y, Z: a grblHAL board (Grbl 1.1h has none).
    let mut s = Sim::new(SimConfig { flavor: Flavor::Grblhal, ..SimConfig::with_axes("XYUV") });
    s.send("$\n$$\n$I\n$G\n$N\n$X\n$32=1\n");
    s.run_until(1.0);
    let t = s.texts();
    assert!(t.contains(&"[VER:1.1f.20250731:]") && t.contains(&"[OPT:VNM+,15,128,4,0]") && t.contains(&"[AXS:4:XYUV]"), "{t:?}");
    assert!(t.contains(&"$32=1") && t.contains(&"$30=1000") && t.contains(&"$113=6000.000") && t.contains(&"$133=300.000"));
    assert!(t.contains(&"[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]"));
    assert!(t.contains(&"$N0=") && t[1].starts_with("[HLP:"));
    assert_eq!(s.responses().len(), 7);
    assert!(s.responses().iter().all(|r| r.1 == Response::Ok));
    s.send("G0 U5 V6\n");
    s.run_until(1.0 + LINK_SILENCE_START + 0.02);
    s.realtime(realtime::STATUS);
    assert!(s.texts().last().unwrap().starts_with("<Run|"), "? arrives while moving");
    s.run_until(2.0);
    s.realtime(realtime::STATUS);
    assert!(s.texts().last().unwrap().starts_with("<Idle|MPos:0.000,0.000,5.000,6.000|"));
}

#[test]
fn check_mode_moves_nothing() {
    let mut s = Sim::new(cfg());
    s.send("$C\nG1 X10 F100\nG4 P5\n");
    s.run_until(0.1);
    assert_eq!(s.ctl.state(), MachineState::Check);
    assert!(s.knots.is_empty());
    assert_eq!(s.responses().len(), 3);
    s.send("$C\n");
    s.run_until(0.2);
    let t = s.texts();
    assert_eq!(&t[t.len() - 3..], &["[MSG:Disabled]", "ok", BANNER]);
    assert_eq!(s.ctl.state(), MachineState::Idle);
    assert_eq!(s.ctl.position(), vec![0.0, 0.0, 0.0]);
}

#[test]
fn laser_only_fires_on_feed_moves() {
    let mut s = Sim::new(cfg());
    s.send("M4 S2000\nG0 X1\nG1 X2 F600\nM5\nG1 X3\n");
    s.run_until(5.0);
    let powers: Vec<(f64, f64)> = s.knots.iter().map(|k| (k.pos[0], k.power)).collect();
    // G0 off; G1 with M4 at S clamped to $30; after M5 off.
    assert!(powers.contains(&(1.0, 0.0)) && powers.contains(&(2.0, 1000.0)) && powers.contains(&(3.0, 0.0)), "{powers:?}");
}

#[test]
fn garbage_never_panics() {
    let mut axes = vec![AxisConfig::new('X')];
    axes[0].max_velocity = -1.0;
    let mut s = Sim::new(SimConfig { axes, rx_buffer: 0, planner_blocks: 0, laser_max_s: f64::NAN, motion: Default::default(), flavor: Default::default(), faults: Faults::default(), settings: vec![(10, 3.0), (0, 1.0), (110, f64::NAN), (999, 1.0)], junction_deviation: f64::NAN });
    let junk: Vec<u8> = (0..5000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
    for chunk in junk.chunks(97) {
        s.link.push(s.t, chunk);
        let t = s.t + 0.05;
        s.run_until(t);
    }
    s.ctl.advance(f64::NAN);
    s.ctl.advance(-5.0);
    let _ = s.ctl.stats();
}

/// A rest-to-rest move sampled into G93 blocks (quintic smoothstep: velocity
/// and acceleration 0 at both ends; peak a = 5.77 d/T², peak jerk = 60 d/T³).
fn smooth_move(from: f64, to: f64, duration: f64, blocks: usize) -> Vec<String> {
    let s = |u: f64| from + (to - from) * u * u * u * (10.0 - 15.0 * u + 6.0 * u * u);
    (1..=blocks)
        .map(|k| format!("G1X{:.5}F{:.6}", s(k as f64 / blocks as f64), 60.0 * blocks as f64 / duration))
        .collect()
}

/// One axis whose acceleration and jerk a 42 mm move over 0.52 s nearly uses up.
fn tight_axis() -> SimConfig {
    let mut c = cfg();
    c.axes = vec![AxisConfig { letter: 'X', min: -100.0, max: 100.0, max_velocity: 1000.0, max_acceleration: 1000.0, max_jerk: 20000.0 }];
    c
}

fn send_lines(s: &mut Sim, lines: &[String]) -> usize {
    lines.iter().map(|l| {
        s.send(&format!("{l}\n"));
        l.len() + 1
    }).sum()
}

#[test]
fn a_move_starts_only_once_a_rest_point_is_queued() {
    let there = smooth_move(0.0, 42.0, 0.52, 10);
    let back = smooth_move(42.0, 0.0, 0.52, 10);

    // Only the first part of a move queued: no rest point, so it waits while the
    // link is busy and runs only once the link falls silent.
    let mut s = Sim::new(tight_axis());
    let bytes = send_lines(&mut s, &["G93".to_string()]) + send_lines(&mut s, &there[..6]);
    s.run_until(1.0);
    let first = s.knots.first().expect("runs after the link fell silent").t;
    assert!(close(first, bytes as f64 * BYTE + LINK_SILENCE_START), "{first}");

    // The whole move and the first block of the next: the rest point between
    // them is queued, so it runs as soon as that block is in, without stopping
    // on the way and within every limit.
    let mut s = Sim::new(tight_axis());
    let bytes = send_lines(&mut s, &["G93".to_string()]) + send_lines(&mut s, &there) + send_lines(&mut s, &back[..1]);
    s.run_until(3.0);
    assert!(close(s.knots[0].t, bytes as f64 * BYTE), "{:?}", s.knots[0]);
    for w in s.knots.windows(2).take(10) {
        assert!(w[0].pos != w[1].pos, "no stop inside the move: {w:?}");
    }
    let mut checker = laserd_sim::limits::LimitChecker::new(&tight_axis().axes);
    for k in &s.knots {
        checker.push(k);
    }
    let report = checker.finish();
    assert_eq!(report.violations, 0, "{report:?}");
    assert!(report.peak_acceleration_use[0] > 0.5, "the move does use the axis: {report:?}");
}

#[test]
fn feed_hold_brakes_within_the_limits_with_the_laser_off() {
    let mut s = Sim::new(tight_axis());
    send_lines(&mut s, &["G93 M4 S300".to_string()]);
    send_lines(&mut s, &smooth_move(0.0, 42.0, 0.52, 10));
    send_lines(&mut s, &smooth_move(42.0, 0.0, 0.52, 10));
    s.run_until(0.15);
    assert_eq!(s.ctl.state(), MachineState::Run);
    s.realtime(realtime::FEED_HOLD);
    assert_eq!(s.ctl.state(), MachineState::Hold(1));
    s.run_until(3.0);
    assert_eq!(s.ctl.state(), MachineState::Hold(0));
    // It stopped on the way, braking within the axis' limits.
    let stopped = s.ctl.position()[0];
    assert!(stopped > 1.0 && stopped < 42.0, "{stopped}");
    let mut checker = laserd_sim::limits::LimitChecker::new(&tight_axis().axes);
    s.knots.iter().for_each(|k| checker.push(k));
    let report = checker.finish();
    assert_eq!(report.violations, 0, "{report:?}");
    let after: Vec<&Knot> = s.knots.iter().filter(|k| k.t > 0.15).collect();
    assert!(after.iter().skip(1).all(|k| k.power == 0.0), "laser off while holding: {after:?}");
}

#[test]
fn jogging() {
    let mut s = Sim::new(cfg());
    // Soft limits on (Grbl's machine space: -300..0 here).
    s.send("$22=1\n$20=1\n");
    s.run_until(0.1);
    // Forbidden words, missing feed, beyond travel: refused, nothing moves.
    for (line, code) in [("$J=G1X-10F100", 16), ("$J=X-10S100F100", 16), ("$J=X-10", 22), ("$J=X5F100", 15), ("$J=F100", 26)] {
        s.send(&format!("{line}\n"));
        s.run_until(s.t + 0.1);
        assert_eq!(s.responses().last().unwrap().1, Response::Error(code), "{line}");
    }
    assert!(s.knots.is_empty());
    // A jog runs in state Jog with the laser off and leaves the parser modes alone.
    s.send("G91\n$J=G90X-10F600\n");
    s.run_until(s.t + 0.5);
    assert_eq!(s.ctl.state(), MachineState::Jog);
    s.send("G1X1F100\n");
    s.run_until(s.t + 0.05);
    assert_eq!(s.responses().last().unwrap().1, Response::Error(9), "G-code while jogging");
    s.run_until(s.t + 2.0);
    assert_eq!(s.ctl.state(), MachineState::Idle);
    assert_eq!(s.ctl.position(), vec![-10.0, 0.0, 0.0]);
    assert!(s.knots.iter().all(|k| k.power == 0.0));
    s.realtime(realtime::STATUS);
    s.send("$G\n");
    s.run_until(s.t + 0.1);
    assert!(s.texts().iter().any(|t| t.starts_with("[GC:") && t.contains("G91")), "G91 kept: {:?}", s.texts());
    // Jog cancel stops at once and drops what is queued.
    s.send("$J=G90X-100F600\n$J=G90Y-50F600\n");
    s.run_until(s.t + 0.5);
    assert_eq!(s.ctl.state(), MachineState::Jog);
    s.realtime(realtime::JOG_CANCEL);
    assert_eq!(s.ctl.state(), MachineState::Idle);
    let x = s.ctl.position()[0];
    assert!(x < -10.0 && x > -100.0, "{x}");
    s.run_until(s.t + 5.0);
    assert_eq!(s.ctl.position()[0], x, "nothing runs after the cancel");
    assert_eq!(s.ctl.position()[1], 0.0);
}

#[test]
fn wco_and_overrides_come_in_their_turn() {
    let mut s = Sim::new(cfg());
    let first = s.status();
    assert!(first.wco.is_some() && first.overrides.is_none(), "WCO in the first report after reset");
    let second = s.status();
    assert_eq!(second.overrides, Some([100, 100, 100]), "Ov in the second");
    assert!(second.wco.is_none());
    let quiet: Vec<StatusReport> = (0..8).map(|_| s.status()).collect();
    assert!(quiet.iter().all(|r| r.wco.is_none()), "then WCO every tenth report");
    assert!(s.status().wco.is_some());
    // An override change and the laser on show in the next report that has room.
    s.realtime(realtime::FEED_OVR_COARSE_PLUS);
    s.send("M4 S100\n");
    s.run_until(s.t + 0.1);
    let r = s.status();
    assert_eq!(r.overrides, Some([110, 100, 100]));
    assert_eq!(r.accessories.as_deref(), Some("C"));
    // An offset change brings WCO back at once.
    s.send("G92 X-5\n");
    s.run_until(s.t + 0.1);
    assert_eq!(s.status().wco, Some(vec![5.0, 0.0, 0.0]));
    let line = s.lines.iter().rev().find(|(_, l)| l.starts_with('<')).unwrap().1.clone();
    assert!(line.contains("|WCO:5.000,0.000"), "{line}");
}

#[test]
fn safety_door_holds_until_closed_and_resumed() {
    let mut s = Sim::new(cfg());
    s.send("G93 M4 S300\nG1X5F60\nG1X10F60\n");
    s.run_until(0.5);
    assert_eq!(s.ctl.state(), MachineState::Run);
    s.ctl.set_door(true);
    assert_eq!(s.ctl.state(), MachineState::Door(2), "stopping");
    s.run_until(2.0);
    assert_eq!(s.ctl.state(), MachineState::Door(1), "stopped, door open");
    assert_eq!(s.ctl.laser_power(), 0.0);
    s.realtime(realtime::CYCLE_START);
    assert_eq!(s.ctl.state(), MachineState::Door(1), "no resume with the door open");
    s.ctl.set_door(false);
    assert_eq!(s.ctl.state(), MachineState::Door(0));
    s.realtime(realtime::CYCLE_START);
    assert_eq!(s.ctl.state(), MachineState::Run);
    s.run_until(2.5);
    // `0x84` stops it the same way, but leaves the switch closed: once
    // stopped, `~` resumes at once.
    s.realtime(realtime::SAFETY_DOOR);
    assert_eq!(s.ctl.state(), MachineState::Door(2), "stopping");
    s.run_until(3.0);
    assert_eq!(s.ctl.state(), MachineState::Door(0), "stopped, door closed");
    s.realtime(realtime::CYCLE_START);
    assert_eq!(s.ctl.state(), MachineState::Run);
    s.run_until(6.0);
    assert_eq!(s.ctl.position(), vec![10.0, 0.0, 0.0], "the job finishes after the door closed");
}

#[test]
fn settings_are_written_act_and_survive_a_reset() {
    let mut s = Sim::new(cfg());
    s.send("$110=600\n$130=50\n$10=0\n$32=1\n");
    s.run_until(0.2);
    assert!(s.responses().iter().all(|r| r.1 == Response::Ok), "{:?}", s.responses());
    s.realtime(realtime::SOFT_RESET);
    s.send("$$\n");
    s.run_until(0.4);
    let t = s.texts();
    assert!(t.contains(&"$110=600.000") && t.contains(&"$130=50.000") && t.contains(&"$10=0"), "kept across the reset: {t:?}");
    // $10=0: work positions, no buffer field.
    let r = s.status();
    assert!(r.mpos.is_empty() && r.wpos.is_some() && r.buffer.is_none(), "{r:?}");
    // The new travel is a soft limit (with homing, so soft limits, on:
    // -50..0); the new rate limits G0.
    s.send("$22=1\n$20=1\nG0X-40\n");
    s.run_until(0.5);
    s.run_until(10.0);
    let moved = s.knots.last().unwrap();
    assert_eq!(moved.pos[0], -40.0);
    let took = moved.t - s.knots[s.knots.len() - 2].t;
    assert!(close(took, 4.0), "40 mm at 600 mm/min: {took}");
    s.send("G0X-60\n");
    s.run_until(11.0);
    assert!(s.texts().contains(&"ALARM:2"));
}

#[test]
fn homing_when_enabled() {
    let mut s = Sim::new(cfg());
    s.send("$H\n");
    s.run_until(0.1);
    assert_eq!(s.responses().last().unwrap().1, Response::Error(5), "homing disabled by default");
    s.send("$22=1\n$25=600\nG0X20\n");
    s.run_until(2.0);
    s.send("$H\n");
    s.run_until(2.5);
    assert_eq!(s.ctl.state(), MachineState::Home);
    let oks_before = s.responses().len();
    s.run_until(5.0);
    assert_eq!(s.ctl.state(), MachineState::Idle);
    // Grbl's machine space is negative: home is the positive end, less the pull-off ($27).
    assert_eq!(s.ctl.position(), vec![-1.0, -1.0, -1.0]);
    assert_eq!(s.responses().len(), oks_before + 1, "the ok comes when homing is done: {:?}", s.lines);
    // A reset during homing fails the cycle: ALARM:6; homing again clears it.
    s.send("G0X20\n");
    s.run_until(8.0);
    s.send("$H\n");
    s.run_until(8.5);
    s.realtime(realtime::SOFT_RESET);
    assert!(s.texts().contains(&"ALARM:6"));
    assert_eq!(s.ctl.state(), MachineState::Alarm);
    s.send("$H\n");
    s.run_until(12.0);
    assert_eq!(s.ctl.state(), MachineState::Idle);
}
