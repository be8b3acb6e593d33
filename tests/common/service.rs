//! `laserd serve` against `laserd sim --pty`, both as child processes, driven
//! through the API on the service's Unix socket (the library's client): the
//! rig the service tests share.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hyper::Method;
use laserd::daemon::client;
use serde_json::Value;

use super::SimProcess;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Real-time tests: one at a time, so that a loaded machine does not starve them.
pub fn take_turn() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

pub fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples").join(name)
}

pub fn galvo(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/galvo").join(name)
}

/// The shipped config with the serial port at `tty`.
pub fn config(dir: &Path, tty: &Path) -> PathBuf {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap();
    let text: String = text
        .lines()
        .map(|l| if l.starts_with("port = ") { format!("port = {:?}", tty.to_str().unwrap()) } else { l.to_string() })
        .collect::<Vec<_>>()
        .join("\n");
    let path = dir.join("laserd.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// `laserd serve` as a child process; killed when dropped.
pub struct Service {
    pub child: Child,
    pub socket: PathBuf,
}

impl Service {
    pub fn start(config: &Path, state: &Path, socket: &Path) -> Service {
        Service::launch(Command::new(env!("CARGO_BIN_EXE_laserd")), config, state, socket)
    }

    /// `laserd serve` run by `command`: laserd itself, or a wrapper whose
    /// arguments end in laserd's path.
    pub fn launch(mut command: Command, config: &Path, state: &Path, socket: &Path) -> Service {
        let child = command
            .args(["serve", "--config", config.to_str().unwrap(), "--state-dir", state.to_str().unwrap(), "--socket", socket.to_str().unwrap()])
            .stderr(Stdio::inherit())
            .spawn()
            .expect("laserd serve starts");
        let started = Instant::now();
        while std::os::unix::net::UnixStream::connect(socket).is_err() {
            assert!(started.elapsed() < Duration::from_secs(10), "the API socket appears");
            std::thread::sleep(Duration::from_millis(20));
        }
        Service { child, socket: socket.to_path_buf() }
    }

    pub fn terminate(mut self) -> std::process::ExitStatus {
        nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.child.id() as i32), nix::sys::signal::Signal::SIGTERM).unwrap();
        self.child.wait().unwrap()
    }

    pub fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub struct Api {
    pub socket: PathBuf,
    pub runtime: tokio::runtime::Runtime,
}

impl Api {
    pub fn new(socket: &Path) -> Api {
        Api { socket: socket.to_path_buf(), runtime: tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap() }
    }

    pub fn call(&self, method: Method, path: &str, body: Option<Value>) -> (u16, Value) {
        let body = body.map(|b| ("application/json", b.to_string().into_bytes()));
        let answer = self.runtime.block_on(client::request(&self.socket, method, path, body)).unwrap();
        (answer.status, serde_json::from_slice(&answer.body).unwrap_or(Value::Null))
    }

    pub fn ok(&self, method: Method, path: &str, body: Option<Value>) -> Value {
        let (status, value) = self.call(method, path, body);
        assert!((200..300).contains(&status), "{path}: {status} {value}");
        value
    }

    pub fn submit(&self, file: &Path) -> String {
        let bytes = std::fs::read(file).unwrap();
        let name = file.file_name().unwrap().to_str().unwrap();
        let answer = self.runtime.block_on(client::request(&self.socket, Method::POST, &format!("/jobs?name={name}"), Some(("application/octet-stream", bytes)))).unwrap();
        assert_eq!(answer.status, 202, "{}", String::from_utf8_lossy(&answer.body));
        let job: Value = serde_json::from_slice(&answer.body).unwrap();
        job["id"].as_str().unwrap().to_string()
    }

    pub fn status(&self) -> Value {
        self.ok(Method::GET, "/status", None)
    }

    /// A job's recording, downloaded through the API to `to`.
    pub fn recording(&self, id: &str, to: &Path) {
        let answer = self.runtime.block_on(client::request(&self.socket, Method::GET, &format!("/jobs/{id}/recording"), None)).unwrap();
        assert_eq!(answer.status, 200, "{id}: {}", String::from_utf8_lossy(&answer.body));
        std::fs::write(to, &answer.body).unwrap();
    }

    pub fn job(&self, id: &str) -> Value {
        self.ok(Method::GET, &format!("/jobs/{id}"), None)
    }

    /// Waits (up to `limit`) until `check` holds of the status.
    pub fn wait_status(&self, limit: Duration, what: &str, check: impl Fn(&Value) -> bool) -> Value {
        let started = Instant::now();
        loop {
            let s = self.status();
            if check(&s) {
                return s;
            }
            assert!(started.elapsed() < limit, "waited {limit:?} for {what}; status {s}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    pub fn wait_job(&self, id: &str, state: &str, limit: Duration) -> Value {
        let started = Instant::now();
        loop {
            let j = self.job(id);
            if j["state"] == state {
                return j;
            }
            assert!(started.elapsed() < limit, "waited {limit:?} for job {id} to be {state}: {j}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Collects every event of the live stream in the background.
    pub fn follow(&self) -> Arc<Mutex<Vec<(String, Value)>>> {
        let events = Arc::new(Mutex::new(Vec::new()));
        let (socket, sink) = (self.socket.clone(), events.clone());
        self.runtime.spawn(async move {
            let _ = client::follow_events(&socket, |kind, value| {
                sink.lock().unwrap().push((kind.to_string(), value.clone()));
                true
            })
            .await;
        });
        events
    }
}

/// A simulated controller at `dir/<tty>` and the service on it, connected.
pub struct Rig {
    pub sim: SimProcess,
    pub config: PathBuf,
    pub state: PathBuf,
    pub socket: PathBuf,
}

impl Rig {
    pub fn start(dir: &Path, tty: &str) -> (Rig, Service, Api) {
        Rig::start_with(dir, tty, &[])
    }

    /// With these controller settings (`$N=value`) written first, straight
    /// to the simulator, as a machine builder would have set the board up.
    pub fn start_with(dir: &Path, tty: &str, settings: &[&str]) -> (Rig, Service, Api) {
        let tty = dir.join(tty);
        let sim = SimProcess::start(&tty, &["--pty"]);
        write_settings(&tty, settings);
        let config = config(dir, &tty);
        let (state, socket) = (dir.join("state"), dir.join("api.sock"));
        let service = Service::start(&config, &state, &socket);
        let api = Api::new(&socket);
        api.wait_status(Duration::from_secs(10), "the controller link", |s| machine_state(s) == "Idle");
        (Rig { sim, config, state, socket }, service, api)
    }

    /// The service again, on the same state and socket.
    pub fn restart(&self) -> (Service, Api) {
        (Service::start(&self.config, &self.state, &self.socket), Api::new(&self.socket))
    }
}

pub fn write_settings(tty: &Path, settings: &[&str]) {
    use std::io::{BufRead, Write};
    if settings.is_empty() {
        return;
    }
    let mut port = std::fs::OpenOptions::new().read(true).write(true).open(tty).unwrap();
    let mut answers = std::io::BufReader::new(port.try_clone().unwrap());
    for setting in settings {
        port.write_all(format!("{setting}\n").as_bytes()).unwrap();
        let mut line = String::new();
        while line.trim() != "ok" {
            line.clear();
            answers.read_line(&mut line).unwrap();
            assert!(!line.starts_with("error"), "{setting}: {line}");
        }
    }
}

pub fn position(s: &Value) -> Vec<f64> {
    s["machine"]["position"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
}

pub fn machine_state(s: &Value) -> &str {
    s["machine"]["state"].as_str().unwrap_or("")
}


/// The shipped config with the serial port at `tty` and these `key = value`
/// lines set in its `[service]` section.
pub fn config_with_service(dir: &Path, tty: &Path, service: &str) -> PathBuf {
    let path = config(dir, tty);
    for line in service.lines() {
        let (key, value) = line.split_once(" = ").unwrap();
        set_key(&path, "service", key, value);
    }
    path
}

/// Sets `key = value` in `[section]` of a config file (replaced where the
/// key is set, else added at the section's start).
pub fn set_key(config: &Path, section: &str, key: &str, value: &str) {
    let text = std::fs::read_to_string(config).unwrap();
    let mut out = Vec::new();
    let (mut inside, mut done) = (false, false);
    for line in text.lines() {
        if line.starts_with('[') {
            if inside && !done {
                panic!("[{section}] has no {key}");
            }
            inside = line.trim() == format!("[{section}]");
            if inside {
                out.push(line.to_string());
                out.push(format!("{key} = {value}"));
                done = true;
                continue;
            }
        }
        if inside && line.starts_with(&format!("{key} = ")) {
            continue;
        }
        out.push(line.to_string());
    }
    assert!(done, "the config has a [{section}] section");
    std::fs::write(config, out.join("\n")).unwrap();
}
