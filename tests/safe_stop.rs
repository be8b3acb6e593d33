//! The sender's safe stop against the simulator in Grbl 1.1h's own settings
//! (`$10=1`: no `Bf:` in reports, a 128-byte receive buffer, 15 planner
//! blocks, Grbl's motion): a hold that does not finish in time is reset
//! anyway and the `ALARM:3` it costs is reported; a stop waits as long as the
//! machine needs to brake; status requests never come faster than the
//! configured rate, during the stop included.

use laserd::program::{LineKind, Program, ProgramLine};
use laserd::figures::{air_left_on, sim_figures, RunLog};
use laserd::run::stream_into_simulator;
use laserd::stream::{LinkEvent, SenderOptions, StreamOutcome};
use laserd_sim::controller::{AxisConfig, Faults, MotionModel, SimConfig};
use laserd_sim::wire::{realtime, MachineState, StatusReport};

/// Top speed and deceleration of the slow machine: a stop from full speed
/// takes 10 s, far beyond the 3 s a safe stop used to wait.
const SPEED: f64 = 20.0;
const DECELERATION: f64 = 2.0;

/// A heavy, slow gantry as Grbl 1.1h sees it.
fn slow_grbl(faults: Faults) -> SimConfig {
    let axis = |letter| AxisConfig { letter, min: 0.0, max: 2000.0, max_velocity: SPEED, max_acceleration: DECELERATION, max_jerk: 20000.0 };
    SimConfig {
        axes: vec![axis('X'), axis('Y'), axis('Z')],
        rx_buffer: 128,
        planner_blocks: 15,
        motion: MotionModel::Grbl,
        faults,
        ..SimConfig::default()
    }
}

/// `$10=1`, then 40 moves of 20 mm at full speed.
fn program() -> Program {
    let line = |text: String| ProgramLine { text, kind: LineKind::Setup, geometry: None, plan_time: None, checks: vec![] };
    let mut lines = vec![line("$10=1".into())];
    lines.extend((1..=40).map(|i| line(format!("G1X{}F{}", 20 * i, SPEED * 60.0))));
    Program { lines, axis_letters: vec!['X', 'Y', 'Z'], start: vec![0.0; 3], sources: vec![] }
}

/// Streams the program; the controller answers `error:20` to its 22nd line
/// (the sender's `$I` is its first), which the machine reaches at speed.
fn stopped_at_speed(options: &SenderOptions) -> (StreamOutcome, RunLog) {
    let sim = slow_grbl(Faults { error_on_line: Some(22), ..Faults::default() });
    stream_into_simulator(&program(), sim, 115200, options, None).expect("the run completes")
}

fn sent_at(log: &RunLog, byte: u8) -> Vec<f64> {
    log.link.iter().filter(|(_, e)| *e == LinkEvent::Realtime { byte }).map(|(t, _)| *t).collect()
}

#[test]
fn a_hold_that_does_not_finish_in_time_is_reset_and_its_alarm_reported() {
    // Waiting 3 s for a 10 s stop: the reset comes while the machine moves.
    let options = SenderOptions::new(128, 5.0);
    let (out, log) = stopped_at_speed(&options);
    let hold = sent_at(&log, realtime::FEED_HOLD)[0];
    let reset = sent_at(&log, realtime::SOFT_RESET)[0];
    assert!(reset - hold < 4.0, "reset {} s after the hold", reset - hold);
    assert_eq!(out.alarms, vec![3], "{out:?}");
    let reason = out.stop_reason.clone().unwrap();
    assert!(reason.starts_with("controller answered error:20"), "{reason}");
    for said in ["no hold to rest within 3.0 s", "ALARM:3", "left in alarm"] {
        assert!(reason.contains(said), "`{said}` missing: {reason}");
    }
    assert_eq!(out.final_status.map(|s| s.state), Some(MachineState::Alarm));
}

