//! A hostile controller on a pseudo-terminal against the real `laserd send`:
//! a scripted peer that behaves like Grbl for the first lines of a job and
//! then babbles garbage, answers `ok` twice, reports `Run` forever, floods
//! bytes without a line end, or hangs up. Each time the sender must end within
//! a bounded time, exit non-zero, stop the machine where the link is still up
//! (feed hold `!`, then soft reset 0x18: the laser goes off) and name the last
//! executed line.

use std::fs::File;
use std::io::{ErrorKind, Read, Write};
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nix::fcntl::{fcntl, FcntlArg, FdFlag, OFlag};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

/// Program lines answered as Grbl would before the peer turns hostile.
/// (Enough for several status reports, at 5 Hz, to tell what ran before.)
const HONEST_LINES: usize = 30;

/// What the peer does from program line `HONEST_LINES + 1` on.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Hostile {
    /// Binary garbage in place of every answer and status report.
    Garbage,
    /// Two `ok` for every line.
    TooManyOk,
    /// Every line acknowledged, then `<Run|…>` forever, nothing moving.
    RunForever,
    /// Bytes without a line end, as fast as the link takes them.
    Flood,
    /// The device closes.
    Disconnect,
}

const BANNER: &[u8] = b"\r\nGrbl 1.1h ['$' for help]\r\n";
const GARBAGE: &[u8] = b"\x07\xff\xfe#~<garbage|\x00>~#\r\n";

/// The peer's side of the pseudo-terminal and what it got.
struct Peer {
    master: File,
    hostile: Hostile,
    /// Program lines received, not yet answered (answered one per tick: a
    /// controller that takes its time, so status reports come in between).
    queued: Vec<String>,
    lines: usize,
    /// Whether it has turned hostile, and every byte received since.
    turned: bool,
    after: Vec<u8>,
    line: Vec<u8>,
}

impl Peer {
    fn write(&mut self, bytes: &[u8]) -> bool {
        let mut rest = bytes;
        while !rest.is_empty() {
            match self.master.write(rest) {
                Ok(n) => rest = &rest[n..],
                Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(1)),
                Err(_) => return false,
            }
        }
        true
    }

    fn report(&self) -> &'static [u8] {
        match (self.turned, self.hostile) {
            (true, Hostile::Garbage) => GARBAGE,
            (true, Hostile::RunForever) => b"<Run|MPos:1.000,2.000,0.000|Bf:14,128|FS:600,0>\r\n",
            _ if self.queued.is_empty() && self.lines == 0 => b"<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>\r\n",
            _ => b"<Run|MPos:0.000,0.000,0.000|Bf:15,128|FS:600,0>\r\n",
        }
    }

    fn receive(&mut self, bytes: &[u8]) {
        if self.turned {
            self.after.extend_from_slice(bytes);
        }
        for &b in bytes {
            match b {
                b'?' => {
                    let report = self.report();
                    self.write(report);
                }
                0x18 => {
                    self.queued.clear();
                    self.write(BANNER);
                }
                b'\n' => {
                    let text = String::from_utf8_lossy(&std::mem::take(&mut self.line)).to_string();
                    // The sender's own commands before the job (build info,
                    // then the work coordinates: settings, offsets, G54) are
                    // answered at once, as an idle Grbl not homed would.
                    match text.as_str() {
                        "$I" => self.write(b"[VER:1.1h:]\r\n[OPT:V,15,128]\r\nok\r\n"),
                        "$$" => self.write(b"$22=0\r\n$23=0\r\nok\r\n"),
                        "$#" => self.write(b"[G54:0.000,0.000,0.000]\r\n[G92:0.000,0.000,0.000]\r\nok\r\n"),
                        "G54G92.1" => self.write(b"ok\r\n"),
                        _ => {
                            self.queued.push(text);
                            true
                        }
                    };
                }
                b if !(0x20..0x7f).contains(&b) || b == b'!' || b == b'~' => {}
                b => self.line.push(b),
            }
        }
    }

    /// Answers the oldest line; `false` once it has hung up.
    fn answer_one(&mut self) -> bool {
        if self.turned && self.hostile == Hostile::Flood {
            let _ = self.master.write(&[b'A'; 4096]);
        }
        if self.queued.is_empty() {
            return true;
        }
        self.queued.remove(0);
        self.lines += 1;
        let hostile = self.lines > HONEST_LINES;
        if hostile && !self.turned {
            self.turned = true;
        }
        match (hostile, self.hostile) {
            (true, Hostile::Disconnect) => return false,
            (true, Hostile::Garbage) => {
                self.write(GARBAGE);
            }
            (true, Hostile::TooManyOk) => {
                self.write(b"ok\r\nok\r\n");
            }
            (true, Hostile::Flood) => {}
            _ => {
                self.write(b"ok\r\n");
            }
        }
        true
    }
}

/// A raw pseudo-terminal: the master (non-blocking), the slave kept open
/// (so the master never reads EIO before the client opens it), the slave's path.
fn open_pty() -> (File, OwnedFd, PathBuf) {
    let pty = nix::pty::openpty(None, None).unwrap();
    let mut tio = tcgetattr(&pty.slave).unwrap();
    cfmakeraw(&mut tio);
    tcsetattr(&pty.slave, SetArg::TCSANOW, &tio).unwrap();
    // Not inherited by `laserd`: a hang-up must close the device for good.
    for fd in [&pty.master, &pty.slave] {
        fcntl(fd, FcntlArg::F_SETFD(FdFlag::FD_CLOEXEC)).unwrap();
    }
    let flags = OFlag::from_bits_truncate(fcntl(&pty.master, FcntlArg::F_GETFL).unwrap());
    fcntl(&pty.master, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK)).unwrap();
    let path = nix::unistd::ttyname(&pty.slave).unwrap();
    (File::from(pty.master), pty.slave, path)
}

