//! The command line as a user runs it: the binary, real files, exit codes.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::SimProcess;

/// Runs laserd in `dir`; no `$LASERD_CONFIG` and an empty user config folder,
/// so that the machine is the one the test names (or the built-in one).
fn laserd(args: &[&str], dir: &Path) -> Output {
    laserd_with_env(args, dir, &[])
}

fn laserd_with_env(args: &[&str], dir: &Path, env: &[(&str, &Path)]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_laserd"));
    command.args(args).current_dir(dir).env_remove("LASERD_CONFIG").env("XDG_CONFIG_HOME", dir.join("no-user-config"));
    for (name, value) in env {
        command.env(name, value);
    }
    command.output().expect("laserd runs")
}

/// Runs laserd in `dir` as `laserd` does, its standard error on a
/// pseudo-terminal as a person at one sees it: the output, and the text the
/// terminal got with its escape sequences and redraws left out.
fn laserd_on_a_terminal(args: &[&str], dir: &Path) -> (Output, String) {
    use std::io::Read;
    let size = nix::pty::Winsize { ws_row: 40, ws_col: 200, ws_xpixel: 0, ws_ypixel: 0 };
    let pty = nix::pty::openpty(Some(&size), None).unwrap();
    let mut command = Command::new(env!("CARGO_BIN_EXE_laserd"));
    command.args(args).current_dir(dir).env_remove("LASERD_CONFIG").env("XDG_CONFIG_HOME", dir.join("no-user-config"));
    command.stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::from(pty.slave));
    let child = command.spawn().unwrap();
    // The terminal ends when the child's end closes: ours too.
    drop(command);
    let mut master = std::fs::File::from(pty.master);
    let reader = std::thread::spawn(move || {
        let mut seen = Vec::new();
        let _ = master.read_to_end(&mut seen);
        seen
    });
    let output = child.wait_with_output().unwrap();
    let seen = String::from_utf8_lossy(&reader.join().unwrap()).into_owned();
    let mut text = String::new();
    let mut chars = seen.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\x1b' => {
                // CSI: ESC [ parameters, then a letter.
                if chars.next_if_eq(&'[').is_some() {
                    while chars.next().is_some_and(|c| !c.is_ascii_alphabetic()) {}
                }
            }
            '\r' => text.push('\n'),
            c => text.push(c),
        }
    }
    (output, text)
}

/// Issue 17, point 2: an installed binary finds its machine config without
/// the build checkout: `--config`, then `$LASERD_CONFIG`, then
/// /etc/laserd/laserd.toml, then the user's config folder ($XDG_CONFIG_HOME,
/// else ~/.config), then the machine built into the binary; reports say which.
/// Run from a folder with no config in it. (The real /etc is only read: when
/// the machine has a system config, it is the one before the user's.)
#[test]
fn config_is_found_in_the_search_order_from_any_folder() {
    let dir = tempfile::tempdir().unwrap();
    let elsewhere = dir.path().join("elsewhere");
    let home = dir.path().join("home");
    let xdg = dir.path().join("xdg");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let shipped = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap();
    // Each file is a machine of its own travel, so the report shows which was read.
    let write = |path: &Path, travel: u32| {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, shipped.replace("travel_x = 300.0", &format!("travel_x = {travel}.0"))).unwrap();
        path.to_path_buf()
    };
    let system = Path::new("/etc/laserd/laserd.toml");
    let has_system = system.exists();
    let dry_run = |env: &[(&str, &Path)], extra: &[&str]| {
        let mut args = vec!["plan", "--json"];
        args.extend_from_slice(extra);
        let job = sample("one-field.svg");
        args.push(&job);
        let out = laserd_with_env(&args, &elsewhere, env);
        json(&out)["config"].clone()
    };
    let no_user = dir.path().join("no-user-config");
    // Nothing anywhere: the built-in machine (or the system's).
    let found = dry_run(&[("HOME", &home), ("XDG_CONFIG_HOME", &no_user)], &[]);
    if has_system {
        assert_eq!(found["from"], "system", "{found}");
    } else {
        assert_eq!(found, serde_json::json!({"from": "builtin"}));
    }
    // ~/.config/laserd/laserd.toml without XDG_CONFIG_HOME; $XDG_CONFIG_HOME/laserd/laserd.toml with it.
    let in_home = write(&home.join(".config/laserd/laserd.toml"), 301);
    let mut command = Command::new(env!("CARGO_BIN_EXE_laserd"));
    let job = sample("one-field.svg");
    let out = command.args(["plan", "--json", &job]).current_dir(&elsewhere).env_remove("LASERD_CONFIG").env_remove("XDG_CONFIG_HOME").env("HOME", &home).output().unwrap();
    let found = json(&out)["config"].clone();
    let in_xdg = write(&xdg.join("laserd/laserd.toml"), 302);
    let found_xdg = dry_run(&[("HOME", &home), ("XDG_CONFIG_HOME", &xdg)], &[]);
    if !has_system {
        assert_eq!(found, serde_json::json!({"from": "user", "path": in_home}));
        assert_eq!(found_xdg, serde_json::json!({"from": "user", "path": in_xdg}));
    }
    // $LASERD_CONFIG before the system's and the user's; --config before all.
    // The named one has no scanner: the plan shows it is the machine used.
    let named = write(&dir.path().join("named.toml"), 303);
    let (start, end) = (shipped.find("\n[scanner]").unwrap(), shipped.find("\n[laser]").unwrap());
    std::fs::write(&named, format!("{}{}", &shipped[..start], &shipped[end..])).unwrap();
    assert_eq!(dry_run(&[("XDG_CONFIG_HOME", &xdg), ("LASERD_CONFIG", &named)], &[]), serde_json::json!({"from": "env", "path": named}));
    let given = write(&dir.path().join("given.toml"), 304);
    let found = dry_run(&[("XDG_CONFIG_HOME", &xdg), ("LASERD_CONFIG", &named)], &["--config", given.to_str().unwrap()]);
    assert_eq!(found, serde_json::json!({"from": "option", "path": given}));
    // $LASERD_CONFIG naming a missing file is an error, not the next place.
    let out = laserd_with_env(&["plan", &job], &elsewhere, &[("LASERD_CONFIG", &dir.path().join("missing.toml"))]);
    assert_clean_error(&out, "missing.toml: cannot read");

    let out = laserd_with_env(&["dry-run", &job, "--json"], &elsewhere, &[("LASERD_CONFIG", &named)]);
    let report = json(&out);
    assert_eq!(report["config"]["from"], "env");
    assert_eq!(report["mode"], "stage-only", "the machine of $LASERD_CONFIG is the one used");
    let text = laserd_with_env(&["dry-run", &job], &elsewhere, &[("LASERD_CONFIG", &named)]);
    assert!(String::from_utf8_lossy(&text.stdout).contains(&format!("machine config: {} ($LASERD_CONFIG)", named.display())), "{}", String::from_utf8_lossy(&text.stdout));
    // A command without a report says it on stderr.
    let out = laserd_with_env(&["bench", "link", "--blocks", "50"], &elsewhere, &[("LASERD_CONFIG", &given)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("laserd: machine config: {} ($LASERD_CONFIG)", given.display())), "{}", String::from_utf8_lossy(&out.stderr));
    // The service never runs the built-in example machine: it needs a file.
    if !has_system {
        let out = laserd_with_env(&["serve", "--state-dir", dir.path().join("state").to_str().unwrap()], &elsewhere, &[("HOME", &no_user)]);
        assert_clean_error(&out, "no machine config");
    }
}

