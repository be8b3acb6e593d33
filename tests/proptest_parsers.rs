//! Property tests of the job and config parsers: generated SVG path data,
//! G-code, job files and config text, on stable, in the normal suite. The fuzz targets in fuzz/
//! search the same parsers far longer (and with the hostile sizes left out
//! here until the importer refuses them: issue 16, findings 4 and 9).

use std::sync::OnceLock;

use laserd::config::MachineConfig;
use laserd::import::svg::import_svg;
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// The same cases on every run and machine (a test that fails, fails
/// again), and no regression files written into the source tree.
fn reproducible() -> ProptestConfig {
    ProptestConfig { rng_seed: RngSeed::Fixed(16), failure_persistence: None, ..ProptestConfig::default() }
}

const SHIPPED: &str = include_str!("../config/laserd.toml");
const SOURCE: &str = "generated.svg";

fn config() -> &'static MachineConfig {
    static CONFIG: OnceLock<MachineConfig> = OnceLock::new();
    CONFIG.get_or_init(|| MachineConfig::parse(SHIPPED, "config/laserd.toml").expect("the shipped config is valid"))
}

/// A coordinate: mostly on the sheet, sometimes tiny, negative or far off it
/// (within 1e4 px, 2.5 m: larger ones are the fuzz target's, see above).
fn coordinate() -> impl Strategy<Value = String> {
    prop_oneof![
        4 => (-100.0f64..500.0).prop_map(|x| format!("{x:.3}")),
        1 => (-1e4f64..1e4).prop_map(|x| format!("{x:e}")),
        1 => prop::sample::select(vec!["0", "-0", ".5", "1e-9", "-.25e1", "1e4", "00"]).prop_map(String::from),
    ]
}

/// One path command with its arguments, any letter case; sometimes with the
/// wrong number of arguments.
fn command() -> impl Strategy<Value = String> {
    let args = |n: usize| prop::collection::vec(coordinate(), n);
    let arc = (coordinate(), coordinate(), coordinate(), 0u8..2, 0u8..2, coordinate(), coordinate())
        .prop_map(|(rx, ry, rot, large, sweep, x, y)| format!("{rx} {ry} {rot} {large} {sweep} {x} {y}"));
    let letter = |l: &'static str| prop::sample::select(vec![l.to_string(), l.to_lowercase()]);
    prop_oneof![
        (letter("M"), args(2)).prop_map(|(c, a)| format!("{c}{}", a.join(" "))),
        (letter("L"), args(2)).prop_map(|(c, a)| format!("{c}{}", a.join(","))),
        (letter("H"), args(1)).prop_map(|(c, a)| format!("{c}{}", a.join(" "))),
        (letter("V"), args(1)).prop_map(|(c, a)| format!("{c} {}", a.join(" "))),
        (letter("C"), args(6)).prop_map(|(c, a)| format!("{c}{}", a.join(" "))),
        (letter("S"), args(4)).prop_map(|(c, a)| format!("{c}{}", a.join(" "))),
        (letter("Q"), args(4)).prop_map(|(c, a)| format!("{c}{}", a.join(" "))),
        (letter("T"), args(2)).prop_map(|(c, a)| format!("{c}{}", a.join(" "))),
        (letter("A"), arc).prop_map(|(c, a)| format!("{c}{a}")),
        letter("Z"),
    ]
}

/// A path: a move to start, then commands, now and then a broken one (a
/// wrong argument count or an unknown letter: usvg keeps what came before).
fn path_data() -> impl Strategy<Value = String> {
    let broken = (prop::sample::select(vec!["L", "C", "A", "X"]), prop::collection::vec(coordinate(), 3)).prop_map(|(c, a)| format!("{c}{}", a.join(" ")));
    let step = prop_oneof![12 => command(), 1 => broken];
    (coordinate(), coordinate(), prop::collection::vec(step, 1..12)).prop_map(|(x, y, rest)| format!("M{x} {y} {}", rest.join(" ")))
}

