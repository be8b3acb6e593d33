//! Cutting technology on whole jobs: kerf offsets and leads through the
//! pipeline as a user runs it, checked here independently of the planner's
//! own bookkeeping (material and waste by a crossing-number count of the
//! drawn contours, crossings by segment tests over a grid of buckets).

use std::collections::HashMap;
use std::path::Path;

use laserd::config::MachineConfig;
use laserd::gen::sheet::{generate_sheet, to_svg, SheetParams};
use laserd::job::{Job, Point};
use laserd::plan::PlannerKind;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The flatbed cutter with `settings` added to its "cut" layer.
fn flatbed_with(settings: &str) -> MachineConfig {
    let text = std::fs::read_to_string(root().join("config/flatbed-cutter.toml")).unwrap();
    MachineConfig::parse(&text.replacen("name = \"cut\"\n", &format!("name = \"cut\"\n{settings}\n"), 1), "flatbed.toml").unwrap()
}

/// An SVG document of 100 x 60 mm holding `body`, written to `dir/name`.
fn svg_job(dir: &Path, name: &str, body: &str) -> std::path::PathBuf {
    let path = dir.join(name);
    let svg = format!("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"100mm\" height=\"60mm\" viewBox=\"0 0 100 60\">\n{body}</svg>\n");
    std::fs::write(&path, svg).unwrap();
    path
}

/// Segments in square buckets, for finding the ones near a point or segment.
struct Buckets {
    cell: f64,
    map: HashMap<(i64, i64), Vec<Tagged>>,
}

/// A segment and whose it is.
type Tagged = (Point, Point, usize);

impl Buckets {
    fn new(cell: f64) -> Buckets {
        Buckets { cell, map: HashMap::new() }
    }

    fn cells(&self, a: Point, b: Point, margin: f64) -> impl Iterator<Item = (i64, i64)> {
        let c = |v: f64| (v / self.cell).floor() as i64;
        let (x0, x1, y0, y1) = (c(a.x.min(b.x) - margin), c(a.x.max(b.x) + margin), c(a.y.min(b.y) - margin), c(a.y.max(b.y) + margin));
        (x0..=x1).flat_map(move |x| (y0..=y1).map(move |y| (x, y)))
    }

    fn add(&mut self, a: Point, b: Point, tag: usize) {
        for cell in self.cells(a, b, 0.0).collect::<Vec<_>>() {
            self.map.entry(cell).or_default().push((a, b, tag));
        }
    }

    fn near(&self, a: Point, b: Point, margin: f64) -> Vec<Tagged> {
        self.cells(a, b, margin).flat_map(|c| self.map.get(&c).into_iter().flatten().copied()).collect()
    }
}

fn cross(o: Point, p: Point, q: Point) -> f64 {
    (p - o).perp(&(q - o))
}

/// Where two segments cross properly, if they do.
fn crossing(a: Point, b: Point, c: Point, d: Point) -> Option<Point> {
    let (d1, d2, d3, d4) = (cross(c, d, a), cross(c, d, b), cross(a, b, c), cross(a, b, d));
    (d1 * d2 < 0.0 && d3 * d4 < 0.0).then(|| a + (b - a) * (d1 / (d1 - d2)))
}

fn point_to_segment(p: Point, a: Point, b: Point) -> f64 {
    let v = b - a;
    let t = ((p - a).dot(&v) / v.norm_squared()).clamp(0.0, 1.0);
    (a + v * t - p).norm()
}

/// How many closed contours of `job` hold `p` (even: waste).
fn depth(job: &Job, p: Point) -> usize {
    job.geometries
        .iter()
        .filter(|g| g.closed)
        .filter(|g| {
            let n = g.points.len();
            (0..n).fold(false, |odd, i| {
                let (a, b) = (g.points[i], g.points[(i + 1) % n]);
                odd ^ ((a.y > p.y) != (b.y > p.y) && a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x) > p.x)
            })
        })
        .count()
}