fn sample(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples").join(name).display().to_string()
}

fn json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON object")
}

/// The error contract: non-zero exit, one line on stderr naming the problem, no panic.
fn assert_clean_error(out: &Output, must_contain: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail: {err}");
    assert!(!err.contains("panicked"), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line: {err}");
    assert!(lines[0].contains(must_contain), "'{must_contain}' in: {err}");
}

#[test]
fn dry_run_json_and_replay_reproduce_the_same_sim_figures() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.mcap");
    let out = laserd(&["dry-run", &sample("one-field.svg"), "--json", "--record", rec.to_str().unwrap()], dir.path());
    let report = json(&out);
    assert_eq!(report["planner"], "hha", "auto is the galvo planner");
    assert_eq!(report["mode"], "on-the-fly", "the default with a scanner");
    assert_eq!(report["scan_fields"], 1);
    // A marking job: nothing falls out, so nothing can be cut too late.
    assert_eq!(report["precedence_violations"], 0);
    let sim = &report["sim"];
    assert_eq!(sim["limit_violations"], 0, "{sim}");
    assert_eq!(sim["laser_state_errors"], 0, "{sim}");
    assert_eq!(sim["alarms"], serde_json::json!([]));
    assert!(sim["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.05, "{sim}");
    assert!(sim["job_time_s"].as_f64().unwrap() >= report["trajectory_time_s"].as_f64().unwrap() * 0.999);
    // The contract's bound takes every jump from rest to rest; marks that
    // begin and end at speed may beat it a little, not by much.
    assert!(report["trajectory_time_s"].as_f64().unwrap() >= 0.95 * report["lower_bound_s"].as_f64().unwrap());
    assert!(sim["peak_field_use"].as_f64().unwrap() <= 1.0);
    // Blocks per second of machine time against what the links carry: the
    // default 921600-baud link carries eight times what 115200 does.
    let (blocks, link, slow) = (report["blocks_per_s"].as_f64().unwrap(), report["link_lines_per_s"].as_f64().unwrap(), report["link_115200_lines_per_s"].as_f64().unwrap());
    assert!(blocks > 0.0 && blocks < link, "{report}");
    assert!((link / slow - 8.0).abs() < 1e-9, "{report}");
    assert!(report["motion_time_s"].as_f64().unwrap() > 0.0);
    assert!(rec.exists());

    let replayed = json(&laserd(&["replay", rec.to_str().unwrap(), "--json"], dir.path()));
    assert_eq!(&replayed, sim, "replay re-derives the dry-run's figures exactly");

    // Re-streaming the recorded program into a fresh simulator gives the same
    // run again: the virtual-time simulation is deterministic.
    let again = json(&laserd(&["replay", rec.to_str().unwrap(), "--to-sim", "--json"], dir.path()));
    assert_eq!(again["same"], true, "{again}");
    assert_eq!(&again["re_simulated"], sim);
}

#[test]
fn dry_run_prints_a_human_summary_and_records_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let out = laserd(&["dry-run", &sample("one-field.svg")], dir.path());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("geometries") && text.contains("limit violations 0"), "{text}");
    assert!(dir.path().join("one-field.mcap").exists());
}

