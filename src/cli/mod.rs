//! The `laserd` commands, one file per group; `main.rs` parses and dispatches.
//! A module of the binary: the library stays free of the command line's
//! printing and exit codes.

pub mod bench;
pub mod common;
pub mod gen;
pub mod plan;
pub mod replay;
pub mod send;
pub mod service;
pub mod sim;
