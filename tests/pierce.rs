//! Pierces end to end: the sample job planned and dry-run on a machine whose
//! layers pierce every cut entry, against the same machine without pierces.

use std::path::Path;

use laserd::mode::Mode;
use laserd::config::{MachineConfig, DEFAULT_CONFIG_PATH};
use laserd::figures::{program_line_of, program_lines};
use laserd::plan::PlannerKind;
use laserd::program::{tcp_of, LineKind};
use laserd::run;
use laserd::stream::{in_process, Connection, Control, SenderOptions};
use laserd_sim::controller::{Controller, Faults, Knot};
use laserd_sim::wire::MachineState;
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// Dry-runs are CPU-bound: the tests of this file take turns, as those of
/// `pipeline.rs` do.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn take_turn() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn sample(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples").join(name)
}

const PIERCE_TIME: f64 = 0.2;
const PIERCE_POWER: f64 = 800.0;

/// The shipped machine, piercing every path for `time` seconds at 800.
fn machine(time: f64) -> MachineConfig {
    let text = std::fs::read_to_string(DEFAULT_CONFIG_PATH).unwrap();
    assert!(text.contains("pierce_time = 0.0\n") && text.contains("# pierce_power = 1000.0"));
    let text = text
        .replace("pierce_time = 0.0\n", &format!("pierce_time = {time}\n"))
        .replace("# pierce_power = 1000.0", &format!("pierce_power = {PIERCE_POWER}"));
    MachineConfig::parse(&text, "pierce.toml").unwrap()
}

/// Rest intervals (same position, time passing) with the laser on, as (start,
/// end, power, the knot that ends it); back-to-back ones at one place are one
/// (the laser lit before the dwell line arrived).
fn burning_rests(knots: &[Knot]) -> Vec<(f64, f64, f64, &Knot)> {
    let mut burns: Vec<(f64, f64, f64, &Knot)> = Vec::new();
    for w in knots.windows(2).filter(|w| w[0].pos == w[1].pos && w[1].t > w[0].t && w[1].power > 0.0) {
        match burns.last_mut() {
            Some(last) if last.1 == w[0].t && last.3.pos == w[0].pos => {
                last.1 = w[1].t;
                last.2 = last.2.max(w[1].power);
                last.3 = &w[1];
            }
            _ => burns.push((w[0].t, w[1].t, w[1].power, &w[1])),
        }
    }
    burns
}