#[test]
fn plan_writes_gcode_and_reports_without_sim() {
    let dir = tempfile::tempdir().unwrap();
    let nc = dir.path().join("job.nc");
    let picture = dir.path().join("job.svg");
    let report = json(&laserd(&["plan", &sample("nested-sheet.svg"), "--json", "-o", nc.to_str().unwrap(), "--plot", picture.to_str().unwrap()], dir.path()));
    assert!(report["sim"].is_null());
    // The picture: an SVG with the fields the report counts and the TCP path.
    let svg = std::fs::read_to_string(&picture).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains(r#"class="mark""#));
    let fields = svg.split(r#"<g id="fields">"#).nth(1).unwrap().split("</g>").next().unwrap().matches("<rect").count();
    assert_eq!(fields as u64, report["scan_fields"].as_u64().unwrap());
    assert!(report["recording"].is_null());
    assert_eq!(report["geometries"], 81);
    let gcode = std::fs::read_to_string(&nc).unwrap();
    assert!(gcode.starts_with("G21G90G93\n"));
    assert!(gcode.lines().count() == report["program_lines"].as_u64().unwrap() as usize);
}

#[test]
fn stage_only_machine_is_the_same_config_without_scanner() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap();
    let start = text.find("\n[scanner]").unwrap();
    let end = text.find("\n[laser]").unwrap();
    let cfg: PathBuf = dir.path().join("xy.toml");
    std::fs::write(&cfg, format!("{}{}", &text[..start], &text[end..])).unwrap();
    let report = json(&laserd(&["dry-run", &sample("one-field.svg"), "--json", "--config", cfg.to_str().unwrap()], dir.path()));
    assert_eq!(report["mode"], "stage-only");
    assert!(report["scan_fields"].is_null());
    assert_eq!(report["sim"]["limit_violations"], 0, "{}", report["sim"]);
    assert!(report["sim"]["peak_field_use"].is_null());
    assert!(report["sim"]["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.05);
}

#[test]
fn a_link_too_slow_for_the_program_slows_the_job_instead_of_starving_the_controller() {
    // The shipped machine on a 115200-baud GRBL link (128-byte receive
    // buffer, 15 planner blocks): one-field's program needs about 770
    // blocks a second, the link carries about 490 lines.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap();
    let text = text.replace("baud = 921600", "baud = 115200").replace("rx_buffer = 1024", "rx_buffer = 128").replace("planner_blocks = 100", "planner_blocks = 15");
    let cfg: PathBuf = dir.path().join("grbl.toml");
    std::fs::write(&cfg, text).unwrap();
    let fast = json(&laserd(&["dry-run", &sample("one-field.svg"), "--json"], dir.path()));
    assert_eq!(fast["link_slowdown"], 1.0, "the fast link carries it at full speed");
    for mode in ["on-the-fly", "step-and-scan"] {
        let slow = json(&laserd(&["dry-run", &sample("one-field.svg"), "--json", "--mode", mode, "--config", cfg.to_str().unwrap()], dir.path()));
        let k = slow["link_slowdown"].as_f64().unwrap();
        assert!(k > 1.2, "{mode}: slowed ({k})");
        let sim = &slow["sim"];
        assert_eq!(sim["limit_violations"], 0, "{mode}: {sim}");
        assert_eq!(sim["planner_starved_s"], 0.0, "{mode}: the controller never runs dry: {sim}");
        assert!(sim["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.01, "{mode}: {sim}");
        // The slow-down is the time against full speed, and the program's
        // blocks now come no faster than the link carries lines.
        let full = json(&laserd(&["dry-run", &sample("one-field.svg"), "--json", "--mode", mode], dir.path()));
        let ratio = slow["trajectory_time_s"].as_f64().unwrap() / full["trajectory_time_s"].as_f64().unwrap();
        assert!((ratio / k - 1.0).abs() < 0.01, "{mode}: {ratio} against {k}");
        assert!(slow["blocks_per_s"].as_f64().unwrap() <= slow["link_lines_per_s"].as_f64().unwrap(), "{mode}: {slow}");
    }
}

#[test]
fn a_link_that_cannot_carry_the_arcs_gets_straight_lines_before_the_job_is_slowed() {
    // One-field's circles (r = 3) on the flatbed run near what their
    // curvature allows; as G2 arcs the controller splits them into short
    // planner blocks faster than the 115200-baud link refills the planner
    // (the job was slowed 1.09 times for it). In straight lines the link
    // keeps up at full speed.
    let dir = tempfile::tempdir().unwrap();
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let report = json(&laserd(&["dry-run", &sample("one-field.svg"), "--json", "--config", cfg.to_str().unwrap()], dir.path()));
    assert_eq!(report["link_slowdown"], 1.0, "{report}");
    assert_eq!(report["sim"]["limit_violations"], 0, "{}", report["sim"]);
}

#[test]
fn malformed_svg_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.svg");
    std::fs::write(&bad, "<svg xmlns='http://www.w3.org/2000/svg'><path d='M 0 0 L 10 10'</svg>").unwrap();
    assert_clean_error(&laserd(&["dry-run", bad.to_str().unwrap()], dir.path()), "malformed SVG");
}

#[test]
fn missing_job_file_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    assert_clean_error(&laserd(&["plan", "no-such-job.svg"], dir.path()), "no-such-job.svg");
}

#[test]
fn invalid_config_value_names_the_setting() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap();
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, text.replace("max_acceleration = 5000.0", "max_acceleration = -1")).unwrap();
    assert_clean_error(
        &laserd(&["dry-run", &sample("one-field.svg"), "--config", cfg.to_str().unwrap()], dir.path()),
        "stage.max_acceleration",
    );
}

#[test]
fn replay_of_a_non_recording_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("x.mcap");
    std::fs::write(&f, b"not mcap at all").unwrap();
    assert_clean_error(&laserd(&["replay", f.to_str().unwrap()], dir.path()), "x.mcap");
}

