//! The laser while the machine stands still, in laser mode (`$32=1`,
//! reference §9): a pierce as laserd writes it (`G1M3S…F…`, `G4P…`, `M4`)
//! burns standing still at its power for its time, M4 and G0 keep a standing
//! laser dark, and a hold or a reset during a dwell switches it off.

mod common;

use common::{cfg, close, Sim};
use laserd_sim::controller::{Knot, MotionModel, SimConfig};
use laserd_sim::wire::{realtime, MachineState, Response, BANNER};

/// A cut entered at X1: the jump there (laser off), the pierce, the cut to X2.
const PIERCE: &str = "G93 M4 S0\nG1 X1 F600\nG1M3S500F60\nG4P0.2\nM4\nG1 X2 S300 F600\n";

/// Rest intervals (same position, time passing) with the power the knot that
/// closes them records, as (start, end, power, received line).
fn rests(knots: &[Knot]) -> Vec<(f64, f64, f64, u64)> {
    knots.windows(2).filter(|w| w[0].pos == w[1].pos && w[1].t > w[0].t).map(|w| (w[0].t, w[1].t, w[1].power, w[1].line)).collect()
}

/// The time of the `ok` answering received line `n` (1-based).
fn ok_of(s: &Sim, n: usize) -> f64 {
    s.responses()[n - 1].0
}

#[test]
fn a_pierce_burns_standing_still_for_its_dwell_then_m4_darkens_it() {
    for motion in [MotionModel::Timed, MotionModel::Grbl] {
        let mut s = Sim::new(SimConfig { motion, ..cfg() });
        s.send(PIERCE);
        s.run_until(0.5);
        let oks = s.responses();
        assert!(oks.iter().all(|r| r.1 == Response::Ok), "{motion:?}: {oks:?}");
        // The jump to X1 ends, the laser lights there (the M3 line waited for
        // motion to stop), stays on through the dwell, and the G4's ok comes after it.
        let arrived = s.knots.iter().find(|k| k.pos == vec![1.0, 0.0, 0.0]).expect("reaches X1").t;
        let pierce = rests(&s.knots);
        assert_eq!(pierce.len(), 1, "{motion:?}: {:?}", s.knots);
        let (a, b, power, line) = pierce[0];
        assert!(close(a, arrived) && close(b - a, 0.2), "{motion:?}: {pierce:?}");
        assert_eq!((power, line), (500.0, 4), "{motion:?}: at the pierce power, closed by the G4 line");
        assert!(close(ok_of(&s, 4), arrived + 0.2));
        // Then the cut, at its own power, from the entry.
        let cut: Vec<&Knot> = s.knots.iter().filter(|k| k.t > arrived + 0.2 + 1e-9).collect();
        assert_eq!(cut.last().unwrap().pos, vec![2.0, 0.0, 0.0], "{motion:?}");
        // M4: 300 at speed (the grbl model scales it down while it ramps).
        assert!(cut.iter().all(|k| k.power > 0.0 && k.power <= 300.0), "{motion:?}: {cut:?}");
        if motion == MotionModel::Timed {
            assert!(cut.iter().all(|k| k.power == 300.0), "{cut:?}");
        }
    }

    // What a status report and the controller say while it pierces.
    let mut s = Sim::new(cfg());
    s.send(PIERCE);
    s.run_until(0.15);
    let arrived = s.knots.iter().find(|k| k.pos == vec![1.0, 0.0, 0.0]).unwrap().t;
    s.run_until(arrived + 0.1);
    assert_eq!(s.ctl.state(), MachineState::Idle, "Grbl reports Idle while it dwells");
    assert_eq!(s.ctl.laser_power(), 500.0);
    assert_eq!(s.status().spindle, Some(500.0));
    s.run_until(arrived + 0.25);
    assert_eq!(s.ctl.state(), MachineState::Run);
    assert_eq!(s.ctl.laser_power(), 300.0);
    s.run_until(2.0);
    assert_eq!(s.ctl.laser_power(), 0.0, "an M4 block ends dark");
    assert_eq!(s.ctl.stats().starved_s, 0.0, "a dwell is not starvation");
}

