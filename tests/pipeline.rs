//! The pipeline through the library: a fault injected in the simulator, and a
//! real pseudo-terminal between the sender and `laserd sim --pty` in real time.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::SimProcess;

use laserd::mode::Mode;
use laserd::config::MachineConfig;
use laserd::figures::{sim_figures, PlannedLine};
use laserd::plan::PlannerKind;
use laserd::program::LineKind;
use laserd::run;
use laserd::stream::{self, SenderOptions};
use laserd_sim::controller::Faults;
use laserd_sim::wire::MachineState;

/// The real-time run below judges the executed motion against the machine's
/// limits: a host too busy to keep the link fed stops the machine dead, which
/// the limit checker rightly counts. The tests of this file take turns, so
/// the CPU-bound dry-runs do not starve it (other test binaries run after).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn take_turn() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn sample(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples").join(name)
}

#[test]
fn error_20_on_a_chosen_line_stops_the_job_there_with_the_laser_off() {
    let _turn = take_turn();
    // A GRBL 1.1-sized controller (128-byte buffer, 15 planner blocks): the
    // error comes back while the machine is a few lines behind it.
    let mut machine = MachineConfig::load(None).unwrap();
    machine.serial.rx_buffer = 128;
    machine.simulator.planner_blocks = 15;
    let planned = run::plan(&sample("one-field.svg"), &machine, PlannerKind::Nearest, None).unwrap();
    // A marking line in the middle of the job: the laser is on when it fails.
    let marks: Vec<usize> = planned.program.lines.iter().enumerate().filter(|(_, l)| l.kind == LineKind::Mark).map(|(i, _)| i + 1).collect();
    let bad = marks[marks.len() / 2];
    let dir = tempfile::tempdir().unwrap();
    // The controller counts the sender's `$I` at connect as its first line.
    let dry = run::dry_run(&planned, &machine, &dir.path().join("e.mcap"), Faults { error_on_line: Some(bad as u64 + 1), ..Default::default() }).unwrap();
    let out = &dry.outcome;
    assert!(!out.completed);
    assert_eq!(out.errors.len(), 1);
    assert_eq!(out.errors[0].line, bad);
    assert_eq!(out.errors[0].code, 20);
    let reason = out.stop_reason.as_deref().unwrap();
    assert!(reason.contains(&format!("G-code line {bad} ")), "{reason}");
    assert!(reason.contains("one-field.svg"), "names the source geometry: {reason}");
    // Nothing past what was already in the controller's 128-byte buffer ran.
    let lines = laserd::figures::program_lines(&dry.log.link);
    let last_executed = dry.log.knots.iter().map(|k| laserd::figures::program_line_of(&lines, k)).max().unwrap();
    assert!(last_executed < bad + 5, "executed up to {last_executed}, error at {bad}");
    assert!(last_executed >= bad.saturating_sub(20), "the job did run up to near the error");
    // The machine ends stopped with the laser off.
    let status = out.final_status.as_ref().expect("a status after the safe stop");
    assert_eq!(status.state, MachineState::Idle);
    assert_eq!(status.spindle.unwrap_or(0.0), 0.0);
    let sim = dry.report.sim.as_ref().unwrap();
    assert_eq!(sim.limit_violations, 0, "{sim:?}");
}

