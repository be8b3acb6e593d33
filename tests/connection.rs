//! The sender as a library API, against the in-process simulator in virtual
//! time: jog, unlock, the operator's hold, resume, override and abort while a
//! job streams, and resuming the job from a line.

use std::path::Path;
use std::time::Duration;

use laserd::config::MachineConfig;
use laserd::plan::PlannerKind;
use laserd::run;
use laserd::stream::{in_process, Connection, Control, SenderOptions};
use laserd_sim::controller::{Controller, Faults};
use laserd_sim::wire::{realtime, MachineState};
use tokio::sync::{mpsc, watch};

#[test]
fn jog_unlock_hold_resume_override_abort_and_resume_from_a_line() {
    let mut machine = MachineConfig::load(None).unwrap();
    // Reports with `Bf:` (`$10=3`): the executed line is known while the job runs.
    machine.simulator.settings = vec![(10, 3.0)];
    let job = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/one-field.svg");
    let planned = run::plan(&job, &machine, PlannerKind::Nearest, None).unwrap();
    let lines: Vec<String> = planned.program.lines.iter().map(|l| l.text.clone()).collect();
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().start_paused(true).build().unwrap();
    runtime.block_on(async {
        let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
        let origin = tokio::time::Instant::now();
        let (stop_tx, stop_rx) = watch::channel(false);
        let controller = Controller::new(run::sim_config(&machine, Faults::default()));
        let knots = std::cell::RefCell::new(Vec::new());
        let sim = in_process::run(controller, sim_io, machine.serial.baud, origin, stop_rx, |k| knots.borrow_mut().extend(k));
        let operator = async {
            let options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
            let heard = std::cell::RefCell::new(Vec::<String>::new());
            let mut c = Connection::open(sender_io, &options, |_, e| {
                if let laserd::stream::LinkEvent::Received { text } = e {
                    heard.borrow_mut().push(text);
                }
            })
            .await
            .unwrap();
            assert_eq!(c.status().await.unwrap().state, MachineState::Idle);
            // The steps per mm: which lines surely make a planner block.
            c.settings().await.unwrap();
            c.unlock().await.unwrap();

            // Jog out and back; the controller reports Jog meanwhile. Soft
            // limits on (they need homing on): Grbl's machine space is -300..0.
            let describe = |n: usize, _: &str| format!("line {n}");
            let settings = ["$22=1", "$20=1"].map(|l| Ok(l.to_string()));
            assert!(c.stream(settings, &describe, None).await.unwrap().completed);
            c.jog("G91X-10F600").await.unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            assert_eq!(c.status().await.unwrap().state, MachineState::Jog);
            tokio::time::sleep(Duration::from_secs(2)).await;
            assert_eq!(c.status().await.unwrap().mpos[0], -10.0);
            assert!(c.jog("G90X5F600").await.is_err(), "beyond travel: error 15");
            c.jog("G90X0F600").await.unwrap();
            tokio::time::sleep(Duration::from_secs(2)).await;
            assert_eq!(c.status().await.unwrap().mpos[0], 0.0);
            // The job below is in positive machine coordinates (not homed).
            assert!(c.stream(["$20=0"].map(|l| Ok(l.to_string())), &describe, None).await.unwrap().completed);

            // A job with a hold, an override and a resume: it completes.
            let (tx, mut rx) = mpsc::unbounded_channel();
            let buttons = async {
                tokio::time::sleep(Duration::from_millis(800)).await;
                tx.send(Control::FeedHold).unwrap();
                tokio::time::sleep(Duration::from_millis(500)).await;
                tx.send(Control::Override(realtime::FEED_OVR_RESET)).unwrap();
                tx.send(Control::Resume).unwrap();
            };
            let describe = |n: usize, _: &str| format!("line {n}");
            let (outcome, _) = tokio::join!(c.stream(lines.iter().cloned().map(Ok), &describe, Some(&mut rx)), buttons);
            let outcome = outcome.unwrap();
            assert!(outcome.completed, "{:?}", outcome.stop_reason);
            assert_eq!(outcome.last_executed_line, Some(lines.len()));
            assert!(heard.borrow().iter().any(|t| t.starts_with("<Hold:0")), "the hold took effect");

            // The same job aborted half way: held, reset, laser off.
            let (tx, mut rx) = mpsc::unbounded_channel();
            let abort = async {
                tokio::time::sleep(Duration::from_millis(1200)).await;
                tx.send(Control::Abort).unwrap();
            };
            let (outcome, _) = tokio::join!(c.stream(lines.iter().cloned().map(Ok), &describe, Some(&mut rx)), abort);
            let outcome = outcome.unwrap();
            assert!(!outcome.completed);
            assert!(outcome.stop_reason.as_deref().unwrap().contains("aborted by the operator"));
            let executed = outcome.last_executed_line.unwrap();
            assert!(executed > 2 && executed < lines.len(), "{executed}");
            let status = outcome.final_status.unwrap();
            assert_eq!(status.state, MachineState::Idle);
            assert_eq!(status.spindle.unwrap_or(0.0), 0.0);

            // Resume right after the last executed line: modes, position and
            // laser come back, and the job finishes where the plan ends.
            let knots_before = knots.borrow().len();
            let letters = machine.axis_letters();
            let outcome = c.resume(lines.iter().cloned().map(Ok), executed + 1, &letters, &describe, None).await.unwrap();
            assert!(outcome.completed, "{:?}", outcome.stop_reason);
            assert_eq!(outcome.last_acked_line, lines.len(), "numbered as in the program");
            let end = c.status().await.unwrap().mpos;
            let planned_end = planned.trajectory.state_at(planned.trajectory.duration());
            assert!((end[0] - planned_end.stage.x).abs() < 1e-3 && (end[2] - planned_end.scanner.x).abs() < 1e-3, "{end:?}");
            // The move back into place ran with the laser off.
            let resumed = &knots.borrow()[knots_before..];
            assert!(resumed.len() > 2 && resumed[1].power == 0.0, "{:?}", &resumed[..2]);
            let _ = stop_tx.send(true);
        };
        tokio::join!(sim, operator);
    });
}

