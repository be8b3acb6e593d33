//! laserd's `send` and service on a homed Grbl with soft limits, in Grbl's
//! own convention: homing on (`$22=1`), soft limits on (`$20=1`), machine
//! space −travel..0 after `$H`. laserd's programs are in bed coordinates
//! (0..travel): they must run there without an alarm, each point executed at
//! its bed position plus the bed's origin (−travel on an axis homing toward
//! plus, Grbl's default).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::service::{machine_state, position, set_key, take_turn, write_settings, Api, Service};
use common::SimProcess;
use hyper::Method;
use laserd_sim::controller::Knot;

/// The bed of these tests: 400 x 300 mm (so the simulator's `$130`, `$131`).
const TRAVEL: [f64; 2] = [400.0, 300.0];
/// Where the bed's 0 is in machine coordinates after homing toward plus.
const ORIGIN: [f64; 2] = [-400.0, -300.0];
/// A homed Grbl with soft limits, reporting machine positions without `Bf:`
/// (Grbl's default `$10=1`).
const GRBL_HOMED: [&str; 3] = ["$22=1", "$20=1", "$10=1"];

/// The shipped cutter config on a 400 x 300 bed, its port at `tty`.
fn cutter_config(dir: &Path, tty: &Path) -> PathBuf {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml")).unwrap();
    let path = dir.join("cutter.toml");
    std::fs::write(&path, text).unwrap();
    set_key(&path, "stage", "travel_x", &format!("{:.1}", TRAVEL[0]));
    set_key(&path, "stage", "travel_y", &format!("{:.1}", TRAVEL[1]));
    set_key(&path, "serial", "port", &format!("{:?}", tty.to_str().unwrap()));
    path
}

/// `laserd sim` at 1 Mbaud on the cutter config (`--config` and `args`), set
/// up as a homed Grbl and sent `$H` (answered `ok` however it ends).
fn homed_sim(link: &Path, config: &Path, args: &[&str]) -> SimProcess {
    let mut all = vec!["--config", config.to_str().unwrap(), "--baud", "1000000"];
    all.extend_from_slice(args);
    let sim = SimProcess::start(link, &all);
    write_settings(link, &GRBL_HOMED);
    write_settings(link, &["$H"]);
    sim
}

/// `laserd send FILE` at 1 Mbaud with the cutter config, `--json`.
fn send(file: &Path, link: &Path, config: &Path, dir: &Path) -> std::process::Output {
    laserd(&["send", file.to_str().unwrap(), "--port", link.to_str().unwrap(), "--baud", "1000000", "--config", config.to_str().unwrap(), "--json"], dir)
}

/// Two parts near opposite corners of the bed, cut (pierced) one after the other.
fn sheet(dir: &Path) -> PathBuf {
    let path = dir.join("sheet.svg");
    let svg = r##"<svg xmlns="http://www.w3.org/2000/svg" width="400mm" height="300mm" viewBox="0 0 400 300">
  <rect x="10" y="10" width="40" height="20" fill="none" stroke="#000000"/>
  <rect x="340" y="260" width="50" height="30" fill="none" stroke="#000000"/>
</svg>"##;
    std::fs::write(&path, svg).unwrap();
    path
}

fn laserd(args: &[&str], dir: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_laserd")).args(args).current_dir(dir).output().unwrap()
}

/// The X, Y end points of a program's motion lines (absolute, in bed coordinates).
fn program_points(program: &Path) -> Vec<[f64; 2]> {
    let text = std::fs::read_to_string(program).unwrap();
    let word = |line: &str, letter: char| -> Option<f64> {
        let at = line.find(letter)? + 1;
        let end = line[at..].find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-')).map_or(line.len(), |e| at + e);
        line[at..end].parse().ok()
    };
    let mut at = [0.0, 0.0];
    let mut points = Vec::new();
    for line in text.lines().filter(|l| l.starts_with("G1") || l.starts_with("G0") || l.starts_with('X') || l.starts_with('Y')) {
        let (x, y) = (word(line, 'X'), word(line, 'Y'));
        if x.is_some() || y.is_some() {
            at = [x.unwrap_or(at[0]), y.unwrap_or(at[1])];
            points.push(at);
        }
    }
    assert!(points.len() > 8, "a program with motion: {text}");
    points
}

