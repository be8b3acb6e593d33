//! Recording bytes → `laserd::record::read`, the reader behind `laserd replay`
//! and the service's recordings, then the figures computed from what it read
//! (as `replay` does). The reader takes a path, so each input is written to one
//! scratch file of this process first.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

fn scratch() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        // /dev/shm keeps the writes off the disk where there is one.
        let dir = PathBuf::from("/dev/shm");
        let dir = if dir.is_dir() { dir } else { std::env::temp_dir() };
        dir.join(format!("laserd-fuzz-{}.mcap", std::process::id()))
    })
}

fuzz_target!(|data: &[u8]| {
    let path = scratch();
    std::fs::write(path, data).expect("write the scratch recording");
    if let Ok(replay) = laserd::record::read(path) {
        let _ = laserd::figures::sim_figures(&replay.log);
    }
});
