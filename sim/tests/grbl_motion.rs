//! The `grbl` motion model: Grbl 1.1's look-ahead planner (trapezoids at each
//! block's acceleration, junction deviation, the queue planned to stop at its
//! end, feed hold braking within the acceleration), checked against textbook
//! figures and the independent limit checker.

mod common;

use common::Sim;
use laserd_sim::controller::{Knot, MotionModel, SimConfig};
use laserd_sim::limits::LimitChecker;
use laserd_sim::wire::{realtime, MachineState};

/// X and Y, 0..300 mm, 100 mm/s, 1000 mm/s².
fn grbl(planner_blocks: usize) -> SimConfig {
    SimConfig { motion: MotionModel::Grbl, planner_blocks, ..SimConfig::with_axes("XY") }
}

/// Speed of every segment between knots (mm/s), with its start time.
fn speeds(knots: &[Knot]) -> Vec<(f64, f64)> {
    knots
        .windows(2)
        .filter(|w| w[1].t > w[0].t)
        .map(|w| {
            let d: f64 = w[0].pos.iter().zip(&w[1].pos).map(|(a, b)| (b - a) * (b - a)).sum::<f64>().sqrt();
            (w[0].t, d / (w[1].t - w[0].t))
        })
        .collect()
}

/// Streams `lines` with Grbl's character counting (never more than the
/// 128-byte receive buffer unanswered), running the machine meanwhile. Call
/// it once per program: it counts every answer from its start on.
fn stream(s: &mut Sim, lines: &[&str]) {
    let mut in_flight: std::collections::VecDeque<usize> = Default::default();
    let mut answered = s.responses().len();
    for line in lines {
        let len = line.len() + 1;
        loop {
            let now = s.responses().len();
            for _ in answered..now {
                in_flight.pop_front();
            }
            answered = now;
            if in_flight.iter().sum::<usize>() + len <= 128 {
                break;
            }
            let t = s.t + 1e-4;
            s.run_until(t);
        }
        s.send(&format!("{line}\n"));
        in_flight.push_back(len);
    }
}

fn peak_acceleration_use(cfg: &SimConfig, knots: &[Knot]) -> f64 {
    let mut checker = LimitChecker::new(&cfg.axes);
    knots.iter().for_each(|k| checker.push(k));
    let report = checker.finish();
    report.peak_acceleration_use.iter().copied().fold(0.0, f64::max)
}

#[test]
fn a_long_move_is_a_trapezoid_at_the_axis_acceleration() {
    let cfg = grbl(15);
    let mut s = Sim::new(cfg.clone());
    s.send("G1X100F6000\n");
    s.run_until(5.0);
    let k = &s.knots;
    let (t0, t1) = (k.first().unwrap().t, k.last().unwrap().t);
    // 0.1 s up to 100 mm/s, 0.1 s down, 0.9 s cruising: 1.1 s.
    assert!((t1 - t0 - 1.1).abs() < 1e-6, "{}", t1 - t0);
    assert!((k.last().unwrap().pos[0] - 100.0).abs() < 1e-9);
    let top = speeds(k).iter().map(|s| s.1).fold(0.0, f64::max);
    assert!((top - 100.0).abs() < 1e-6, "{top}");
    // Ramps in 10 ms segments; the limit checker sees the acceleration it has.
    let use_ = peak_acceleration_use(&cfg, k);
    assert!(use_ <= 1.0 + 1e-6 && use_ > 0.9, "{use_}");
}

#[test]
fn corners_slow_to_the_junction_speed_of_the_deviation() {
    let corner_speed = |deviation: &str| {
        let mut s = Sim::new(grbl(15));
        s.send(&format!("$11={deviation}\nG1X50F6000\nY50\n"));
        s.run_until(5.0);
        // The knot at the corner: its neighbouring segments' speeds.
        let k = &s.knots;
        let i = k.iter().position(|k| (k.pos[0] - 50.0).abs() < 1e-9 && k.pos[1].abs() < 1e-9).unwrap();
        let v = speeds(&k[i - 1..=i + 1]);
        assert!((k.last().unwrap().pos[1] - 50.0).abs() < 1e-9);
        (v[0].1 + v[1].1) / 2.0
    };
    // 90°: v² = a·δ·sin(45°)/(1 − sin(45°)), a = 1000·√2 along the diagonal.
    let s45 = 0.5f64.sqrt();
    let expected = |d: f64| (1000.0 * 2f64.sqrt() * d * s45 / (1.0 - s45)).sqrt();
    let (slow, fast) = (corner_speed("0.010"), corner_speed("0.500"));
    // The segments next to the corner average the ramp around it: within one
    // segment's change of speed (10 ms · 1000 mm/s² = 10 mm/s).
    assert!((slow - expected(0.01)).abs() < 10.0, "{slow} vs {}", expected(0.01));
    assert!((fast - expected(0.5)).abs() < 10.0, "{fast} vs {}", expected(0.5));
    assert!(fast > slow + 20.0);
}

