//! SVG bytes → `import_svg` with the shipped machine config. Any result is
//! fine; a panic, a hang (libFuzzer's `-timeout`) or an allocation past
//! `-rss_limit_mb` is a finding. An error must name the file.
#![no_main]

use std::sync::OnceLock;

use laserd::config::MachineConfig;
use libfuzzer_sys::fuzz_target;

const SOURCE: &str = "fuzz.svg";

fn config() -> &'static MachineConfig {
    static CONFIG: OnceLock<MachineConfig> = OnceLock::new();
    // Compiled in: the target reads no file at run time.
    CONFIG.get_or_init(|| {
        let mut config = MachineConfig::parse(include_str!("../../config/laserd.toml"), "config/laserd.toml").expect("the shipped config is valid");
        // Smaller drawings than the shipped limits allow, so that the largest
        // one imports within libFuzzer's per-input time under the sanitizer
        // (about ten times slower than a release build): the limits are what
        // is fuzzed, not their default values.
        config.import.max_elements = 20_000;
        config.import.max_points = 500_000;
        config
    })
}

fuzz_target!(|data: &[u8]| {
    // import_job hands usvg UTF-8 text only.
    let Ok(text) = std::str::from_utf8(data) else { return };
    // <image> and <feImage> are fed too: the importer loads no resource but
    // the job itself (issue 16 finding 2), so none of them reads a file.
    if let Err(e) = laserd::import::svg::import_svg(text, SOURCE, config()) {
        let message = e.to_string();
        assert!(message.contains(SOURCE), "the error does not name the file: {message}");
    }
});