/// The recording opens in an independent MCAP implementation (the Python
/// reference library), with JSON messages and JSON Schemas on every channel.
#[test]
fn recording_reads_in_the_reference_python_mcap_library() {
    let have = |py: &str| Command::new("python3").args(["-c", py]).status().map(|s| s.success()).unwrap_or(false);
    // Installed (pinned) by .ci/run; a test installs nothing.
    assert!(have("import mcap"), "this test needs the reference MCAP reader, the Python packages mcap 1.6.0, lz4 4.4.5 and zstandard 0.25.0: .ci/run installs them, pinned");
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("r.mcap");
    let out = laserd(&["dry-run", &sample("one-field.svg"), "--record", rec.to_str().unwrap()], dir.path());
    assert!(out.status.success());
    let script = r#"
import sys, json
from mcap.reader import make_reader
counts = {}
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    for schema, channel, message in reader.iter_messages():
        assert schema.encoding == "jsonschema", schema.encoding
        assert channel.message_encoding == "json"
        json.loads(message.data)
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
print(json.dumps(counts))
"#;
    let py = Command::new("python3").args(["-c", script, rec.to_str().unwrap()]).output().unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    let counts: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    for topic in ["/run/setup", "/run/job", "/plan/lines", "/link", "/status", "/sim/axes", "/run/report"] {
        assert!(counts[topic].as_u64().unwrap_or(0) > 0, "{topic} in {counts}");
    }
}

/// Issue 24: a long `plan` or `dry-run` shows its stages on a terminal
/// (the name of the one under way, the simulation as a bar), and nothing
/// when standard error is no terminal; the reports give machine time as
/// people read it.
#[test]
fn plan_and_dry_run_show_their_stages_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let cutter = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let job = sample("nested-sheet.svg");
    let args = ["--config", cutter.to_str().unwrap(), &job];
    let (out, terminal) = laserd_on_a_terminal(&[&["dry-run"][..], &args].concat(), dir.path());
    assert!(out.status.success(), "{terminal}");
    assert!(terminal.contains("topology and planning") && terminal.contains("simulation [") && terminal.contains('%'), "{terminal}");
    // Piped: the same report, nothing on standard error.
    let quiet = laserd(&[&["plan"][..], &args].concat(), dir.path());
    assert!(quiet.status.success() && quiet.stderr.is_empty(), "{}", String::from_utf8_lossy(&quiet.stderr));
    let report = json(&laserd(&[&["plan", "--json"][..], &args].concat(), dir.path()));
    let time = report["trajectory_time_s"].as_f64().unwrap();
    assert!(time > 60.0, "a job over a minute: {time} s");
    let text = String::from_utf8_lossy(&quiet.stdout);
    assert!(text.contains(&format!("machine time {} (", laserd::report::duration(time))), "{text}");
    assert!(laserd::report::duration(time).contains(" min "), "{text}");
}

/// `laserd send` streams a G-code file to `laserd sim --pty`, and stops at a
/// line the controller rejects, naming the file and line.
#[test]
fn send_streams_a_file_to_the_simulator_and_names_a_rejected_line() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttySEND");
    let _sim = SimProcess::start(&link, &["--baud", "1000000"]);

    let good = dir.path().join("good.nc");
    let mut text = String::from("G21G90G93\r\nM4S0\n");
    for i in 1..=200 {
        text.push_str(&format!("G1X{}Y{}S100F60000\n", i as f64 * 0.05, i as f64 * 0.02));
    }
    text.push_str("M5\nM2\n");
    std::fs::write(&good, &text).unwrap();
    let report = json(&laserd(&["send", good.to_str().unwrap(), "--port", link.to_str().unwrap(), "--baud", "1000000", "--json"], dir.path()));
    assert_eq!(report["completed"], true, "{report}");
    assert_eq!(report["lines_sent"], 204);
    assert_eq!(report["last_acked_line"], 204);
    assert_eq!(report["bytes_sent"].as_u64().unwrap() as usize, text.len() - 1, "the \\r is not sent");

    // Check mode validates without motion and reports every rejected line.
    let check = dir.path().join("check.nc");
    std::fs::write(&check, "G90G94\nG0X0Y0\nG1X1F600\nG1Z1F600\nG1X2F600\nG1X2Q1F600\nG1X3F600\n").unwrap();
    let out = laserd(&["send", check.to_str().unwrap(), "--port", link.to_str().unwrap(), "--baud", "1000000", "--check", "--json"], dir.path());
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let bad_lines: Vec<u64> = report["errors"].as_array().unwrap().iter().map(|e| e["line"].as_u64().unwrap()).collect();
    assert_eq!(bad_lines, vec![4, 6]);
    assert_eq!(report["last_acked_line"], 7, "it went on past the errors");

    // The machine is now at the end of the first program: go back, then fail on line 4.
    let bad = dir.path().join("bad.nc");
    std::fs::write(&bad, "G90G94\nG0X0Y0\nG1X1F600\nG1Z1F600\nG1X2F600\n").unwrap();
    let out = laserd(&["send", bad.to_str().unwrap(), "--port", link.to_str().unwrap(), "--baud", "1000000", "--json"], dir.path());
    assert_eq!(out.status.code(), Some(2));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["completed"], false);
    assert_eq!(report["errors"][0]["line"], 4);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.nc:4 `G1Z1F600`") && err.contains("error:20"), "{err}");
}

