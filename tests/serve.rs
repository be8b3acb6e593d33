//! `laserd serve` against `laserd sim --pty`, both as child processes, driven
//! through the API on the service's Unix socket (the library's client).

mod common;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use common::service::*;
use common::SimProcess;
use hyper::Method;
use laserd::daemon::client;
use serde_json::Value;

#[test]
fn a_job_through_the_api_pauses_resumes_completes_and_a_second_is_aborted_half_way_laser_off() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyLASER");
    let sim_rec = dir.path().join("sim.mcap");
    let sim = SimProcess::start(&tty, &["--pty", "--record", sim_rec.to_str().unwrap()]);
    // Reports with `Bf:`: the executed line is known while a job runs.
    write_settings(&tty, &["$10=3"]);
    let config = config(dir.path(), &tty);
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    let events = api.follow();
    api.wait_status(Duration::from_secs(10), "the controller link", |s| s["machine"]["connected"] == true && machine_state(s) == "Idle");
    // The socket: rw for the service's user and group only.
    use std::os::unix::fs::PermissionsExt;
    assert_eq!(std::fs::metadata(&service.socket).unwrap().permissions().mode() & 0o777, 0o660);

    // Job 1: planned by the service, started, held, resumed, completed.
    let first = api.submit(&galvo("SC278C18.svg"));
    let queued = api.wait_job(&first, "queued", Duration::from_secs(60));
    let total = queued["lines_total"].as_u64().unwrap();
    assert!(total > 1000, "{queued}");
    api.ok(Method::POST, "/start", None);
    api.wait_status(Duration::from_secs(10), "a third of job 1 sent", |s| s["job"]["line"].as_u64().unwrap_or(0) > total / 3);
    let (status, conflict) = api.call(Method::POST, "/jog", Some(serde_json::json!({ "block": "G91 X10 F600" })));
    assert_eq!(status, 409, "no jogging while a job runs: {conflict}");
    api.ok(Method::POST, "/pause", None);
    let held = api.wait_status(Duration::from_secs(3), "feed hold", |s| machine_state(s).starts_with("Hold"));
    assert_eq!(held["job"]["state"], "paused");
    // Held still, laser off: the position does not move over half a second.
    api.wait_status(Duration::from_secs(3), "the hold complete", |s| machine_state(s) == "Hold:0");
    std::thread::sleep(Duration::from_millis(300));
    let a = api.status();
    std::thread::sleep(Duration::from_millis(500));
    let b = api.status();
    assert_eq!(a["machine"]["position"], b["machine"]["position"], "standing still in the hold");
    assert_eq!(b["machine"]["laser"].as_f64().unwrap(), 0.0, "laser off in the hold: {b}");
    assert_eq!(api.job(&first)["state"], "paused");
    api.ok(Method::POST, "/resume", None);
    let done = api.wait_job(&first, "completed", Duration::from_secs(30));
    assert_eq!(done["last_executed_line"].as_u64(), Some(total));

    // Job 2: aborted half way.
    let second = api.submit(&galvo("SC122C4.svg"));
    let queued = api.wait_job(&second, "queued", Duration::from_secs(60));
    let total = queued["lines_total"].as_u64().unwrap();
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": second })));
    api.wait_status(Duration::from_secs(10), "half of job 2 sent", |s| s["job"]["line"].as_u64().unwrap_or(0) > total / 2);
    api.ok(Method::POST, "/abort", None);
    let aborted = api.wait_job(&second, "aborted", Duration::from_secs(10));
    let last = aborted["last_executed_line"].as_u64().unwrap();
    assert!(last > 0 && last < total, "stopped part way: {aborted}");
    let idle = api.wait_status(Duration::from_secs(5), "idle after the abort", |s| machine_state(s) == "Idle" && s["job"].is_null());
    assert_eq!(idle["machine"]["laser"].as_f64().unwrap(), 0.0);
    // Both recordings download through the API and read back.
    for id in [&first, &second] {
        let path = dir.path().join(format!("{id}.mcap"));
        api.recording(id, &path);
        let replay = laserd::record::read(&path).unwrap();
        assert!(replay.truncated.is_none(), "{id}: a whole recording");
        assert!(replay.log.link.len() > 100, "{id}: the link traffic is in it");
    }

    // The events told all of it, in order.
    std::thread::sleep(Duration::from_millis(200));
    let events = events.lock().unwrap().clone();
    let job_states = |id: &str| -> Vec<String> {
        let mut states: Vec<String> = events.iter().filter(|(k, v)| k == "job" && v["id"] == id).map(|(_, v)| v["state"].as_str().unwrap().to_string()).collect();
        states.dedup();
        states
    };
    assert_eq!(job_states(&first), ["planning", "queued", "running", "paused", "running", "completed"]);
    assert_eq!(job_states(&second), ["planning", "queued", "running", "aborted"]);
    let machine_states: Vec<&str> = events.iter().filter(|(k, _)| k == "status").map(|(_, v)| v["machine"]["state"].as_str().unwrap()).collect();
    assert!(machine_states.contains(&"Hold:0") && machine_states.contains(&"Run"), "{machine_states:?}");
    assert!(events.iter().any(|(k, v)| k == "status" && v["job"]["percent"].as_f64().unwrap_or(0.0) > 50.0));

    assert!(service.terminate().success(), "a clean stop on SIGTERM");
    sim.terminate();
    // The simulator's own record of the motion: the laser was off whenever
    // the machine stood still (the hold, between the jobs).
    let knots = laserd::record::read(&sim_rec).unwrap().log.knots;
    let rests: Vec<_> = knots.windows(2).filter(|w| w[1].t - w[0].t > 0.4 && w[0].pos == w[1].pos).collect();
    assert!(!rests.is_empty(), "the hold is in the simulator's record");
    assert!(rests.iter().all(|w| w[1].power == 0.0), "the laser is off while held");
}

