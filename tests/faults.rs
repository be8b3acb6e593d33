//! Link and controller faults injected in the simulator during a dry-run: for
//! each, the sender notices within a second of machine time, leaves the machine
//! stopped with the laser off where it can still reach it, says which lines
//! were acknowledged and executed, and the recording stays readable.

use std::path::Path;

use laserd::config::MachineConfig;
use laserd::figures::sim_figures;
use laserd::plan::PlannerKind;
use laserd::program::LineKind;
use laserd::run::{self, DryRun, Planned};
use laserd::stream::LinkEvent;
use laserd_sim::controller::Faults;
use laserd_sim::wire::{realtime, MachineState};

fn planned() -> (MachineConfig, Planned) {
    let machine = MachineConfig::load(None).unwrap();
    let job = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/one-field.svg");
    let planned = run::plan(&job, &machine, PlannerKind::Nearest, None).unwrap();
    (machine, planned)
}

/// A marking line in the middle of the job (the laser is on around it).
fn middle_mark(p: &Planned) -> usize {
    let marks: Vec<usize> =
        p.program.lines.iter().enumerate().filter(|(_, l)| l.kind == LineKind::Mark).map(|(i, _)| i + 1).collect();
    marks[marks.len() / 2]
}

/// The controller's number for program line `n`: it counts every line it
/// receives, the sender's `$I` at connect first.
fn received(n: usize) -> u64 {
    n as u64 + 1
}

/// Program lines of the executed blocks (knots carry the controller's count).
fn executed_lines(dry: &DryRun) -> Vec<usize> {
    let lines = laserd::figures::program_lines(&dry.log.link);
    dry.log.knots.iter().map(|k| laserd::figures::program_line_of(&lines, k)).collect()
}

/// 1-based offset of the first byte of program line `n` among the line bytes
/// sent (after the sender's own `$I` at connect).
fn first_byte_of(p: &Planned, n: usize) -> u64 {
    let connect = laserd::stream::BUILD_INFO.len() as u64 + 1;
    connect + p.program.lines[..n - 1].iter().map(|l| l.text.len() as u64 + 1).sum::<u64>() + 1
}

fn dry_run(faults: Faults) -> (Planned, DryRun, tempfile::TempDir) {
    let (mut machine, planned) = planned();
    // Reports with `Bf:` (`$10=3`): the executed line is known while the job runs.
    machine.simulator.settings = vec![(10, 3.0)];
    let dir = tempfile::tempdir().unwrap();
    let dry = run::dry_run(&planned, &machine, &dir.path().join("fault.mcap"), faults).expect("the run itself completes");
    (planned, dry, dir)
}

/// Time of the first feed hold the sender sent: its reaction to the fault.
fn hold_time(dry: &DryRun) -> f64 {
    dry.log
        .link
        .iter()
        .find(|(_, e)| matches!(e, LinkEvent::Realtime { byte } if *byte == realtime::FEED_HOLD))
        .map(|(t, _)| *t)
        .expect("the sender held the machine")
}

/// Time the controller received program line `n` (its last byte was sent then
/// plus the wire time; the send time is a lower bound that is close enough).
fn sent_time(dry: &DryRun, n: usize) -> f64 {
    dry.log.link.iter().find(|(_, e)| matches!(e, LinkEvent::Sent { line, .. } if *line == n)).map(|(t, _)| *t).unwrap()
}

fn assert_safe_and_recorded(dry: &DryRun, dir: &tempfile::TempDir) {
    let out = &dry.outcome;
    assert!(!out.completed);
    assert!(out.stop_reason.is_some());
    let executed = out.last_executed_line.expect("the controller reports its buffers");
    assert!(executed <= out.last_acked_line, "{executed} > {}", out.last_acked_line);
    // The machine ends with the laser off and not moving (the last knot ends the
    // motion; nothing runs after the sender's stop).
    if let Some(s) = &out.final_status {
        assert_eq!(s.spindle.unwrap_or(0.0), 0.0, "laser off: {s:?}");
        assert!(matches!(s.state, MachineState::Idle | MachineState::Alarm | MachineState::Hold(0)), "{s:?}");
    }
    let replay = laserd::record::read(&dir.path().join("fault.mcap")).expect("the recording reads back");
    assert_eq!(sim_figures(&replay.log), dry.report.sim.clone().unwrap());
}

#[test]
fn a_dropped_line_end_is_caught_and_the_machine_stopped() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    // Drop the `\n` of line n: lines n and n+1 arrive as one.
    let newline = first_byte_of(&p, n + 1) - 1;
    let (_, dry, dir) = dry_run(Faults { drop_byte: Some(newline), ..Default::default() });
    let reason = dry.outcome.stop_reason.clone().unwrap();
    assert!(reason.contains(&format!("G-code line {n} ")) || reason.contains("lost"), "{reason}");
    assert!(hold_time(&dry) - sent_time(&dry, n + 1) < 1.0);
    assert_safe_and_recorded(&dry, &dir);
}