#[test]
fn a_dry_run_pierces_every_entry_standing_still_at_the_pierce_power() {
    let _turn = take_turn();
    let (plain_machine, pierce_machine) = (machine(0.0), machine(PIERCE_TIME));
    // Step-and-scan: every mark from rest with or without a pierce, so the
    // pierces add exactly their time.
    let mode = Some(Mode::StepAndScan);
    let plain = run::plan(&sample("one-field.svg"), &plain_machine, PlannerKind::Nearest, mode).unwrap();
    let planned = run::plan(&sample("one-field.svg"), &pierce_machine, PlannerKind::Nearest, mode).unwrap();
    let paths: Vec<_> = planned.sequence.paths().collect();
    assert_eq!(paths.len(), plain.sequence.paths().count());
    assert!(paths.len() >= 20, "the sample has many paths: {}", paths.len());
    let pierces = PIERCE_TIME * paths.len() as f64;

    // Without a pierce time the program has no pierce; with one, each path's
    // entry has M3 at the pierce power, the dwell and M4, before its cut.
    assert!(!plain.program.lines.iter().any(|l| l.kind == LineKind::Pierce || l.text.contains("G4")));
    let lines = &planned.program.lines;
    let starts: Vec<usize> = lines.iter().enumerate().filter(|(_, l)| l.text.starts_with("G1M3")).map(|(i, _)| i).collect();
    assert_eq!(starts.len(), paths.len(), "one pierce per planned path");
    for (&i, path) in starts.iter().zip(&paths) {
        let texts: Vec<&str> = lines[i..i + 3].iter().map(|l| l.text.as_str()).collect();
        assert_eq!(texts, ["G1M3S800F60", "G4P0.2", "M4"]);
        assert!(lines[i..i + 3].iter().all(|l| l.kind == LineKind::Pierce && l.geometry == Some(path.geometry)));
        assert_eq!(lines[i + 3].kind, LineKind::Mark);
    }
    assert_eq!(lines.iter().filter(|l| l.kind == LineKind::Pierce).count(), 3 * paths.len());

    // Planned: the trajectory is longer by the pierces, and so is the bound.
    let (p, q) = (&plain.report, &planned.report);
    assert!((q.trajectory_time_s - p.trajectory_time_s - pierces).abs() < 1e-9, "{} vs {}", q.trajectory_time_s, p.trajectory_time_s);
    assert!(q.lower_bound_s >= pierces && q.lower_bound_s <= q.trajectory_time_s);
    assert!((q.lower_bound_s - p.lower_bound_s - pierces).abs() < 1e-9, "T_proc holds the pierces: {} vs {}", q.lower_bound_s, p.lower_bound_s);
    assert_eq!(q.mark_length_mm, p.mark_length_mm);
    assert_eq!(q.idle_stroke_mm, p.idle_stroke_mm);

    // Simulated: the job takes about the pierces longer, within every limit,
    // the laser right on every block, no dwell counted as starvation.
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("pierce.mcap");
    let dry_plain = run::dry_run(&plain, &plain_machine, &dir.path().join("plain.mcap"), Faults::default()).unwrap();
    let dry = run::dry_run(&planned, &pierce_machine, &rec, Faults::default()).unwrap();
    assert!(dry_plain.outcome.completed && dry.outcome.completed, "{:?}", dry.outcome.stop_reason);
    let (a, b) = (dry_plain.report.sim.as_ref().unwrap(), dry.report.sim.as_ref().unwrap());
    eprintln!("without pierces: {}\nwith pierces:    {}", serde_json::to_string(a).unwrap(), serde_json::to_string(b).unwrap());
    assert_eq!(b.limit_violations, 0, "{b:?}");
    assert_eq!(b.laser_state_errors, 0, "{b:?}");
    assert!(b.alarms.is_empty());
    assert!(b.max_tcp_deviation_mm.unwrap() <= a.max_tcp_deviation_mm.unwrap() + 1e-9, "{b:?}");
    // About the pierces longer (the link fills the controller's buffers while
    // it dwells, so it starves a little less); without the waits for data,
    // exactly the pierces longer.
    let grown = b.job_time_s - a.job_time_s;
    assert!((grown - pierces).abs() <= 0.1 * pierces, "job time grew by {grown} s for {pierces} s of pierces");
    let busy = |f: &laserd::figures::SimFigures| f.job_time_s - f.planner_starved_s;
    for (figures, report) in [(a, &dry_plain.report), (b, &dry.report)] {
        assert!((busy(figures) - report.trajectory_time_s).abs() < 1e-3, "{} vs planned {}", busy(figures), report.trajectory_time_s);
    }
    assert!(busy(b) - busy(a) >= pierces - 1e-3, "{} vs {}", busy(b), busy(a));
    assert!(b.planner_starved_s < a.planner_starved_s + 0.05 * pierces, "dwells are no starvation: {} vs {}", b.planner_starved_s, a.planner_starved_s);
    assert!(b.job_time_s >= q.trajectory_time_s * 0.999);

    // The executed motion, as recorded: at every entry the machine stands
    // still with the laser at the pierce power for the pierce time, and
    // nowhere else; the knot that ends it belongs to the dwell line.
    let replay = laserd::record::read(&rec).unwrap();
    assert_eq!(replay.log.knots, dry.log.knots, "the recording holds the knots");
    let received = program_lines(&replay.log.link);
    let burns = burning_rests(&replay.log.knots);
    assert_eq!(burns.len(), paths.len(), "{burns:?}");
    for ((start, end, power, knot), path) in burns.iter().zip(&paths) {
        assert!((end - start - PIERCE_TIME).abs() < 1e-6, "{start}..{end}");
        assert_eq!(*power, PIERCE_POWER);
        assert!((tcp_of(&knot.pos) - path.start()).norm() < 1e-4, "at the entry of geometry {}", path.geometry);
        let line = program_line_of(&received, knot);
        assert!(planned.program.lines[line - 1].text.starts_with("G4"), "{}", planned.program.lines[line - 1].text);
    }
    assert!(burning_rests(&dry_plain.log.knots).is_empty(), "no pierce, no standing burn");
}