#[test]
fn after_a_kill_9_mid_job_the_job_is_interrupted_with_its_last_line_and_its_recording_reads() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    // Reports with `Bf:`: the executed line is known while a job runs.
    let (rig, service, api) = Rig::start_with(dir.path(), "ttyKILL", &["$10=3"]);
    let id = api.submit(&sample("marking-300.svg"));
    let queued = api.wait_job(&id, "queued", Duration::from_secs(60));
    let total = queued["lines_total"].as_u64().unwrap();
    let waiting = api.submit(&sample("one-field.svg"));
    api.wait_job(&waiting, "queued", Duration::from_secs(60));
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": id })));
    let (sent_before, job, service, api) = kill_9_past(&rig, service, api, &id, total / 5);
    let last = job["last_executed_line"].as_u64().unwrap();
    assert!(last > 0 && last <= sent_before, "last executed line {last}, {sent_before} sent before the kill: {job}");
    assert!(job["message"].as_str().unwrap().contains(&last.to_string()));
    // The queue kept the waiting job, and the restart started nothing.
    let jobs = api.ok(Method::GET, "/jobs", None);
    assert_eq!(jobs[0]["id"], waiting.as_str());
    assert_eq!(jobs[0]["state"], "queued");
    std::thread::sleep(Duration::from_millis(500));
    assert!(api.status()["job"].is_null(), "nothing runs on its own after a restart");
    // The recording up to the kill reads back.
    let path = dir.path().join("cut.mcap");
    api.recording(&id, &path);
    let replay = laserd::record::read(&path).expect("a recording cut by the kill reads");
    assert!(replay.log.link.len() > 50, "link traffic up to the kill: {}", replay.log.link.len());

    // Resumed and killed again: the line saved is a line of the program
    // (not one counted from the resume), past the first, near what was sent.
    api.ok(Method::POST, &format!("/jobs/{id}/resume"), Some(serde_json::json!({ "confirm": true })));
    let (sent_before, job, service, _api) = kill_9_past(&rig, service, api, &id, last + (total - last) / 3);
    let again = job["last_executed_line"].as_u64().unwrap();
    // Counted from the resume, the line saved would lag what was sent by at
    // least `last` (over 1600 lines); a program line lags by what is in the
    // controller and what streamed since the last save (a few hundred).
    assert!(again > last && again <= sent_before && sent_before - again < last, "resumed at {}, {sent_before} sent before the kill, saved {again}", last + 1);
    drop(service);
}