#[test]
fn m4_and_g0_keep_a_standing_laser_dark_and_m3_in_g1_does_not() {
    // M4: dynamic power, nothing moves, no power, dwell or not.
    let mut s = Sim::new(cfg());
    s.send("G93 M4 S500\nG1 X1 F600\nG4 P0.3\nG1 X2 F600\n");
    s.run_until(0.2);
    assert!(s.ctl.position() == vec![1.0, 0.0, 0.0] && s.ctl.laser_power() == 0.0);
    s.run_until(2.0);
    let r = rests(&s.knots);
    assert_eq!(r.len(), 1);
    assert!(close(r[0].1 - r[0].0, 0.3) && r[0].2 == 0.0, "{r:?}");

    // M3 in G0 (the power-up mode): dark; switching to G1 without motion
    // syncs and lights it; back to G0 darkens it; M5 too.
    let mut s = Sim::new(cfg());
    s.send("M3 S500\n");
    s.run_until(0.1);
    assert_eq!(s.ctl.laser_power(), 0.0, "G0 keeps the laser off");
    s.send("G1 F100\n");
    s.run_until(0.2);
    assert_eq!(s.ctl.laser_power(), 500.0, "M3 in G1 burns standing still");
    s.send("G0\n");
    s.run_until(0.3);
    assert_eq!(s.ctl.laser_power(), 0.0);
    s.send("G1 F100\nM5\n");
    s.run_until(0.4);
    assert_eq!(s.ctl.laser_power(), 0.0);
    // The laser-on interval is in the knots, even with no motion at all.
    let r = rests(&s.knots);
    assert_eq!(r.len(), 3, "on, off, on-then-off: {:?}", s.knots);
    assert_eq!(r.iter().filter(|x| x.2 == 500.0).count(), 2);

    // M3 leaves the laser on at a block's power once the machine stops there;
    // the program's end switches it off.
    let mut s = Sim::new(cfg());
    s.send("G93 M3 S400\nG1 X1 F600\n");
    s.run_until(1.0);
    assert_eq!(s.ctl.laser_power(), 400.0);
    s.send("M2\n");
    s.run_until(1.5);
    assert_eq!(s.ctl.laser_power(), 0.0);
    let r = rests(&s.knots);
    assert_eq!(r.len(), 1, "{:?}", s.knots);
    assert!(r[0].2 == 400.0 && close(r[0].1, 1.0 + "M2\n".len() as f64 * common::BYTE), "{r:?}");
}

#[test]
fn a_hold_during_a_pierce_darkens_it_and_stops_the_dwell_until_resumed() {
    let mut s = Sim::new(cfg());
    s.send("G93 M4 S0\nG1 X1 F600\nG1M3S500F60\nG4P1\nM4\nG1 X2 S300 F600\n");
    s.run_until(0.15);
    let arrived = s.knots.iter().find(|k| k.pos == vec![1.0, 0.0, 0.0]).unwrap().t;
    let held = arrived + 0.4;
    s.run_until(held);
    assert_eq!(s.ctl.laser_power(), 500.0);
    s.realtime(realtime::FEED_HOLD);
    assert_eq!(s.ctl.state(), MachineState::Hold(0));
    assert_eq!(s.ctl.laser_power(), 0.0, "the laser goes off at once");
    let n = s.knots.len();
    assert!(close(s.knots[n - 1].t, held) && s.knots[n - 1].power == 0.0 && s.knots[n - 2].power == 500.0, "{:?}", s.knots);
    // Held: the dwell's clock stands, nothing moves, no ok for the G4.
    s.run_until(held + 3.0);
    assert_eq!(s.responses().len(), 3);
    assert_eq!(s.ctl.position(), vec![1.0, 0.0, 0.0]);
    assert_eq!(s.ctl.laser_power(), 0.0);
    // Resumed: the rest of the dwell, dark (Grbl brings the laser back with
    // motion), then the cut.
    let resumed = held + 3.0;
    s.realtime(realtime::CYCLE_START);
    assert_eq!(s.ctl.state(), MachineState::Idle);
    assert_eq!(s.ctl.laser_power(), 0.0);
    s.run_until(resumed + 2.0);
    assert!(close(ok_of(&s, 4), resumed + 0.6), "dwell ok {} vs {}", ok_of(&s, 4), resumed + 0.6);
    assert_eq!(s.ctl.position(), vec![2.0, 0.0, 0.0]);
    assert!(s.knots.iter().filter(|k| k.t > held + 1e-9 && k.t <= resumed + 0.6 + 1e-9).all(|k| k.power == 0.0));
}

