//! What the service takes in: job files (uploaded or, from configured
//! folders only, by path), checked by size and by content, and planned each
//! in a child process of its own with bounded time and memory. A hostile or
//! broken file fails alone: the service, its API and the controller link go on.

use std::io::Read;
use std::os::unix::fs::OpenOptionsExt;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::config::MachineConfig;
use crate::plan::PlannerKind;
use crate::error::{Error, Result};
// The G-code checks live with the pipeline (the dry-run of a G-code file uses them too).
pub use crate::run::gcode::{check_gcode, JobKind, GCODE_EXTENSIONS};

/// Reads a job file the operator named by path: only inside `folders`
/// (symbolic links resolved), only a regular file, at most `max_bytes`.
/// Returns the file's name and bytes.
pub fn read_by_path(path: &str, folders: &[String], max_bytes: usize) -> Result<(String, Vec<u8>)> {
    if folders.is_empty() {
        return Err(Error::Forbidden("submitting by path is off: upload the file, or list the folders the service may read jobs from in [service] job_folders".into()));
    }
    let outside = || Error::Forbidden(format!("{path}: not inside the job folders ([service] job_folders)"));
    let real = std::fs::canonicalize(path).map_err(|_| outside())?;
    let inside = |p: &Path| folders.iter().filter_map(|f| std::fs::canonicalize(f).ok()).any(|f| p.starts_with(f));
    if !inside(&real) {
        return Err(outside());
    }
    // Opened without following a link swapped in since, without waiting on
    // a FIFO; then checked again by what was opened.
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(nix::libc::O_NOFOLLOW | nix::libc::O_NONBLOCK)
        .open(&real)
        .map_err(|e| Error::Config(format!("{path}: cannot read: {e}")))?;
    let opened = std::fs::read_link(format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(&file))).unwrap_or_else(|_| real.clone());
    if !inside(&opened) {
        return Err(outside());
    }
    let bytes = crate::import::read_regular(file, max_bytes, path)?;
    let name = real.file_name().and_then(|n| n.to_str()).unwrap_or("job").to_string();
    Ok((name, bytes))
}

/// What planning a job gave: the child's answer.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct PlanResult {
    pub lines: usize,
    pub planned_time_s: Option<f64>,
    pub start: Option<Vec<f64>>,
    /// Cuts after their part has fallen out, in the planned order.
    #[serde(default)]
    pub precedence_violations: Option<u64>,
    /// Where the marks lie (work mm: x min, y min, x max, y max).
    #[serde(default)]
    pub bounds: Option<[f64; 4]>,
    #[serde(default)]
    pub figures: Option<super::queue::JobFigures>,
    /// Set when the job cannot run: why.
    pub error: Option<String>,
}

/// Most lines of a G-code job whose time is estimated (simulating 4,344
/// lines took 0.1 s here, so this cap holds it near a second, well inside
/// `[service] plan_timeout`); a longer one runs without an ETA.
const GCODE_TIME_LINES: usize = 50_000;

/// A G-code job as Grbl's planner runs it on this machine, simulated in
/// virtual time: its time (the ETA), each line's end (`times`, next to
/// `program`) and where the laser is on. None past `GCODE_TIME_LINES`, or
/// where the simulated run stops.
fn gcode_run(source: &Path, program_path: &Path, lines: usize, machine: &MachineConfig) -> Option<(f64, Option<[f64; 4]>)> {
    if lines > GCODE_TIME_LINES {
        return None;
    }
    let mut grbl = machine.clone();
    grbl.simulator.motion = laserd_sim::controller::MotionModel::Grbl;
    let program = crate::run::gcode::read_gcode(source, &grbl).ok()?;
    let (outcome, log) = crate::run::gcode::simulate(&program, Vec::new(), &grbl, None).ok()?;
    if outcome.stop_reason.is_some() {
        return None;
    }
    let figures = crate::figures::sim_figures(&log);
    // Times by line only where the simulated lines are the file's lines.
    if program.lines.len() == lines {
        let start = log.knots.first().map_or(0.0, |k| k.t);
        let mut ends = vec![(None, None); lines];
        for k in &log.knots {
            if let Some(end) = (k.line as usize).checked_sub(1).and_then(|i| ends.get_mut(i)) {
                let at = |i: usize| k.pos.get(i).copied().unwrap_or(0.0);
                *end = (Some(k.t - start), Some([at(0) + at(2), at(1) + at(3)]));
            }
        }
        let _ = super::eta::LineTimes::from_ends(ends).write(&program_path.with_file_name(TIMES_FILE));
    }
    // The TCP where the laser is on: stage plus scanner.
    let lit = log.knots.windows(2).filter(|w| w[1].power > 0.0).flat_map(|w| [&w[0], &w[1]]).map(|k| {
        let at = |i: usize| k.pos.get(i).copied().unwrap_or(0.0);
        crate::job::Point::new(at(0) + at(2), at(1) + at(3))
    });
    let bounds = bounds_of(lit);
    Some((figures.job_time_s, bounds))
}