/// Once more than `line` lines of job `id` are sent, and its progress and
/// recording have had time to reach the disk, kills the service (SIGKILL)
/// and starts it again: the lines sent before the kill, the job as the new
/// service lists it (interrupted), and the new service.
fn kill_9_past(rig: &Rig, service: Service, api: Api, id: &str, line: u64) -> (u64, Value, Service, Api) {
    api.wait_status(Duration::from_secs(20), &format!("line {line} sent"), |s| s["job"]["line"].as_u64().unwrap_or(0) > line);
    std::thread::sleep(Duration::from_millis(1500));
    let sent_before = api.status()["job"]["line"].as_u64().unwrap();
    service.kill();
    drop(api);
    let (service, api) = rig.restart();
    let job = api.job(id);
    assert_eq!(job["state"], "interrupted", "{job}");
    (sent_before, job, service, api)
}

#[test]
fn tcp_needs_the_bearer_token_and_is_refused_without_one() {
    use std::io::{Read, Write};
    let dir = tempfile::tempdir().unwrap();
    let port = 20000 + std::process::id() % 20000;
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, "0123456789abcdef-secret\n").unwrap();
    let base = config(dir.path(), &dir.path().join("ttyNONE"));
    let with_tcp = |token: Option<&Path>| {
        // The shipped config's [service] section, with its TCP lines set.
        let text = std::fs::read_to_string(&base).unwrap();
        assert!(text.contains("# tcp = ") && text.contains("# token_file = "));
        let text: String = text
            .lines()
            .map(|l| match (l.starts_with("# tcp = "), l.starts_with("# token_file = "), token) {
                (true, _, _) => format!("tcp = \"127.0.0.1:{port}\""),
                (_, true, Some(t)) => format!("token_file = {:?}", t.to_str().unwrap()),
                _ => l.to_string(),
            })
            .collect::<Vec<_>>()
            .join("\n");
        let path = dir.path().join(if token.is_some() { "tcp.toml" } else { "tcp-open.toml" });
        std::fs::write(&path, text).unwrap();
        path
    };
    // No token: the service will not start.
    let open = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["serve", "--config", with_tcp(None).to_str().unwrap(), "--state-dir", dir.path().join("s0").to_str().unwrap(), "--socket", dir.path().join("a0.sock").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!open.status.success());
    assert!(String::from_utf8_lossy(&open.stderr).contains("token_file"), "{}", String::from_utf8_lossy(&open.stderr));

    let service = Service::start(&with_tcp(Some(&token_file)), &dir.path().join("s1"), &dir.path().join("a1.sock"));
    let ask = |auth: Option<&str>| -> String {
        let mut stream = std::net::TcpStream::connect(("127.0.0.1", port as u16)).unwrap();
        let auth = auth.map(|a| format!("Authorization: Bearer {a}\r\n")).unwrap_or_default();
        write!(stream, "GET /status HTTP/1.1\r\nHost: laserd\r\n{auth}Connection: close\r\n\r\n").unwrap();
        let mut answer = String::new();
        stream.read_to_string(&mut answer).unwrap();
        answer
    };
    assert!(ask(None).starts_with("HTTP/1.1 401"), "no token: refused");
    assert!(ask(Some("0123456789abcdef-wrong!")).starts_with("HTTP/1.1 401"), "a wrong token: refused");
    let ok = ask(Some("0123456789abcdef-secret"));
    assert!(ok.starts_with("HTTP/1.1 200") && ok.contains("\"machine\""), "{ok}");
    // The Unix socket needs no token (its mode guards it).
    let api = Api::new(&service.socket);
    assert_eq!(api.status()["machine"]["connected"], false);
    drop(service);
}