#[test]
fn a_reset_during_a_pierce_leaves_the_laser_off_and_the_job_dropped() {
    let mut s = Sim::new(cfg());
    s.send(PIERCE);
    s.run_until(0.15);
    let arrived = s.knots.iter().find(|k| k.pos == vec![1.0, 0.0, 0.0]).unwrap().t;
    s.run_until(arrived + 0.1);
    assert_eq!(s.ctl.laser_power(), 500.0);
    let n = s.lines.len();
    s.realtime(realtime::SOFT_RESET);
    assert_eq!(&s.texts()[n..], &["ok", BANNER], "standing still: no alarm; the dwell's line answered");
    assert_eq!(s.ctl.laser_power(), 0.0);
    let last = s.knots.last().unwrap();
    assert!(close(last.t, arrived + 0.1) && last.power == 0.0, "{last:?}");
    s.run_until(3.0);
    assert_eq!(s.ctl.position(), vec![1.0, 0.0, 0.0], "the cut never starts");
    assert_eq!(s.status().spindle, Some(0.0));
}

/// The flatbed cutter's X axis: 500 mm/s, 5000 mm/s², 250000 mm/s³.
fn flatbed() -> SimConfig {
    let mut c = cfg();
    c.axes = vec![laserd_sim::controller::AxisConfig {
        letter: 'X',
        min: 0.0,
        max: 3000.0,
        max_velocity: 500.0,
        max_acceleration: 5000.0,
        max_jerk: 250000.0,
    }];
    c
}

/// A rest-to-rest move of `blocks` G93 blocks (quintic smoothstep, peak jerk
/// 60 d/T³): the first block is gentle, the next ones are not.
fn smooth_move(from: f64, to: f64, duration: f64, blocks: usize) -> Vec<String> {
    let s = |u: f64| from + (to - from) * u * u * u * (10.0 - 15.0 * u + 6.0 * u * u);
    (1..=blocks).map(|k| format!("G1X{:.5}F{:.4}", s(k as f64 / blocks as f64), 60.0 * blocks as f64 / duration)).collect()
}

/// Streams `lines` with GRBL character counting into `rx` bytes (the next
/// line goes as soon as the `ok`s leave room for it) until `t_end`.
fn stream_counting(s: &mut Sim, lines: &[String], rx: usize, t_end: f64) {
    let (mut next, mut in_rx, mut answered) = (0, std::collections::VecDeque::<usize>::new(), 0);
    loop {
        let answers = s.responses().len();
        while answered < answers {
            in_rx.pop_front();
            answered += 1;
        }
        while let Some(line) = lines.get(next).map(|l| format!("{l}\n")) {
            if in_rx.iter().sum::<usize>() + line.len() > rx {
                break;
            }
            s.send(&line);
            in_rx.push_back(line.len());
            next += 1;
        }
        if !s.step(t_end) {
            break;
        }
    }
    s.run_until(t_end);
}

