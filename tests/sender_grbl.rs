//! laserd's sender against the simulator in Grbl 1.1h's own settings (128-byte
//! receive buffer, 15 planner blocks, `$10=1`: no `Bf:` in the reports,
//! unless a test sets `$10=3`), in process: dwells as long as a thick
//! sheet's pierce, the executed line as a true lower bound, and silence
//! detection on a host that holds the sender up.

use std::cell::RefCell;
use std::rc::Rc;
use std::time::Duration;

use laserd::stream::{in_process, Connection, Control, ExecutedLine, LinkEvent, SenderOptions, StreamOutcome};
use laserd_sim::controller::{Controller, MotionModel, SimConfig};
use laserd_sim::wire::{Response, StatusReport};
use tokio::sync::{mpsc, watch};

const BAUD: u32 = 115_200;

/// Grbl 1.1h as built (X, Y, Z; 128 bytes; 15 blocks), its `$10` set to
/// `status_mask`.
fn grbl(status_mask: u32, motion: MotionModel) -> Controller {
    Controller::new(SimConfig { motion, settings: vec![(10, status_mask as f64)], ..SimConfig::with_axes("XYZ") })
}

type Watch = Rc<RefCell<Option<ExecutedLine>>>;

/// Streams `lines` into `controller` in virtual time; `check(report, executed
/// line)` sees every status report with the executed line the sender took
/// from it, `buttons` the operator's buttons (seconds after the start).
/// Reads `$$` first when `settings` (the steps per mm).
fn run(controller: Controller, lines: &[String], settings: bool, check: impl Fn(&StatusReport, Option<usize>) + 'static, buttons: Vec<(f64, Control)>) -> StreamOutcome {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().start_paused(true).build().unwrap();
    runtime.block_on(async {
        let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
        let (stop_tx, stop_rx) = watch::channel(false);
        let sim = in_process::run(controller, sim_io, BAUD, tokio::time::Instant::now(), stop_rx, |_| {});
        let sender = async {
            let watch: Watch = Rc::default();
            let seen = watch.clone();
            // The bound after a report holds at that report's time: checked
            // against it at the next event (it changes with reports only).
            let mut last_report: Option<StatusReport> = None;
            let on_event = move |_: f64, e: LinkEvent| {
                if let (Some(r), Some(w)) = (&last_report, seen.borrow().as_ref()) {
                    check(r, w.get());
                }
                if let LinkEvent::Received { text } = e {
                    if let Response::Status(s) = Response::parse(&text) {
                        last_report = Some(s);
                    }
                }
            };
            let mut c = Connection::open(sender_io, &SenderOptions::new(128, 10.0), on_event).await.unwrap();
            if settings {
                c.settings().await.unwrap();
            }
            *watch.borrow_mut() = Some(c.executed_line());
            let (tx, mut rx) = mpsc::unbounded_channel();
            let press = async move {
                for (at, button) in buttons {
                    tokio::time::sleep(Duration::from_secs_f64(at)).await;
                    let _ = tx.send(button);
                }
                std::future::pending::<()>().await
            };
            let describe = |n: usize, _: &str| format!("line {n}");
            let outcome = tokio::select! {
                o = c.stream(lines.iter().cloned().map(Ok), &describe, Some(&mut rx)) => o.unwrap(),
                _ = press => unreachable!(),
            };
            let _ = stop_tx.send(true);
            outcome
        };
        let (_, outcome) = tokio::join!(sim, sender);
        outcome
    })
}