#[test]
fn the_link_comes_back_after_an_unplug_nothing_moves_until_the_operator_resumes_and_a_faster_controller_is_refused() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyUSB");
    let sim = SimProcess::start(&tty, &["--pty"]);
    // Reports with `Bf:`: the executed line is known while a job runs.
    write_settings(&tty, &["$10=3"]);
    let config = config(dir.path(), &tty);
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
    let id = api.submit(&galvo("SC278C18.svg"));
    let total = api.wait_job(&id, "queued", Duration::from_secs(60))["lines_total"].as_u64().unwrap();
    api.ok(Method::POST, "/start", None);
    api.wait_status(Duration::from_secs(10), "a third sent", |s| s["job"]["line"].as_u64().unwrap_or(0) > total / 3);
    // The USB cable pulled: the device is gone mid-job.
    sim.kill();
    let job = api.wait_job(&id, "interrupted", Duration::from_secs(5));
    let last = job["last_executed_line"].as_u64().unwrap();
    assert!(last > 0 && last < total, "{job}");
    api.wait_status(Duration::from_secs(5), "disconnected", |s| s["machine"]["connected"] == false);
    let (status, _) = api.call(Method::POST, "/start", None);
    assert_eq!(status, 409, "nothing starts without a controller");

    // Plugged back in (a fresh controller at the same device path): the
    // service reconnects and re-syncs, and nothing moves.
    let sim = SimProcess::start(&tty, &["--pty"]);
    api.wait_status(Duration::from_secs(10), "reconnected", |s| s["machine"]["connected"] == true && machine_state(s) == "Idle");
    std::thread::sleep(Duration::from_millis(700));
    let s = api.status();
    assert!(s["job"].is_null() && machine_state(&s) == "Idle", "no motion on its own: {s}");
    assert!(s["machine"]["position"].as_array().unwrap().iter().all(|p| p.as_f64() == Some(0.0)), "{s}");
    assert_eq!(api.job(&id)["state"], "interrupted");

    // Resuming needs the operator's explicit word.
    let (status, refused) = api.call(Method::POST, &format!("/jobs/{id}/resume"), Some(serde_json::json!({}))); 
    assert_eq!(status, 409);
    assert!(refused["error"].as_str().unwrap().contains(&format!("line {}", last + 1)), "{refused}");
    let answer = api.ok(Method::POST, &format!("/jobs/{id}/resume"), Some(serde_json::json!({ "confirm": true })));
    assert!(answer["done"].as_str().unwrap().contains(&format!("resumed at line {}", last + 1)), "{answer}");
    let done = api.wait_job(&id, "completed", Duration::from_secs(30));
    assert_eq!(done["last_executed_line"].as_u64(), Some(total));
    sim.terminate();
    api.wait_status(Duration::from_secs(5), "disconnected", |s| s["machine"]["connected"] == false);

    // A controller that allows more than the config (a faster X axis): connected,
    // but jobs are refused, and the status says why.
    let text = std::fs::read_to_string(&config).unwrap().replace("max_velocity = 500.0", "max_velocity = 600.0");
    let faster = dir.path().join("faster.toml");
    std::fs::write(&faster, text).unwrap();
    let _sim = SimProcess::start(&tty, &["--pty", "--config", faster.to_str().unwrap()]);
    let s = api.wait_status(Duration::from_secs(10), "reconnected to the faster controller", |s| s["machine"]["connected"] == true);
    assert!(s["machine"]["message"].as_str().unwrap_or("").contains("$110=36000"), "{s}");
    let again = api.submit(&sample("one-field.svg"));
    api.wait_job(&again, "queued", Duration::from_secs(60));
    let (status, refused) = api.call(Method::POST, "/start", None);
    assert_eq!(status, 409);
    assert!(refused["error"].as_str().unwrap().contains("exceeds the config"), "{refused}");
    drop(service);
}