use super::queue::{PLOT_FILE, TIMES_FILE};

/// The box round some points, if there are any.
fn bounds_of(points: impl Iterator<Item = crate::job::Point>) -> Option<[f64; 4]> {
    points.fold(None, |b: Option<[f64; 4]>, p| {
        Some(match b {
            None => [p.x, p.y, p.x, p.y],
            Some([x0, y0, x1, y1]) => [x0.min(p.x), y0.min(p.y), x1.max(p.x), y1.max(p.y)],
        })
    })
}

/// The child's side (`laserd plan-job`): plans or checks `source`, writes the
/// program to `program` and the result as JSON to `result`. The config comes
/// as text on standard input: the service's, as it was loaded.
/// `place`: the operator's work origin (`X,Y`), for `[job] anchor`.
pub fn plan_job_child(source: &Path, name: &str, program: &Path, result: &Path, allow_precedence_violations: bool, place: Option<&str>) -> Result<()> {
    let mut config = String::new();
    std::io::stdin().take(1 << 20).read_to_string(&mut config).map_err(|e| Error::Config(format!("standard input: {e}")))?;
    let mut machine = MachineConfig::parse(&config, "the service's config")?;
    if let Some(place) = place {
        machine.job.anchor = place.parse().map_err(|e| Error::Config(format!("--place: {e}")))?;
    }
    let answer = match plan_or_check(source, name, program, &machine, PlannerKind::Auto, allow_precedence_violations) {
        Ok(answer) => answer,
        Err(e) => PlanResult { error: Some(e.to_string()), ..Default::default() },
    };
    let text = serde_json::to_vec(&answer).map_err(|e| Error::Io(e.to_string()))?;
    super::queue::write_atomic(result, &text)
}

/// Plans an SVG, DXF or job-file job with `planner` (the service's is `auto`), refusing an
/// order with precedence violations unless `allow_precedence_violations`:
/// the answer then carries the count and the error, and no program is
/// written. G-code is checked as the controller parses it.
fn plan_or_check(source: &Path, name: &str, program: &Path, machine: &MachineConfig, planner: PlannerKind, allow_precedence_violations: bool) -> Result<PlanResult> {
    let bytes = std::fs::read(source).map_err(|e| Error::Io(format!("{name}: cannot read: {e}")))?;
    match JobKind::of(name, &bytes)? {
        JobKind::Gcode => {
            let text = String::from_utf8_lossy(&bytes);
            let lines = check_gcode(name, &text, machine)?;
            super::queue::write_atomic(program, text.as_bytes())?;
            let run = gcode_run(source, program, lines, machine);
            Ok(PlanResult { lines, planned_time_s: run.map(|r| r.0), bounds: run.and_then(|r| r.1), ..Default::default() })
        }
        JobKind::Svg | JobKind::Dxf | JobKind::Json => {
            let named = |e: Error| Error::Plan(e.to_string().replace(&source.display().to_string(), name));
            let planned = crate::run::plan(source, machine, planner, None).map_err(named)?;
            let precedence_violations = planned.report.precedence_violations;
            if let Err(refused) = planned.check_precedence(allow_precedence_violations, "the submission's allow_precedence_violations") {
                let why = refused.to_string().replace(&source.display().to_string(), name);
                return Ok(PlanResult { precedence_violations, error: Some(why), ..Default::default() });
            }
            super::queue::write_atomic(program, planned.program.to_gcode().as_bytes())?;
            // What the operator's screen shows: the picture, each line's
            // planned end (the ETA), the figures, where the marks lie (framing).
            super::eta::LineTimes::of_program(&planned.program).write(&program.with_file_name(TIMES_FILE))?;
            // Titled with the name it was submitted under, not the stored file's.
            let caption = crate::plot::Caption { job: name.to_string(), ..crate::plot::Caption::of(&planned.report) };
            let picture = crate::plot::plot_captioned(&planned.job, &planned.sequence, &planned.trajectory, machine, planned.drawn.as_ref(), &caption);
            super::queue::write_atomic(&program.with_file_name(PLOT_FILE), picture.as_bytes())?;
            let report = &planned.report;
            let figures = super::queue::JobFigures {
                geometries: report.geometries,
                scan_fields: report.scan_fields,
                mark_length_mm: report.mark_length_mm,
                pierces: report.pierces,
                planner: report.planner.clone(),
                mode: report.mode.clone(),
            };
            Ok(PlanResult {
                lines: planned.program.lines.len(),
                planned_time_s: Some(report.trajectory_time_s),
                start: Some(planned.program.start.clone()),
                precedence_violations,
                bounds: bounds_of(planned.sequence.paths().flat_map(|p| p.points.iter().copied())),
                figures: Some(figures),
                error: None,
            })
        }
    }
}