/// Runs `operator` on a connection to an in-process simulator with these
/// faults, in virtual time.
fn with_connection<F>(faults: Faults, operator: impl FnOnce(Connection<tokio::io::DuplexStream, Box<dyn FnMut(f64, laserd::stream::LinkEvent)>>) -> F)
where
    F: std::future::Future<Output = ()>,
{
    let machine = MachineConfig::load(None).unwrap();
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().start_paused(true).build().unwrap();
    runtime.block_on(async {
        let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
        let (stop_tx, stop_rx) = watch::channel(false);
        let controller = Controller::new(run::sim_config(&machine, faults));
        let sim = in_process::run(controller, sim_io, machine.serial.baud, tokio::time::Instant::now(), stop_rx, |_| {});
        let operator = async {
            let options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
            let c = Connection::open(sender_io, &options, Box::new(|_, _| {}) as Box<dyn FnMut(f64, laserd::stream::LinkEvent)>).await.unwrap();
            operator(c).await;
            let _ = stop_tx.send(true);
        };
        tokio::join!(sim, operator);
    });
}

#[test]
fn homing_answers_when_home_fails_at_once_on_an_alarm_and_stops_on_abort() {
    let describe = |n: usize, _: &str| format!("line {n}");
    // Homing on ($22), then out to X40 Y30 to have a way to go home.
    let setup = || ["$22=1", "G90 G0 X40 Y30", "G4 P0"].map(|l| Ok(l.to_string()));

    // A cycle that gets there: the answer comes when the machine is home.
    with_connection(Faults::default(), |mut c| async move {
        assert!(c.stream(setup(), &describe, None).await.unwrap().completed);
        while c.status().await.unwrap().mpos[..2] != [40.0, 30.0] {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let started = tokio::time::Instant::now();
        c.home(None).await.unwrap();
        // X's 41 mm to Grbl's home (-1: the pull-off inside the switch at 0)
        // at the seek rate ($25 = 500 mm/min): 4.9 s.
        assert!(started.elapsed() > Duration::from_millis(4700), "{:?}", started.elapsed());
        let status = c.status().await.unwrap();
        assert_eq!(status.state, MachineState::Idle);
        assert_eq!(status.mpos, [-1.0, -1.0, 0.0, 0.0], "X and Y homed, the scanner's U and V not");
    });

    // No switch found: the alarm is the answer (the `ok` after it only ends the cycle).
    let faults = Faults { homing_switch_missing: true, ..Faults::default() };
    with_connection(faults, |mut c| async move {
        assert!(c.stream(setup(), &describe, None).await.unwrap().completed);
        while c.status().await.unwrap().mpos[..2] != [40.0, 30.0] {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let started = tokio::time::Instant::now();
        let error = c.home(None).await.unwrap_err().to_string();
        assert!(error.contains("ALARM:9"), "{error}");
        assert!(started.elapsed() < Duration::from_secs(30), "not the 300 s time-out: {:?}", started.elapsed());
        assert_eq!(c.status().await.unwrap().state, MachineState::Alarm);
    });

    // Aborted after a second: reset mid-cycle, the machine stops part way in alarm.
    with_connection(Faults::default(), |mut c| async move {
        assert!(c.stream(setup(), &describe, None).await.unwrap().completed);
        while c.status().await.unwrap().mpos[..2] != [40.0, 30.0] {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let (tx, mut rx) = mpsc::unbounded_channel();
        let abort = async {
            tokio::time::sleep(Duration::from_secs(1)).await;
            tx.send(Control::FeedHold).unwrap(); // ignored while homing
            tx.send(Control::Abort).unwrap();
        };
        let (homed, _) = tokio::join!(c.home(Some(&mut rx)), abort);
        let error = homed.unwrap_err().to_string();
        assert!(error.contains("homing aborted"), "{error}");
        let status = c.status().await.unwrap();
        assert_eq!(status.state, MachineState::Alarm);
        assert!(status.mpos[0] > 0.0 && status.mpos[0] < 40.0, "stopped part way: {:?}", status.mpos);
    });
}