/// Every knot within Grbl's soft limits, and every program point executed at
/// its bed position plus the bed's origin.
fn assert_ran_in_bed_coordinates(knots: &[Knot], program: &Path) {
    for k in knots {
        let inside = (0..2).all(|i| k.pos[i] <= 1e-6 && k.pos[i] >= -TRAVEL[i] - 1e-6);
        assert!(inside, "a knot outside the soft limits: {k:?}");
    }
    for p in program_points(program) {
        let machine = [p[0] + ORIGIN[0], p[1] + ORIGIN[1]];
        let hit = knots.iter().any(|k| (k.pos[0] - machine[0]).abs() < 2e-3 && (k.pos[1] - machine[1]).abs() < 2e-3);
        assert!(hit, "program point {p:?} never executed at machine {machine:?}");
    }
}

#[test]
fn send_runs_a_planned_program_on_a_homed_grbl_within_soft_limits() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyHOMEDSEND");
    let config = cutter_config(dir.path(), &link);
    let rec = dir.path().join("sim.mcap");
    let sim = homed_sim(&link, &config, &["--record", rec.to_str().unwrap()]);

    let program = dir.path().join("sheet.nc");
    let planned = laserd(&["plan", sheet(dir.path()).to_str().unwrap(), "--config", config.to_str().unwrap(), "-o", program.to_str().unwrap()], dir.path());
    assert!(planned.status.success(), "{}", String::from_utf8_lossy(&planned.stderr));
    let out = send(&program, &link, &config, dir.path());
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
    assert!(out.status.success(), "{report} {}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(report["completed"], true, "{report}");
    assert_eq!(report["alarms"], serde_json::json!([]), "{report}");

    assert!(sim.terminate().success());
    let replay = laserd::record::read(&rec).unwrap();
    // Homed first: at minus the pull-off ($27 = 1), Grbl's home.
    assert_eq!(replay.log.knots.first().map(|k| k.pos[..2].to_vec()), Some(vec![0.0, 0.0]));
    assert!(replay.log.knots.iter().any(|k| k.pos[..2] == [-1.0, -1.0]), "homed to -1, -1");
    assert_ran_in_bed_coordinates(&replay.log.knots, &program);
}

