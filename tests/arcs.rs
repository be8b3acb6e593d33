//! Arcs on the wire: a stage-only program of circles sent with G2/G3 takes
//! far fewer lines than with straight blocks only, and the simulated Grbl
//! (which cuts each arc into chords by `$12`) follows the plan as closely and
//! as fast, within every limit.
//!
//! Stage-only marks run from rest to rest at every vertex today, so no run of
//! blocks there has the constant speed of an arc; the trajectory here is the
//! on-the-fly TCP of the circles (blended, at speed) given to a stage that
//! follows the TCP and has the limits the TCP was planned with.

use laserd::config::MachineConfig;
use laserd::figures::{sim_figures, PlannedLine, SimFigures};
use laserd::job::{Geometry, Job, Point, Process};
use laserd::mode::Mode;
use laserd::motion::stage::StagePath;
use laserd::motion::{build, AxisState, Trajectory};
use laserd::plan::{nearest::NearestNeighbour, PlanContext, Planner};
use laserd::program::{self, Program};
use laserd::run;
use laserd::stream::SenderOptions;
use laserd_sim::controller::Faults;

fn circles() -> Job {
    let circle = |cx: f64, cy: f64, r: f64| {
        let n = 128;
        let points = (0..n)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / n as f64;
                Point::new(cx + r * a.cos(), cy + r * a.sin())
            })
            .collect();
        Geometry { arcs: Vec::new(), profile: Vec::new(), points, closed: true, process: 0, source: format!("circle at {cx},{cy}") }
    };
    Job {
        source: "circles".into(),
        geometries: vec![circle(140.0, 150.0, 8.0), circle(160.0, 150.0, 6.0), circle(150.0, 165.0, 4.0)],
        processes: vec![Process { layer: "cut".into(), speed: 50.0, power: 500.0, passes: 1, fill: false }],
    }
}

fn simulate(program: &Program, machine: &MachineConfig) -> SimFigures {
    let sim = run::sim_config(machine, Faults::default());
    let setup = run::run_setup(machine, &sim);
    let options = SenderOptions::new(machine.serial.rx_buffer, machine.serial.status_hz);
    let (_, log) = run::stream_into_simulator(program, sim, 115_200, &options, None).unwrap();
    sim_figures(&laserd::figures::RunLog { setup: Some(setup), planned: PlannedLine::from_program(program), ..log })
}

#[test]
fn a_stage_only_job_of_circles_sends_arcs_in_fewer_lines_as_closely_and_as_fast() {
    // The TCP planned on the fly...
    let planning = MachineConfig::load(None).unwrap();
    let scanner = planning.scanner_limits().unwrap();
    let job = circles();
    let planning_machine = Mode::OnTheFly.planning_machine(&planning);
    let ctx = PlanContext { machine: &planning_machine, mode: Mode::OnTheFly, start: Point::origin(), plate: None };
    let sequence = NearestNeighbour.plan(&job, &ctx).unwrap();
    let on_the_fly = build(&job, &sequence, &planning, Mode::OnTheFly, Point::origin()).unwrap();
    // ...run by an XY machine whose stage follows it, with the scanner's limits.
    let mut machine = planning.clone();
    machine.scanner = None;
    (machine.stage.max_velocity, machine.stage.max_acceleration, machine.stage.max_jerk) = (scanner.velocity, scanner.acceleration, scanner.jerk);
    machine.serial.baud = 115_200;
    let start = AxisState { stage: on_the_fly.start.tcp(), scanner: Point::origin() };
    let trajectory = Trajectory { tcp: on_the_fly.tcp, stage: StagePath::FollowsTcp, start, job_start: on_the_fly.job_start, has_scanner: false, stage_flow: None, head: None };

    let with_arcs = program::generate(&job, &trajectory, &machine).unwrap();
    let mut lines_only = machine.clone();
    lines_only.program.arcs = false;
    let straight = program::generate(&job, &trajectory, &lines_only).unwrap();
    // G2 or G3, not G21.
    let is_arc = |text: &str| (text.starts_with("G2") || text.starts_with("G3")) && !text[2..].starts_with(|c: char| c.is_ascii_digit());
    let arcs = with_arcs.lines.iter().filter(|l| is_arc(&l.text)).count();
    assert!(arcs >= 3, "{arcs} arc blocks");
    assert!(!straight.lines.iter().any(|l| is_arc(&l.text)), "arcs = false: straight blocks only");
    assert!(2 * with_arcs.lines.len() <= straight.lines.len(), "{} lines with arcs, {} without", with_arcs.lines.len(), straight.lines.len());

    let (a, s) = (simulate(&with_arcs, &machine), simulate(&straight, &lines_only));
    // A unit of the last decimal on each axis: what rounding adds.
    let bound = machine.program.tolerance + 2.0 * 10f64.powi(-(machine.program.decimals as i32));
    for (what, f) in [("arcs", &a), ("straight", &s)] {
        assert_eq!(f.limit_violations, 0, "{what}: {:?}", f.limit_breaches);
        assert!(f.limit_breaches.is_empty(), "{what}: {:?}", f.limit_breaches);
        assert!(f.alarms.is_empty(), "{what}: {:?}", f.alarms);
        let deviation = f.max_tcp_deviation_mm.expect("a planned program has check points");
        assert!(deviation <= bound, "{what}: deviation {deviation} mm, bound {bound}");
    }
    assert!(a.lines_sent < s.lines_sent);
    assert!(a.planner_starved_s <= s.planner_starved_s + 1e-6, "starved: arcs {} s, straight {} s", a.planner_starved_s, s.planner_starved_s);
    assert!(a.job_time_s <= s.job_time_s + 1e-3, "arcs {} s, straight {} s", a.job_time_s, s.job_time_s);
}

