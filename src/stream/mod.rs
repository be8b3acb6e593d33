//! Stream: the sender and the transports it talks through.

pub mod file_lines;
pub mod frame;
pub mod in_process;
pub mod resume;
pub mod sender;

pub use file_lines::FileLines;
pub use sender::{clean_line, quote, stream, Connection, Control, ExecutedLine, LineError, LinkEvent, SenderOptions, StreamOutcome, BUILD_INFO};