#[test]
fn a_garbled_byte_is_caught_at_its_line() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    let (_, dry, dir) = dry_run(Faults { corrupt_byte: Some(first_byte_of(&p, n)), ..Default::default() });
    assert_eq!(dry.outcome.errors.len(), 1);
    assert_eq!(dry.outcome.errors[0].line, n);
    assert!(hold_time(&dry) - sent_time(&dry, n) < 1.0);
    assert_safe_and_recorded(&dry, &dir);
}

#[test]
fn a_controller_that_stops_answering_is_held_within_a_second() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    let (_, dry, dir) = dry_run(Faults { mute_from_line: Some(received(n)), ..Default::default() });
    let reason = dry.outcome.stop_reason.clone().unwrap();
    assert!(reason.contains("silent"), "{reason}");
    // From the last thing heard to the hold: at most a second.
    let last_heard = dry.log.link.iter().filter(|(_, e)| matches!(e, LinkEvent::Received { .. })).map(|(t, _)| *t).fold(0.0, f64::max);
    let hold = hold_time(&dry);
    assert!(hold > last_heard && hold - last_heard <= 1.0, "heard {last_heard}, hold {hold}");
    // It still listens: the hold and reset stop it, so no block runs after them.
    let last_motion = dry.log.knots.last().unwrap().t;
    assert!(last_motion <= hold + 0.5, "motion until {last_motion}, hold at {hold}");
    assert!(dry.log.knots.iter().filter(|k| k.t > hold + 1e-6).skip(1).all(|k| k.power == 0.0));
    assert!(dry.outcome.last_acked_line < n);
    let out = &dry.outcome;
    assert!(out.last_executed_line.unwrap() <= out.last_acked_line);
    laserd::record::read(&dir.path().join("fault.mcap")).expect("the recording reads back");
}

#[test]
fn a_controller_resetting_itself_mid_job_is_reported() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    let (_, dry, dir) = dry_run(Faults { reset_at_line: Some(received(n)), ..Default::default() });
    let reason = dry.outcome.stop_reason.clone().unwrap();
    assert!(reason.contains("reset itself") || reason.contains("ALARM:3"), "{reason}");
    assert!(hold_time(&dry) - sent_time(&dry, n) < 1.0);
    assert_safe_and_recorded(&dry, &dir);
    // Nothing after line n ran: the reset flushed it.
    assert!(executed_lines(&dry).iter().all(|l| *l < n), "no block of line {n} or later ran");
}

#[test]
fn a_hard_limit_mid_job_stops_everything() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    let (_, dry, dir) = dry_run(Faults { limit_alarm_at_line: Some(received(n)), ..Default::default() });
    assert_eq!(dry.outcome.alarms, vec![1]);
    assert!(dry.outcome.stop_reason.clone().unwrap().contains("ALARM:1"));
    assert!(hold_time(&dry) - sent_time(&dry, n) < 1.0);
    assert_safe_and_recorded(&dry, &dir);
    assert_eq!(dry.outcome.final_status.as_ref().map(|s| s.state.clone()), Some(MachineState::Alarm), "locked until unlocked");
}

#[test]
fn the_link_closing_mid_job_is_reported() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    let (_, dry, dir) = dry_run(Faults { close_link_at_line: Some(received(n)), ..Default::default() });
    let reason = dry.outcome.stop_reason.clone().unwrap();
    assert!(reason.contains("closed the link"), "{reason}");
    assert!(dry.outcome.last_acked_line < n + 5);
    // Noticed at once: the stream ends within a second of line n going out.
    let first_sent = sent_time(&dry, 1);
    assert!(first_sent + dry.outcome.stream_time_s - sent_time(&dry, n) < 1.0, "stream ran {} s", dry.outcome.stream_time_s);
    // Unreachable now, the controller runs out what it had queued and stops:
    // nothing from beyond the lines that reached it (those still in its
    // receive buffer when line n was taken run too: it does not know the
    // link is gone), and it ends at rest.
    let last_sent = dry.log.link.iter().filter_map(|(_, e)| if let laserd::stream::LinkEvent::Sent { line, .. } = e { Some(*line) } else { None }).max().unwrap();
    assert!(last_sent < n + 100, "the buffer holds at most 1024 bytes: {last_sent}");
    assert!(executed_lines(&dry).iter().all(|l| *l <= last_sent), "{:?} vs {last_sent}", executed_lines(&dry).iter().max());
    laserd::record::read(&dir.path().join("fault.mcap")).expect("the recording reads back");
}

#[test]
fn the_last_executed_line_matches_what_the_machine_ran() {
    let (_, p) = planned();
    let n = middle_mark(&p);
    let (_, dry, _) = dry_run(Faults { error_on_line: Some(received(n)), ..Default::default() });
    let ran = executed_lines(&dry).into_iter().max().unwrap();
    let executed = dry.outcome.last_executed_line.expect("Bf: tells");
    // A lower bound: never past what ran, and behind it by at most what the
    // planner (100 blocks on the default grblHAL board) and grblHAL's
    // step-segment buffer (9) may hold.
    assert!(executed <= ran && ran - executed <= 109, "sender's view {executed} vs the simulator's {ran}");
}
