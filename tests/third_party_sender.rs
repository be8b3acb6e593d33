//! In real-time pty mode any GRBL sender can connect and stream: here a sender
//! laserd did not write, the PyPI package `pygrbl-streamer` (its `GrblStreamer`
//! connects with a soft reset and `$X`, then streams a file by character
//! counting against Grbl's 128-byte receive buffer and polls `?` until Idle).
//! It streams a CAM-style laser job to `laserd sim --motion grbl`; the
//! simulator's recording then shows what the controller received and executed.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::SimProcess;
use laserd::stream::LinkEvent;
use laserd_sim::limits::LimitChecker;

const BAUD: &str = "115200";

/// The streaming script: connects with the library's defaults, sends the file
/// with `send_file` (default character counting), and prints one JSON object.
/// The library reports traffic through callbacks that run, in order, on its
/// own callback thread; `disconnect()` joins that thread after it has run
/// every callback queued before, so the counts are complete when printed.
const STREAM_PY: &str = r#"
import json, sys
import pygrbl_streamer
from pygrbl_streamer import GrblStreamer, State

port, path, baud = sys.argv[1], sys.argv[2], int(sys.argv[3])
events = []
def record(kind):
    return lambda *args: events.append((kind, args))
g = GrblStreamer(port, baudrate=baud)
for kind in ("send", "receive", "state", "alarm", "error", "disconnect"):
    setattr(g, kind + "_callback", record(kind))
g.connect()
completed = g.send_file(path, completion_timeout=90)
g.disconnect()

# The job is what happened between entering STREAMING and leaving it.
streaming = False
sent = ok = 0
errors, alarms, disconnects, received = [], [], [], []
for kind, args in events:
    if kind == "state":
        streaming = args[0] == State.STREAMING
    elif kind == "alarm":
        alarms.append(args[0])
    elif kind == "error":
        errors.append(args[0])
    elif kind == "disconnect":
        disconnects.append(args[0])
    elif streaming and kind == "send" and args[0].endswith("\n"):
        sent += 1
    elif streaming and kind == "receive":
        received.append(args[0])
        ok += args[0] == "ok"
print(json.dumps({
    "version": pygrbl_streamer.__version__,
    "completed": completed,
    "lines_sent": sent,
    "ok": ok,
    "errors": errors,
    "alarms": alarms,
    "disconnects": disconnects,
    "last_status": g.last_status.get("raw"),
    "received_not_ok": [r for r in received if r != "ok" and not r.startswith("<")],
}))
"#;

/// A CAM-style laser job (what a LightBurn-like tool writes): G21 G90 G94,
/// M4 dynamic power, for each of 12 parts a rapid to it, a circle traced as
/// 24 short G1 segments, and a ring of four quarter arcs (G3 or G2 with I/J);
/// a rapid home and M5 at the end. All of it within 20..270 mm on X and Y.
/// Returns the lines and where the program's last motion ends.
fn cam_program() -> (Vec<String>, [f64; 2]) {
    let mut lines = vec!["G21 G90 G94".to_string(), "M4 S0".to_string()];
    for k in 0..12 {
        let (cx, cy) = (40.0 + 70.0 * (k % 4) as f64, 50.0 + 100.0 * (k / 4) as f64);
        let (r, big_r) = (15.0, 20.0);
        let feed = 6000 + 800 * k;
        let power = 200 + 50 * k;
        lines.push(format!("G0 X{:.3} Y{:.3}", cx + r, cy));
        for i in 1..=24 {
            let a = std::f64::consts::TAU * i as f64 / 24.0;
            let (x, y) = (cx + r * a.cos(), cy + r * a.sin());
            if i == 1 {
                lines.push(format!("G1 X{x:.3} Y{y:.3} S{power} F{feed}"));
            } else {
                lines.push(format!("G1 X{x:.3} Y{y:.3}"));
            }
        }
        lines.push(format!("G1 X{:.3} Y{:.3}", cx + big_r, cy));
        // Quarter arcs about (cx, cy): counter-clockwise for even parts,
        // clockwise for odd ones, back to where the ring started.
        let quarters: [(&str, f64, f64, f64, f64); 4] = if k % 2 == 0 {
            [("G3", 0.0, big_r, -big_r, 0.0), ("G3", -big_r, 0.0, 0.0, -big_r), ("G3", 0.0, -big_r, big_r, 0.0), ("G3", big_r, 0.0, 0.0, big_r)]
        } else {
            [("G2", 0.0, -big_r, -big_r, 0.0), ("G2", -big_r, 0.0, 0.0, big_r), ("G2", 0.0, big_r, big_r, 0.0), ("G2", big_r, 0.0, 0.0, -big_r)]
        };
        for (g, dx, dy, i, j) in quarters {
            lines.push(format!("{g} X{:.3} Y{:.3} I{i:.3} J{j:.3}", cx + dx, cy + dy));
        }
    }
    let end = [5.0, 5.0];
    lines.push(format!("G0 X{:.3} Y{:.3}", end[0], end[1]));
    lines.push("M5".into());
    (lines, end)
}

/// Runs `python3 ARGS…` with its output in files, killed after `limit`.
fn python_with_timeout(args: &[&str], dir: &Path, limit: Duration) -> (bool, String, String) {
    let (out_path, err_path) = (dir.join("py.out"), dir.join("py.err"));
    let mut child = Command::new("python3")
        .args(args)
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("python3 runs");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "the pygrbl_streamer script did not finish within {limit:?}; stderr: {}",
                std::fs::read_to_string(&err_path).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    (status.success(), std::fs::read_to_string(&out_path).unwrap(), std::fs::read_to_string(&err_path).unwrap())
}