fn lines(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// Pierces of 3 s (a thick sheet's), as a job's last line or not, with and
/// without `Bf:`: Grbl reports Idle while it dwells with the `G4` unanswered,
/// which is no loss of bytes; every job completes.
#[test]
fn dwells_as_long_as_a_thick_sheets_pierce_stream_fine() {
    let middle = lines(&["G0X10", "G1M3S1000F60", "G4P3", "M4S1000", "G1X20F600", "M5"]);
    let last = lines(&["G0X10", "G1M3S1000F60", "G4P3"]);
    for status_mask in [1, 3] {
        for program in [&middle, &last] {
            let out = run(grbl(status_mask, MotionModel::Timed), program, false, |_, _| {}, vec![]);
            assert!(out.completed, "$10={status_mask}, {program:?}: {:?}", out.stop_reason);
            assert_eq!(out.last_executed_line, Some(program.len()));
        }
    }
}

/// Short moves (5 ms, several in a 10 ms step segment), moves in place and
/// lines without motion, under both motion models: at every status report
/// the sender's executed line has truly run: the machine is at or past its
/// end (the moves only go +X). Grbl's `Bf:` runs ahead of the machine by the
/// blocks in its step-segment buffer; the bound does not.
#[test]
fn the_executed_line_never_runs_ahead_of_the_machine() {
    let mut program = vec!["G21G90G94".to_string(), "M4S500".to_string()];
    for i in 1..=200 {
        program.push(format!("G1X{:.1}F6000", i as f64 * 0.5));
        if i % 20 == 0 {
            program.push(format!("G1X{:.1}", i as f64 * 0.5));
            program.push("S400".into());
        }
    }
    let target = |n: usize, program: &[String]| -> f64 {
        program[..n].iter().rev().find_map(|l| l.strip_prefix("G1X").and_then(|r| r.split('F').next()).and_then(|x| x.parse().ok())).unwrap_or(0.0)
    };
    for motion in [MotionModel::Timed, MotionModel::Grbl] {
        let shared = program.clone();
        let highest = Rc::new(RefCell::new(0usize));
        let seen = highest.clone();
        let check = move |s: &StatusReport, executed: Option<usize>| {
            if let Some(n) = executed {
                let x = s.position()[0];
                assert!(target(n, &shared) <= x + 1e-6, "{motion:?}: line {n} taken for executed at X {} while the machine is at X {x}", target(n, &shared));
                *seen.borrow_mut() = n;
            }
        };
        let out = run(grbl(3, motion), &program, true, check, vec![]);
        assert!(out.completed, "{:?}", out.stop_reason);
        assert!(*highest.borrow() > program.len() / 2, "{motion:?}: the bound moves while the job runs: {}", highest.borrow());
    }
}

/// Without `Bf:` a running controller tells nothing of which lines ran: an
/// abort mid-job reports the executed line as unknown, not a guess.
#[test]
fn without_bf_the_executed_line_of_an_aborted_job_is_unknown() {
    let mut program = vec!["G21G90G94".to_string(), "M4S500".to_string()];
    program.extend((1..=100).map(|i| format!("G1X{i}F600")));
    let out = run(grbl(1, MotionModel::Timed), &program, true, |_, _| {}, vec![(2.0, Control::Abort)]);
    assert!(!out.completed);
    assert_eq!(out.last_executed_line, None, "{:?}", out.stop_reason);
    assert!(out.stop_reason.unwrap().contains("last executed (a lower bound): unknown"));
    // With `Bf:` the same abort names a line that ran.
    let out = run(grbl(3, MotionModel::Timed), &program, true, |_, _| {}, vec![(2.0, Control::Abort)]);
    let executed = out.last_executed_line.expect("Bf: tells");
    assert!(executed > 2 && executed < program.len(), "{executed}");
}

/// The service's interrupted jobs: its controller thread also writes the
/// progress file (and syncs it), and on a loaded host that held the sender
/// up for over a second while the controller, dwelling, had nothing to
/// answer; the sender then took the time it had not listened for silence.
/// Here the hold-up is 1.3 s at the second line, in real time, the
/// simulator on a thread of its own.
#[test]
fn a_sender_held_up_by_its_host_does_not_call_the_controller_silent() {
    let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
    let (stop_tx, stop_rx) = watch::channel(false);
    let sim = std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        runtime.block_on(in_process::run(grbl(1, MotionModel::Timed), sim_io, BAUD, tokio::time::Instant::now(), stop_rx, |_| {}));
    });
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let program = lines(&["G4P2", "G0X1", "G0X2", "G4P2", "G0X3"]);
    let out = runtime.block_on(async {
        let hold_up = |_: f64, e: LinkEvent| {
            if matches!(e, LinkEvent::Sent { line: 2, .. }) {
                std::thread::sleep(Duration::from_millis(1300));
            }
        };
        let options = SenderOptions::new(128, 10.0);
        let mut c = Connection::open(sender_io, &options, hold_up).await.unwrap();
        c.stream(program.iter().cloned().map(Ok), &|n, _| format!("line {n}"), None).await.unwrap()
    });
    let _ = stop_tx.send(true);
    sim.join().unwrap();
    assert!(out.completed, "{:?}", out.stop_reason);
}
