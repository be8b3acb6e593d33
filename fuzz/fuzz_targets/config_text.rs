//! Config text → `MachineConfig::parse` (TOML, then every setting validated).
//! An accepted config is then put to the first uses every command makes of it:
//! the sender's options (`send`, `serve`) and the import of a small drawing
//! with its layers and tolerance, so a value that passes validation but breaks
//! arithmetic later shows here as a panic or a hang. Planning is left out: one
//! input would cost seconds.
#![no_main]

use laserd::config::MachineConfig;
use laserd::stream::sender::SenderOptions;
use libfuzzer_sys::fuzz_target;

const ORIGIN: &str = "fuzz.toml";

/// A square, a circle and a stroke-coloured line: curves to flatten, layers to pick.
const DRAWING: &str = r##"<svg xmlns="http://www.w3.org/2000/svg" width="40mm" height="40mm" viewBox="0 0 40 40">
  <rect x="5" y="5" width="10" height="10" fill="none" stroke="#000000"/>
  <circle cx="25" cy="25" r="8" fill="none" stroke="#ff0000"/>
  <path d="M 2 38 C 10 30 20 45 38 38" fill="none" stroke="#0000ff"/>
</svg>"##;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    match MachineConfig::parse(text, ORIGIN) {
        Ok(config) => {
            let _ = SenderOptions::new(config.serial.rx_buffer, config.serial.status_hz);
            let _ = config.axis_letters();
            let _ = laserd::import::svg::import_svg(DRAWING, "drawing.svg", &config);
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.contains(ORIGIN), "the error does not name the file: {message}");
        }
    }
});