#[test]
fn pygrbl_streamer_streams_a_cam_job_to_the_simulator_on_a_pty() {
    let have = |py: &str| Command::new("python3").args(["-c", py]).status().map(|s| s.success()).unwrap_or(false);
    // Installed (pinned) by .ci/run; a test installs nothing.
    assert!(have("import pygrbl_streamer, serial"), "this test needs the third-party GRBL sender, the Python packages pygrbl-streamer 1.0.5 and pyserial 3.5: .ci/run installs them, pinned");

    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyGRBL");
    let rec = dir.path().join("third-party.mcap");
    let sim = SimProcess::start(&link, &["--motion", "grbl", "--baud", BAUD, "--record", rec.to_str().unwrap()]);

    let (lines, end) = cam_program();
    assert!(lines.len() > 300, "a few hundred lines: {}", lines.len());
    let nc = dir.path().join("job.nc");
    // A CAM header comment, as such tools write: the sender strips it.
    std::fs::write(&nc, format!("; laserd third-party sender test job\n{}\n", lines.join("\n"))).unwrap();
    let script = dir.path().join("stream.py");
    std::fs::write(&script, STREAM_PY).unwrap();

    let (ok, stdout, stderr) = python_with_timeout(
        &[script.to_str().unwrap(), link.to_str().unwrap(), nc.to_str().unwrap(), BAUD],
        dir.path(),
        Duration::from_secs(120),
    );
    assert!(ok, "the pygrbl_streamer script failed: {stderr}");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout:?}; stderr: {stderr}"));
    eprintln!("pygrbl_streamer: {report}");
    assert_eq!(report["completed"], true, "send_file reports success: {report}");
    assert_eq!(report["errors"], serde_json::json!([]), "{report}");
    assert_eq!(report["alarms"], serde_json::json!([]), "{report}");
    assert_eq!(report["disconnects"], serde_json::json!([]), "{report}");
    assert_eq!(report["lines_sent"].as_u64(), Some(lines.len() as u64), "{report}");
    assert_eq!(report["ok"].as_u64(), Some(lines.len() as u64), "one ok per line: {report}");
    assert!(report["last_status"].as_str().is_some_and(|s| s.starts_with("<Idle|")), "{report}");

    // SIGTERM: the simulator finishes its recording.
    assert!(sim.terminate().success());
    let replay = laserd::record::read(&rec).expect("the simulator's recording reads back");
    assert!(replay.truncated.is_none(), "{:?}", replay.truncated);
    let log = replay.log;

    // Every program line reached the controller, in order and intact; before
    // them only the sender's own `$` commands (its unlock on connect).
    let sent: Vec<(usize, &str)> = log
        .link
        .iter()
        .filter_map(|(_, e)| match e {
            LinkEvent::Sent { line, text } => Some((*line, text.as_str())),
            _ => None,
        })
        .collect();
    assert!(sent.len() >= lines.len(), "{} lines received, the program has {}", sent.len(), lines.len());
    let (own, program) = sent.split_at(sent.len() - lines.len());
    assert!(own.iter().all(|(_, t)| t.starts_with('$')), "only the sender's $ commands before the job: {own:?}");
    let received: Vec<&str> = program.iter().map(|(_, t)| *t).collect();
    assert_eq!(received, lines, "the controller received the program as written");
    // The controller answered without an error or alarm.
    let answers: Vec<&str> = log
        .link
        .iter()
        .filter_map(|(_, e)| match e {
            LinkEvent::Received { text } => Some(text.as_str()),
            _ => None,
        })
        .collect();
    assert!(!answers.iter().any(|t| t.starts_with("error") || t.starts_with("ALARM")), "{answers:?}");
    assert_eq!(answers.iter().filter(|t| **t == "ok").count(), sent.len(), "one ok per line received");

    // The motion ran to the program's last move, and ended where it ends, laser off.
    let knots = &log.knots;
    assert!(knots.len() > lines.len(), "motion was executed: {} knots", knots.len());
    let last_motion_line = program[program.len() - 2].0 as u64; // the final G0, before M5
    assert_eq!(knots.iter().map(|k| k.line).max(), Some(last_motion_line), "the last move was executed");
    let last = knots.last().unwrap();
    assert!((last.pos[0] - end[0]).abs() < 1e-6 && (last.pos[1] - end[1]).abs() < 1e-6, "ends at {end:?}: {last:?}");
    assert!(last.pos[2..].iter().all(|p| p.abs() < 1e-9), "the scanner axes stay at rest: {last:?}");
    assert_eq!(last.power, 0.0, "laser off at the end: {last:?}");

    // Grbl's planner keeps every axis within its max rate. (Not the checker's
    // acceleration or jerk: Grbl turns corners at the junction speed at once.)
    let setup = log.setup.as_ref().expect("the recording has the run setup");
    assert_eq!(setup.axes.iter().map(|a| a.letter).collect::<String>(), "XYUV");
    let mut checker = LimitChecker::new(&setup.axes);
    knots.iter().for_each(|k| checker.push(k));
    let limits = checker.finish();
    eprintln!("peak velocity use per axis: {:?}", limits.peak_velocity_use);
    assert!(limits.peak_velocity_use.iter().all(|u| *u <= 1.0 + 1e-6), "{limits:?}");
    assert!(limits.peak_velocity_use[0] > 0.5 && limits.peak_velocity_use[1] > 0.5, "rapids ran near the max rate: {limits:?}");
    for (axis, (lo, hi)) in limits.peak_position.iter().take(2).enumerate() {
        assert!(*lo >= 0.0 && *hi <= 300.0, "axis {axis} within its travel: {lo}..{hi}");
    }
}