/// Issue 24: `send` on a terminal shows a laserd program's progress and ETA
/// by its planned time (not by its rate of lines, which misjudged a 29 s
/// job as 2 h), and the report's time as people read it.
#[test]
fn send_shows_the_time_left_of_a_laserd_programs_planned_time() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyETA");
    let _sim = SimProcess::start(&link, &["--baud", "1000000"]);
    let nc = dir.path().join("one.nc");
    assert!(laserd(&["plan", &sample("one-field.svg"), "-o", nc.to_str().unwrap()], dir.path()).status.success());
    let text = std::fs::read_to_string(&nc).unwrap();
    let planned = laserd::program::times::PlannedTimes::read(text.lines().map(Ok::<_, laserd::error::Error>)).unwrap();
    let (out, terminal) = laserd_on_a_terminal(&["send", nc.to_str().unwrap(), "--port", link.to_str().unwrap(), "--baud", "1000000"], dir.path());
    assert!(out.status.success(), "{terminal}");
    let total = laserd::report::duration(planned.total_s);
    let lefts: Vec<&str> = terminal.lines().filter_map(|l| l.split(", ").nth(1)).filter_map(|l| l.trim_end().strip_suffix(&format!(" left of {total} planned"))).collect();
    assert!(!lefts.is_empty(), "the bar says what is left of {total}: {terminal}");
    let seconds: Vec<f64> = lefts.iter().map(|l| l.trim_end_matches(" s").parse().unwrap()).collect();
    assert!(seconds.iter().all(|&s| s <= planned.total_s + 1e-9) && seconds.windows(2).all(|w| w[1] <= w[0] + 1e-9), "{seconds:?} of {}", planned.total_s);
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(report.contains(" bytes in ") && report.contains(" s, completed"), "{report}");
}

/// A fast stream of lines that do not move (setup lines, comments, what CAM
/// headers are made of): the controller is idle with nothing queued at every
/// status report while lines are rightly on their way, which must not be
/// taken for lost bytes. Comments and spaces never reach the link.
#[test]
fn send_streams_lines_without_motion_and_strips_comments() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyFAST");
    let _sim = SimProcess::start(&link, &["--baud", "4000000"]);
    let file = dir.path().join("setup.nc");
    let line = "G21 G90 G94 G17 G54 M5 M9 S0 F1000 T0 (a long comment that is stripped)\n";
    std::fs::write(&file, format!("%\n{}%\n", line.repeat(20_000))).unwrap();
    let report = json(&laserd(&["send", file.to_str().unwrap(), "--port", link.to_str().unwrap(), "--baud", "4000000", "--json"], dir.path()));
    assert_eq!(report["completed"], true, "{report}");
    assert_eq!(report["lines_sent"], 20_000, "the % lines are not sent");
    assert_eq!(report["last_acked_line"], 20_002);
    assert_eq!(report["bytes_sent"], 20_000 * "G21G90G94G17G54M5M9S0F1000T0\n".len());
}

/// `bench link`: character counting keeps a 115200-baud link busy with short
/// blocks, and never lets the planner starve when blocks outlast their lines.
#[test]
fn bench_link_reports_character_counting_against_send_response() {
    let dir = tempfile::tempdir().unwrap();
    let short = json(&laserd(&["bench", "link", "--blocks", "600", "--block-ms", "1", "--json"], dir.path()));
    let cc = &short["character_counting"];
    let sr = &short["send_response"];
    assert_eq!(cc["completed"], true);
    assert!(cc["link_utilization"].as_f64().unwrap() >= 0.95, "{short}");
    assert!(sr["link_utilization"].as_f64().unwrap() < cc["link_utilization"].as_f64().unwrap());
    assert!(short["speedup"].as_f64().unwrap() > 1.2, "{short}");
    let long = json(&laserd(&["bench", "link", "--blocks", "600", "--block-ms", "5", "--json"], dir.path()));
    assert!(long["block_s"].as_f64().unwrap() > long["line_time_s"].as_f64().unwrap());
    assert_eq!(long["character_counting"]["planner_starved_s"].as_f64().unwrap(), 0.0, "{long}");
}