/// Jumps to X10, pierces there, then cuts `cut` (G93 lines), streamed with
/// character counting into 128 bytes: the simulator, and the X of every stop
/// after the dwell.
fn pierce_then_cut(cut: Vec<String>) -> (Sim, Vec<f64>) {
    let mut lines = vec!["G93 M4 S0".to_string()];
    lines.extend(smooth_move(0.0, 10.0, 0.2, 20));
    lines.extend(["G1M3S1000F60", "G4P0.2", "M4 S1000"].map(String::from));
    lines.extend(cut);
    lines.push("M5".to_string());
    let mut s = Sim::new(flatbed());
    stream_counting(&mut s, &lines, 128, 5.0);
    assert!(s.responses().iter().all(|r| r.1 == Response::Ok) && s.responses().len() == lines.len(), "{:?}", s.texts());
    let dwell_end = s.knots.iter().find(|k| k.line == 23).expect("the dwell ends with a knot of its line").t;
    let cut: Vec<&Knot> = s.knots.iter().filter(|k| k.t > dwell_end + 1e-9).collect();
    let stops = cut.windows(2).filter(|w| w[0].pos == w[1].pos && w[1].t > w[0].t).map(|w| w[0].pos[0]).collect();
    (s, stops)
}

#[test]
fn after_a_pierce_the_cut_waits_for_its_rest_point_though_the_dwell_held_the_link() {
    // A jump to X10, a pierce there, then a cut of two rest-to-rest moves of
    // blocks shorter than three lines take on the link. While the controller
    // dwells, the `G4` and `M4` lines hold its receive buffer, so only the
    // first few blocks of the cut are in when the dwell ends, and the link has
    // been quiet for longer than `LINK_SILENCE_START`: not because the stream
    // ended, but because the buffer was full.
    let (s, stops) = pierce_then_cut([smooth_move(10.0, 13.0, 0.0965, 15), smooth_move(13.0, 16.0, 0.0965, 15)].concat());
    assert_eq!(s.ctl.position(), vec![16.0, 0.0, 0.0], "Grbl adds Y and Z to an X-only config");

    // The cut ran only once its rest point was queued: it never stops inside
    // a move, so the machine stays within every limit.
    assert!(stops.iter().all(|x| [10.0, 13.0].iter().any(|r| (x - r).abs() < 1e-6)), "stopped inside a move at X {stops:?}");
    let mut checker = laserd_sim::limits::LimitChecker::new(&flatbed().axes);
    s.knots.iter().for_each(|k| checker.push(k));
    let report = checker.finish();
    assert_eq!(report.violations, 0, "{report:?}");
    assert!(report.peak_jerk_use[0] > 0.5, "the cut does use the axis: {report:?}");
}

#[test]
fn a_cut_fed_as_fast_as_it_runs_goes_on_through_its_block_ends() {
    // After a pierce, a cut of 80 blocks, each as long in time (1.975 ms) as
    // its line takes on the link (23 bytes): the planner fills up, and from
    // then on the next line arrives microseconds after each block ends. A
    // full planner is why the cut runs; the block that just ended still held
    // its slot, so Grbl's stepper goes on into the next block, and it must not
    // stop there (each such stop shows as a jerk far beyond the limit).
    let (s, stops) = pierce_then_cut(smooth_move(10.0, 20.0, 0.158, 80));
    assert_eq!(s.ctl.position(), vec![20.0, 0.0, 0.0]);
    assert!(stops.iter().all(|x| (x - 10.0).abs() < 1e-6 || (x - 20.0).abs() < 1e-6), "stopped inside the cut at X {stops:?}");
    let mut checker = laserd_sim::limits::LimitChecker::new(&flatbed().axes);
    s.knots.iter().for_each(|k| checker.push(k));
    assert_eq!(checker.finish().violations, 0);
}

#[test]
fn after_a_pierce_a_line_longer_than_any_before_still_holds_the_cut() {
    // As above, but the fourth line of the cut is longer than every line
    // before it (an arc's words are): when the dwell ends the receive buffer
    // has room for a line as long as the longest seen so far, yet not for
    // this one, so the sender was still waiting. The cut must not take the
    // quiet link for the stream's end, start without its rest point, and
    // stop inside the move when the blocks after the first few come late.
    let mut cut = [smooth_move(10.0, 13.0, 0.0965, 15), smooth_move(13.0, 16.0, 0.0965, 15)].concat();
    cut[3].push_str(" (a comment as long as an arc's words)");
    let (s, stops) = pierce_then_cut(cut);
    assert_eq!(s.ctl.position(), vec![16.0, 0.0, 0.0]);
    assert!(stops.iter().all(|x| [10.0, 13.0].iter().any(|r| (x - r).abs() < 1e-6)), "stopped inside a move at X {stops:?}");
    let mut checker = laserd_sim::limits::LimitChecker::new(&flatbed().axes);
    s.knots.iter().for_each(|k| checker.push(k));
    assert_eq!(checker.finish().violations, 0);
}