/// Runs the peer until `stop`; the bytes it got after turning hostile.
fn serve(master: File, slave: OwnedFd, hostile: Hostile, stop: Arc<AtomicBool>) -> Vec<u8> {
    let mut peer = Peer { master, hostile, queued: Vec::new(), lines: 0, turned: false, after: Vec::new(), line: Vec::new() };
    let mut buf = [0u8; 4096];
    let mut next_answer = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        match peer.master.read(&mut buf) {
            Ok(n) if n > 0 => peer.receive(&buf[..n]),
            Ok(_) => {}
            Err(e) if e.kind() == ErrorKind::WouldBlock || e.kind() == ErrorKind::Interrupted => {}
            // EIO: nobody has the port open at the moment.
            Err(_) => {}
        }
        if Instant::now() >= next_answer {
            next_answer = Instant::now() + Duration::from_millis(30);
            if !peer.answer_one() {
                // Hang up: both ends of the device go away.
                drop(slave);
                return peer.after;
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    peer.after
}

/// A job of straight moves, 2 mm each: more than a step of any machine, so
/// each surely makes a planner block (the sender does not read `$$` here).
fn job(dir: &Path) -> PathBuf {
    let file = dir.join("job.nc");
    let mut text = String::from("G21G90\n");
    for i in 1..=60 {
        text.push_str(&format!("G1X{}.000F600\n", 2 * i));
    }
    std::fs::write(&file, text).unwrap();
    file
}

/// `laserd send FILE --port PTY` against a peer; its output and the bytes
/// the peer got after turning hostile. Killed (and the test failed) when it
/// runs over `limit`.
fn send_against(hostile: Hostile, file: &Path, limit: Duration) -> (Output, Vec<u8>) {
    let (master, slave, path) = open_pty();
    let stop = Arc::new(AtomicBool::new(false));
    let peer = {
        let stop = stop.clone();
        std::thread::spawn(move || serve(master, slave, hostile, stop))
    };
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml");
    let mut child = Command::new(env!("CARGO_BIN_EXE_laserd"))
        .args(["send", file.to_str().unwrap(), "--port", path.to_str().unwrap(), "--config", config.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("laserd runs");
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            stop.store(true, Ordering::Relaxed);
            panic!("{hostile:?}: `laserd send` still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    stop.store(true, Ordering::Relaxed);
    (out, peer.join().unwrap())
}

/// The common verdict: non-zero, no panic, the machine stopped where the
/// link is up, the last executed line named. The error line.
fn assert_stopped_safely(hostile: Hostile, out: &Output, after: &[u8]) -> String {
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "{hostile:?}: exits non-zero: {err}");
    assert!(!err.contains("panicked"), "{hostile:?}: {err}");
    if hostile != Hostile::Disconnect {
        assert!(after.contains(&b'!'), "{hostile:?}: feed hold sent: {err}");
        assert!(after.contains(&0x18), "{hostile:?}: soft reset sent: {err}");
    }
    let named = err.split("last executed (a lower bound): ").nth(1).unwrap_or("");
    assert!(named.contains("job.nc:"), "{hostile:?}: names the last executed line: {err}");
    err
}

fn run_case(hostile: Hostile, limit: Duration) -> String {
    let dir = tempfile::tempdir().unwrap();
    let file = job(dir.path());
    let (out, after) = send_against(hostile, &file, limit);
    assert_stopped_safely(hostile, &out, &after)
}

#[test]
fn garbage_from_the_controller_stops_the_job() {
    let err = run_case(Hostile::Garbage, Duration::from_secs(30));
    assert!(err.contains("silent"), "{err}");
}

#[test]
fn more_ok_than_lines_is_a_protocol_error() {
    let err = run_case(Hostile::TooManyOk, Duration::from_secs(30));
    assert!(err.contains("protocol error") && err.contains("more answers than lines sent"), "{err}");
}

#[test]
fn running_forever_after_the_last_ok_is_a_stall() {
    let err = run_case(Hostile::RunForever, Duration::from_secs(60));
    assert!(err.contains("stalled"), "{err}");
}

#[test]
fn a_flood_without_line_ends_is_garbage_in_bounded_memory() {
    let err = run_case(Hostile::Flood, Duration::from_secs(30));
    assert!(err.contains("without a line end"), "{err}");
}

#[test]
fn a_disconnect_mid_job_names_the_last_acknowledged_and_executed_line() {
    let err = run_case(Hostile::Disconnect, Duration::from_secs(30));
    assert!(err.contains("closed the link"), "{err}");
    assert!(err.contains("last acknowledged: ") && err.contains(&format!("job.nc:{HONEST_LINES} `")), "{err}");
}

/// A line of a megabyte (beyond what `send` reads as a line) and one of 300
/// bytes (beyond the receive buffer): each quoted by its start and length,
/// the message one short line.
#[test]
fn over_long_g_code_lines_are_quoted_by_their_start() {
    let dir = tempfile::tempdir().unwrap();
    for (name, length) in [("mega.nc", 1_000_000), ("long.nc", 300)] {
        let file = dir.path().join(name);
        std::fs::write(&file, format!("G21G90\nG1X{}\nG1X1F600\n", "1".repeat(length))).unwrap();
        let (out, _) = send_against(Hostile::Garbage, &file, Duration::from_secs(30));
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(!out.status.success(), "{err}");
        assert!(err.contains(&format!("{name}:2 `G1X{}… ({} bytes)`", "1".repeat(77), length + 3)), "{err}");
        assert!(err.len() < 600, "{} bytes: {err}", err.len());
    }
}
