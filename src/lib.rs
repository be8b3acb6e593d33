//! laserd: plans laser jobs, turns them into jerk-limited motion split between a
//! galvo scanner and the XY stage that carries it, and streams the result to a
//! GRBL-style controller (or to the built-in simulator), recording every run.
//!
//! The modules follow the pipeline (see ARCHITECTURE.md):
//! import → plan → motion → program → stream, with record beside them.

pub mod config;
pub mod error;
pub mod job;
pub mod mode;
pub mod topology;
pub mod import;
pub mod motion;
pub mod parallel;
pub mod plan;
pub mod program;
pub mod figures;
pub mod plot;
pub mod record;
pub mod report;
pub mod run;
pub mod stream;
pub mod gen;
pub mod bench;
pub mod daemon;