#[test]
fn after_a_pierce_two_slow_first_blocks_are_no_rest_point_when_a_stop_between_them_breaks_the_jerk() {
    // A cut from rest whose first two blocks are slow for their length in
    // time (v/T² about 12000 and 84000 mm/s⁴, within half the jerk limit) but
    // whose third is not. Stopping after the first block and starting into
    // the second shows to the limit checker as a jerk of 6·(v₁/T₁ + v₂/T₂)
    // / (T₁ + T₂), beyond the limit: that pair is no rest point. When the
    // dwell ends only a few blocks are in (the dwell held the link), so the
    // cut must wait for its planner to fill rather than start and stand still
    // after its first block.
    let (s, stops) = pierce_then_cut(smooth_move(10.0, 19.6, 0.2, 15));
    assert_eq!(s.ctl.position(), vec![19.6, 0.0, 0.0]);
    assert!(stops.iter().all(|x| (x - 10.0).abs() < 1e-6 || (x - 19.6).abs() < 1e-6), "stopped inside the cut at X {stops:?}");
    let mut checker = laserd_sim::limits::LimitChecker::new(&flatbed().axes);
    s.knots.iter().for_each(|k| checker.push(k));
    let report = checker.finish();
    assert_eq!(report.violations, 0, "{report:?}");
}

/// Air assist (flood coolant, M8) as Grbl 1.1h keeps it: on through a feed
/// hold (only a door or sleep stops coolant), off after a soft reset (its
/// reset stops spindle and coolant), mid-motion too, and off at M9 and at
/// the program's end (M2). The status report's `A:` says the same.
#[test]
fn air_assist_stays_on_in_a_hold_and_goes_off_at_a_reset_m9_or_the_program_end() {
    let flood = |r: &laserd_sim::wire::StatusReport| r.accessories.as_deref().is_some_and(|a| a.contains('F'));
    let mut s = Sim::new(cfg());
    s.send("M8\nG1 X50 F600\n");
    s.run_until(0.5);
    assert!(s.ctl.coolant_on() && s.ctl.state() == MachineState::Run);
    s.realtime(realtime::FEED_HOLD);
    s.run_until(2.0);
    assert_eq!(s.ctl.state(), MachineState::Hold(0));
    assert_eq!(s.ctl.laser_power(), 0.0);
    assert!(s.ctl.coolant_on(), "a hold keeps the air on");
    let reports: Vec<_> = (0..3).map(|_| s.status()).collect();
    assert!(reports.iter().any(|r| r.overrides.is_some() && flood(r)), "{reports:?}");
    s.realtime(realtime::SOFT_RESET);
    assert!(!s.ctl.coolant_on(), "the reset turns it off");
    let reports: Vec<_> = (0..3).map(|_| s.status()).collect();
    assert!(reports.iter().any(|r| r.overrides.is_some()) && !reports.iter().any(flood), "{reports:?}");

    // A reset while it moves: off too (and the alarm for the lost position).
    let mut s = Sim::new(cfg());
    s.send("M8\nG1 X50 F600\n");
    s.run_until(0.5);
    s.realtime(realtime::SOFT_RESET);
    assert_eq!(s.ctl.state(), MachineState::Alarm);
    assert!(!s.ctl.coolant_on());

    // M9, and the program's end.
    for end in ["M9", "M2"] {
        let mut s = Sim::new(cfg());
        s.send(&format!("M8\nG1 X1 F600\n{end}\n"));
        s.run_until(0.05);
        assert!(s.ctl.coolant_on(), "{end}: on while it moves");
        s.run_until(1.0);
        assert!(!s.ctl.coolant_on(), "{end}: off after it");
    }
}
