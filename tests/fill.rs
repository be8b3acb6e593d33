//! Fill layers through the pipeline as a user runs them: the area each
//! drawing encloses, hatched and marked once, the laser on exactly along
//! the hatch, at speed on overscanned lines, within the machine's limits in
//! the simulator, and never slower than the plain raster of the same hatch.

use std::path::{Path, PathBuf};

use laserd::config::MachineConfig;
use laserd::motion::tcp::PieceKind;
use laserd::plan::PlannerKind;
use laserd::run;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn config(name: &str, edit: impl Fn(String) -> String) -> MachineConfig {
    let text = std::fs::read_to_string(root().join("config").join(name)).unwrap();
    MachineConfig::parse(&edit(text), name).unwrap()
}

fn engraver() -> MachineConfig {
    config("xy-engraver.toml", |t| t)
}

fn svg_job(dir: &Path, name: &str, body: &str) -> PathBuf {
    let path = dir.join(name);
    let svg = format!("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"200mm\" height=\"100mm\" viewBox=\"0 0 200 100\">\n{body}</svg>\n");
    std::fs::write(&path, svg).unwrap();
    path
}

/// The marked length along the trajectory (laser on, moving).
fn marked_length(planned: &run::Planned) -> f64 {
    planned
        .trajectory
        .tcp
        .pieces
        .iter()
        .filter(|p| matches!(p.kind, PieceKind::Mark { .. }))
        .map(|p| {
            let n = 64;
            (0..n).map(|k| (p.position(p.duration * (k + 1) as f64 / n as f64) - p.position(p.duration * k as f64 / n as f64)).norm()).sum::<f64>()
        })
        .sum()
}