#[test]
fn sample_job_through_a_real_pty_at_115200_baud_follows_the_plan() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyLASER");
    let rec = dir.path().join("sim.mcap");
    let sim = SimProcess::start(&link, &["--pty", "--baud", "115200", "--record", rec.to_str().unwrap()]);

    let machine = MachineConfig::load(None).unwrap();
    // Step-and-scan: 115200 baud carries its program with rests to spare (the
    // on-the-fly program of this job needs more lines a second than that).
    let planned = run::plan(&sample("one-field.svg"), &machine, PlannerKind::Nearest, Some(Mode::StepAndScan)).unwrap();
    let lines: Vec<String> = planned.program.lines.iter().map(|l| l.text.clone()).collect();
    let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    options.expect_start = Some(planned.program.start.clone());
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let outcome = runtime
        .block_on(async {
            use tokio_serial::SerialPortBuilderExt;
            let io = tokio_serial::new(link.to_str().unwrap(), 115_200).open_native_async().expect("open the pty");
            let describe = |n: usize, _: &str| planned.program.describe_line(n);
            let source = lines.iter().cloned().map(Ok);
            tokio::time::timeout(Duration::from_secs(120), stream::stream(io, source, &options, &describe, |_, _| {})).await
        })
        .expect("streams within two minutes")
        .expect("streams");
    assert!(outcome.completed, "{:?}", outcome.stop_reason);
    assert_eq!(outcome.last_acked_line, lines.len());

    // Stop the simulator cleanly so it finishes its recording, then compare the
    // motion it executed with the plan.
    let status = sim.terminate();
    assert!(status.success());
    let replay = laserd::record::read(&rec).expect("the simulator's recording reads back");
    assert!(replay.truncated.is_none());
    let mut log = replay.log;
    log.planned = PlannedLine::from_program(&planned.program);
    // The simulator numbers every line it received; the sender's own `$I`
    // came first. Number the program's lines as the program does.
    let mut program_line = 0;
    for (_, event) in &mut log.link {
        if let laserd::stream::LinkEvent::Sent { line, text } = event {
            *line = if text.starts_with('$') { 0 } else { program_line += 1; program_line };
        }
    }
    let figures = sim_figures(&log);
    eprintln!("pty run at 115200 baud: {}", serde_json::to_string(&figures).unwrap());
    assert!(log.knots.len() > lines.len() / 2, "motion was executed: {} knots", log.knots.len());
    assert!(figures.max_tcp_deviation_mm.unwrap() <= 0.05, "{figures:?}");
    assert_eq!(figures.laser_state_errors, 0, "laser off on every jump, on while marking");
    assert_eq!(figures.limit_violations, 0, "{figures:?}");
    assert!(figures.job_time_s >= planned.trajectory.job_time() * 0.999);
    // The simulator's side of the link is in its recording too.
    assert_eq!(figures.lines_sent, lines.len() + 1, "the program and `$I`");
    assert_eq!(figures.bytes_sent, outcome.bytes_sent + laserd::stream::BUILD_INFO.len() + 1);
    assert!(figures.link_utilization > 0.0 && figures.link_utilization <= 1.0, "{figures:?}");
}

#[test]
fn a_simulator_killed_mid_run_leaves_a_readable_recording() {
    let _turn = take_turn();
    use std::io::{Read, Write};
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyCRASH");
    let rec = dir.path().join("crash.mcap");
    let sim = SimProcess::start(&link, &["--pty", "--record", rec.to_str().unwrap()]);
    let mut port = std::fs::OpenOptions::new().read(true).write(true).open(&link).unwrap();
    port.write_all(b"G93\nG1X1F600\nG1X2F600\nG1X3F600\nG1X4F600\n").unwrap();
    // Let it move and record for longer than the recorder's flush interval.
    std::thread::sleep(Duration::from_millis(1600));
    let mut buf = [0u8; 512];
    let _ = port.read(&mut buf);
    sim.kill(); // SIGKILL: no chance to finish the file
    let replay = laserd::record::read(&rec).expect("what was flushed reads back");
    assert!(!replay.log.knots.is_empty(), "executed motion up to the crash is there");
    assert!(replay.log.setup.is_some());
    let out = Command::new(env!("CARGO_BIN_EXE_laserd")).args(["replay", rec.to_str().unwrap(), "--json"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("ends early"));
}

/// What `plan` and `dry-run` show on a terminal: the library tells its
/// stages in the pipeline's order, and the simulation's share done rising to
/// the whole (it prints nothing itself).
#[test]
fn a_plan_and_dry_run_tell_their_stages_in_order() {
    struct Heard(std::cell::RefCell<Vec<(String, Option<f64>)>>);
    impl run::Progress for Heard {
        fn stage(&self, name: &str) {
            self.0.borrow_mut().push((name.to_string(), None));
        }
        fn done(&self, share: f64) {
            self.0.borrow_mut().push((String::new(), Some(share)));
        }
    }
    let machine = MachineConfig::load(None).unwrap();
    let heard = Heard(Default::default());
    let planned = run::plan_showing(&sample("one-field.svg"), &machine, PlannerKind::Auto, None, &heard).unwrap();
    let dir = tempfile::tempdir().unwrap();
    run::dry_run_showing(&planned, &machine, &dir.path().join("r.mcap"), Faults::default(), &heard).unwrap();
    let heard = heard.0.into_inner();
    let stages: Vec<&str> = heard.iter().filter(|(_, s)| s.is_none()).map(|(n, _)| n.as_str()).collect();
    let first = |name: &str| stages.iter().position(|s| s.starts_with(name)).unwrap_or_else(|| panic!("no {name} in {stages:?}"));
    assert!(first("import") < first("planning") && first("planning") < first("motion") && first("motion") < first("program") && first("program") < first("simulation"), "{stages:?}");
    assert_eq!(stages.last(), Some(&"simulation"));
    let shares: Vec<f64> = heard.iter().filter_map(|(_, s)| *s).collect();
    assert!(shares.windows(2).all(|w| w[1] >= w[0]) && shares.last() == Some(&1.0), "{} shares, last {:?}", shares.len(), shares.last());
}