#[test]
fn under_systemd_it_reports_ready_pings_the_watchdog_and_stops_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    // systemd's side of Type=notify: a datagram socket named by NOTIFY_SOCKET.
    let notify = dir.path().join("notify.sock");
    let listener = std::os::unix::net::UnixDatagram::bind(&notify).unwrap();
    listener.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let config = config(dir.path(), &dir.path().join("ttyNONE"));
    let socket = dir.path().join("api.sock");
    let mut child = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["serve", "--config", config.to_str().unwrap(), "--state-dir", dir.path().join("state").to_str().unwrap(), "--socket", socket.to_str().unwrap()])
        .env("NOTIFY_SOCKET", &notify)
        .env("WATCHDOG_USEC", "400000")
        .spawn()
        .unwrap();
    let mut seen = Vec::new();
    let started = Instant::now();
    let mut buf = [0u8; 512];
    while seen.iter().filter(|m: &&String| m.contains("WATCHDOG=1")).count() < 3 {
        assert!(started.elapsed() < Duration::from_secs(10), "messages so far: {seen:?}");
        let n = listener.recv(&mut buf).expect("a notification");
        seen.push(String::from_utf8_lossy(&buf[..n]).to_string());
    }
    assert!(seen[0].contains("READY=1"), "ready first: {seen:?}");
    // Ready means the API answers.
    assert!(std::os::unix::net::UnixStream::connect(&socket).is_ok());
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), nix::sys::signal::Signal::SIGTERM).unwrap();
    assert!(child.wait().unwrap().success());
    let n = listener.recv(&mut buf).unwrap();
    let mut last = String::from_utf8_lossy(&buf[..n]).to_string();
    while !last.contains("STOPPING=1") {
        let n = listener.recv(&mut buf).expect("STOPPING=1 before exit");
        last = String::from_utf8_lossy(&buf[..n]).to_string();
    }
    assert!(!socket.exists(), "the socket is removed on a clean stop");
}

#[test]
fn sigterm_mid_job_stops_the_machine_safely_and_keeps_the_job_as_interrupted() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let (rig, service, api) = Rig::start(dir.path(), "ttyTERM");
    let id = api.submit(&galvo("SC278C18.svg"));
    let total = api.wait_job(&id, "queued", Duration::from_secs(60))["lines_total"].as_u64().unwrap();
    api.ok(Method::POST, "/start", None);
    api.wait_status(Duration::from_secs(10), "a third sent", |s| s["job"]["line"].as_u64().unwrap_or(0) > total / 3);
    // systemctl stop: SIGTERM, and the service waits for the safe stop.
    let stopped = Instant::now();
    assert!(service.terminate().success());
    assert!(stopped.elapsed() < Duration::from_secs(6));
    let (service, api) = rig.restart();
    let job = api.job(&id);
    assert_eq!(job["state"], "interrupted", "{job}");
    assert!(job["message"].as_str().unwrap().contains("stopped"), "{job}");
    // The controller was left standing, laser off, not in alarm.
    let s = api.wait_status(Duration::from_secs(10), "reconnected", |s| s["machine"]["connected"] == true);
    assert_eq!(machine_state(&s), "Idle", "{s}");
    assert_eq!(s["machine"]["laser"].as_f64(), Some(0.0));
    drop(service);
}