/// `bench ecp` (issue 25): `--no-precedence` is the plain TSP of the same
/// cities; a tour whose length is not the published optimum (`--optimum`,
/// or the .tsp's OPTIMAL line) is refused naming both figures, before any
/// search; an EDGE_WEIGHT_TYPE it does not measure is refused by name.
#[test]
fn bench_ecp_plain_tsp_and_the_optimum_it_checks() {
    let dir = tempfile::tempdir().unwrap();
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tsplib");
    let (tsp, tour) = (data.join("att48.tsp"), data.join("att48.opt.tour"));
    let (tsp, tour) = (tsp.to_str().unwrap(), tour.to_str().unwrap());
    let ecp = |extra: &[&str]| laserd(&[&["bench", "ecp", "--tsp", tsp, "--tour", tour, "--time-limit", "0.5"], extra].concat(), dir.path());

    let plain = json(&ecp(&["--no-precedence", "--optimum", "10628", "--json"]));
    assert_eq!((plain["precedence"].as_bool(), plain["precedences"].as_u64(), plain["contours"].as_u64()), (Some(false), Some(0), Some(48)), "{plain}");
    assert_eq!((plain["inner_outer"].as_u64(), plain["common_cuts"].as_u64()), (Some(0), Some(0)), "{plain}");
    assert_eq!((plain["edge_weight_type"].as_str(), plain["optimum"].as_f64(), plain["optimum_source"].as_str()), (Some("ATT"), Some(10628.0), Some("published")), "{plain}");
    assert!(plain["feasible"].as_bool().unwrap() && plain["best"].as_f64().unwrap() >= 10628.0 && plain["gap"].as_f64().unwrap() >= 0.0, "{plain}");
    let constrained = json(&ecp(&["--json"]));
    assert_eq!((constrained["precedence"].as_bool(), constrained["optimum_source"].as_str()), (Some(true), Some("tour")), "{constrained}");
    assert!(constrained["precedences"].as_u64().unwrap() > 0 && constrained["contours"].as_u64().unwrap() < 48, "{constrained}");
    let text = ecp(&["--optimum", "10628"]);
    assert!(text.status.success());
    let said = String::from_utf8_lossy(&text.stdout);
    assert!(said.contains("optimum 10628 (published, checked: ") && said.contains("att48.opt.tour is that long"), "{said}");

    // Exit 1, one line naming the tour, its length and the figure.
    for (optimum, says) in [("10627", "att48.opt.tour is 10628 long, not the optimum 10627 given with --optimum: the gap would be false"), ("10629", "att48.opt.tour is 10628 long, shorter than the optimum 10629 given with --optimum")] {
        let out = ecp(&["--optimum", optimum]);
        assert_eq!(out.status.code(), Some(1));
        assert_clean_error(&out, says);
    }
    let out = ecp(&["--optimum", "0"]);
    assert_clean_error(&out, "--optimum: must be between 1 and 1000000000000, got 0");
    // The .tsp's own OPTIMAL line is checked too; --optimum wins over it.
    let text = std::fs::read_to_string(data.join("att48.tsp")).unwrap();
    let stated = dir.path().join("stated.tsp");
    std::fs::write(&stated, text.replacen("COMMENT", "OPTIMAL : 10600\nCOMMENT", 1)).unwrap();
    let with = |extra: &[&str]| laserd(&[&["bench", "ecp", "--tsp", stated.to_str().unwrap(), "--tour", tour, "--time-limit", "0.5", "--json"], extra].concat(), dir.path());
    assert_clean_error(&with(&[]), "att48.opt.tour is 10628 long, not the optimum 10600 of ");
    assert_clean_error(&with(&[]), "stated.tsp:2 (OPTIMAL): the gap would be false");
    assert_eq!(json(&with(&["--optimum", "10628"]))["optimum_source"], "published");
    // Without a tour only the plain TSP, measured against the stated figure.
    let untoured = json(&laserd(&["bench", "ecp", "--tsp", stated.to_str().unwrap(), "--no-precedence", "--time-limit", "0.5", "--json"], dir.path()));
    assert_eq!((untoured["optimum"].as_f64(), untoured["optimum_source"].as_str()), (Some(10600.0), Some("published")), "{untoured}");
    assert_clean_error(&laserd(&["bench", "ecp", "--tsp", tsp], dir.path()), "--tour is needed unless --no-precedence");

    let man = dir.path().join("man.tsp");
    std::fs::write(&man, "NAME : man\nTYPE : TSP\nCOMMENT : Manhattan\nDIMENSION : 3\nEDGE_WEIGHT_TYPE : MAN_2D\nNODE_COORD_SECTION\n1 0 0\n2 1 0\n3 0 1\nEOF\n").unwrap();
    let out = laserd(&["bench", "ecp", "--tsp", man.to_str().unwrap(), "--no-precedence", "--optimum", "4"], dir.path());
    assert_clean_error(&out, "man.tsp:5: EDGE_WEIGHT_TYPE MAN_2D is not supported (EUC_2D, CEIL_2D, ATT and GEO are)");
}

/// `gen galvo --n`: up to 100000 geometries, on a base grown beyond 5000;
/// outside the range, one line naming the flag and the range.
#[test]
fn gen_galvo_takes_up_to_100000_geometries() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("g.svg");
    let made = laserd(&["gen", "galvo", "--family", "rnd", "--n", "100000", "-o", out.to_str().unwrap()], dir.path());
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let svg = std::fs::read_to_string(&out).unwrap();
    assert_eq!(svg.matches("<rect ").count(), 100_000);
    assert!(svg.contains("viewBox=\"0 0 1342 1342\""), "{}", &svg[..300]);
    for n in ["0", "100001"] {
        assert_clean_error(&laserd(&["gen", "galvo", "--family", "rnd", "--n", n], dir.path()), &format!("--n: must be between 1 and 100000 geometries, got {n}"));
    }
}