/// An ellipse within 0.012 mm of a circle of 10 mm, run at 200 mm/s in
/// straight blocks of 5 ms, reached along its tangent from far away (a long first and
/// last segment, so that the checker's rest before and after the knots asks
/// for nothing): `position(t)` and the block ends.
fn near_circle() -> (impl Fn(f64) -> Point, Vec<f64>) {
    let (cx, cy, omega) = (100.0, 100.0, 20.0);
    let on_ellipse = move |t: f64| Point::new(cx + 10.012 * (omega * t).cos(), cy + 9.988 * (omega * t).sin());
    let turn = std::f64::consts::TAU / omega;
    let position = move |t: f64| {
        if t < 0.0 {
            on_ellipse(0.0) + Point::new(0.0, 9.988 * omega * t).coords
        } else if t > turn {
            on_ellipse(turn) + Point::new(0.0, 9.988 * omega * (t - turn)).coords
        } else {
            on_ellipse(t)
        }
    };
    let times: Vec<f64> = (0..=62).map(|k| k as f64 * 0.005).chain([turn]).collect();
    (position, times)
}

/// The knots a timed controller runs through for `blocks` (from
/// `arcs::merge`): the block ends as written, each arc's chord ends; with a
/// far knot on the tangent 100 s before and after.
fn executed_knots(position: &impl Fn(f64) -> Point, times: &[f64], blocks: &[(usize, Option<program::arcs::ArcWords>)], decimals: usize) -> Vec<laserd_sim::Knot> {
    let written = |t: f64| {
        let p = position(t);
        let round = |v: f64| (v * 10f64.powi(decimals as i32)).round() / 10f64.powi(decimals as i32);
        Point::new(round(p.x), round(p.y))
    };
    let mut knots = vec![(-100.0, written(-100.0)), (times[0], written(times[0]))];
    let mut from = 0;
    for &(to, arc) in blocks {
        match arc {
            Some(arc) => knots.extend(program::arcs::chord_knots(written(times[from]), written(times[to]), &arc, times[from], times[to]).expect("a fitted arc runs")),
            None => knots.push((times[to], written(times[to]))),
        }
        from = to;
    }
    let end = times[times.len() - 1];
    knots.push((end + 100.0, written(end + 100.0)));
    knots.into_iter().map(|(t, p)| laserd_sim::Knot { t, pos: vec![p.x, p.y], power: 0.0, line: 1 }).collect()
}

/// The simulator's limit checker (X and Y with `limits`) over `knots`.
fn check_limits(limits: laserd::config::Limits, knots: &[laserd_sim::Knot]) -> laserd_sim::LimitReport {
    let axes: Vec<laserd_sim::AxisConfig> = ['X', 'Y']
        .into_iter()
        .map(|letter| laserd_sim::AxisConfig { letter, min: -1e5, max: 1e5, max_velocity: limits.velocity, max_acceleration: limits.acceleration, max_jerk: limits.jerk })
        .collect();
    let mut checker = laserd_sim::LimitChecker::new(&axes);
    knots.iter().for_each(|k| checker.push(k));
    checker.finish()
}