#[test]
fn jog_abort_home_unlock_and_a_job_held_or_aborted_on_its_way_to_its_start() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    // Homing on: the simulator seeks home at $25 = 500 mm/min.
    let (rig, service, api) = Rig::start_with(dir.path(), "ttyHOME", &["$22=1"]);
    let events = api.follow();
    let jog = |block: &str| api.ok(Method::POST, "/jog", Some(serde_json::json!({ "block": block })));
    let idle_at = |x: f64, y: f64| {
        api.wait_status(Duration::from_secs(10), &format!("Idle at X{x} Y{y}"), |s| {
            machine_state(s) == "Idle" && (position(s)[0] - x).abs() < 1e-3 && (position(s)[1] - y).abs() < 1e-3
        })
    };

    // A jog there, and a slow one cut short by an abort.
    jog("G90 X20 Y10 F6000");
    idle_at(20.0, 10.0);
    jog("G91 X200 F600");
    api.wait_status(Duration::from_secs(3), "jogging", |s| machine_state(s) == "Jog");
    let answer = api.ok(Method::POST, "/abort", None);
    assert!(answer["done"].as_str().unwrap().contains("jog cancelled"), "{answer}");
    let stopped = api.wait_status(Duration::from_secs(3), "the jog stopped", |s| machine_state(s) == "Idle");
    let x = position(&stopped)[0];
    assert!(x > 20.0 && x < 60.0, "stopped part way: {stopped}");

    // Homing, aborted part way: the answer says so, the controller is in
    // alarm and runs no job until unlocked.
    let socket = rig.socket.clone();
    let homing = std::thread::spawn(move || Api::new(&socket).call(Method::POST, "/home", None));
    api.wait_status(Duration::from_secs(3), "homing", |s| machine_state(s) == "Home");
    let (status, refused) = api.call(Method::POST, "/pause", None);
    assert_eq!(status, 409, "no hold while homing: {refused}");
    api.ok(Method::POST, "/abort", None);
    let (status, failed) = homing.join().unwrap();
    assert_eq!(status, 502, "{failed}");
    assert!(failed["error"].as_str().unwrap().contains("homing aborted"), "{failed}");
    api.wait_status(Duration::from_secs(5), "alarm after the aborted homing", |s| machine_state(s) == "Alarm");
    let job = api.submit(&sample("one-field.svg"));
    api.wait_job(&job, "queued", Duration::from_secs(60));
    let (status, refused) = api.call(Method::POST, "/start", None);
    assert_eq!(status, 409, "no job from an alarm: {refused}");
    api.ok(Method::POST, "/unlock", None);
    api.wait_status(Duration::from_secs(3), "unlocked", |s| machine_state(s) == "Idle");
    // Homing to the end: the call answers when the machine is home, at
    // Grbl's home (minus the pull-off, in its negative machine space); from
    // then on work coordinates are the bed's: its 0 is at machine -300, -300.
    jog("G90 X4 Y3 F6000");
    idle_at(4.0, 3.0);
    assert_eq!(api.ok(Method::POST, "/home", None)["done"], "homed");
    let home = idle_at(-1.0, -1.0);
    assert!(position(&home)[2..].iter().all(|p| p.abs() < 1e-3), "the scanner is not homed: {home}");

    // A job starts at the bed's origin: from elsewhere it is jogged there
    // first. A pause on the way cancels the jog; the resume goes on and runs the job.
    jog("G90 X290 Y290 F30000");
    idle_at(-10.0, -10.0);
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": job })));
    api.ok(Method::POST, "/pause", None);
    let held = api.wait_status(Duration::from_secs(3), "held on the way", |s| s["job"]["state"] == "paused" && machine_state(s) == "Idle");
    assert_eq!(held["job"]["line"], 0, "no program line sent yet: {held}");
    let x = position(&held)[0];
    assert!(x > -300.0 && x < -10.0, "stopped on the way: {held}");
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(position(&api.status()), position(&held), "standing still while paused");
    assert_eq!(api.status()["machine"]["laser"].as_f64(), Some(0.0));
    api.ok(Method::POST, "/resume", None);
    let done = api.wait_job(&job, "completed", Duration::from_secs(30));
    assert_eq!(done["last_executed_line"], done["lines_total"]);

    // An abort on the way ends the job before its first line.
    let second = api.submit(&sample("one-field.svg"));
    api.wait_job(&second, "queued", Duration::from_secs(60));
    jog("G90 X290 Y290 F30000");
    idle_at(-10.0, -10.0);
    api.ok(Method::POST, "/start", None);
    api.ok(Method::POST, "/abort", None);
    let aborted = api.wait_job(&second, "aborted", Duration::from_secs(5));
    assert_eq!(aborted["last_executed_line"], 0, "{aborted}");
    let stopped = api.wait_status(Duration::from_secs(3), "Idle, no job", |s| machine_state(s) == "Idle" && s["job"].is_null());
    assert!(position(&stopped)[0] > -300.0, "stopped on the way: {stopped}");
    assert_eq!(stopped["machine"]["laser"].as_f64(), Some(0.0));

    std::thread::sleep(Duration::from_millis(200));
    let events = events.lock().unwrap().clone();
    let mut states: Vec<&str> = events.iter().filter(|(k, v)| k == "job" && v["id"] == job).map(|(_, v)| v["state"].as_str().unwrap()).collect();
    states.dedup();
    assert_eq!(states, ["planning", "queued", "running", "paused", "running", "completed"]);
    assert!(events.iter().any(|(k, v)| k == "status" && v["machine"]["state"] == "Home"), "the homing cycle was shown");
    assert!(service.terminate().success());
}

