//! DXF bytes (ASCII or binary) → `import_dxf` with the shipped machine
//! config. Any result is fine; a panic, a hang (libFuzzer's `-timeout`) or
//! an allocation past `-rss_limit_mb` is a finding. An error must name the
//! file.
#![no_main]

use std::sync::OnceLock;

use laserd::config::MachineConfig;
use libfuzzer_sys::fuzz_target;

const SOURCE: &str = "fuzz.dxf";

fn config() -> &'static MachineConfig {
    static CONFIG: OnceLock<MachineConfig> = OnceLock::new();
    // Compiled in: the target reads no file at run time. Smaller caps than
    // the shipped ones, as for the SVG target: the caps are what is fuzzed.
    CONFIG.get_or_init(|| {
        let mut config = MachineConfig::parse(include_str!("../../config/flatbed-cutter.toml"), "config/flatbed-cutter.toml").expect("the shipped config is valid");
        config.import.max_elements = 20_000;
        config.import.max_points = 500_000;
        config
    })
}

fuzz_target!(|data: &[u8]| {
    if let Err(e) = laserd::import::dxf::import_dxf(data, SOURCE, config()) {
        let message = e.to_string();
        assert!(message.contains(SOURCE), "the error does not name the file: {message}");
    }
});
