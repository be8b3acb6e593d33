//! `laserd-sim`: a GRBL 1.1-compatible laser controller in software.
//!
//! * [`wire`]: protocol definitions shared by sender and simulator;
//! * [`controller`]: the controller state machine, driven by an external clock;
//! * [`gcode`]: Grbl's line cleaning and word splitting, shared with the sender;
//! * [`limits`]: an independent kinematic limit checker over executed knots;
//! * [`planner`]: Grbl's look-ahead velocity planner (the `grbl` motion model);
//! * [`link`]: serial byte pacing;
//! * [`pty`]: the real-time driver on a pseudo-terminal.

pub mod controller;
pub mod gcode;
pub mod limits;
pub mod link;
pub mod planner;
pub mod pty;
pub mod wire;

pub use controller::{AxisConfig, Controller, Faults, Flavor, Knot, MotionModel, SimConfig, SimStats};
pub use limits::{LimitChecker, LimitReport};
pub use link::PacedLink;
pub use pty::{open_pty, run_realtime, Observed, PtyDevice};
pub use wire::{MachineState, Response, StatusReport};

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    #[error("system call: {0}")]
    Nix(#[from] nix::Error),
    #[error("{0} exists and is not a symlink; refusing to replace it")]
    LinkOccupied(std::path::PathBuf),
}
