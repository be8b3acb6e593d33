//! The one error type of the pipeline. Every variant's message names the place
//! (file and line, setting name, G-code line) so the CLI can print it as one line.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum Error {
    #[error("config: {0}")]
    Config(String),
    #[error("import: {0}")]
    Import(String),
    #[error("plan: {0}")]
    Plan(String),
    #[error("motion: {0}")]
    Motion(String),
    #[error("program: {0}")]
    Program(String),
    #[error("stream: {0}")]
    Stream(String),
    #[error("record: {0}")]
    Record(String),
    #[error("{0}")]
    Io(String),
    /// The service: no such job (or other object).
    #[error("not found: {0}")]
    NotFound(String),
    /// The service: not allowed to anyone (a path outside the job folders).
    #[error("forbidden: {0}")]
    Forbidden(String),
    /// The service: a file or body over its size limit.
    #[error("too large: {0}")]
    TooLarge(String),
    /// The service: the request does not fit the machine's or the job's state.
    #[error("conflict: {0}")]
    Conflict(String),
}

pub type Result<T> = std::result::Result<T, Error>;