#[test]
fn the_service_plans_a_cut_sheet_keeping_every_rule_and_records_the_count_and_the_override() {
    let dir = tempfile::tempdir().unwrap();
    // The shipped cutter, no controller: planning needs none.
    let config = dir.path().join("cutter.toml");
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml"), &config).unwrap();
    set_key(&config, "serial", "port", &format!("{:?}", dir.path().join("ttyNONE").to_str().unwrap()));
    set_key(&config, "cutting", "time_limit", "2.0");
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    let id = api.submit(&sample("nested-sheet.svg"));
    let job = api.wait_job(&id, "queued", Duration::from_secs(60));
    assert_eq!(job["precedence_violations"], 0, "{job}");
    assert_eq!(job["allow_precedence_violations"], false, "{job}");
    // The override is the submission's, kept in its record.
    let bytes = std::fs::read(sample("nested-sheet.svg")).unwrap();
    let answer = api
        .runtime
        .block_on(client::request(&service.socket, Method::POST, "/jobs?name=again.svg&allow_precedence_violations=true", Some(("application/octet-stream", bytes))))
        .unwrap();
    assert_eq!(answer.status, 202);
    let again: Value = serde_json::from_slice(&answer.body).unwrap();
    assert_eq!(again["allow_precedence_violations"], true, "{again}");
    let again = api.wait_job(again["id"].as_str().unwrap(), "queued", Duration::from_secs(60));
    assert_eq!(again["precedence_violations"], 0, "{again}");
}

/// A service recording carries the motion the controller reported: replayed,
/// it has knots, and its job time is the job's (the approach to the start
/// included, as the stream's time is).
#[test]
fn a_service_recording_replays_the_motion_the_controller_reported() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let (_rig, service, api) = Rig::start(dir.path(), "ttyLASER");
    let id = api.submit(&galvo("SC122C4.svg"));
    api.wait_job(&id, "queued", Duration::from_secs(60));
    api.ok(Method::POST, "/start", Some(serde_json::json!({ "id": id })));
    let done = api.wait_job(&id, "completed", Duration::from_secs(120));
    let path = dir.path().join("job.mcap");
    api.recording(&id, &path);
    let replay = laserd::record::read(&path).unwrap();
    let knots = &replay.log.knots;
    let streamed = done["stream_time_s"].as_f64().unwrap();
    assert!(streamed > 1.0, "{done}");
    // A knot per status report, at 5 Hz (some may go to the sender's own requests' gaps).
    assert!(knots.len() as f64 >= 2.5 * streamed, "{} knots in {streamed} s", knots.len());
    // The machine moved, as far as the job reaches.
    let reach = knots.iter().flat_map(|k| k.pos.iter().take(2)).fold(0.0f64, |m, p| m.max(p.abs()));
    assert!(reach > 1.0, "reached {reach} mm");
    let figures = laserd::figures::sim_figures(&replay.log);
    // Status reports come at 5 Hz: the first and last a fifth of a second
    // from the ends at most, and the job runs until its last answer.
    assert!((figures.job_time_s - streamed).abs() < 0.5 + 0.1 * streamed, "job time {} s, streamed {streamed} s", figures.job_time_s);
    assert!(service.terminate().success());
}