#[test]
fn an_arc_is_taken_only_where_its_chords_keep_the_controllers_limits() {
    let flatbed = MachineConfig::load(Some(std::path::Path::new("config/flatbed-cutter.toml"))).unwrap();
    let limits = flatbed.stage_limits();
    let check = |knots: &[laserd_sim::Knot]| check_limits(limits, knots);
    let (position, times) = near_circle();
    let decimals = flatbed.program.decimals;
    // The blocks as written, straight only, keep the limits.
    let straight: Vec<_> = (1..times.len()).map(|j| (j, None)).collect();
    let report = check(&executed_knots(&position, &times, &straight, decimals));
    assert_eq!(report.violations, 0, "{:?}", report.first_violation);
    // Fitted by position alone (limits that ask for nothing), the ellipse
    // becomes arcs whose chords break the jerk limit.
    let unlimited = laserd::config::Limits { velocity: f64::INFINITY, acceleration: f64::INFINITY, jerk: f64::INFINITY };
    let by_position = program::arcs::merge(&times, decimals, 0.018, unlimited, 0, &position);
    assert!(by_position.iter().any(|(_, arc)| arc.is_some()), "{by_position:?}");
    let report = check(&executed_knots(&position, &times, &by_position, decimals));
    assert!(report.violations > 0, "{report:?}");
    // With the machine's limits, every arc taken keeps them.
    let kinematic = program::arcs::merge(&times, decimals, 0.018, limits, 0, &position);
    let report = check(&executed_knots(&position, &times, &kinematic, decimals));
    assert_eq!(report.violations, 0, "{:?} {kinematic:?}", report.first_violation);
    eprintln!("arcs kept: {}", kinematic.iter().filter(|(_, a)| a.is_some()).count());
}

/// A circle of 10 mm run speeding up from 150 to 170 mm/s at 200 mm/s²
/// (the end of a stage-only curve's ramp), reached and left along its
/// tangents from far away, in straight blocks of 4 ms: `position(t)`, the
/// speed along it and the block ends.
fn ramp_on_circle() -> (impl Fn(f64) -> Point, impl Fn(f64) -> f64, Vec<f64>) {
    let (cx, cy, r, v0, accel, ramp) = (100.0, 100.0, 10.0, 150.0, 200.0, 0.1);
    let angle = move |t: f64| (v0 * t + 0.5 * accel * t * t) / r;
    let on_circle = move |t: f64| Point::new(cx + r * angle(t).cos(), cy + r * angle(t).sin());
    let tangent = move |t: f64| Point::new(-angle(t).sin(), angle(t).cos());
    let position = move |t: f64| {
        if t < 0.0 {
            on_circle(0.0) + tangent(0.0).coords * (v0 * t)
        } else if t > ramp {
            on_circle(ramp) + tangent(ramp).coords * ((v0 + accel * ramp) * (t - ramp))
        } else {
            on_circle(t)
        }
    };
    let times: Vec<f64> = (0..=25).map(|k| k as f64 * 0.004).collect();
    (position, move |t: f64| v0 + accel * t.clamp(0.0, ramp), times)
}

#[test]
fn a_curve_speeding_up_is_sent_as_arcs_that_keep_its_place_and_the_limits() {
    let flatbed = MachineConfig::load(Some(std::path::Path::new("config/flatbed-cutter.toml"))).unwrap();
    let limits = flatbed.stage_limits();
    let check = |knots: &[laserd_sim::Knot]| check_limits(limits, knots);
    let (position, speed, times) = ramp_on_circle();
    let (decimals, tolerance) = (flatbed.program.decimals, flatbed.program.tolerance);
    let straight: Vec<_> = (1..times.len()).map(|j| (j, None)).collect();
    assert_eq!(check(&executed_knots(&position, &times, &straight, decimals)).violations, 0);

    let merged = program::arcs::merge(&times, decimals, 0.9 * tolerance, limits, 0, &position);
    let arcs = merged.iter().filter(|(_, arc)| arc.is_some()).count();
    assert!(arcs >= 2 && merged.len() < straight.len(), "{merged:?}");
    // Every arc spans a change of speed (an arc covers two blocks or more:
    // at least 1 %), which the controller's constant-speed chords meet.
    let mut from = 0;
    for &(to, arc) in &merged {
        if arc.is_some() {
            let (v0, v1) = (speed(times[from]), speed(times[to]));
            assert!(v1 - v0 > 0.01 * v0, "{v0} -> {v1} mm/s");
        }
        from = to;
    }
    let knots = executed_knots(&position, &times, &merged, decimals);
    let report = check(&knots);
    assert_eq!(report.violations, 0, "{:?} {merged:?}", report.first_violation);
    // Run straight from knot to knot (the chords at their times), the
    // machine stays within the tolerance of the plan at every instant.
    for w in knots.windows(2).filter(|w| w[0].t >= 0.0 && w[1].t <= times[times.len() - 1]) {
        for q in 0..8 {
            let f = q as f64 / 8.0;
            let t = w[0].t + f * (w[1].t - w[0].t);
            let run = Point::new(w[0].pos[0] + f * (w[1].pos[0] - w[0].pos[0]), w[0].pos[1] + f * (w[1].pos[1] - w[0].pos[1]));
            let off = (run - position(t)).norm();
            assert!(off <= tolerance, "{off} mm off the plan at t = {t}");
        }
    }
}