/// `bench motion`: the compute time of trajectory, split and program against
/// the machine time they produce, per job and in all.
#[test]
fn bench_motion_reports_compute_time_against_machine_time() {
    let dir = tempfile::tempdir().unwrap();
    let r = json(&laserd(&["bench", "motion", &sample("one-field.svg"), &sample("marking-300.svg"), "--repeats", "1", "--json"], dir.path()));
    assert_eq!(r["mode"], "on-the-fly");
    let jobs = r["jobs"].as_array().unwrap();
    assert_eq!(jobs.len(), 2);
    let mut worst: f64 = 0.0;
    for job in jobs {
        let (machine, motion, share) = (job["machine_time_s"].as_f64().unwrap(), job["motion_time_s"].as_f64().unwrap(), job["share"].as_f64().unwrap());
        assert!(machine > 0.1 && motion > 0.0, "{job}");
        assert!((share - motion / machine).abs() < 1e-12, "{job}");
        worst = worst.max(share);
    }
    assert_eq!(r["worst_share"].as_f64().unwrap(), worst);
    let out = laserd(&["bench", "motion", "--json"], dir.path());
    assert_clean_error(&out, "at least one job");
}

/// The pseudo-terminal closing in the middle of a job (`--fault
/// close-link-at-line`): `send` stops with a message saying so, and the
/// simulator's recording of what ran is complete.
#[test]
fn send_reports_the_pseudo_terminal_closing_mid_job() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyGONE");
    let rec = dir.path().join("gone.mcap");
    let sim = SimProcess::start(&link, &["--baud", "1000000", "--record", rec.to_str().unwrap(), "--fault", "close-link-at-line=50"]);
    let nc = dir.path().join("job.nc");
    let mut text = String::from("G21G90G93\n");
    for i in 1..=400 {
        text.push_str(&format!("G1X{}F6000\n", i as f64 * 0.01));
    }
    std::fs::write(&nc, &text).unwrap();
    let out = laserd(&["send", nc.to_str().unwrap(), "--port", link.to_str().unwrap(), "--json"], dir.path());
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("closed the link") || err.contains("read failed"), "{err}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(report["last_acked_line"].as_u64().unwrap() <= 50);
    // The simulator ends by itself with the link, and its recording is whole.
    let status = sim.wait();
    assert!(status.success());
    let replay = laserd::record::read(&rec).unwrap();
    assert!(replay.truncated.is_none());
    assert!(!replay.log.knots.is_empty());
}

#[test]
fn an_unknown_fault_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    assert_clean_error(&laserd(&["sim", "--fault", "gremlins=3"], dir.path()), "gremlins");
    assert_clean_error(&laserd(&["sim", "--fault", "probe-contact-mm=-1"], dir.path()), "probe-contact-mm");
    assert_clean_error(&laserd(&["sim", "--fault", "drop-byte=x"], dir.path()), "drop-byte");
    assert_clean_error(&laserd(&["sim", "--fault", "drop-byte"], dir.path()), "drop-byte");
}

/// `laserd ctl` without a running service, and `laserd serve` with a config it
/// cannot use: one clear line each, non-zero, no panic.
#[test]
fn ctl_and_serve_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("none.sock");
    let out = laserd(&["ctl", "--socket", socket.to_str().unwrap(), "status"], dir.path());
    assert_clean_error(&out, "is `laserd serve` running?");
    let out = laserd(&["serve", "--config", dir.path().join("missing.toml").to_str().unwrap()], dir.path());
    assert_clean_error(&out, "missing.toml: cannot read");
    // A state folder it cannot create.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, "").unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml");
    let out = laserd(
        &["serve", "--config", config.to_str().unwrap(), "--state-dir", blocker.join("state").to_str().unwrap(), "--socket", socket.to_str().unwrap()],
        dir.path(),
    );
    assert_clean_error(&out, "cannot create");
}

/// Issue 17, point 5: a dry-run that breaks a limit of the machine exits
/// non-zero (4), lists each broken limit in its text report, and still
/// prints its JSON report. Under `--motion grbl` (a stock Grbl: trapezoids,
/// junction deviation) the jerk limits of every axis are broken; the TCP
/// stays on the path (once counted 5.97 mm off: each of Grbl's segments of
/// a block was taken for the whole block).
#[test]
fn a_dry_run_that_breaks_a_limit_fails_and_names_each_limit() {
    let dir = tempfile::tempdir().unwrap();
    let out = laserd(&["dry-run", &sample("one-field.svg"), "--motion", "grbl", "--json"], dir.path());
    assert_eq!(out.status.code(), Some(4), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("broke"), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("the JSON report still comes");
    let sim = &report["sim"];
    let breaches: Vec<&str> = sim["limit_breaches"].as_array().unwrap().iter().map(|b| b.as_str().unwrap()).collect();
    assert!(sim["limit_violations"].as_u64().unwrap() > 0, "{sim}");
    for axis in ["X", "Y"] {
        assert!(breaches.iter().any(|b| b.starts_with(&format!("jerk of {axis}: "))), "{breaches:?}");
    }
    assert!(sim["max_tcp_deviation_mm"].as_f64().unwrap() <= 0.0102, "{sim}");
    assert!(!breaches.iter().any(|b| b.contains("TCP deviation")), "{breaches:?}");
    let text = laserd(&["dry-run", &sample("one-field.svg"), "--motion", "grbl"], dir.path());
    assert_eq!(text.status.code(), Some(4));
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("LIMITS BROKEN (") && text.contains("jerk of X: "), "{text}");
    assert!(text.contains("a stock Grbl 1.1 cannot keep a jerk limit"), "{text}");
    // Within its limits, the same job passes with none listed.
    let report = json(&laserd(&["dry-run", &sample("one-field.svg"), "--json"], dir.path()));
    assert_eq!(report["sim"]["limit_breaches"], serde_json::json!([]));
}