#[test]
fn a_hold_during_a_pierce_darkens_it_an_abort_leaves_it_dark_and_a_resume_pierces_again() {
    let _turn = take_turn();
    let machine = machine(PIERCE_TIME);
    let planned = run::plan(&sample("one-field.svg"), &machine, PlannerKind::Nearest, None).unwrap();
    let lines: Vec<String> = planned.program.lines.iter().map(|l| l.text.clone()).collect();
    let paths: Vec<_> = planned.sequence.paths().collect();
    // Program line (1-based) of the third pierce's first line.
    let third = lines.iter().enumerate().filter(|(_, l)| l.starts_with("G1M3")).nth(2).unwrap().0 + 1;
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().start_paused(true).build().unwrap();
    let knots = std::cell::RefCell::new(Vec::<Knot>::new());
    let (held_at, outcome, resumed_from, resumed) = runtime.block_on(async {
        let (sender_io, sim_io) = tokio::io::duplex(1 << 16);
        let origin = tokio::time::Instant::now();
        let (stop_tx, stop_rx) = watch::channel(false);
        let controller = Controller::new(run::sim_config(&machine, Faults::default()));
        let sim = in_process::run(controller, sim_io, machine.serial.baud, origin, stop_rx, |k| knots.borrow_mut().extend(k));
        let operator = async {
            let mut options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
            options.expect_start = Some(planned.program.start.clone());
            let mut c = Connection::open(sender_io, &options, |_, _| {}).await.unwrap();
            let (tx, mut rx) = mpsc::unbounded_channel();
            let buttons = async {
                // Wait for the third pierce to light, then hold half way through it.
                let lit = || knots.borrow().iter().filter(|k| k.power == PIERCE_POWER).count();
                while lit() < 5 {
                    tokio::time::sleep(Duration::from_millis(2)).await;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
                let held_at = origin.elapsed().as_secs_f64();
                tx.send(Control::FeedHold).unwrap();
                tokio::time::sleep(Duration::from_millis(500)).await;
                tx.send(Control::Abort).unwrap();
                held_at
            };
            let describe = |n: usize, _: &str| format!("line {n}");
            let (outcome, held_at) = tokio::join!(c.stream(lines.iter().cloned().map(Ok), &describe, Some(&mut rx)), buttons);
            // Resumed at the interrupted pierce's first line: it pierces again.
            let resumed_from = knots.borrow().len();
            let letters = machine.axis_letters();
            let resumed = c.resume(lines.iter().cloned().map(Ok), third, &letters, &describe, None).await.unwrap();
            let _ = stop_tx.send(true);
            (held_at, outcome.unwrap(), resumed_from, resumed)
        };
        let (_, r) = tokio::join!(sim, operator);
        r
    });
    assert!(!outcome.completed);
    assert!(outcome.stop_reason.as_deref().unwrap().contains("aborted by the operator"));
    let status = outcome.final_status.unwrap();
    assert_eq!(status.state, MachineState::Idle);
    assert_eq!(status.spindle.unwrap_or(0.0), 0.0);
    // Two whole pierces, the third cut short by the hold (the laser off at
    // once, though the dwell was not over), and nothing lit after it.
    let knots = knots.into_inner();
    let (aborted, after) = knots.split_at(resumed_from);
    let burns = burning_rests(aborted);
    assert_eq!(burns.len(), 3, "{burns:?}");
    assert!(burns[..2].iter().all(|b| (b.1 - b.0 - PIERCE_TIME).abs() < 1e-6));
    let (start, end, power, _) = burns[2];
    assert_eq!(power, PIERCE_POWER);
    assert!(end - start < PIERCE_TIME && (end - held_at).abs() < 0.01, "lit {start}..{end}, held at {held_at}");
    assert!(aborted.iter().filter(|k| k.t > end + 1e-9).all(|k| k.power == 0.0), "dark after the hold");
    assert_eq!(aborted.last().unwrap().power, 0.0);
    // The resumed job pierces the third path again, whole, at its entry, and
    // every later one.
    assert!(resumed.completed, "{:?}", resumed.stop_reason);
    let burns = burning_rests(after);
    assert_eq!(burns.len(), paths.len() - 2, "{burns:?}");
    let (start, end, power, knot) = burns[0];
    assert!(end - start >= PIERCE_TIME - 1e-9 && end - start < PIERCE_TIME + 0.01 && power == PIERCE_POWER, "{:?}", burns[0]);
    assert!((tcp_of(&knot.pos) - paths[2].start()).norm() < 1e-4);
}

/// The shipped flatbed cutter, piercing every cut for 0.2 s, or not at all.
fn flatbed(pierce: bool) -> MachineConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml");
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains("\npierce_time = 0.2\n"));
    let text = if pierce { text } else { text.replace("\npierce_time = 0.2\n", "\npierce_time = 0.0\n") };
    MachineConfig::parse(&text, "flatbed.toml").unwrap()
}