#[test]
fn the_service_homes_then_runs_and_resumes_a_job_on_a_homed_grbl_within_soft_limits() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyHOMEDSERVE");
    let config = cutter_config(dir.path(), &tty);
    let rec = dir.path().join("sim.mcap");
    let sim = SimProcess::start(&tty, &["--config", config.to_str().unwrap(), "--record", rec.to_str().unwrap()]);
    write_settings(&tty, &GRBL_HOMED);
    // Reports with `Bf:`: the resume below starts from the executed line
    // the service kept (without them it is unknown and the resume asks for one).
    write_settings(&tty, &["$10=3"]);
    let (state, socket) = (dir.path().join("state"), dir.path().join("api.sock"));
    let service = Service::start(&config, &state, &socket);
    let api = Api::new(&socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");

    assert_eq!(api.ok(Method::POST, "/home", None)["done"], "homed");
    let home = api.wait_status(Duration::from_secs(5), "home", |s| machine_state(s) == "Idle");
    assert_eq!(position(&home)[..2], [-1.0, -1.0], "{home}");
    // Jogs are in bed coordinates once homed (G54 is the bed's origin).
    api.ok(Method::POST, "/jog", Some(serde_json::json!({ "block": "G90 X100 Y50 F30000" })));
    api.wait_status(Duration::from_secs(5), "jogged to bed X100 Y50", |s| {
        machine_state(s) == "Idle" && (position(s)[0] - (100.0 + ORIGIN[0])).abs() < 1e-3 && (position(s)[1] - (50.0 + ORIGIN[1])).abs() < 1e-3
    });

    let id = api.submit(&sheet(dir.path()));
    api.wait_job(&id, "queued", Duration::from_secs(60));
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": id })));
    let done = api.wait_job(&id, "completed", Duration::from_secs(60));
    assert_eq!(done["last_executed_line"], done["lines_total"], "{done}");
    let s = api.status();
    assert_eq!(machine_state(&s), "Idle", "no alarm: {s}");
    let program = state.join("jobs").join(&id).join("program.nc");
    // The job's recording gives the travel in the machine coordinates the
    // controller reports: the bed from its origin on.
    let recorded = laserd::record::read(&state.join("jobs").join(&id).join("recording.mcap")).unwrap();
    let axes = recorded.log.setup.expect("the recording's setup").axes;
    assert_eq!([axes[0].min, axes[0].max, axes[1].min, axes[1].max], [ORIGIN[0], 0.0, ORIGIN[1], 0.0]);
    let end = *program_points(&program).last().unwrap();
    let at_end = |s: &serde_json::Value| (0..2).all(|i| (position(s)[i] - (end[i] + ORIGIN[i])).abs() < 2e-3);
    assert!(at_end(&s), "the job ends at its bed position {end:?}: {s}");

    // The same job stopped half way by a service stop, then resumed by the
    // service started again: it runs on in bed coordinates to the same end.
    let again = api.submit(&sheet(dir.path()));
    let total = api.wait_job(&again, "queued", Duration::from_secs(60))["lines_total"].as_u64().unwrap();
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": again })));
    api.wait_status(Duration::from_secs(20), "half sent", |s| s["job"]["line"].as_u64().unwrap_or(0) > total / 2);
    assert!(service.terminate().success());
    let service = Service::start(&config, &state, &socket);
    let api = Api::new(&socket);
    api.wait_status(Duration::from_secs(10), "reconnected", |s| machine_state(s) == "Idle");
    assert_eq!(api.job(&again)["state"], "interrupted");
    api.ok(Method::POST, &format!("/jobs/{again}/resume"), Some(serde_json::json!({ "confirm": true })));
    api.wait_job(&again, "completed", Duration::from_secs(60));
    let s = api.status();
    assert!(at_end(&s), "the resumed job ends at its bed position {end:?}: {s}");

    drop(service);
    assert!(sim.terminate().success());
    let replay = laserd::record::read(&rec).unwrap();
    assert_ran_in_bed_coordinates(&replay.log.knots, &program);
}

/// A line past the soft limits: Grbl stops with ALARM:2 and answers the
/// line `ok` only with the reset. `send` stops there, and that `ok` does not
/// count the line as acknowledged: it never ran.
#[test]
fn send_stops_at_a_soft_limit_and_never_counts_the_line_acknowledged() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttySOFTLIMIT");
    let config = cutter_config(dir.path(), &link);
    let _sim = homed_sim(&link, &config, &[]);
    let program = dir.path().join("over.nc");
    // In bed coordinates: X450 is 50 mm past the 400 mm bed.
    std::fs::write(&program, "G21G90G94\nG1X10Y10F3000\nG1X20Y20\nG1X450Y20\nG1X30Y30\n").unwrap();
    let out = send(&program, &link, &config, dir.path());
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["alarms"], serde_json::json!([2]), "{report}");
    assert_eq!(report["last_acked_line"], 3, "{report}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("ALARM:2") && err.contains("over.nc:3"), "{err}");
}

/// A controller left in alarm by a failed homing cycle: `send` says to home
/// or unlock it, before it writes anything.
#[test]
fn send_to_a_controller_in_alarm_says_to_home_or_unlock_it() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyALARMED");
    let config = cutter_config(dir.path(), &link);
    // ALARM:9, then the `$H` answered `ok`, then Grbl's own reset into Alarm.
    let _sim = homed_sim(&link, &config, &["--fault", "homing-switch-missing"]);
    let program = dir.path().join("job.nc");
    std::fs::write(&program, "G21G90G94\nG1X10Y10F3000\n").unwrap();
    let out = send(&program, &link, &config, dir.path());
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("in alarm: home ($H) or unlock ($X) it first"), "{err}");
}