/// Issue 21's acceptance: on a dense generated sheet of at least 500 parts,
/// every pierce lies in the waste and clear of every contour, and no lead
/// crosses a contour (other than where it runs onto its own) or another lead.
#[test]
fn leads_on_a_dense_generated_sheet_pierce_in_the_waste_and_cross_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let params = SheetParams::with_target(5000);
    let sheet = generate_sheet(&params, 1);
    let parts = {
        let inst = &sheet.instance;
        let outer: HashMap<usize, usize> = inst.inner_outer.iter().map(|&(i, o)| (i, o)).collect();
        let level = |mut k: usize| {
            let mut l = 0;
            while let Some(&o) = outer.get(&k) {
                k = o;
                l += 1;
            }
            l
        };
        (0..inst.contours.len()).filter(|&k| level(k) % 2 == 0).count()
    };
    assert!(parts >= 500, "a dense sheet: {parts} parts");
    let path = dir.path().join("sheet.svg");
    std::fs::write(&path, to_svg(&sheet, &params)).unwrap();
    let machine = flatbed_with("lead_in = \"line\"\nlead_in_length = 0.8\nlead_in_angle = 60.0\nlead_out = \"arc\"\nlead_out_length = 0.5\novercut = 0.3");
    let planned = laserd::run::plan(&path, &machine, PlannerKind::Auto, None).unwrap();
    let job = &planned.job;

    let mut drawing = Buckets::new(5.0);
    for (k, g) in job.geometries.iter().enumerate() {
        for i in 0..g.segments() {
            drawing.add(g.points[i], g.points[(i + 1) % g.points.len()], k);
        }
    }
    // Every lead piece, with its path and the contour point it meets.
    let mut leads = Buckets::new(5.0);
    let mut pieces: Vec<(Point, Point, usize, Point)> = Vec::new();
    let paths: Vec<_> = planned.sequence.paths().collect();
    for (number, p) in paths.iter().enumerate() {
        let n = p.points.len();
        let (entry, exit) = (p.points[p.lead_in], p.points[n - 1 - p.lead_out]);
        for (w, on) in p.points[..=p.lead_in].windows(2).map(|w| (w, entry)).chain(p.points[n - 1 - p.lead_out..].windows(2).map(|w| (w, exit))) {
            pieces.push((w[0], w[1], number, on));
            leads.add(w[0], w[1], number);
        }
    }
    let pierces: Vec<_> = paths.iter().filter(|p| p.pierce).collect();
    assert!(pierces.len() >= 500);
    let with_lead = pierces.iter().filter(|p| p.lead_in > 0).count();
    assert_eq!(with_lead, planned.report.lead_ins);
    assert!(with_lead * 10 >= pierces.len() * 9, "{with_lead} of {} pierces have a lead-in", pierces.len());
    for p in pierces.iter().filter(|p| p.lead_in > 0) {
        let pierce = p.points[0];
        assert!(depth(job, pierce).is_multiple_of(2), "pierce {pierce:?} lies in a part");
        let nearest = drawing.near(pierce, pierce, 0.2).iter().map(|&(a, b, _)| point_to_segment(pierce, a, b)).fold(f64::INFINITY, f64::min);
        assert!(nearest >= 0.1 - 1e-9, "pierce {pierce:?} is {nearest} mm from a contour");
    }
    eprintln!(
        "dense sheet: {parts} parts, {} pierces, {with_lead} lead-ins ({} moved for room), {} lead-outs, {} cuts without a lead; {} lead pieces checked",
        pierces.len(),
        planned.report.lead_ins_moved,
        planned.report.lead_outs,
        planned.report.leads_skipped,
        pieces.len()
    );
    for &(a, b, number, on) in &pieces {
        for (c, d, _) in drawing.near(a, b, 0.0) {
            if let Some(x) = crossing(a, b, c, d) {
                assert!((x - on).norm() < 1e-6, "a lead of path {number} ({a:?}-{b:?}, onto {on:?}) crosses a contour ({c:?}-{d:?}) at {x:?}");
            }
        }
        for (c, d, other) in leads.near(a, b, 0.0) {
            if other != number {
                let shared = pieces.iter().any(|&(e, f, o, at)| o == other && e == c && f == d && (at - on).norm() < 1e-9);
                assert!(shared || crossing(a, b, c, d).is_none(), "leads of paths {number} and {other} cross");
            }
        }
    }
    assert_eq!(planned.report.precedence_violations, Some(0));
}

