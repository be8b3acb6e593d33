//! laserd: plans laser jobs, turns them into jerk-limited motion split between a
//! galvo scanner and the XY stage that carries it, and streams the result to a
//! GRBL-style controller (or to the built-in simulator), recording every run.
//!
//! The modules follow the pipeline (see ARCHITECTURE.md): a shared base
//! (error, parallel, job, config, mode), then import → topology → (thermal) → plan →
//! motion → program → stream, then what uses the whole pipeline (figures,
//! record, report, plot, gen, run, bench, daemon). No module imports a later
//! one; tests/layers.rs holds the order and checks it.

pub mod error;
pub mod parallel;
pub mod job;
pub mod config;
pub mod mode;
pub mod import;
pub mod topology;
pub mod thermal;
pub mod plan;
pub mod motion;
pub mod program;
pub mod stream;
pub mod figures;
pub mod record;
pub mod report;
pub mod plot;
pub mod gen;
pub mod run;
pub mod bench;
pub mod daemon;