fn svg() -> impl Strategy<Value = String> {
    let stroke = prop::sample::select(vec!["#000000", "#000000", "#ff0000", "#0000ff", "#123456", "none"]);
    let path = (path_data(), stroke);
    let transform = prop_oneof![
        4 => prop::sample::select(vec!["", "rotate(33)", "matrix(0 1 -1 0 5 5)", "translate(-50 20)"]),
        1 => prop::sample::select(vec!["scale(1000)", "scale(0)", "scale(1e-9)"]),
    ];
    let size = prop_oneof![
        4 => prop::sample::select(vec![r#"width="100mm" height="100mm" viewBox="0 0 100 100""#, r#"width="300" height="200""#]),
        1 => prop::sample::select(vec![r#"viewBox="-10 -10 0 0""#, ""]),
    ];
    (prop::collection::vec(path, 1..4), transform, size).prop_map(|(paths, transform, size)| {
        let body: String = paths
            .iter()
            .map(|(d, stroke)| format!(r#"<path d="{d}" stroke="{stroke}" fill="none"/>"#))
            .collect();
        format!(r#"<svg xmlns="http://www.w3.org/2000/svg" {size}><g transform="{transform}">{body}</g></svg>"#)
    })
}

proptest! {
    #![proptest_config(reproducible())]

    /// Generated path data never panics: it imports to finite geometry of at
    /// least two points each, or is refused with an error naming the file.
    #[test]
    fn svg_path_data_imports_or_names_the_file(text in svg()) {
        match import_svg(&text, SOURCE, config()) {
            Ok(job) => {
                prop_assert!(!job.geometries.is_empty());
                for g in &job.geometries {
                    prop_assert!(g.points.len() >= 2, "{:?}", g);
                    prop_assert!(g.points.iter().all(|p| p.x.is_finite() && p.y.is_finite()), "{:?}", g);
                    prop_assert!(g.process < job.processes.len());
                }
            }
            Err(e) => prop_assert!(e.to_string().starts_with(&format!("import: {SOURCE}: ")), "{}", e),
        }
    }

    /// Any text at all as a job: never a panic, an error names the file.
    #[test]
    fn any_text_as_svg_never_panics(text in ".{0,200}") {
        if let Err(e) = import_svg(&text, SOURCE, config()) {
            prop_assert!(e.to_string().starts_with(&format!("import: {SOURCE}: ")), "{}", e);
        }
    }
}

/// A value for a setting: numbers of every size and sign, TOML's specials,
/// and values of the wrong type.
fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<f64>().prop_map(|x| format!("{x:?}")),
        any::<i64>().prop_map(|n| n.to_string()),
        prop::sample::select(vec!["0", "-1", "0.0", "1e-300", "1e300", "5e-324", "inf", "-inf", "nan", "4294967295", "\"x\"", "[]", "true", "{}"])
            .prop_map(String::from),
    ]
}

proptest! {
    #![proptest_config(reproducible())]

    /// The shipped config with one setting set to any value, or dropped:
    /// parsed and validated without a panic; refused with the file's name.
    #[test]
    fn config_with_any_value_never_panics(pick in any::<prop::sample::Index>(), v in value(), drop in any::<bool>()) {
        let settings: Vec<usize> = SHIPPED.lines().enumerate().filter(|(_, l)| l.contains(" = ") && !l.starts_with('#')).map(|(i, _)| i).collect();
        let chosen = settings[pick.index(settings.len())];
        let text: String = SHIPPED
            .lines()
            .enumerate()
            .filter_map(|(i, l)| match (i == chosen, drop) {
                (false, _) => Some(l.to_string()),
                (true, true) => None,
                (true, false) => Some(format!("{} = {v}", l.split(" = ").next().unwrap_or(l))),
            })
            .collect::<Vec<_>>()
            .join("\n");
        if let Err(e) = MachineConfig::parse(&text, "mutated.toml") {
            prop_assert!(e.to_string().starts_with("config: mutated.toml: "), "{}", e);
        }
    }

    /// Any text at all as a config: never a panic.
    #[test]
    fn any_config_text_never_panics(text in "(.|\n){0,300}") {
        if let Err(e) = MachineConfig::parse(&text, "any.toml") {
            prop_assert!(e.to_string().starts_with("config: any.toml: "), "{}", e);
        }
    }
}

/// A line of another tool's G-code: moves, arcs (I/J or R, sometimes off
/// their circle), powers and feeds, laser on and off, now and then a word
/// laserd does not read.
fn gcode_line() -> impl Strategy<Value = String> {
    let c = || (-50.0f64..350.0).prop_map(|x| format!("{x:.3}"));
    prop_oneof![
        4 => (0u8..2, c(), c(), prop::option::of(0u32..1200)).prop_map(|(g, x, y, s)| format!("G{g} X{x} Y{y}{}", s.map(|s| format!(" S{s}")).unwrap_or_default())),
        2 => (2u8..4, c(), c(), (-30.0f64..30.0), (-30.0f64..30.0)).prop_map(|(g, x, y, i, j)| format!("G{g} X{x} Y{y} I{i:.3} J{j:.3}")),
        2 => (2u8..4, c(), c(), prop_oneof![(150.0f64..400.0), (-400.0f64..-150.0), (-80.0f64..80.0)]).prop_map(|(g, x, y, r)| format!("G{g} X{x} Y{y} R{r:.3}")),
        1 => (0u32..1000).prop_map(|s| format!("S{s}")),
        1 => (1u32..6000).prop_map(|f| format!("F{f}")),
        1 => prop::sample::select(vec!["M3", "M4", "M5", "G90", "G91", "G20", "G21", "G92 X0 Y0", "G38.2 X1", "Q5", "%"]).prop_map(String::from),
    ]
}

/// A job file: one geometry's points with arcs and a profile of any values.
fn job_file() -> impl Strategy<Value = String> {
    let point = (0.0f64..300.0, 0.0f64..300.0).prop_map(|(x, y)| format!("[{x:.4},{y:.4}]"));
    let arc = (0usize..12, 0usize..12, prop_oneof![(-1.5f64..1.5).prop_map(|b| b.to_string()), Just("1e308".to_string())]).prop_map(|(a, b, bulge)| format!("{{\"from\":{a},\"to\":{b},\"bulge\":{bulge}}}"));
    (prop::collection::vec(point, 0..10), any::<bool>(), prop::collection::vec(arc, 0..3), prop::collection::vec(0usize..3, 0..10)).prop_map(|(points, closed, arcs, profile)| {
        format!(
            "{{\"format\":\"laserd-job\",\"version\":1,\"source\":\"t\",\"processes\":[{{\"layer\":\"a\",\"speed\":10,\"power\":1,\"passes\":1}},{{\"layer\":\"b\",\"speed\":20,\"power\":2,\"passes\":1}}],\
             \"geometries\":[{{\"points\":[{}],\"closed\":{closed},\"arcs\":[{}],\"profile\":[{}],\"process\":0,\"source\":\"g\"}}]}}",
            points.join(","),
            arcs.join(","),
            profile.iter().map(|p| p.to_string()).collect::<Vec<_>>().join(",")
        )
    })
}

proptest! {
    #![proptest_config(reproducible())]

    /// Generated G-code never panics: it imports to geometries whose arcs
    /// match their points and whose profile has a process per segment, or is
    /// refused naming the file.
    #[test]
    fn gcode_imports_with_consistent_arcs_and_profiles_or_names_the_file(lines in prop::collection::vec(gcode_line(), 1..40)) {
        let text = format!("M4 F600\n{}\n", lines.join("\n"));
        match laserd::import::gcode::import_gcode(&text, "t.nc", config()) {
            Ok(job) => {
                for g in &job.geometries {
                    prop_assert!(g.profile.is_empty() || g.profile.len() == g.segments(), "{:?}", g);
                    prop_assert!(g.profile.iter().chain([&g.process]).all(|&p| p < job.processes.len()));
                    prop_assert!(g.arc_error(config().import.tolerance + 0.01).is_none(), "{:?}: {:?}", g.arc_error(config().import.tolerance + 0.01), g);
                    prop_assert!(g.length().is_finite() && g.length() > 0.0);
                }
            }
            Err(e) => prop_assert!(e.to_string().contains("t.nc"), "{}", e),
        }
    }

    /// A job file's arcs and profile of any values: read or refused naming
    /// the file, never a panic.
    #[test]
    fn a_job_files_arcs_and_profile_are_read_or_refused(text in job_file()) {
        match laserd::import::json::import_json(text.as_bytes(), "j.json", config()) {
            Ok(job) => {
                let g = &job.geometries[0];
                prop_assert!(g.length().is_finite());
                let (lo, hi) = g.bounds();
                prop_assert!(lo.x.is_finite() && hi.y.is_finite());
            }
            Err(e) => prop_assert!(e.to_string().contains("j.json"), "{}", e),
        }
    }
}

fn fill_config() -> &'static MachineConfig {
    static CONFIG: std::sync::OnceLock<MachineConfig> = std::sync::OnceLock::new();
    CONFIG.get_or_init(|| {
        let text = include_str!("../config/laserd.toml").replace("hatch_spacing = 0.05", "hatch_spacing = 0.5");
        MachineConfig::parse(&text, "laserd.toml").unwrap()
    })
}

proptest! {
    // Fewer cases: each hatches up to a scaled-up drawing's area.
    #![proptest_config(ProptestConfig { cases: 48, ..reproducible() })]

    /// Generated path data filled (either rule, any transform) never panics
    /// and never hatches without bound: its hatch lies inside the area's
    /// bounds, or the job is refused naming the file.
    #[test]
    fn filled_path_data_hatches_inside_its_area_or_names_the_file(text in svg(), even_odd in any::<bool>()) {
        let rule = if even_odd { "evenodd" } else { "nonzero" };
        let text = text.replace(r#"fill="none""#, &format!(r##"fill="#008000" fill-rule="{rule}""##)).replace(r#"stroke="#, r#"data-stroke="#);
        let machine = fill_config();
        let job = match import_svg(&text, SOURCE, machine) {
            Ok(job) => job,
            Err(e) => return { prop_assert!(e.to_string().contains(SOURCE), "{}", e); Ok(()) },
        };
        let (lo, hi) = laserd::job::bounds_of(job.geometries.iter().filter(|g| job.processes[g.process].fill).flat_map(|g| g.points.iter()));
        match laserd::plan::area::hatch::hatch(job, machine) {
            Ok((job, count)) => {
                let hatch: Vec<&laserd::job::Geometry> = job.geometries.iter().filter(|g| job.processes[g.process].fill).collect();
                prop_assert_eq!(count.lines, hatch.len());
                let slack = 1e-6 * (1.0 + hi.x.abs().max(hi.y.abs()).max(lo.x.abs()).max(lo.y.abs()));
                for g in hatch {
                    prop_assert!(g.points.len() == 2 && !g.closed);
                    prop_assert!(g.points.iter().all(|p| p.x >= lo.x - slack && p.x <= hi.x + slack && p.y >= lo.y - slack && p.y <= hi.y + slack), "{:?} outside {:?}..{:?}", g.points, lo, hi);
                }
            }
            Err(e) => prop_assert!(e.to_string().contains(SOURCE), "{}", e),
        }
    }
}
