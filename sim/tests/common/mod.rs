//! The virtual-time driver the simulator's integration tests share.
#![allow(dead_code)]

use laserd_sim::controller::{Controller, Knot, SimConfig};
use laserd_sim::link::PacedLink;
use laserd_sim::wire::{realtime, Response, StatusReport};

pub const BYTE: f64 = 10.0 / 115200.0;

/// Minimal virtual-time driver: host -> controller bytes paced at 115200.
pub struct Sim {
    pub ctl: Controller,
    pub link: PacedLink,
    pub t: f64,
    pub partial: String,
    pub lines: Vec<(f64, String)>,
    pub knots: Vec<Knot>,
    /// When `status` last asked.
    pub last_status: f64,
}

impl Sim {
    pub fn new(cfg: SimConfig) -> Sim {
        let mut s = Sim { ctl: Controller::new(cfg), link: PacedLink::new(115200), t: 0.0, partial: String::new(), lines: vec![], knots: vec![], last_status: f64::NEG_INFINITY };
        s.collect();
        s
    }

    pub fn send(&mut self, text: &str) {
        self.link.push(self.t, text.as_bytes());
    }

    pub fn collect(&mut self) {
        for b in self.ctl.take_output() {
            self.partial.push(b as char);
        }
        while let Some(i) = self.partial.find("\r\n") {
            let line: String = self.partial.drain(..i + 2).collect();
            let line = line.trim_end().to_string();
            if !line.is_empty() {
                self.lines.push((self.t, line));
            }
        }
        self.knots.extend(self.ctl.take_knots());
    }

    /// Runs the next event (a byte arrival or a controller event) if it comes
    /// by `t_end`; false when none does.
    pub fn step(&mut self, t_end: f64) -> bool {
        let next = [self.link.next_arrival(), self.ctl.next_event()].into_iter().flatten().fold(f64::INFINITY, f64::min);
        if next > t_end {
            return false;
        }
        self.t = next.max(self.t);
        for (ta, b) in self.link.pop_due(next) {
            self.ctl.receive(ta, b);
        }
        self.ctl.advance(next);
        self.collect();
        true
    }

    /// Runs events (byte arrivals, controller events) up to `t_end`.
    pub fn run_until(&mut self, t_end: f64) {
        for _ in 0..10_000_000 {
            if !self.step(t_end) {
                break;
            }
        }
        self.ctl.advance(t_end);
        self.t = t_end;
        self.collect();
    }

    pub fn realtime(&mut self, b: u8) {
        self.ctl.receive(self.t, b);
        self.collect();
    }

    pub fn texts(&self) -> Vec<&str> {
        self.lines.iter().map(|(_, l)| l.as_str()).collect()
    }

    pub fn responses(&self) -> Vec<(f64, Response)> {
        self.lines.iter().map(|(t, l)| (*t, Response::parse(l))).filter(|(_, r)| matches!(r, Response::Ok | Response::Error(_))).collect()
    }

    /// Asks for a report and parses it. Asked again at once, it first lets
    /// 2 ms pass: Grbl answers one report for `?`s closer than its
    /// formatting time, as a poller never sends them.
    pub fn status(&mut self) -> StatusReport {
        if self.t < self.last_status + 0.002 {
            let t = self.last_status + 0.002;
            self.run_until(t);
        }
        self.last_status = self.t;
        let before = self.lines.len();
        self.realtime(realtime::STATUS);
        assert_eq!(self.lines.len(), before + 1, "one report expected");
        StatusReport::parse(&self.lines[before].1).unwrap()
    }
}

pub fn cfg() -> SimConfig {
    SimConfig::with_axes("XY")
}

pub fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