/// Kerf through the pipeline: the report names it, and parts drawn touching
/// are refused naming both.
#[test]
fn kerf_through_the_pipeline_is_reported_and_touching_parts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let spaced = svg_job(
        dir.path(),
        "spaced.svg",
        r##"<rect id="left" x="10" y="10" width="30" height="30" fill="none" stroke="#000000"/>
<rect id="right" x="40.3" y="10" width="30" height="30" fill="none" stroke="#000000"/>
<circle id="hole" cx="25" cy="25" r="5" fill="none" stroke="#000000"/>
"##,
    );
    let machine = flatbed_with("kerf = 0.3\nkerf_corners = \"sharp\"");
    let planned = laserd::run::plan(&spaced, &machine, PlannerKind::Auto, None).unwrap();
    assert_eq!(planned.report.kerf_mm, Some(0.3));
    // The picture shows the drawn contours over the offset paths.
    let picture = laserd::plot::plot(&planned.job, &planned.sequence, &planned.trajectory, &machine, planned.drawn.as_ref());
    assert!(picture.contains(r#"<g id="drawn">"#) && planned.drawn.as_ref().is_some_and(|d| d.geometries.len() == 3));
    let (lo, hi) = planned.job.bounds();
    assert!((lo.x - 9.85).abs() < 1e-4 && (hi.x - 70.45).abs() < 1e-4, "{lo:?} {hi:?}");
    // A kerf apart: the two parts share the cut between them.
    assert!(planned.report.cut_length_mm < planned.job.mark_length() - 29.0, "{} of {}", planned.report.cut_length_mm, planned.job.mark_length());
    let touching = dir.path().join("touching.svg");
    std::fs::write(&touching, std::fs::read_to_string(&spaced).unwrap().replace("x=\"40.3\"", "x=\"40\"")).unwrap();
    let err = laserd::run::plan(&touching, &machine, PlannerKind::Auto, None).err().unwrap().to_string();
    assert!(err.contains("'left'") || err.contains("left"), "{err}");
    assert!(err.contains("closer than the kerf"), "{err}");
}

/// Tabs: each leaves its width of a part's outline uncut, a tabbed part's
/// hole need not come before its outline (the planner and the checker both
/// treat the part as staying), and tabs that would take half an outline are
/// refused naming the part and the setting.
#[test]
fn tabs_leave_the_outline_uncut_where_they_are_and_hold_the_part() {
    use laserd::plan::cutting::{topology, whole_geometry_violations};
    use laserd::plan::{tabs, PathGroup, PlannedPath, Sequence};
    let dir = tempfile::tempdir().unwrap();
    let job_path = svg_job(
        dir.path(),
        "part.svg",
        r##"<rect id="part" x="10" y="10" width="50" height="30" fill="none" stroke="#000000"/>
<circle id="hole" cx="25" cy="25" r="5" fill="none" stroke="#000000"/>
"##,
    );
    let plain = laserd::run::plan(&job_path, &flatbed_with(""), PlannerKind::Auto, None).unwrap();
    let machine = flatbed_with("tabs = 3\ntab_width = 1.2");
    let tabbed = laserd::run::plan(&job_path, &machine, PlannerKind::Auto, None).unwrap();
    assert_eq!((plain.report.tabs, tabbed.report.tabs), (0, 3));
    let uncut = plain.report.cut_length_mm - tabbed.report.cut_length_mm;
    assert!((uncut - 3.6).abs() < 1e-6, "3 tabs of 1.2 mm: {uncut}");
    assert_eq!(tabbed.report.precedence_violations, Some(0));
    // The cut goes on past each tab with a pierce.
    assert_eq!(tabbed.report.pierces, plain.report.pierces + 3);
    let picture = laserd::plot::plot(&tabbed.job, &tabbed.sequence, &tabbed.trajectory, &machine, tabbed.drawn.as_ref());
    assert_eq!(picture.matches(r#"class="tab""#).count(), 3);
    assert_eq!(picture.matches(r#"class="pierce""#).count(), tabbed.report.pierces);

    // The outline before the hole: a broken rule, unless tabs hold the part.
    let job = &plain.job;
    let outline = job.geometries.iter().position(|g| g.source.contains("part")).unwrap();
    let hole = 1 - outline;
    let whole = |k: usize| PlannedPath::new(k, job.geometries[k].points.clone(), 0, true);
    let outline_first = Sequence { groups: vec![PathGroup { field_center: None, paths: vec![whole(outline), whole(hole)] }] };
    let topo = topology(job, &machine.cutting).unwrap();
    assert_eq!(whole_geometry_violations(&topo, &outline_first, &[true], &[]).len(), 1);
    let held = tabs::held(&tabs::place(job, &machine).unwrap());
    assert!(held[outline]);
    assert!(!held[hole], "holes get no tabs");
    assert!(whole_geometry_violations(&topo, &outline_first, &[true], &held).is_empty());

    let err = laserd::run::plan(&job_path, &flatbed_with("tabs = 40\ntab_width = 2.0"), PlannerKind::Auto, None).err().unwrap().to_string();
    assert!(err.contains("part") && err.contains("tab_width") && err.contains("less than half"), "{err}");
}

/// Bridges: where one cut ends near the next one's pierce, the cut goes on
/// across the waste instead; a bridge crosses no contour, runs through the
/// waste and closes no piece of it (bridges join contours that do not touch
/// otherwise, never twice the same pair of groups).
#[test]
fn bridges_replace_an_air_move_and_a_pierce_and_cut_only_waste() {
    let dir = tempfile::tempdir().unwrap();
    let params = SheetParams::with_target(1500);
    let sheet = generate_sheet(&params, 2);
    let path = dir.path().join("sheet.svg");
    std::fs::write(&path, to_svg(&sheet, &params)).unwrap();
    let text = std::fs::read_to_string(root().join("config/flatbed-cutter.toml")).unwrap();
    let bridging = MachineConfig::parse(&text.replacen("bridge_max = 0.0\n", "bridge_max = 15.0\n", 1), "bridge.toml").unwrap();
    let plain = laserd::run::plan(&path, &flatbed_with(""), PlannerKind::Auto, None).unwrap();
    let bridged = laserd::run::plan(&path, &bridging, PlannerKind::Auto, None).unwrap();
    let (b, saved) = (bridged.report.bridges, bridged.report.pierces_saved);
    assert!(b > 0 && saved == b, "{b} bridges, {saved} pierces saved");
    assert_eq!(bridged.report.pierces + saved, plain.report.pierces);
    assert_eq!(bridged.report.precedence_violations, Some(0));
    assert!(bridged.report.trajectory_time_s < plain.report.trajectory_time_s);
    eprintln!(
        "bridges: {b} on {} contours, pierces {} -> {}, trajectory {:.3} s -> {:.3} s",
        bridged.job.geometries.len(),
        plain.report.pierces,
        bridged.report.pierces,
        plain.report.trajectory_time_s,
        bridged.report.trajectory_time_s
    );
    let job = &bridged.job;
    let topology = laserd::plan::cutting::topology(job, &bridging.cutting).unwrap();
    let mut parent: Vec<usize> = (0..topology.group_count()).collect();
    fn root_of(parent: &mut [usize], mut k: usize) -> usize {
        while parent[k] != k {
            k = parent[k];
        }
        k
    }
    let paths: Vec<_> = bridged.sequence.paths().collect();
    let mut drawing = Buckets::new(5.0);
    for (k, g) in job.geometries.iter().enumerate() {
        for i in 0..g.segments() {
            drawing.add(g.points[i], g.points[(i + 1) % g.points.len()], k);
        }
    }
    for i in (1..paths.len()).filter(|&i| paths[i].bridge) {
        let (from, to) = (paths[i].points[0], paths[i].points[1]);
        assert_eq!(from, paths[i - 1].points[paths[i - 1].points.len() - 1], "a bridge starts where the cut before ended");
        assert!(!paths[i].pierce && (to - from).norm() <= 15.0);
        assert!(depth(job, nalgebra::center(&from, &to)).is_multiple_of(2), "a bridge runs through the waste");
        for (c, d, _) in drawing.near(from, to, 0.0) {
            if let Some(x) = crossing(from, to, c, d) {
                assert!((x - from).norm() < 1e-6 || (x - to).norm() < 1e-6, "a bridge crosses a contour at {x:?}");
            }
        }
        let (a, b) = (root_of(&mut parent, topology.groups[paths[i - 1].geometry]), root_of(&mut parent, topology.groups[paths[i].geometry]));
        assert_ne!(a, b, "a bridge between contours already joined would cut a piece of waste free");
        parent[a] = b;
    }
}

/// The flatbed cutter on a plate of `width` x `height` mm at the origin with
/// a 30 mm support grid, and a fast Z axis lifting 5 mm over pieces that may
/// have tipped (`lift_moves`: whether it lifts at all).
fn flatbed_lifting(width: f64, height: f64, lift_moves: bool) -> MachineConfig {
    let text = std::fs::read_to_string(root().join("config/flatbed-cutter.toml")).unwrap();
    let extra = format!(
        "\n[plate]\nwidth = {width}\nheight = {height}\nsupport_grid = 30.0\n\n[head]\ntravel_z = 50.0\nlift_height = 5.0\nmax_velocity = 200.0\nmax_acceleration = 10000.0\nmax_jerk = 1000000.0\nclearance = 2.0\nlift_moves = {lift_moves}\n"
    );
    MachineConfig::parse(&(text + &extra), "lifting.toml").unwrap()
}

/// Seed 000's lift moves on a generated sheet: the simulator's figures count
/// collisions from the executed motion alone (a piece cut free, then the head
/// over it low with the laser off). Without lifts there are some, so the
/// check can fail; with them none, for under 1 % more machine time, every
/// limit (the Z axis's too) and precedence rule kept.
#[test]
fn lifts_keep_the_head_off_pieces_that_may_have_tipped_for_under_one_percent_more_time() {
    let dir = tempfile::tempdir().unwrap();
    let params = SheetParams::with_target(1000);
    let sheet = generate_sheet(&params, 3);
    let path = dir.path().join("sheet.svg");
    std::fs::write(&path, to_svg(&sheet, &params)).unwrap();
    let run = |lift_moves: bool| {
        let machine = flatbed_lifting(params.width, params.height, lift_moves);
        let planned = laserd::run::plan(&path, &machine, PlannerKind::Auto, None).unwrap();
        let dry = laserd::run::dry_run(&planned, &machine, &dir.path().join(format!("{lift_moves}.mcap")), Default::default()).unwrap();
        assert!(dry.outcome.completed && dry.outcome.errors.is_empty(), "{:?}", dry.outcome.stop_reason);
        let sim = dry.report.sim.clone().unwrap();
        assert_eq!((sim.limit_violations, dry.report.precedence_violations), (0, Some(0)), "{:?}", sim.limit_breaches);
        (dry.report, sim)
    };
    let (lifted, lifted_sim) = run(true);
    let (down, down_sim) = run(false);
    let pieces = lifted.tipping_pieces.unwrap();
    let lifts = lifted.lifts.unwrap();
    let added = lifted_sim.job_time_s / down_sim.job_time_s - 1.0;
    eprintln!(
        "lifts: {} contours, {pieces} may tip; collisions without lifts {:?}, with {lifts} lifts {:?}; simulated {:.3} s -> {:.3} s (+{:.3} %)",
        lifted.geometries,
        down_sim.collisions,
        lifted_sim.collisions,
        down_sim.job_time_s,
        lifted_sim.job_time_s,
        100.0 * added
    );
    assert!(pieces > 0 && lifts > 0, "{pieces} pieces, {lifts} lifts");
    assert!(down_sim.collisions.unwrap() > 0, "the head stays down over fallen pieces without lifts");
    assert_eq!(lifted_sim.collisions, Some(0));
    assert_eq!(down.lifts, Some(0));
    assert!(added <= 0.01, "lifts add {:.3} % machine time", 100.0 * added);
}

/// A support grid of 0, or one without a Z axis to lift, is refused by name.
#[test]
fn a_support_grid_of_zero_or_without_a_z_axis_is_refused_by_name() {
    let text = std::fs::read_to_string(root().join("config/flatbed-cutter.toml")).unwrap();
    let plate = "\n[plate]\nwidth = 300.0\nheight = 300.0\n";
    let head = "\n[head]\ntravel_z = 50.0\nlift_height = 5.0\nmax_velocity = 200.0\nmax_acceleration = 10000.0\nmax_jerk = 1000000.0\n";
    for (extra, wanted) in [
        (format!("{plate}support_grid = 0.0\n{head}"), "plate.support_grid: must be between 1 and 1000 mm, got 0"),
        (format!("{plate}support_grid = 30.0\n"), "plate.support_grid: lifting over pieces that may tip needs the head's Z axis: add [head]"),
        (format!("{plate}support_grid = 30.0\n{head}").replace("lift_height = 5.0", "lift_height = 60.0"), "head.lift_height: must be between 0.1 and 50 mm (up to head.travel_z), got 60"),
        (format!("{plate}support_grid = 30.0\n{head}clearance = -1.0\n"), "head.clearance: must be between 0 and 100 mm, got -1"),
    ] {
        let err = MachineConfig::parse(&(text.clone() + &extra), "grid.toml").unwrap_err().to_string();
        assert!(err.contains("grid.toml") && err.contains(wanted), "{err}");
    }
}

/// Turns sharper than `corner_angle` (degrees) along `headings`: the
/// sharp-angle macros, counted here from the definition.
fn sharp_turns(headings: &[nalgebra::Vector2<f64>], corner_angle: f64) -> usize {
    headings.windows(2).filter(|w| w[0].angle(&w[1]) > corner_angle.to_radians() + 1e-12).count()
}

/// Every order of `items`.
fn permutations(items: &[usize]) -> Vec<Vec<usize>> {
    if items.len() <= 1 {
        return vec![items.to_vec()];
    }
    let mut out = Vec::new();
    for (i, &first) in items.iter().enumerate() {
        let rest: Vec<usize> = items.iter().enumerate().filter(|&(j, _)| j != i).map(|(_, &x)| x).collect();
        for mut p in permutations(&rest) {
            p.insert(0, first);
            out.push(p);
        }
    }
    out
}

/// Seed 000's pre-cut order on a sheet of 60 star junctions (2 to 5 spokes
/// started later from a junction a cut runs through, at random angles):
/// every junction's pre-cuts come out in an order with as few sharp-angle
/// macros as the best of all orders, counted from the written path alone;
/// each later spoke starts in its pre-cut's kerf without a pierce.
#[test]
fn the_precut_order_at_every_junction_of_a_sheet_is_the_brute_force_optimum() {
    use laserd::job::{Geometry, Process};
    use laserd::plan::{PathGroup, PlannedPath, Sequence};
    use rand::{Rng, SeedableRng};
    let mut machine = flatbed_with("");
    machine.cutting.precut_length = 2.0;
    machine.cutting.sharp_angle_cost = 2.0;
    let layer = machine.layers.iter().find(|l| machine.pierce(&l.name).active()).unwrap().name.clone();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    let mut geometries = Vec::new();
    let mut paths = Vec::new();
    let mut junctions = Vec::new();
    for j in 0..60 {
        let centre = Point::new(40.0 + 60.0 * (j % 10) as f64, 40.0 + 60.0 * (j / 10) as f64);
        let at = |deg: f64, r: f64| centre + nalgebra::Vector2::new(deg.to_radians().cos(), deg.to_radians().sin()) * r;
        // The cut through: in from one side, out the other (bent a little).
        let a: f64 = rng.random_range(0.0..360.0);
        let through = vec![at(a, 20.0), centre, at(a + 180.0 + rng.random_range(-40.0..40.0), 20.0)];
        let spokes = rng.random_range(2..=5usize);
        let g = geometries.len();
        geometries.push(Geometry { arcs: Vec::new(), profile: Vec::new(), points: through.clone(), closed: false, process: 0, source: format!("through {j}") });
        paths.push(PlannedPath::new(g, through, 0, true));
        let mut later = Vec::new();
        for s in 0..spokes {
            let spoke = vec![centre, at(rng.random_range(0.0..360.0), 15.0)];
            let g = geometries.len();
            geometries.push(Geometry { arcs: Vec::new(), profile: Vec::new(), points: spoke.clone(), closed: false, process: 0, source: format!("spoke {j}.{s}") });
            later.push(PlannedPath::new(g, spoke, 0, true));
        }
        junctions.push((centre, spokes));
        paths.extend(later);
    }
    let job = Job { source: "stars".into(), geometries, processes: vec![Process { layer, speed: 50.0, power: 1000.0, passes: 1, fill: false }] };
    let pierces_before = paths.iter().filter(|p| p.pierce).count();
    let sequence = Sequence { groups: vec![PathGroup { field_center: None, paths }] };
    let (cut, count) = laserd::plan::precut::add_precuts(&job, sequence, &machine);
    let spokes: usize = junctions.iter().map(|j| j.1).sum();
    assert_eq!(count.precuts, spokes, "every spoke pre-cut: a pierce costs more than 2 mm and back");
    let paths: Vec<&PlannedPath> = cut.paths().collect();
    assert_eq!(paths.iter().filter(|p| p.pierce).count(), pierces_before - spokes);
    let corner = machine.cutting.corner_angle;
    let mut ordered = 0;
    for (centre, n) in &junctions {
        // The cut through, from the written points: in, the pre-cuts (out
        // and back to the centre), out.
        let through = paths.iter().find(|p| p.pierce && p.points.len() > 3 && p.points[1] == *centre).expect("the cut through the junction");
        let pts = &through.points;
        assert_eq!(pts.len(), 3 + 2 * n, "{n} pre-cuts at {centre:?}: {pts:?}");
        let outs: Vec<nalgebra::Vector2<f64>> = (0..*n).map(|k| (pts[2 + 2 * k] - centre).normalize()).collect();
        for k in 0..*n {
            assert_eq!(pts[3 + 2 * k], *centre, "each pre-cut comes back to the junction");
            assert!(((pts[2 + 2 * k] - centre).norm() - 2.0).abs() < 1e-9, "2 mm into the spoke");
            // The spoke it belongs to starts there, in the kerf, without a pierce.
            let spoke = paths.iter().find(|p| p.points[0] == *centre && (p.points[1] - centre).normalize().dot(&outs[k]) > 1.0 - 1e-12).unwrap();
            assert!(!spoke.pierce);
        }
        let headings = |order: &[usize]| {
            let mut h = vec![(centre - pts[0]).normalize()];
            for &k in order {
                h.push(outs[k]);
                h.push(-outs[k]);
            }
            h.push((pts[pts.len() - 1] - centre).normalize());
            h
        };
        let made: Vec<usize> = (0..*n).collect();
        let chosen = sharp_turns(&headings(&made), corner);
        let best = permutations(&made).iter().map(|o| sharp_turns(&headings(o), corner)).min().unwrap();
        assert_eq!(chosen, best, "junction {centre:?}: {chosen} sharp angles, the best order has {best}");
        let worst = permutations(&made).iter().map(|o| sharp_turns(&headings(o), corner)).max().unwrap();
        ordered += usize::from(worst > best);
    }
    eprintln!("pre-cuts: {spokes} at {} junctions, {ordered} where the order matters, {} sharp angles in all", junctions.len(), count.macros);
    assert!(ordered > 0, "some junction where the order matters");
}
