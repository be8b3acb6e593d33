//! What the integration tests share: `laserd sim` as a child process.
#![allow(dead_code)]

pub mod service;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};

/// `laserd sim` running on a pseudo-terminal linked at `link`; killed when
/// dropped, so a failing test never leaves it behind.
pub struct SimProcess(Child);

impl SimProcess {
    /// Starts `laserd sim --link LINK ARGS…` and waits until it has printed the
    /// device path (the link then exists).
    pub fn start(link: &Path, args: &[&str]) -> SimProcess {
        let mut child = Command::new(env!("CARGO_BIN_EXE_laserd"))
            .args(["sim", "--link", link.to_str().unwrap()])
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("laserd sim starts");
        let mut first = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
        assert_eq!(first.trim(), link.to_str().unwrap(), "prints the device path");
        SimProcess(child)
    }

    /// Asks it to stop (SIGTERM: it finishes its recording) and waits.
    pub fn terminate(mut self) -> ExitStatus {
        nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.0.id() as i32), nix::sys::signal::Signal::SIGTERM).unwrap();
        self.0.wait().unwrap()
    }

    /// Kills it outright (SIGKILL: no chance to finish anything) and waits.
    pub fn kill(mut self) {
        self.0.kill().unwrap();
        self.0.wait().unwrap();
    }

    /// Waits for it to end by itself.
    pub fn wait(mut self) -> ExitStatus {
        self.0.wait().unwrap()
    }
}

impl Drop for SimProcess {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
