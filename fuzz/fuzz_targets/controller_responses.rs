//! What a controller sends → the sender's parsing of it: bytes split into
//! lines as the sender's link reader does (at `\n`, lossy UTF-8, CR/LF
//! trimmed), each classified by `wire::Response::parse`. A status report must
//! survive a round trip through `to_line` with its state, fields and every
//! count unchanged (positions to the 3 decimals Grbl sends).
#![no_main]

use laserd_sim::wire::{Response, StatusReport};
use libfuzzer_sys::fuzz_target;

/// Equal as printed with 3 decimals: within half the last digit (and the
/// float error of that rounding).
fn same_numbers(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y || (x - y).abs() <= 5.0001e-4 * x.abs().max(1.0) || (x.is_nan() && y.is_nan()))
}

fuzz_target!(|data: &[u8]| {
    for segment in data.split(|&b| b == b'\n') {
        let text = String::from_utf8_lossy(segment);
        let text = text.trim_matches(|c| c == '\r' || c == '\n');
        if text.is_empty() {
            continue;
        }
        match Response::parse(text) {
            Response::Status(report) => {
                let line = report.to_line();
                let again = StatusReport::parse(&line).unwrap_or_else(|e| panic!("{text:?} → {line:?} does not parse again: {e}"));
                assert_eq!(again.state, report.state, "{line}");
                assert_eq!(again.buffer, report.buffer, "{line}");
                assert_eq!(again.line, report.line, "{line}");
                assert_eq!(again.overrides, report.overrides, "{line}");
                assert!(same_numbers(again.position(), report.position()), "{text:?} → {line:?}");
            }
            Response::Other(other) => assert!(!other.contains('\n')),
            _ => {}
        }
        // The sender reads `$$` lines as settings and `[OPT:]` as build options
        // with plain number parsing of their fields; the status parser is the
        // only part with structure, exercised directly too.
        let _ = StatusReport::parse(text);
    }
});
