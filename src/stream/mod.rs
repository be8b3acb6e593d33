//! Stream: the sender and the transports it talks through.

pub mod in_process;
pub mod sender;

pub use sender::{stream, LineError, LinkEvent, SenderOptions, StreamOutcome};
