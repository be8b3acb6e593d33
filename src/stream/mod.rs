//! Stream: the sender and the transports it talks through.

pub mod in_process;
pub mod resume;
pub mod sender;

pub use sender::{stream, Connection, Control, LineError, LinkEvent, SenderOptions, StreamOutcome};
