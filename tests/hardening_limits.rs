//! Issue 16, findings 10 to 12: numbers and recordings from outside (a
//! config, a flag, a file) end in a clear error naming them, never a panic,
//! a hang or an allocation by a corrupt length's word.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};

fn laserd(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_laserd")).args(args).current_dir(dir).output().expect("laserd runs")
}

fn sample(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples").join(name).display().to_string()
}

fn shipped_config() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap()
}

/// Non-zero exit, no panic, the last line on stderr naming `must_contain`.
fn assert_clean_error(out: &Output, must_contain: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "a clean error: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.lines().last().unwrap_or("").contains(must_contain), "'{must_contain}' in: {err}");
}

/// Finding 10 and 11: the values that panicked (exit 101), hung or
/// overflowed are refused by `dry-run` with the setting and its range.
#[test]
fn out_of_range_settings_are_refused_by_name_before_planning() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("machine.toml");
    let text = shipped_config();
    let cases = [
        ("status_hz = 5.0", "status_hz = 1e-300", "serial.status_hz: must be between 0.1 and 100 Hz, got 1e-300"),
        ("status_hz = 5.0", "status_hz = 1e300", "serial.status_hz: must be between 0.1 and 100 Hz, got 1e300"),
        ("tolerance = 0.01\n# Unit", "tolerance = 1e-300\n# Unit", "import.tolerance: must be between"),
        ("[galvo]\n", "[galvo]\ntime_limit = 1e30\n", "galvo.time_limit: must be between 0.01 and 86400 s"),
        ("[cutting]\n", "[cutting]\ntime_limit = 1e19\n", "cutting.time_limit: must be between 0.01 and 86400 s"),
        ("passes = 1", "passes = 4294967295", "layer[0] (mark).passes: must be between 1 and 1000"),
        ("max_velocity = 500.0", "max_velocity = 1e-300", "stage.max_velocity: must be between"),
        ("speed = 200.0", "speed = 5e-324", "layer[1] (cut).speed: must be between"),
        ("max_velocity = 500.0", "max_velocity = 1e308", "stage.max_velocity: must be between 0.1 and 100000 mm/s, got 1e308"),
        ("max_jerk = 250000.0", "max_jerk = 1e308", "stage.max_jerk: must be between"),
    ];
    for (from, to, message) in cases {
        assert!(text.contains(from), "{from}");
        std::fs::write(&config, text.replacen(from, to, 1)).unwrap();
        let out = laserd(&["dry-run", &sample("one-field.svg"), "--config", config.to_str().unwrap(), "--record", "x.mcap"], dir.path());
        assert_clean_error(&out, message);
        assert!(String::from_utf8_lossy(&out.stderr).contains("machine.toml"), "names the file");
    }
}

/// Finding 10: numeric flags have ranges too.
#[test]
fn out_of_range_flags_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let job = sample("one-field.svg");
    let cases: [(&[&str], &str); 7] = [
        (&["plan", &job, "--planner", "hga", "--time-limit", "1e30"], "--time-limit: must be between 0.01 and 86400 s, got 1e30"),
        (&["dry-run", &job, "--planner", "ecp", "--time-limit", "1e19"], "--time-limit: must be between 0.01 and 86400 s, got 1e19"),
        (&["plan", &job, "--time-limit", "0"], "--time-limit: must be between"),
        (&["sim", "--baud", "0"], "--baud: must be between 300 and 12000000 baud, got 0"),
        (&["bench", "link", "--blocks", "1000000000"], "--blocks: must be between"),
        (&["bench", "galvo", "--seeds", "0"], "--seeds: must be between 1 and 1000"),
        (&["bench", "serve", "--hz", "1e300"], "--hz: must be between 0.1 and 1000 Hz, got 1e300"),
    ];
    for (args, message) in cases {
        assert_clean_error(&laserd(args, dir.path()), message);
    }
}

/// Where the length fields of a recording's top-level records and chunk
/// headers are (byte offsets of little-endian u64s, and the u32 length of
/// each chunk's compression name).
struct LengthFields {
    u64s: Vec<usize>,
    u32s: Vec<usize>,
}