/// Issue 24: `laserd ctl` answers people in sentences, labelled lines and a
/// table (planned times as `4 min 3 s`), scripts with `--json` (the API's
/// objects as they are); `ctl jog X10` is a relative jog at `[service]
/// jog_feed`, while a full block goes as it is.
#[test]
fn ctl_answers_in_sentences_and_tables_or_json_and_jogs_axis_words_at_the_jog_feed() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyCTL");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let config = config_with_service(dir.path(), &tty, "jog_feed = 600");
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
    let socket = service.socket.to_str().unwrap().to_string();
    let ctl = |args: &[&str]| -> String {
        let out = Command::new(env!("CARGO_BIN_EXE_laserd")).args(["ctl", "--socket", &socket]).args(args).output().unwrap();
        assert!(out.status.success(), "ctl {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };

    let status = ctl(&["status"]);
    assert!(status.contains("Machine:   Idle (connected)") && status.contains("Job:       none running") && status.contains("Queue:     0 jobs waiting"), "{status}");
    assert!(serde_json::from_str::<Value>(&status).is_err(), "text, not JSON: {status}");
    let raw: Value = serde_json::from_str(&ctl(&["status", "--json"])).unwrap();
    assert_eq!(raw["machine"]["state"], "Idle", "{raw}");

    let file = sample("one-field.svg");
    let said = ctl(&["submit", file.to_str().unwrap()]);
    let id = said.strip_prefix("Submitted one-field.svg as job ").and_then(|r| r.split_whitespace().next()).unwrap_or_else(|| panic!("{said}")).to_string();
    assert!(id.starts_with('j') && said.contains(&format!("`laserd ctl job {id}`")), "{said}");
    let planned = api.wait_job(&id, "queued", Duration::from_secs(60))["planned_time_s"].as_f64().unwrap();
    let table = ctl(&["jobs"]);
    let header = table.lines().next().unwrap();
    assert!(header.starts_with("ID") && header.contains("PLANNED TIME"), "{table}");
    let row = table.lines().find(|l| l.starts_with(&id)).unwrap_or_else(|| panic!("{table}"));
    let human = laserd::daemon::ctl::human_duration(planned);
    assert!(row.contains("one-field.svg") && row.contains("queued") && row.contains(&human), "{human}:\n{table}");
    assert_eq!(row.find("queued"), header.find("STATE"), "aligned:\n{table}");
    let jobs: Value = serde_json::from_str(&ctl(&["--json", "jobs"])).unwrap();
    assert_eq!(jobs[0]["id"], id.as_str(), "{jobs}");
    assert_eq!(jobs[0]["planned_time_s"].as_f64(), Some(planned));
    let record = ctl(&["job", &id]);
    assert!(record.contains(&format!("Planned time:   {human}")), "{record}");

    // Axis words: G91 and the jog feed added; 10 mm at 600 mm/min take a second.
    let x0 = position(&api.status())[0];
    let asked = Instant::now();
    assert_eq!(ctl(&["jog", "X10"]).trim(), "Jogging: G91 X10 F600.");
    api.wait_status(Duration::from_secs(10), "Idle 10 mm on", |s| machine_state(s) == "Idle" && (position(s)[0] - x0 - 10.0).abs() < 1e-3);
    assert!(asked.elapsed() >= Duration::from_millis(990), "at 600 mm/min: {:?}", asked.elapsed());
    // A full block as it is.
    let done: Value = serde_json::from_str(&ctl(&["jog", "G91 X-10 F6000", "--json"])).unwrap();
    assert_eq!(done["done"], "jogging: G91 X-10 F6000", "{done}");
    api.wait_status(Duration::from_secs(10), "Idle back", |s| machine_state(s) == "Idle" && (position(s)[0] - x0).abs() < 1e-3);
    assert!(service.terminate().success());
}