/// The junction deviation of the config is `$11` at power-up (what `$$`
/// lists and `$RST=$` returns to) and sets the corner speed as a written
/// `$11` does.
#[test]
fn the_configured_junction_deviation_is_11_at_power_up() {
    let corner_time = |cfg: SimConfig, prefix: &str| {
        let mut s = Sim::new(cfg);
        s.send(&format!("{prefix}G1X50F6000\nY50\n"));
        s.run_until(5.0);
        assert!((s.knots.last().unwrap().pos[1] - 50.0).abs() < 1e-9);
        s.knots.last().unwrap().t - s.knots[0].t
    };
    let configured = SimConfig { junction_deviation: 0.5, ..grbl(15) };
    let mut s = Sim::new(configured.clone());
    s.send("$$\n");
    s.run_until(0.1);
    assert!(s.texts().contains(&"$11=0.500"), "{:?}", s.texts());
    s.send("$11=0.01\n$RST=$\n$$\n");
    s.run_until(0.3);
    assert_eq!(s.texts().iter().filter(|t| **t == "$11=0.500").count(), 2, "{:?}", s.texts());
    let by_config = corner_time(configured, "");
    let by_setting = corner_time(grbl(15), "$11=0.5\n");
    let by_default = corner_time(grbl(15), "");
    assert!((by_config - by_setting).abs() < 1e-3, "{by_config} vs {by_setting}");
    assert!(by_default > by_config + 0.01, "Grbl's default 0.010 takes the corner slower: {by_default} vs {by_config}");
}

#[test]
fn the_look_ahead_depth_caps_the_speed_of_short_blocks() {
    // 0.1 mm blocks at up to 100 mm/s, sent faster than they run: the machine
    // may only go as fast as it can stop within what is queued.
    let peak = |blocks: usize| {
        let mut s = Sim::new(grbl(blocks));
        let mut lines = vec!["G91G1F6000"];
        lines.extend(["X0.1"; 400]);
        stream(&mut s, &lines);
        s.run_until(s.t + 10.0);
        assert!((s.knots.last().unwrap().pos[0] - 40.0).abs() < 1e-6, "{:?} {:?}", s.knots.last(), &s.texts()[s.texts().len().saturating_sub(3)..]);
        speeds(&s.knots).iter().map(|s| s.1).fold(0.0, f64::max)
    };
    let (shallow, deep) = (peak(15), peak(100));
    // 15 blocks (one executing): at most sqrt(2·a·15·0.1 mm) = 54.8 mm/s.
    assert!(shallow <= (2.0f64 * 1000.0 * 1.5).sqrt() + 1e-6, "{shallow}");
    assert!(shallow > 40.0, "{shallow}");
    assert!(deep > 99.0, "a 100-block planner reaches the feed: {deep}");
}

#[test]
fn feed_hold_brakes_within_the_acceleration_and_resumes() {
    let cfg = grbl(15);
    let mut s = Sim::new(cfg.clone());
    s.send("M4S500\nG1X200F6000\n");
    s.run_until(0.5);
    let before = s.ctl.position()[0];
    s.realtime(realtime::FEED_HOLD);
    assert_eq!(s.status().state, MachineState::Hold(1));
    s.run_until(0.55);
    assert_eq!(s.ctl.laser_power(), 0.0, "the laser is off while braking");
    s.run_until(0.7);
    assert_eq!(s.status().state, MachineState::Hold(0));
    // From 100 mm/s at 1000 mm/s²: 5 mm to a stop (within one 10 ms segment's latency).
    let stopped = s.ctl.position()[0];
    assert!((stopped - before - 5.0).abs() < 1.0 + 1e-6, "{}", stopped - before);
    s.run_until(2.0);
    assert_eq!(s.ctl.position()[0], stopped, "held");
    s.realtime(realtime::CYCLE_START);
    s.run_until(5.0);
    assert_eq!(s.status().state, MachineState::Idle);
    assert!((s.ctl.position()[0] - 200.0).abs() < 1e-9);
    assert!(peak_acceleration_use(&cfg, &s.knots) <= 1.0 + 1e-6);
}

#[test]
fn a_starved_queue_brakes_to_a_stop_instead_of_stopping_dead() {
    // Lines spaced 0.3 s apart, each 10 mm at 100 mm/s (0.1 s of motion plus
    // ramps): the machine must stop after each one, within its acceleration.
    let cfg = grbl(15);
    let mut s = Sim::new(cfg.clone());
    s.send("G91G1F6000\n");
    for i in 0..5 {
        s.run_until(0.3 * i as f64 + 0.01);
        s.send("X10\n");
    }
    s.run_until(3.0);
    assert!((s.ctl.position()[0] - 50.0).abs() < 1e-9);
    assert!(peak_acceleration_use(&cfg, &s.knots) <= 1.0 + 1e-6);
    // Each move takes 0.2 s (a triangle: 5 mm up, 5 mm down), so the machine
    // waits 0.1 s for each of the four later lines.
    assert!((s.ctl.stats().starved_s - 0.4).abs() < 1e-3, "{:?}", s.ctl.stats());
}