#[test]
fn a_long_cut_job_waits_after_each_pierce_for_the_lines_the_dwell_held_back_and_never_stops_inside_a_cut() {
    let _turn = take_turn();
    // A sheet of nested parts, ordered by nearest (deterministic): many cuts of
    // short blocks at 50 mm/s on a 115200-baud link and a 128-byte buffer.
    // While the controller dwells, the `G4` and `M4` lines hold its receive
    // buffer, so only a few blocks of the cut are in when the dwell ends.
    let dir = tempfile::tempdir().unwrap();
    let params = laserd::gen::sheet::SheetParams::with_target(120);
    let job = dir.path().join("sheet.svg");
    let sheet = laserd::gen::sheet::generate_sheet(&params, 3);
    std::fs::write(&job, laserd::gen::sheet::to_svg(&sheet, &params)).unwrap();
    let (plain_machine, pierce_machine) = (flatbed(false), flatbed(true));
    let plain = run::plan(&job, &plain_machine, PlannerKind::Nearest, None).unwrap();
    let planned = run::plan(&job, &pierce_machine, PlannerKind::Nearest, None).unwrap();
    let paths: Vec<_> = planned.sequence.paths().collect();
    assert!(paths.len() >= 30, "{} paths", paths.len());
    let pierces = PIERCE_TIME * paths.len() as f64;

    let dry_plain = run::dry_run(&plain, &plain_machine, &dir.path().join("plain.mcap"), Faults::default()).unwrap();
    let dry = run::dry_run(&planned, &pierce_machine, &dir.path().join("pierce.mcap"), Faults::default()).unwrap();
    assert!(dry_plain.outcome.completed && dry.outcome.completed, "{:?}", dry.outcome.stop_reason);
    let (a, b) = (dry_plain.report.sim.as_ref().unwrap(), dry.report.sim.as_ref().unwrap());
    eprintln!("without pierces: {}\nwith pierces:    {}", serde_json::to_string(a).unwrap(), serde_json::to_string(b).unwrap());
    assert_eq!((a.limit_violations, a.planner_starved_s), (0, 0.0), "{a:?}");
    // The controller starts a cut only once the rest point after it is
    // queued: within every limit, whatever the link delivers.
    assert_eq!(b.limit_violations, 0, "{b:?}");
    assert_eq!(b.laser_state_errors, 0, "{b:?}");

    // It waits only standing at a cut's entry, after the pierce, for the lines
    // the dwell held back; never inside a cut. The rest of the time is the
    // plan's (without pierces the cuts also take the laser-off moves' speed
    // over, so the plain job is faster by more than the pierces).
    let knots = &dry.log.knots;
    let dwells = laserd::figures::dwell_lines(&dry.log.link);
    let moving = |w: &[Knot]| w[0].pos != w[1].pos;
    let (first, last) = (knots.windows(2).position(moving).unwrap(), knots.windows(2).rposition(moving).unwrap());
    let waits: Vec<&[Knot]> = knots[first..=last + 1].windows(2).filter(|w| !moving(w) && w[1].t > w[0].t && !dwells.contains(&w[1].line)).collect();
    for w in &waits {
        let at = tcp_of(&w[0].pos);
        assert!(paths.iter().any(|p| (at - p.start()).norm() < 1e-4), "waited {} s at {at:?}, not at a cut's entry (t = {})", w[1].t - w[0].t, w[0].t);
    }
    let waited: f64 = waits.iter().map(|w| w[1].t - w[0].t).sum();
    assert!((waited - b.planner_starved_s).abs() < 1e-9, "{waited} vs {}", b.planner_starved_s);
    assert!(b.planner_starved_s < 0.05 * pierces, "short waits: {} s for {} pierces", b.planner_starved_s, paths.len());
    let busy = |f: &laserd::figures::SimFigures| f.job_time_s - f.planner_starved_s;
    for (figures, report) in [(a, &dry_plain.report), (b, &dry.report)] {
        assert!((busy(figures) - report.trajectory_time_s).abs() < 1e-3, "{} vs planned {}", busy(figures), report.trajectory_time_s);
    }
    assert!(busy(b) - busy(a) >= pierces - 1e-3, "{} vs {}", busy(b), busy(a));
}
