//! `Mode`: how the scanner and the stage share the work (on the fly,
//! step and scan, or the stage alone). Planning, motion and the reports all
//! take it, so it lives below them.

use std::str::FromStr;

use crate::config::MachineConfig;
use crate::error::{Error, Result};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    OnTheFly,
    StepAndScan,
    StageOnly,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::OnTheFly => "on-the-fly",
            Mode::StepAndScan => "step-and-scan",
            Mode::StageOnly => "stage-only",
        }
    }

    /// The mode used when none is asked for (the contract's default).
    pub fn default_for(machine: &MachineConfig) -> Mode {
        if machine.scanner.is_some() {
            Mode::OnTheFly
        } else {
            Mode::StageOnly
        }
    }

    /// Checks the mode against the machine.
    pub fn check(self, machine: &MachineConfig) -> Result<()> {
        match self {
            Mode::OnTheFly | Mode::StepAndScan if machine.scanner.is_none() => {
                Err(Error::Motion(format!("--mode {} needs a [scanner] section in the config", self.as_str())))
            }
            _ => Ok(()),
        }
    }

    /// How much of the usable field the planner may fill in this mode: on the
    /// fly, marks begin and end at speed and overshoot their ends a little
    /// with the laser off, which must stay inside the field too.
    pub fn planning_half_field(self, machine: &MachineConfig) -> Option<f64> {
        let s = machine.scanner.as_ref()?;
        Some(match self {
            Mode::OnTheFly => s.usable_half_field - ON_THE_FLY_FIELD_MARGIN,
            _ => s.usable_half_field,
        })
    }
}

impl Mode {
    /// The machine as the planner sees it in this mode (its usable field
    /// reduced by `planning_half_field`).
    pub fn planning_machine(self, machine: &MachineConfig) -> MachineConfig {
        let mut m = machine.clone();
        if let (Some(s), Some(half)) = (m.scanner.as_mut(), self.planning_half_field(machine)) {
            s.usable_half_field = half;
        }
        m
    }
}

/// Field margin kept for the overshoot of on-the-fly marks (mm).
pub const ON_THE_FLY_FIELD_MARGIN: f64 = 0.5;

impl FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "on-the-fly" => Ok(Mode::OnTheFly),
            "step-and-scan" => Ok(Mode::StepAndScan),
            "stage-only" => Ok(Mode::StageOnly),
            _ => Err(format!("unknown mode '{s}' (on-the-fly, step-and-scan, stage-only)")),
        }
    }
}