#[test]
fn after_a_pierce_arcs_do_not_keep_the_controller_waiting() {
    // Circles cut on the flatbed (a pierce before each), stage-only: after
    // each dwell the controller starts once its queue holds a rest point;
    // an arc's long line must not be what it waits for.
    let machine = MachineConfig::load(Some(std::path::Path::new("config/flatbed-cutter.toml"))).unwrap();
    assert!(machine.laser.pierce_time > 0.0);
    let mut job = circles();
    for g in &mut job.geometries {
        for p in &mut g.points {
            *p = Point::new(150.0 + 2.0 * (p.x - 150.0), 150.0 + 2.0 * (p.y - 150.0));
        }
    }
    let planning_machine = Mode::StageOnly.planning_machine(&machine);
    let ctx = PlanContext { machine: &planning_machine, mode: Mode::StageOnly, start: Point::origin(), plate: None };
    let sequence = NearestNeighbour.plan(&job, &ctx).unwrap();
    let trajectory = build(&job, &sequence, &machine, Mode::StageOnly, Point::origin()).unwrap();
    let with_arcs = program::generate(&job, &trajectory, &machine).unwrap();
    let mut lines_only = machine.clone();
    lines_only.program.arcs = false;
    let straight = program::generate(&job, &trajectory, &lines_only).unwrap();
    assert!(with_arcs.lines.iter().any(|l| l.text.starts_with("G2G94") || l.text.starts_with("G3G94")));
    assert!(2 * with_arcs.lines.len() <= straight.lines.len(), "{} lines with arcs, {} without", with_arcs.lines.len(), straight.lines.len());
    let (a, s) = (simulate(&with_arcs, &machine), simulate(&straight, &lines_only));
    for (what, f) in [("arcs", &a), ("straight", &s)] {
        assert!(f.limit_breaches.is_empty() && f.alarms.is_empty(), "{what}: {:?} {:?}", f.limit_breaches, f.alarms);
    }
    // (Within 0.1 ms over the job: an arc kept waiting costs ~2 ms a pierce.)
    assert!(a.planner_starved_s <= s.planner_starved_s + 1e-4, "starved: arcs {} s, straight {} s", a.planner_starved_s, s.planner_starved_s);
    assert!(a.job_time_s <= s.job_time_s + 1e-4, "arcs {} s, straight {} s", a.job_time_s, s.job_time_s);
}

/// `send`'s ETA goes by a laserd program's planned time read back from its
/// words: G93 blocks, arcs at their feed, dwells; line by line it is the
/// time the program was planned for (to the rounding of its words), on a
/// stage-only job with arcs and pierces and on a galvo job.
#[test]
fn a_programs_planned_time_is_read_back_from_its_words_line_by_line() {
    let cutter = MachineConfig::load(Some(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/flatbed-cutter.toml"))).unwrap();
    let galvo = MachineConfig::load(None).unwrap();
    for (machine, mode) in [(&cutter, Mode::StageOnly), (&galvo, Mode::OnTheFly)] {
        let planning_machine = mode.planning_machine(machine);
        let job = circles();
        let ctx = PlanContext { machine: &planning_machine, mode, start: Point::origin(), plate: None };
        let sequence = NearestNeighbour.plan(&job, &ctx).unwrap();
        let trajectory = build(&job, &sequence, machine, mode, Point::origin()).unwrap();
        let program = program::generate(&job, &trajectory, machine).unwrap();
        let arcs = program.lines.iter().filter(|l| (l.text.starts_with("G2") || l.text.starts_with("G3")) && !l.text.starts_with("G21")).count();
        assert_eq!(arcs > 0, mode == Mode::StageOnly, "{mode:?}: {arcs} arcs");
        assert!(mode != Mode::StageOnly || program.lines.iter().any(|l| l.text.starts_with("G4P")), "the cutter's pierces dwell");
        let text = program.to_gcode();
        let times = program::times::PlannedTimes::read(text.lines().map(Ok::<_, laserd::error::Error>)).unwrap();
        // Every 64th line (where the times are kept exactly) against the plan.
        let mut planned = 0.0;
        for (k, line) in program.lines.iter().enumerate() {
            planned += line.plan_time.map_or(0.0, |(a, b)| b - a);
            if (k + 1) % 64 == 0 || k + 1 == program.lines.len() {
                let read = times.through(k + 1);
                assert!((read - planned).abs() <= 1e-4 * planned.max(1.0), "{mode:?} line {}: {read} s read, {planned} s planned", k + 1);
            }
        }
        assert!((times.total_s - trajectory.duration()).abs() <= 1e-3 * trajectory.duration(), "{mode:?}: {} s read, {} s planned", times.total_s, trajectory.duration());
    }
}