#[test]
fn a_safe_stop_waits_as_long_as_the_machine_needs_to_brake() {
    let mut options = SenderOptions::new(128, 5.0);
    let stop_s = SPEED / DECELERATION;
    options.hold_limit = options.hold_limit_for(stop_s);
    assert!(options.hold_limit.as_secs_f64() > 2.0 * stop_s);
    let (out, log) = stopped_at_speed(&options);
    assert!(out.alarms.is_empty(), "{out:?}");
    let reason = out.stop_reason.clone().unwrap();
    assert!(!reason.contains("no hold to rest"), "{reason}");
    assert_eq!(out.final_status.map(|s| s.state), Some(MachineState::Idle));
    // It was moving fast: the stop took seconds, and nothing moved after the reset.
    let hold = sent_at(&log, realtime::FEED_HOLD)[0];
    let reset = sent_at(&log, realtime::SOFT_RESET)[0];
    assert!(reset - hold > 3.0, "reset {} s after the hold", reset - hold);
    let last_motion = log.knots.last().unwrap().t;
    assert!(last_motion < reset, "moved until {last_motion}, reset at {reset}");
}

#[test]
fn status_requests_keep_to_the_status_rate_also_in_a_safe_stop() {
    let options = SenderOptions::new(128, 5.0);
    let (_, log) = stopped_at_speed(&options);
    let asked = sent_at(&log, realtime::STATUS);
    let hold = sent_at(&log, realtime::FEED_HOLD)[0];
    assert!(asked.iter().filter(|t| **t > hold).count() >= 5, "polled during the stop: {asked:?}");
    let fastest = asked.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
    assert!(fastest >= 0.2 - 1e-6, "two status requests {fastest} s apart (at most 5 Hz)");
}

/// Issue 24: air assist (M8) on while the job runs is off after every stop:
/// the safe stop's reset ends it (Grbl's reset stops coolant), as the
/// figures read from the link; a run that leaves it on breaks a limit.
#[test]
fn a_safe_stop_leaves_air_assist_off_and_air_left_on_breaks_a_limit() {
    let line = |text: &str| ProgramLine { text: text.into(), kind: LineKind::Setup, geometry: None, plan_time: None, checks: vec![] };
    let mut with_air = program();
    with_air.lines.insert(1, line("M8"));
    let mut options = SenderOptions::new(128, 5.0);
    options.hold_limit = options.hold_limit_for(SPEED / DECELERATION);
    let sim = slow_grbl(Faults { error_on_line: Some(22), ..Faults::default() });
    let (out, log) = stream_into_simulator(&with_air, sim, 115200, &options, None).unwrap();
    assert!(out.stop_reason.is_some(), "{out:?}");
    // The controller had it on: A:F in a report before the reset.
    let reset = sent_at(&log, realtime::SOFT_RESET)[0];
    let on_before = log.link.iter().any(|(t, e)| match e {
        LinkEvent::Received { text } if *t < reset => StatusReport::parse(text).ok().is_some_and(|r| r.accessories.is_some_and(|a| a.contains('F'))),
        _ => false,
    });
    assert!(on_before, "air on while it ran");
    assert!(!air_left_on(&log.link));
    assert!(!sim_figures(&log).limit_breaches.iter().any(|b| b.contains("air")), "{:?}", sim_figures(&log).limit_breaches);

    // Run to its end with no M9, program end or reset: left on, a breach.
    with_air.lines.truncate(4);
    let (out, log) = stream_into_simulator(&with_air, slow_grbl(Faults::default()), 115200, &options, None).unwrap();
    assert!(out.completed, "{out:?}");
    assert!(air_left_on(&log.link));
    let breaches = sim_figures(&log).limit_breaches;
    assert!(breaches.iter().any(|b| b.starts_with("air assist left on at the end")), "{breaches:?}");
    // M9 at the end: off, no breach.
    with_air.lines.push(line("M9"));
    let (_, log) = stream_into_simulator(&with_air, slow_grbl(Faults::default()), 115200, &options, None).unwrap();
    assert!(!air_left_on(&log.link) && !sim_figures(&log).limit_breaches.iter().any(|b| b.contains("air")));
}
