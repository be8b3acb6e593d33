//! Stream: the sender and the transports it talks through.

pub mod file_lines;
pub mod frame;
pub mod in_process;
pub mod resume;
pub mod sender;

/// The share of the link's capacity that `bytes` sent in `seconds` used,
/// against the nominal character rate: `baud / 10` bytes a second (8N1,
/// 11,520 B/s at 115200). A UART's real rate can differ from the nominal
/// one: an AVR Grbl at "115200" divides its 16 MHz clock to 117,647 baud
/// (2.1 % faster), so a link it paces may show up to about 1.02. 0 when
/// nothing was timed.
pub fn link_utilization(bytes: usize, baud: u32, seconds: f64) -> f64 {
    if seconds > 0.0 && baud > 0 {
        bytes as f64 / (baud as f64 / 10.0 * seconds)
    } else {
        0.0
    }
}

pub use file_lines::FileLines;
pub use sender::{clean_line, jog_block, quote, stream, Connection, Control, ExecutedLine, LineError, LinkEvent, SenderOptions, StreamOutcome, BUILD_INFO};

#[cfg(test)]
mod tests {
    #[test]
    fn link_utilization_is_against_the_nominal_character_rate() {
        // 115200 baud carries 11,520 bytes a second, nominally.
        assert_eq!(super::link_utilization(11_520, 115_200, 1.0), 1.0);
        // An AVR at "115200" really sends 117,647 baud: a full link shows 1.021.
        let avr = super::link_utilization(11_765, 115_200, 1.0);
        assert!((avr - 1.0213).abs() < 1e-4, "{avr}");
        assert_eq!(super::link_utilization(100, 115_200, 0.0), 0.0);
        assert_eq!(super::link_utilization(100, 0, 1.0), 0.0);
    }
}