fn length_fields(bytes: &[u8]) -> LengthFields {
    const CHUNK: u8 = 0x06;
    const FOOTER: u8 = 0x02;
    let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let mut fields = LengthFields { u64s: Vec::new(), u32s: Vec::new() };
    let mut at = 8; // after the magic
    while at + 9 <= bytes.len() {
        let (opcode, len) = (bytes[at], u64_at(at + 1) as usize);
        fields.u64s.push(at + 1);
        let body = at + 9;
        if opcode == CHUNK {
            // start and end time, uncompressed size, CRC, compression, compressed size.
            fields.u64s.push(body + 16);
            fields.u32s.push(body + 28);
            let name = u32_at(body + 28) as usize;
            fields.u64s.push(body + 32 + name);
        }
        if opcode == FOOTER {
            break;
        }
        at = body + len;
    }
    fields
}

/// `laserd replay FILE` under a 1 GiB address-space limit, killed after a
/// minute: (exit code, stderr). A minute is no speed figure: a replay of
/// this small file takes milliseconds, a hang forever.
fn replay_bounded(file: &Path) -> (Option<i32>, String) {
    let mut child = Command::new("sh")
        .args(["-c", "ulimit -v 1048576 && exec \"$0\" replay \"$1\" --json", env!("CARGO_BIN_EXE_laserd"), file.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sh runs");
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
            return (status.code(), err);
        }
        if started.elapsed() > Duration::from_secs(60) {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("{}: replay still running after a minute", file.display());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A replay of a damaged recording either reads what is good (exit 0,
/// perhaps warning that it ends early) or fails with one clear line naming
/// the file; never a panic, an abort or a kill by the memory limit.
fn assert_replay_survives(file: &Path, what: &str) {
    let (code, err) = replay_bounded(file);
    assert!(!err.contains("panicked") && !err.contains("memory allocation"), "{what}: {err}");
    match code {
        Some(0) => {}
        Some(1) => assert!(err.contains(file.to_str().unwrap()), "{what}: the error names the file: {err}"),
        other => panic!("{what}: exit {other:?}: {err}"),
    }
}

fn recording(dir: &Path) -> PathBuf {
    let rec = dir.join("run.mcap");
    let out = laserd(&["dry-run", &sample("one-field.svg"), "--json", "--record", rec.to_str().unwrap()], dir);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    rec
}

/// Finding 12: every length field of every record and chunk header set to
/// huge and off-by-a-little values.
#[test]
fn replay_of_a_recording_with_corrupt_lengths_ends_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let original = std::fs::read(recording(dir.path())).unwrap();
    let mutant = dir.path().join("mutant.mcap");
    assert_replay_survives(&dir.path().join("run.mcap"), "the original");
    assert_eq!(replay_bounded(&dir.path().join("run.mcap")).0, Some(0), "the original replays under the limit");
    let fields = length_fields(&original);
    assert!(!fields.u32s.is_empty(), "the recording has a chunk");
    for &at in &fields.u64s {
        let was = u64::from_le_bytes(original[at..at + 8].try_into().unwrap());
        for value in [u64::MAX, u64::MAX / 2, 1 << 40, 4 << 30, original.len() as u64, was + 1, was.saturating_sub(1), 0] {
            let mut bytes = original.clone();
            bytes[at..at + 8].copy_from_slice(&value.to_le_bytes());
            std::fs::write(&mutant, &bytes).unwrap();
            assert_replay_survives(&mutant, &format!("u64 at {at} = {value}"));
        }
    }
    for &at in &fields.u32s {
        for value in [u32::MAX, 1 << 30, 0] {
            let mut bytes = original.clone();
            bytes[at..at + 4].copy_from_slice(&value.to_le_bytes());
            std::fs::write(&mutant, &bytes).unwrap();
            assert_replay_survives(&mutant, &format!("u32 at {at} = {value}"));
        }
    }
}

/// Finding 12: random damage anywhere (seeded, so every run tries the same).
#[test]
fn replay_of_a_randomly_damaged_recording_ends_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let original = std::fs::read(recording(dir.path())).unwrap();
    let mutant = dir.path().join("mutant.mcap");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
    for round in 0..300 {
        let mut bytes = original.clone();
        for _ in 0..rng.random_range(1..=8) {
            let at = rng.random_range(0..bytes.len());
            bytes[at] = match rng.random_range(0..3) {
                0 => bytes[at] ^ (1 << rng.random_range(0..8)),
                1 => 0xff,
                _ => rng.random(),
            };
        }
        if round % 10 == 0 {
            bytes.truncate(rng.random_range(0..bytes.len()));
        }
        std::fs::write(&mutant, &bytes).unwrap();
        assert_replay_survives(&mutant, &format!("round {round}"));
    }
}