#[test]
fn a_drawing_is_filled_as_its_fill_rule_says_and_overlaps_are_marked_once() {
    let dir = tempfile::tempdir().unwrap();
    let spacing = 0.1;
    // 40 x 40 with a 20 x 20 square inside, both drawn the same way round:
    // even-odd leaves a hole, nonzero fills it; a star drawn as one crossing
    // line fills its middle by nonzero only; two overlapping squares are one area.
    let square = |x: f64, y: f64, s: f64| format!("M{x} {y}h{s}v{s}h-{s}Z");
    let cases = [
        (format!(r#"<path fill="black" fill-rule="evenodd" d="{}{}"/>"#, square(20.0, 20.0, 40.0), square(30.0, 30.0, 20.0)), 1600.0 - 400.0),
        (format!(r#"<path fill="black" d="{}{}"/>"#, square(20.0, 20.0, 40.0), square(30.0, 30.0, 20.0)), 1600.0),
        (format!(r#"<path fill="black" d="{}"/><path fill="black" d="{}"/>"#, square(20.0, 20.0, 30.0), square(40.0, 30.0, 30.0)), 900.0 + 900.0 - 200.0),
    ];
    let machine = engraver();
    for (k, (body, area)) in cases.iter().enumerate() {
        let job = svg_job(dir.path(), &format!("case{k}.svg"), body);
        let planned = run::plan(&job, &machine, PlannerKind::Auto, None).unwrap();
        let hatch: f64 = planned.job.geometries.iter().filter(|g| planned.job.processes[g.process].fill).map(|g| g.length()).sum();
        assert!((hatch * spacing - area).abs() < 0.01 * area, "case {k}: {} mm² hatched of {area}", hatch * spacing);
        // The trajectory marks exactly the hatch: overlaps once, gaps with the laser off.
        let marked = marked_length(&planned);
        assert!((marked - hatch).abs() < 1e-3 * hatch, "case {k}: marked {marked} of {hatch} mm");
        assert_eq!(planned.report.fill_areas, Some(1), "case {k}: one outline with or without its hole");
    }
}

#[test]
fn overscanned_hatch_lines_are_marked_at_their_speed_from_end_to_end() {
    let machine = engraver();
    let planned = run::plan(&root().join("samples/fill-logo.svg"), &machine, PlannerKind::Auto, None).unwrap();
    let speed = machine.layers.iter().find(|l| l.name == "fill").unwrap().speed;
    let marks: Vec<_> = planned.trajectory.tcp.pieces.iter().filter(|p| matches!(p.kind, PieceKind::Mark { .. })).collect();
    assert!(marks.len() > 1000);
    for p in &marks {
        for t in [0.0, 0.5 * p.duration, p.duration] {
            let v = p.motion.velocity(t).norm();
            assert!((v - speed).abs() < 1e-6 * speed, "a hatch line marked at {v} mm/s, not {speed}");
        }
    }
    // Without overscan the lines start and end at rest.
    let plain = config("xy-engraver.toml", |t| t.replace("hatch_spacing = 0.1\n", "hatch_spacing = 0.1\noverscan = false\n"));
    let planned = run::plan(&root().join("samples/fill-logo.svg"), &plain, PlannerKind::Auto, None).unwrap();
    let slow_ends = planned.trajectory.tcp.pieces.iter().filter(|p| matches!(p.kind, PieceKind::Mark { .. }) && p.motion.velocity(0.0).norm() < 0.5 * speed).count();
    assert!(slow_ends > 100, "{slow_ends}");
}

#[test]
fn a_one_way_fill_marks_every_line_the_hatch_way_and_a_cross_hatch_adds_the_other() {
    let one_way = config("xy-engraver.toml", |t| t.replace("hatch_spacing = 0.1\n", "hatch_spacing = 0.1\nbidirectional = false\nhatch_angle = 30.0\n"));
    let job = root().join("samples/fill-logo.svg");
    let planned = run::plan(&job, &one_way, PlannerKind::Auto, None).unwrap();
    let way = nalgebra::Vector2::new(30f64.to_radians().cos(), 30f64.to_radians().sin());
    let fill_paths: Vec<_> = planned.sequence.paths().filter(|p| planned.job.processes[p.process].fill && planned.job.processes[p.process].power > 0.0).collect();
    assert!(!fill_paths.is_empty());
    for p in &fill_paths {
        let d = (p.end() - p.start()).normalize();
        assert!((d - way).norm() < 1e-6, "marked {d} against the hatch's {way}");
    }
    let crossed = config("xy-engraver.toml", |t| t.replace("hatch_spacing = 0.1\n", "hatch_spacing = 0.1\ncross_hatch = true\n"));
    let plain = run::plan(&job, &engraver(), PlannerKind::Auto, None).unwrap();
    let both = run::plan(&job, &crossed, PlannerKind::Auto, None).unwrap();
    let length = |p: &run::Planned| p.job.geometries.iter().filter(|g| p.job.processes[g.process].fill).map(|g| g.length()).sum::<f64>();
    assert!((length(&both) / length(&plain) - 2.0).abs() < 0.02, "a cross-hatch marks the area twice over");
}

#[test]
fn fills_keep_every_limit_in_the_simulator_and_are_never_slower_than_the_plain_raster() {
    // Stage-only (overscan near the bed's edge included: the logo moved to the corner) and on the fly.
    let dir = tempfile::tempdir().unwrap();
    let corner = std::fs::read_to_string(root().join("samples/fill-logo.svg")).unwrap().replace("<g id=\"logo\">", "<g id=\"logo\" transform=\"translate(-105,100)\">");
    let corner_job = dir.path().join("corner.svg");
    std::fs::write(&corner_job, corner).unwrap();
    let galvo = config("laserd.toml", |t| t);
    let cases = [
        (root().join("samples/fill-text.svg"), engraver(), 1.0),
        (root().join("samples/fill-halftone.svg"), engraver(), 1.0),
        // Against the bed's corner overscan rests where it would leave the
        // travel, which the time objective does not model: a route it
        // prefers can come out a little slower there.
        (corner_job, engraver(), 1.001),
        (root().join("samples/fill-text.svg"), galvo.clone(), 0.95),
        (root().join("samples/fill-logo.svg"), galvo, 0.95),
    ];
    for (job, machine, at_most) in cases {
        let mut times = Vec::new();
        for kind in [PlannerKind::Auto, PlannerKind::Raster] {
            let planned = run::plan(&job, &machine, kind, None).unwrap();
            let (sim, _) = run::measure(&planned, &machine).unwrap();
            assert_eq!(sim.limit_violations, 0, "{} {kind:?}: {:?}", job.display(), sim.limit_breaches);
            assert!(sim.limit_breaches.is_empty() && sim.laser_state_errors == 0, "{} {kind:?}: {:?}", job.display(), sim.limit_breaches);
            assert!(sim.max_tcp_deviation_mm.unwrap() <= 0.02, "{} {kind:?}: {:?}", job.display(), sim.max_tcp_deviation_mm);
            times.push(sim.job_time_s);
        }
        let ratio = times[0] / times[1];
        assert!(ratio <= at_most + 1e-9, "{}: the fill takes {ratio:.6} ({times:?}) of the raster's time", job.display());
    }
}

#[test]
fn a_fill_layer_that_pierces_and_an_open_shape_on_a_fill_layer_are_refused_by_name() {
    let text = std::fs::read_to_string(root().join("config/xy-engraver.toml")).unwrap();
    let err = MachineConfig::parse(&text.replacen("hatch_spacing = 0.1\n", "hatch_spacing = 0.1\npierce_time = 0.3\n", 1), "e.toml").unwrap_err().to_string();
    assert!(err.contains("layer[0] (engrave).mode") && err.contains("pierce"), "{err}");
    let err = MachineConfig::parse(&text.replacen("hatch_spacing = 0.1\n", "hatch_spacing = 0.0\n", 1), "e.toml").unwrap_err().to_string();
    assert!(err.contains("hatch_spacing") && err.contains('0'), "{err}");
    // An SVG line filled: it encloses nothing, and its layer only fills.
    let dir = tempfile::tempdir().unwrap();
    let job = svg_job(dir.path(), "line.svg", r#"<path id="stray" d="M10 10 L50 10" stroke="black"/>"#);
    let err = run::plan(&job, &engraver(), PlannerKind::Auto, None).err().unwrap().to_string();
    assert!(err.contains("path 'stray'") && err.contains("encloses no area") && err.contains("engrave"), "{err}");
}

#[test]
fn the_fill_plan_is_the_same_every_time() {
    let machine = config("laserd.toml", |t| t);
    let job = root().join("samples/fill-text.svg");
    let a = run::plan(&job, &machine, PlannerKind::Auto, None).unwrap();
    let b = run::plan(&job, &machine, PlannerKind::Auto, None).unwrap();
    assert_eq!(a.program.lines.iter().map(|l| &l.text).collect::<Vec<_>>(), b.program.lines.iter().map(|l| &l.text).collect::<Vec<_>>());
    assert_eq!(a.report.objective, "time");
}

#[test]
fn the_fishhead_bench_orders_the_seeds_grid_and_each_objective_wins_its_own_figure() {
    let machine = engraver();
    let objectives: Vec<String> = ["time", "heat"].iter().map(|s| s.to_string()).collect();
    let r = laserd::bench::fill::fill_bench(&machine, &root().join("samples/fishhead.svg"), 3.0, 1.0, &objectives, &[1]).unwrap();
    assert!(r.points > 300, "{} points", r.points);
    let (time, heat) = (&r.objectives[0].runs[0], &r.objectives[1].runs[0]);
    for run in [time, heat] {
        assert!(run.length_mm >= r.length_lower_bound_mm - 1e-9 && run.time_s >= r.time_lower_bound_s - 1e-9);
        assert!(run.turns < r.points);
    }
    assert!(time.time_s < heat.time_s, "time {} against heat's {}", time.time_s, heat.time_s);
    assert!(heat.heat < time.heat, "heat {} against time's {}", heat.heat, time.heat);
}
