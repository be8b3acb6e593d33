//! The service against hostile and careless clients, uploads and disks:
//! `laserd serve` and `laserd sim --pty` as child processes, driven through
//! the API. Each test is one finding of the hardening review (issue 16).

mod common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::service::*;
use common::SimProcess;
use hyper::Method;
use laserd::daemon::client;
use serde_json::{json, Value};

/// Uploads `bytes` as `name`: the answer's status and JSON body.
fn upload(api: &Api, name: &str, bytes: &[u8]) -> (u16, Value) {
    let answer = api.runtime.block_on(client::request(&api.socket, Method::POST, &format!("/jobs?name={name}"), Some(("application/octet-stream", bytes.to_vec())))).unwrap();
    (answer.status, serde_json::from_slice(&answer.body).unwrap_or(Value::Null))
}

/// A raw request: status and body as JSON (`Null` if it is not JSON).
fn raw(api: &Api, method: Method, path: &str, body: Option<(&str, Vec<u8>)>) -> (u16, Value) {
    let answer = api.runtime.block_on(client::request(&api.socket, method, path, body)).unwrap();
    (answer.status, serde_json::from_slice(&answer.body).unwrap_or(Value::Null))
}

/// Waits until the job has left `planning`; its record.
fn planned(api: &Api, id: &str, limit: Duration) -> Value {
    let started = Instant::now();
    loop {
        let job = api.job(id);
        if job["state"] != "planning" {
            return job;
        }
        assert!(started.elapsed() < limit, "job {id} still planning after {limit:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `laserd plan-job` children of the service still alive.
fn planning_children(service: &Service) -> usize {
    let parent = service.child.id().to_string();
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter(|e| {
            let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
            let cmdline = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
            // Field 4 of stat is the parent's pid (after the name in parentheses).
            let ppid = stat.rsplit_once(") ").and_then(|(_, rest)| rest.split(' ').nth(1)).unwrap_or("");
            ppid == parent && String::from_utf8_lossy(&cmdline).contains("plan-job")
        })
        .count()
}

/// A job that plans for about ten seconds and takes some 400 MB: 400
/// circles flattened and programmed to 0.1 µm (`fine_tolerance`).
fn slow_job() -> Vec<u8> {
    let mut svg = String::from(r#"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300">"#);
    for i in 0..400 {
        let (x, y) = (40.0 + (i * 37 % 220) as f64, 40.0 + (i * 53 % 220) as f64);
        svg.push_str(&format!(r#"<circle cx="{x}" cy="{y}" r="{}" stroke="black" fill="none"/>"#, 20 + i % 15));
    }
    svg.push_str("</svg>");
    svg.into_bytes()
}

fn fine_tolerance(config: &Path) {
    set_key(config, "import", "tolerance", "0.0001");
    set_key(config, "program", "tolerance", "0.0001");
}

/// Finding 1: a path named in a request was read whatever it was (`/etc/shadow`,
/// the token file) and its bytes came back as the job's "program".
#[test]
fn submit_by_path_is_off_by_default_and_reads_only_job_files_inside_the_job_folders() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let (rig, service, api) = Rig::start(dir.path(), "ttyLASER");
    let by_path = |api: &Api, path: &Path| api.call(Method::POST, "/jobs", Some(json!({ "path": path })));
    let (status, body) = by_path(&api, Path::new("/etc/passwd"));
    assert_eq!(status, 403, "{body}");
    assert!(body["error"].as_str().unwrap().contains("job_folders"), "{body}");
    drop(service);

    // With a job folder: only job files inside it.
    let jobs = dir.path().join("jobs");
    std::fs::create_dir(&jobs).unwrap();
    let secret = dir.path().join("token");
    std::fs::write(&secret, "0123456789abcdef0123\n").unwrap();
    std::os::unix::fs::symlink(&secret, jobs.join("token.nc")).unwrap();
    std::os::unix::fs::symlink("/etc/passwd", jobs.join("passwd.nc")).unwrap();
    std::fs::copy("/etc/passwd", jobs.join("passwd")).unwrap();
    std::fs::copy("/etc/passwd", jobs.join("users.nc")).unwrap();
    std::fs::copy(sample("one-field.svg"), jobs.join("part.svg")).unwrap();
    let config = config_with_service(dir.path(), &dir.path().join("ttyLASER"), &format!("job_folders = [{:?}]", jobs.to_str().unwrap()));
    let service = Service::start(&config, &rig.state, &rig.socket);
    let api = Api::new(&service.socket);
    for outside in [PathBuf::from("/etc/shadow"), jobs.join("token.nc"), jobs.join("passwd.nc"), jobs.join("../token")] {
        let (status, body) = by_path(&api, &outside);
        assert_eq!(status, 403, "{}: {body}", outside.display());
    }
    let (status, body) = by_path(&api, &jobs.join("passwd"));
    assert_eq!(status, 400, "an extension-less file is no job: {body}");
    // Named as G-code but not G-code: checked as the controller would parse it.
    let (status, body) = by_path(&api, &jobs.join("users.nc"));
    assert_eq!(status, 202, "{body}");
    let id = body["id"].as_str().unwrap();
    let job = planned(&api, id, Duration::from_secs(30));
    assert_eq!(job["state"], "failed", "{job}");
    assert!(job["message"].as_str().unwrap().contains("users.nc:1"), "names the line: {job}");
    let (status, body) = raw(&api, Method::GET, &format!("/jobs/{id}/program"), None);
    assert_eq!(status, 404, "no program from a file that failed its check: {body}");
    // A real job inside the folder plans, and its program is laserd's.
    let (status, body) = by_path(&api, &jobs.join("part.svg"));
    assert_eq!(status, 202, "{body}");
    let id = body["id"].as_str().unwrap();
    assert_eq!(planned(&api, id, Duration::from_secs(60))["state"], "queued");
    let answer = api.runtime.block_on(client::request(&api.socket, Method::GET, &format!("/jobs/{id}/program"), None)).unwrap();
    assert_eq!(answer.status, 200);
    assert!(answer.body.starts_with(b"G21"), "the planned program");
}

/// Finding 2: a job whose planning cannot end (or takes the memory) took
/// the planning thread, and `DELETE` did not stop it.
#[test]
fn planning_is_bounded_in_time_and_memory_and_delete_cancels_it() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyLASER");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let config = config_with_service(dir.path(), &tty, "plan_timeout = 1.5\nplan_memory_mb = 8192");
    fine_tolerance(&config);
    let (state, socket) = (dir.path().join("state"), dir.path().join("api.sock"));
    let service = Service::start(&config, &state, &socket);
    let api = Api::new(&socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| s["machine"]["connected"] == true);

    let (status, body) = upload(&api, "slow.svg", &slow_job());
    assert_eq!(status, 202, "{body}");
    let started = Instant::now();
    let job = planned(&api, body["id"].as_str().unwrap(), Duration::from_secs(20));
    assert_eq!(job["state"], "failed", "{job}");
    assert!(job["message"].as_str().unwrap().contains("plan_timeout"), "{job}");
    assert!(started.elapsed() < Duration::from_secs(6), "stopped at its time limit: {:?}", started.elapsed());
    assert_eq!(planning_children(&service), 0, "the planning process is gone");
    drop(service);

    // Memory: the same job under a limit below what it needs.
    let config = config_with_service(dir.path(), &tty, "plan_memory_mb = 256");
    fine_tolerance(&config);
    let service = Service::start(&config, &state, &socket);
    let api = Api::new(&socket);
    let (_, body) = upload(&api, "big.svg", &slow_job());
    let job = planned(&api, body["id"].as_str().unwrap(), Duration::from_secs(120));
    assert_eq!(job["state"], "failed", "{job}");
    assert!(job["message"].as_str().unwrap().contains("plan_memory_mb"), "{job}");
    assert_eq!(api.status()["machine"]["connected"], true, "the service and its link go on");

    // Cancel: deleting a job being planned stops its planning at once, and
    // the next job plans.
    let (_, body) = upload(&api, "slow.svg", &slow_job());
    let slow = body["id"].as_str().unwrap().to_string();
    let (_, body) = upload(&api, "one-field.svg", &std::fs::read(sample("one-field.svg")).unwrap());
    let next = body["id"].as_str().unwrap().to_string();
    let started = Instant::now();
    while planning_children(&service) == 0 {
        assert!(started.elapsed() < Duration::from_secs(10), "planning starts");
        std::thread::sleep(Duration::from_millis(10));
    }
    api.ok(Method::DELETE, &format!("/jobs/{slow}"), None);
    let (status, _) = api.call(Method::GET, &format!("/jobs/{slow}"), None);
    assert_eq!(status, 404);
    assert_eq!(planned(&api, &next, Duration::from_secs(8))["state"], "queued", "the next job plans, not after the deleted one's ten seconds");
}

/// Finding 6: a resume at a line the job does not have answered 409 but
/// left the job `running`, and nothing could move it after.
#[test]
fn a_refused_resume_changes_nothing() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let id = {
        // A job cut short at line 1 of 3, as a restart finds it.
        let mut store = laserd::daemon::queue::Store::open(&state).unwrap();
        let id = store.add("part.nc", b"G21 G90\nG1 X1 F600\nG1 X2\n", false).unwrap().id;
        std::fs::write(store.program_path(&id), "G21 G90\nG1 X1 F600\nG1 X2\n").unwrap();
        store
            .update(&id, |j| {
                j.state = laserd::daemon::queue::JobState::Running;
                j.lines_total = 3;
                j.last_executed_line = Some(1);
            })
            .unwrap();
        id
    };
    let tty = dir.path().join("ttyLASER");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let config = config(dir.path(), &tty);
    let service = Service::start(&config, &state, &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
    assert_eq!(api.job(&id)["state"], "interrupted");
    for from in [99_999_999u64, 0, 4] {
        let (status, body) = api.call(Method::POST, &format!("/jobs/{id}/resume"), Some(json!({ "confirm": true, "from": from })));
        assert_eq!(status, 409, "from {from}: {body}");
        assert!(body["error"].as_str().unwrap().contains("3 lines"), "{body}");
        assert_eq!(api.job(&id)["state"], "interrupted", "unchanged after the refusal");
    }
    api.ok(Method::DELETE, &format!("/jobs/{id}"), None);
}

/// Finding 14: errors axum gives itself (body too large, wrong content type,
/// wrong shape, unknown call) were plain text; the API promises JSON.
#[test]
fn every_error_of_the_api_is_json() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyLASER");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let config = config(dir.path(), &tty);
    set_key(&config, "import", "max_file_mb", "0.01");
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    let (_, job) = upload(&api, "part.nc", b"G21\nG1 X1 F600\n");
    let id = job["id"].as_str().unwrap().to_string();
    let move_path = format!("/jobs/{id}/move");
    // (expected code, method, path, body)
    type Case<'a> = (u16, Method, String, Option<(&'a str, Vec<u8>)>);
    let cases: Vec<Case> = vec![
        (413, Method::POST, "/jobs?name=big.nc".into(), Some(("application/octet-stream", vec![b'G'; 20_000]))),
        (415, Method::POST, move_path.clone(), Some(("text/plain", b"{\"position\": 0}".to_vec()))),
        (422, Method::POST, move_path.clone(), Some(("application/json", b"{\"position\": \"first\"}".to_vec()))),
        (400, Method::POST, move_path, Some(("application/json", b"{\"position\": ".to_vec()))),
        (400, Method::POST, "/jobs?name=part.step".into(), Some(("application/octet-stream", b"ISO-10303-21;\n".to_vec()))),
        (404, Method::GET, "/no/such/call".into(), None),
        (405, Method::GET, "/start".into(), None),
    ];
    for (code, method, path, body) in cases {
        let (status, answer) = raw(&api, method, &path, body);
        assert_eq!(status, code, "{path}: {answer}");
        assert!(answer["error"].as_str().is_some_and(|e| !e.is_empty()), "{path} {code}: JSON error, got {answer}");
    }
}

/// A mount namespace of its own holding a small tmpfs at `state`: a disk
/// that fills up. Services run inside it through `nsenter`; the test sees
/// its files through `/proc/<holder>/root`.
struct SmallDisk {
    holder: Child,
    state: PathBuf,
}

impl SmallDisk {
    fn new(state: &Path, size: &str) -> SmallDisk {
        std::fs::create_dir_all(state).unwrap();
        let script = format!("mount -t tmpfs -o size={size} tmpfs '{}' && echo ready && exec sleep 3600", state.display());
        let mut holder = Command::new("unshare")
            .args(["--user", "--map-root-user", "--mount", "--propagation", "private", "sh", "-c", &script])
            .stdout(Stdio::piped())
            .spawn()
            .expect("unshare (util-linux) runs");
        let mut line = String::new();
        std::io::BufRead::read_line(&mut std::io::BufReader::new(holder.stdout.take().unwrap()), &mut line).unwrap();
        assert_eq!(line.trim(), "ready", "a user and mount namespace with a tmpfs (needs user namespaces)");
        SmallDisk { holder, state: state.to_path_buf() }
    }

    /// laserd run inside the namespace (its arguments to follow).
    fn command(&self) -> Command {
        let mut c = Command::new("nsenter");
        c.args(["-t", &self.holder.id().to_string(), "--user", "--mount", "--preserve-credentials", "--", env!("CARGO_BIN_EXE_laserd")]);
        c
    }

    /// `path` under the state folder, as seen from outside the namespace.
    fn seen(&self, path: &str) -> PathBuf {
        PathBuf::from(format!("/proc/{}/root{}/{path}", self.holder.id(), self.state.display()))
    }

    /// Fills the disk to the last byte.
    fn fill(&self) {
        let mut filler = std::fs::File::create(self.seen("filler")).unwrap();
        let block = vec![0u8; 4096];
        while filler.write_all(&block).is_ok() {}
        let _ = filler.write_all(&[0]);
    }

    fn free(&self) {
        std::fs::remove_file(self.seen("filler")).unwrap();
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = self.holder.kill();
        let _ = self.holder.wait();
    }
}

/// Finding 5: with the state folder full, the recording was cut short with
/// only a log line, the final record was lost and logged as a lost link,
/// the status showed the job running at 100 % on an Idle machine, and after
/// a restart the job offered to resume 1,220 lines before its end.
#[test]
fn a_full_disk_mid_job_is_a_storage_error_and_loses_no_progress() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let disk = SmallDisk::new(&dir.path().join("state"), "3M");
    let tty = dir.path().join("ttyLASER");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let config = config(dir.path(), &tty);
    let socket = dir.path().join("api.sock");
    let service = Service::launch(disk.command(), &config, &disk.state, &socket);
    let api = Api::new(&socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
    let id = api.submit(&sample("marking-300.svg"));
    let lines = api.wait_job(&id, "queued", Duration::from_secs(60))["lines_total"].as_u64().unwrap();
    api.ok(Method::POST, "/start", Some(json!({ "id": id })));
    api.wait_job(&id, "running", Duration::from_secs(10));
    api.wait_status(Duration::from_secs(30), "the first lines", |s| s["job"]["line"].as_u64().unwrap_or(0) > 0);
    disk.fill();

    // The job runs to its end; the disk's state is on the status.
    let full = api.wait_status(Duration::from_secs(15), "the full disk on the status", |s| s["storage"].is_string());
    assert!(full["storage"].as_str().unwrap().contains("No space left"), "{full}");
    let job = api.wait_job(&id, "completed", Duration::from_secs(120));
    assert_eq!((job["last_executed_line"].as_u64(), job["last_acked_line"].as_u64()), (Some(lines), Some(lines)));
    assert!(job["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("recording is cut short")), "{job}");
    let status = api.status();
    assert_eq!((status["job"].clone(), machine_state(&status)), (Value::Null, "Idle"), "no job shown running on an idle machine: {status}");
    assert_eq!(status["machine"]["connected"], true, "a storage error is not a lost link");

    // A crash while the disk is still full: the job comes back completed,
    // not offered for a resume that would mark lines twice.
    service.kill();
    let service = Service::launch(disk.command(), &config, &disk.state, &socket);
    let api = Api::new(&socket);
    let job = api.job(&id);
    assert_eq!((job["state"].as_str(), job["last_executed_line"].as_u64()), (Some("completed"), Some(lines)), "{job}");
    assert!(api.status()["storage"].is_string(), "still full");
    // Space again: the records are written, the status clears.
    disk.free();
    api.wait_status(Duration::from_secs(10), "the storage error to clear", |s| s["storage"].is_null());
    let on_disk: Value = serde_json::from_slice(&std::fs::read(disk.seen(&format!("jobs/{id}/job.json"))).unwrap()).unwrap();
    assert_eq!(on_disk["state"], "completed");
    drop(service);
}

/// Acceptance: a stream of random uploads (valid, truncated, hostile) leaves
/// the controller link up and ends every job `queued` or `failed` with a
/// message. `LASERD_UPLOADS` sets how many (default 200; the issue's bar is
/// 1,000).
#[test]
fn a_stream_of_random_uploads_leaves_the_link_up_and_every_job_planned_or_failed() {
    use rand::{Rng, SeedableRng};
    let _turn = take_turn();
    let count: usize = std::env::var("LASERD_UPLOADS").ok().and_then(|v| v.parse().ok()).unwrap_or(200);
    let dir = tempfile::tempdir().unwrap();
    let tty = dir.path().join("ttyLASER");
    let _sim = SimProcess::start(&tty, &["--pty"]);
    let config = config_with_service(dir.path(), &tty, "plan_timeout = 60\nplan_memory_mb = 2048\nkeep_jobs = 10000");
    set_key(&config, "import", "max_file_mb", "1");
    let service = Service::start(&config, &dir.path().join("state"), &dir.path().join("api.sock"));
    let api = Api::new(&service.socket);
    api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");

    let mut valid: Vec<(String, Vec<u8>)> = ["one-field.svg", "nested-sheet.svg"].iter().map(|n| (n.to_string(), std::fs::read(sample(n)).unwrap())).collect();
    valid.extend(["SC32C2.svg", "SC110C2.svg"].iter().map(|n| (n.to_string(), std::fs::read(galvo(n)).unwrap())));
    valid.push(("part.nc".into(), b"G21 G90\nG1 X10 Y10 F600 M4 S100\nG1 X20\nM5\n".to_vec()));
    let doc = |body: &str| format!(r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">{body}</svg>"#).into_bytes();
    let hostile: Vec<(&str, Vec<u8>)> = vec![
        ("arc.svg", doc(r#"<path d="M 10 10 A 2.5 2.5 0 0 1 1e38 10" stroke="black"/>"#)),
        ("nan.svg", doc(r#"<path d="M 10 10 L NaN 5" stroke="black"/>"#)),
        ("huge.svg", doc(r#"<path d="M 1e308 10 L 20 20" stroke="black"/>"#)),
        ("zero.svg", doc(r#"<image href="/dev/zero" width="10" height="10"/><path d="M 0 0 L 9 9" stroke="black"/>"#)),
        ("port.svg", doc(&format!(r#"<image href="{}" width="10" height="10"/><path d="M 0 0 L 9 9" stroke="black"/>"#, tty.display()))),
        ("bomb.svg", format!(r#"<?xml version="1.0"?><!DOCTYPE svg [<!ENTITY a "{}"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;"><!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;"><!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">]><svg xmlns="http://www.w3.org/2000/svg"><desc>&d;&d;&d;&d;&d;&d;</desc></svg>"#, "x".repeat(100)).into_bytes()),
        ("deep.svg", format!(r#"<svg xmlns="http://www.w3.org/2000/svg">{}{}</svg>"#, "<g>".repeat(5000), "</g>".repeat(5000)).into_bytes()),
        ("many.svg", doc(&r#"<path d="M 1 1 L 2 2" stroke="black"/>"#.repeat(30000))),
        ("reset.nc", b"G21\n$RST=*\n".to_vec()),
        ("long.nc", format!("G1 X{}\n", "1".repeat(100_000)).into_bytes()),
        ("binary.nc", (0..=255u8).cycle().take(5000).collect()),
        ("big.svg", vec![b' '; 1_500_000]),
        ("noext", b"G0 X1\n".to_vec()),
        ("../escape.svg", doc(r#"<path d="M 0 0 L 9 9" stroke="black"/>"#)),
    ];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
    let mut accepted = Vec::new();
    let mut refused = 0;
    for _ in 0..count {
        let (name, bytes) = match rng.random_range(0..3) {
            0 => valid[rng.random_range(0..valid.len())].clone(),
            1 => {
                let (name, bytes) = &valid[rng.random_range(0..valid.len())];
                let cut = rng.random_range(0..bytes.len());
                (name.clone(), bytes[..cut].to_vec())
            }
            _ => {
                let (name, bytes) = &hostile[rng.random_range(0..hostile.len())];
                let mut bytes = bytes.clone();
                // Now and then a byte flipped as well.
                if rng.random_bool(0.3) && !bytes.is_empty() {
                    let at = rng.random_range(0..bytes.len());
                    bytes[at] = rng.random();
                }
                (name.to_string(), bytes)
            }
        };
        if bytes.len() > 1_000_000 {
            // Refused before the body is read: the client may not even get
            // to the answer before the service closes the connection.
            let answer = api.runtime.block_on(client::request(&api.socket, Method::POST, &format!("/jobs?name={name}"), Some(("application/octet-stream", bytes))));
            assert!(answer.as_ref().map_or(true, |a| a.status == 413), "{name}: over the size limit");
            refused += 1;
            continue;
        }
        let (status, body) = upload(&api, &name, &bytes);
        match status {
            202 => accepted.push(body["id"].as_str().unwrap().to_string()),
            400 | 403 | 413 => {
                refused += 1;
                assert!(body["error"].as_str().is_some_and(|e| !e.is_empty()), "{name}: {status} {body}");
            }
            other => panic!("{name}: unexpected {other} {body}"),
        }
    }
    let mut failed = 0;
    for id in &accepted {
        let job = planned(&api, id, Duration::from_secs(120));
        match job["state"].as_str().unwrap() {
            "queued" => {}
            "failed" => {
                failed += 1;
                assert!(job["message"].as_str().is_some_and(|m| !m.is_empty()), "{job}");
            }
            other => panic!("job {id} ended {other}: {job}"),
        }
    }
    eprintln!("{count} uploads: {} accepted ({failed} failed planning), {refused} refused", accepted.len());
    let status = api.status();
    assert_eq!((status["machine"]["connected"].clone(), machine_state(&status)), (Value::Bool(true), "Idle"), "the link stayed up: {status}");
    assert_eq!(planning_children(&service), 0);
}