#[test]
fn status_reports_the_free_planner_blocks() {
    let mut s = Sim::new(grbl(15));
    let mut lines = vec!["$10=3", "G91G1F600"];
    lines.extend(["X1"; 40]);
    stream(&mut s, &lines);
    s.run_until(s.t + 0.1);
    let st = s.status();
    assert_eq!(st.state, MachineState::Run);
    // The planner is full (the executing block counts until its last step
    // segment is prepared, its final 50 ms), RX holds what waits.
    assert!(st.buffer.unwrap().0 <= 1, "{st:?}");
    s.run_until(60.0);
    assert_eq!(s.status().buffer, Some((15, 128)));
    assert!((s.ctl.position()[0] - 40.0).abs() < 1e-9);
}

#[test]
fn m4_power_follows_the_actual_speed_and_m3_does_not() {
    let powers = |spindle: &str| {
        let mut s = Sim::new(grbl(15));
        s.send(&format!("{spindle}S500\nG1X100F6000\n"));
        s.run_until(5.0);
        // (speed, power) of every segment.
        speeds(&s.knots).into_iter().zip(s.knots.windows(2).filter(|w| w[1].t > w[0].t).map(|w| w[1].power)).map(|((_, v), p)| (v, p)).collect::<Vec<_>>()
    };
    let m4 = powers("M4");
    assert!(m4.iter().all(|(v, p)| (p - 500.0 * v / 100.0).abs() < 1e-6), "{m4:?}");
    assert!(m4.iter().any(|(_, p)| *p < 100.0), "low power while slow");
    let m3 = powers("M3");
    assert!(m3.iter().all(|(_, p)| *p == 500.0), "{m3:?}");
}

#[test]
fn jog_cancel_brakes_in_jog_then_drops_the_jog() {
    let cfg = grbl(15);
    let mut s = Sim::new(cfg.clone());
    s.send("$10=3\n$J=G91X100F6000\n$J=G91X50F6000\n");
    s.run_until(0.6);
    let before = s.ctl.position()[0];
    s.realtime(realtime::JOG_CANCEL);
    assert_eq!(s.status().state, MachineState::Jog, "still Jog while braking");
    s.run_until(1.0);
    let st = s.status();
    assert_eq!(st.state, MachineState::Idle);
    assert_eq!(st.buffer.unwrap().0, 15, "the queued jog is gone");
    let stopped = s.ctl.position()[0];
    assert!((stopped - before - 5.0).abs() < 1.0 + 1e-6, "{}", stopped - before);
    assert!(peak_acceleration_use(&cfg, &s.knots) <= 1.0 + 1e-6);
    // Jogging works again from where it stopped.
    s.send("$J=G91X1F600\n");
    s.run_until(3.0);
    assert!((s.ctl.position()[0] - stopped - 1.0).abs() < 1e-9);
}

/// Back and forth along X with reversals, straight-on junctions and feeds
/// that change from block to block: every ramp keeps the acceleration, to the
/// checker's rounding. (Before: a block too short to reach the exit speed its
/// queue allowed ramped for a whole segment's time over a shorter distance,
/// 11 times the limit; and a stop before a reversal kept an end speed of
/// 1e-6 mm/s from the root of a rounded distance, 1 + 1e-6 times it.)
#[test]
fn reversals_and_feed_changes_keep_the_acceleration() {
    let cfg = grbl(15);
    let mut lines = vec!["G21G90G94".to_string()];
    // A fixed pseudo-random walk (no seed to vary): 200 moves inside 0..100 mm.
    let mut state: u64 = 3;
    let mut next = |n: u64| {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 33) % n
    };
    for _ in 0..200 {
        let x = next(100_000) as f64 / 1000.0;
        let feed = [600, 3000, 6000, 12000, 30000][next(5) as usize];
        lines.push(format!("G1X{x:.3}F{feed}"));
    }
    let lines: Vec<&str> = lines.iter().map(String::as_str).collect();
    let mut s = Sim::new(cfg.clone());
    stream(&mut s, &lines);
    s.run_until(s.t + 400.0);
    assert!(s.knots.len() > 1000, "{} knots", s.knots.len());
    let use_ = peak_acceleration_use(&cfg, &s.knots);
    assert!(use_ <= 1.0 + 1e-9 && use_ > 0.99, "acceleration {use_} times the limit");
}