/// What the submission asks of a job's planning.
#[derive(Debug, Clone, Copy, Default)]
pub struct PlanAsked {
    /// Plan and run an order that cuts after a part has fallen out.
    pub allow_precedence_violations: bool,
    /// The operator's work origin: the job's lower-left corner there.
    pub place: Option<[f64; 2]>,
}

/// Bounds on a job's planning.
pub struct PlanLimits {
    pub timeout: Duration,
    pub memory_bytes: u64,
}

/// Plans a job in a child process (this program's `plan-job`), under
/// `limits`; the child is killed when `cancelled` says so. An answer with
/// an `error` is a job planned but refused (its figures are kept); `Err`,
/// one that could not be planned.
pub fn plan_in_child(
    config_text: &str,
    source: &Path,
    name: &str,
    program: &Path,
    asked: PlanAsked,
    limits: &PlanLimits,
    cancelled: &dyn Fn() -> bool,
) -> Result<PlanResult> {
    let exe = std::env::current_exe().map_err(|e| Error::Io(format!("cannot find laserd's own program to plan with: {e}")))?;
    let result = program.with_file_name("plan-result.json");
    let _ = std::fs::remove_file(&result);
    let memory = limits.memory_bytes;
    let mut command = Command::new(exe);
    command
        .arg("plan-job")
        .arg(source)
        .args(["--name", name])
        .arg("--program")
        .arg(program)
        .arg("--result")
        .arg(&result)
        .args(asked.allow_precedence_violations.then_some("--allow-precedence-violations"))
        .args(asked.place.map(|[x, y]| format!("--place={x},{y}")))
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit());
    // SAFETY: setrlimit is async-signal-safe; nothing else runs in the fork.
    unsafe {
        command.pre_exec(move || {
            let limit = nix::libc::rlimit { rlim_cur: memory, rlim_max: memory };
            if nix::libc::setrlimit(nix::libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = command.spawn().map_err(|e| Error::Io(format!("{name}: cannot start planning: {e}")))?;
    if let Some(mut stdin) = child.stdin.take() {
        use std::io::Write;
        // A child that died at once closed its end: its exit says why.
        let _ = stdin.write_all(config_text.as_bytes());
    }
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().map_err(|e| Error::Io(format!("{name}: planning: {e}")))? {
            break status;
        }
        let stop = if cancelled() {
            Some(Error::Plan(format!("{name}: planning cancelled")))
        } else if started.elapsed() > limits.timeout {
            Some(Error::Plan(format!("{name}: planning took more than {} s ([service] plan_timeout)", limits.timeout.as_secs_f64())))
        } else {
            None
        };
        if let Some(why) = stop {
            let _ = child.kill();
            let _ = child.wait();
            return Err(why);
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let answer = std::fs::File::open(&result).ok().and_then(|f| {
        let mut text = Vec::new();
        f.take(16 << 20).read_to_end(&mut text).ok()?;
        serde_json::from_slice::<PlanResult>(&text).ok()
    });
    let _ = std::fs::remove_file(&result);
    match (answer, status.code(), status.signal()) {
        (Some(answer), Some(0), _) => Ok(answer),
        (_, _, Some(signal)) if signal == nix::libc::SIGABRT || signal == nix::libc::SIGSEGV || signal == nix::libc::SIGKILL => Err(Error::Plan(format!(
            "{name}: planning ran out of memory or crashed (signal {signal}; [service] plan_memory_mb = {})",
            memory / (1 << 20)
        ))),
        (_, code, signal) => Err(Error::Plan(format!("{name}: planning failed unexpectedly (exit {code:?}, signal {signal:?}); the service log has its message"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn machine() -> MachineConfig {
        MachineConfig::load(Some(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/laserd.toml"))).unwrap()
    }

    #[test]
    fn a_job_file_is_taken_by_what_it_is_not_by_its_name() {
        let svg = br#"<?xml version="1.0"?><svg xmlns="http://www.w3.org/2000/svg"/>"#;
        assert_eq!(JobKind::of("a.svg", svg).unwrap(), JobKind::Svg);
        assert_eq!(JobKind::of("a.GCODE", b"G21\nG0 X1\n").unwrap(), JobKind::Gcode);
        assert_eq!(JobKind::of("a.DXF", b"0\nSECTION\n").unwrap(), JobKind::Dxf);
        assert_eq!(JobKind::of("a.json", b"{\"format\": \"laserd-job\"}").unwrap(), JobKind::Json);
        assert_eq!(JobKind::of("a.dxf", b"AutoCAD Binary DXF\r\n\x1a\x00\xff\xfe").unwrap(), JobKind::Dxf, "binary DXF is no text");
        let cases: [(&str, &[u8], &str); 7] = [
            ("shadow", b"root:$y$j9T$abc:19000:0:99999:7:::\n", "not a job file"),
            ("a.svg", b"G21\nG0 X1\n", "not an SVG"),
            ("a.nc", svg, "SVG document named as G-code"),
            ("a.nc", b"G0 X1\n\x7fELF\x02\x01", "control character"),
            ("a.nc", b"G0 X1\n\xff\xfe", "not UTF-8"),
            ("a.step", b"ISO-10303-21;\n", "not a job file"),
            ("a.dxf", svg, "SVG document named as DXF"),
        ];
        for (name, bytes, says) in cases {
            let err = JobKind::of(name, bytes).unwrap_err().to_string();
            assert!(err.contains(name) && err.contains(says), "{name}: {err}");
        }
    }

    #[test]
    fn by_path_only_regular_files_inside_the_job_folders_up_to_the_size_limit() {
        let dir = tempfile::tempdir().unwrap();
        let jobs = dir.path().join("jobs");
        std::fs::create_dir(&jobs).unwrap();
        let folders = vec![jobs.display().to_string()];
        let part = jobs.join("part.nc");
        std::fs::write(&part, b"G0 X1\n").unwrap();
        let secret = dir.path().join("token");
        std::fs::write(&secret, b"G0 X2\n").unwrap();
        std::os::unix::fs::symlink(&secret, jobs.join("link.nc")).unwrap();
        std::os::unix::fs::symlink("/dev/zero", jobs.join("zero.nc")).unwrap();
        nix::unistd::mkfifo(&jobs.join("fifo.nc"), nix::sys::stat::Mode::S_IRWXU).unwrap();
        let read = |p: &Path, folders: &[String], max| read_by_path(p.to_str().unwrap(), folders, max);

        assert_eq!(read(&part, &folders, 1000).unwrap(), ("part.nc".to_string(), b"G0 X1\n".to_vec()));
        assert!(matches!(read(&part, &[], 1000), Err(Error::Forbidden(m)) if m.contains("off")), "off unless folders are configured");
        for outside in [secret.clone(), jobs.join("link.nc"), jobs.join("zero.nc"), PathBuf::from("/etc/passwd"), jobs.join("../token")] {
            assert!(matches!(read(&outside, &folders, 1000), Err(Error::Forbidden(_))), "{}", outside.display());
        }
        let started = Instant::now();
        let err = read(&jobs.join("fifo.nc"), &folders, 1000).unwrap_err().to_string();
        assert!(err.contains("not a regular file") && started.elapsed() < Duration::from_secs(2), "{err}");
        assert!(matches!(read(&part, &folders, 3), Err(Error::TooLarge(_))));
    }

    #[test]
    fn a_dxf_job_and_a_job_file_are_planned_like_an_svg_one_with_their_time() {
        let dir = tempfile::tempdir().unwrap();
        let source = dir.path().join("source.dxf");
        let line = |(x0, y0): (f64, f64), (x1, y1): (f64, f64)| format!("0\nLINE\n8\n0\n10\n{x0}\n20\n{y0}\n11\n{x1}\n21\n{y1}\n");
        let square = [line((10.0, 10.0), (30.0, 10.0)), line((30.0, 10.0), (30.0, 30.0)), line((30.0, 30.0), (10.0, 30.0)), line((10.0, 30.0), (10.0, 10.0))].concat();
        std::fs::write(&source, format!("0\nSECTION\n2\nENTITIES\n{square}0\nENDSEC\n0\nEOF\n")).unwrap();
        let program = dir.path().join("program.nc");
        let planned = plan_or_check(&source, "square.dxf", &program, &machine(), PlannerKind::Auto, false).unwrap();
        assert!(planned.error.is_none() && planned.planned_time_s.is_some_and(|t| t > 0.0) && planned.lines > 4, "{planned:?}");
        assert_eq!(std::fs::read_to_string(&program).unwrap().lines().count(), planned.lines);
        // The same job as laserd's own job file plans to the same time.
        let job = crate::import::import_job(&source, &machine()).unwrap();
        let job_file = dir.path().join("source.json");
        std::fs::write(&job_file, serde_json::to_string(&crate::import::json::to_file(&job, None)).unwrap()).unwrap();
        assert_eq!(JobKind::of("square.json", &std::fs::read(&job_file).unwrap()).unwrap(), JobKind::Json);
        let from_file = plan_or_check(&job_file, "square.json", &program, &machine(), PlannerKind::Auto, false).unwrap();
        assert_eq!(from_file.planned_time_s, planned.planned_time_s, "{from_file:?}");
    }

    #[test]
    fn an_order_with_precedence_violations_is_refused_unless_the_submission_allows_it() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut machine = MachineConfig::load(Some(&root.join("config/flatbed-cutter.toml"))).unwrap();
        machine.cutting.time_limit = Some(1.0);
        let dir = tempfile::tempdir().unwrap();
        let source = dir.path().join("source.svg");
        std::fs::copy(root.join("samples/nested-sheet.svg"), &source).unwrap();
        let program = dir.path().join("program.nc");
        // The galvo planner alone cuts holes after their parts: refused,
        // with the count and the first rules named after the job, no program.
        let refused = plan_or_check(&source, "sheet.svg", &program, &machine, PlannerKind::Hha, false).unwrap();
        let count = refused.precedence_violations.unwrap();
        let why = refused.error.unwrap();
        assert!(count > 0);
        assert!(why.starts_with("plan: sheet.svg: ") && why.contains(&format!("{count} precedence violation(s)")) && why.contains(" subpath 1 cut after path #"), "{why}");
        assert!(why.contains("allow_precedence_violations"), "says how to override: {why}");
        assert!(!program.exists());
        let allowed = plan_or_check(&source, "sheet.svg", &program, &machine, PlannerKind::Hha, true).unwrap();
        // (The galvo planner's search is capped in time: its count may differ.)
        assert!(allowed.precedence_violations.unwrap() > 0 && allowed.error.is_none(), "{allowed:?}");
        assert!(std::fs::read_to_string(&program).unwrap().lines().count() == allowed.lines);
        // The service's planner keeps every rule.
        let auto = plan_or_check(&source, "sheet.svg", &program, &machine, PlannerKind::Auto, false).unwrap();
        assert_eq!((auto.precedence_violations, auto.error), (Some(0), None));
    }

    #[test]
    fn gcode_is_checked_as_the_controller_parses_it_and_errors_name_the_line() {
        let machine = machine();
        assert_eq!(check_gcode("ok.nc", "G21 G90\n(a comment)\n\nG1 X10 Y10 F600 M4 S100\nM5\n", &machine).unwrap(), 5);
        for (text, says) in [
            ("G21\nroot:$y$j9T$abc:19000:0:99999:7:::\n", "ok.nc:2 `root:$y$j9T$abc:19000:0:99999:7:::`: error:"),
            ("G21\n$RST=*\n", "ok.nc:2 `$RST=*`: a system command"),
            ("G21\nG1 X1 F100 G0\n", "ok.nc:2"),
        ] {
            let err = check_gcode("ok.nc", text, &machine).unwrap_err().to_string();
            assert!(err.contains(says), "{text:?}: {err}");
        }
        let long = format!("G1 X1 F100 ({})\nG1X{}\n", "c".repeat(500), "1".repeat(300));
        let err = check_gcode("long.nc", &long, &machine).unwrap_err().to_string();
        assert!(err.contains("long.nc:2") && err.contains("error:11") && err.contains("… (303 bytes)"), "{err}");
        assert!(err.len() < 400, "the line is quoted by its start: {err}");
    }

    #[test]
    fn a_gcode_job_gets_its_time_as_grbls_planner_runs_it() {
        let dir = tempfile::tempdir().unwrap();
        let source = dir.path().join("source.nc");
        // 50 mm at 10 mm/s with the laser on, after a 10 mm rapid.
        std::fs::write(&source, "G21 G90\nG0 X10\nM4 S500\nG1 X60 F600\nM5\n").unwrap();
        let program = dir.path().join("program.nc");
        let checked = plan_or_check(&source, "part.nc", &program, &machine(), PlannerKind::Auto, false).unwrap();
        let t = checked.planned_time_s.expect("an ETA");
        assert!((5.0..5.5).contains(&t), "{t} s");
        assert_eq!(std::fs::read(&program).unwrap(), std::fs::read(&source).unwrap(), "streamed as it is");
    }
}