/// Issue 17, point 6: a scanner field larger than the stage's travel is
/// planned, with a warning naming both settings.
#[test]
fn a_scanner_field_larger_than_the_travel_is_said() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml")).unwrap();
    let cfg = dir.path().join("wide.toml");
    std::fs::write(&cfg, text.replace("travel_x = 300.0", "travel_x = 60.0")).unwrap();
    let out = laserd(&["plan", &sample("one-field.svg"), "--config", cfg.to_str().unwrap()], dir.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("scanner.field_x = 70 mm is larger than stage.travel_x = 60 mm"), "{err}");
}

/// Issue 17, point 8: `replay --to-sim` runs the recording's own machine
/// (here the flatbed cutter run as a stock Grbl, `--motion grbl`, not the
/// default machine), and says what differs and why when it is not the same run.
#[test]
fn replay_to_sim_runs_the_recordings_machine_and_says_what_differs() {
    let dir = tempfile::tempdir().unwrap();
    let cutter = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let rec = dir.path().join("cut.mcap");
    let out = laserd(&["dry-run", &sample("one-field.svg"), "--config", cutter.to_str().unwrap(), "--motion", "grbl", "--record", rec.to_str().unwrap(), "--json"], dir.path());
    assert!(rec.exists(), "{}", String::from_utf8_lossy(&out.stderr));
    let again = json(&laserd(&["replay", rec.to_str().unwrap(), "--to-sim", "--json"], dir.path()));
    assert_eq!(again["same"], true, "{again}");
    assert_eq!(again["machine"], "the recording's");
    assert_eq!(again["differences"], serde_json::json!([]));
    // Another machine asked for: the differences, each saying why.
    let default = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml");
    let out = laserd(&["replay", rec.to_str().unwrap(), "--to-sim", "--json", "--config", default.to_str().unwrap()], dir.path());
    assert_eq!(out.status.code(), Some(3));
    let other: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let differences = other["differences"].as_array().unwrap();
    assert!(!differences.is_empty(), "{other}");
    for d in differences {
        assert!(d.as_str().unwrap().contains("is not the recording's"), "{d}");
    }

    // A recording made on the controller's side (`laserd sim --record`) of
    // `laserd send`: every difference of the re-simulation is explained.
    let nc = dir.path().join("one.nc");
    let out = laserd(&["plan", &sample("one-field.svg"), "-o", nc.to_str().unwrap()], dir.path());
    assert!(out.status.success());
    let link = dir.path().join("tty");
    let sim_rec = dir.path().join("sim.mcap");
    let sim = SimProcess::start(&link, &["--record", sim_rec.to_str().unwrap()]);
    let sent = json(&laserd(&["send", nc.to_str().unwrap(), "--port", link.to_str().unwrap(), "--json"], dir.path()));
    assert_eq!(sent["completed"], true);
    sim.terminate();
    let out = laserd(&["replay", sim_rec.to_str().unwrap(), "--to-sim", "--json"], dir.path());
    let replayed: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(replayed["machine"], "the recording's");
    for d in replayed["differences"].as_array().unwrap() {
        let d = d.as_str().unwrap();
        let (figure, why) = d.split_once(": ").unwrap();
        assert!(why.contains("re-simulated: "), "each difference says why: {d}");
        if figure == "lines_sent" {
            assert!(d.contains("line(s) of its own"), "{d}");
        }
    }
    assert_eq!(out.status.code(), Some(if replayed["same"] == true { 0 } else { 3 }));
}

/// A recording is untrusted: the machine it holds is checked as a config
/// file is before `replay --to-sim` runs it, the setting named.
#[test]
fn replay_to_sim_refuses_a_recorded_machine_out_of_range() {
    use laserd::record::{Recording, TOPIC_LINK, TOPIC_SETUP};
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("hostile.mcap");
    let mut machine = laserd::config::MachineConfig::builtin();
    machine.serial.rx_buffer = 0;
    machine.simulator.planner_blocks = 1 << 40;
    let sim = laserd::run::sim_config(&machine, Default::default());
    let setup = laserd::run::run_setup(&machine, &sim);
    let recording = Recording::create(&rec).unwrap();
    let recorder = recording.recorder();
    recorder.write(TOPIC_SETUP, 0.0, &setup);
    recorder.write(TOPIC_LINK, 0.1, &laserd::record::LinkMessage { t: 0.1, event: laserd::stream::LinkEvent::Sent { line: 1, text: "G4P0.1".into() } });
    drop(recorder);
    recording.finish().unwrap();
    let out = laserd(&["replay", rec.to_str().unwrap(), "--to-sim"], dir.path());
    assert_clean_error(&out, "hostile.mcap: the recorded machine: serial.rx_buffer: must be between");
}
