//! Import: reads a job file and turns it into a [`Job`] in machine millimetres.
//!
//! The format is chosen by the file extension; each format lives in its own module.

use std::path::Path;

use crate::config::{Anchor, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{ArcSpan, Geometry, Job, Point, Process};
pub(crate) use crate::job::arc_segments;

pub mod dxf;
pub mod fill;
mod fit_spline;
pub mod gcode;
pub mod json;
pub mod svg;
pub mod svg_size;

/// Reads the job file at `path` and converts it with the import settings of `config`.
///
/// Every error is one line that names the file, so the CLI can print it as is.
pub fn import_job(path: &Path, config: &MachineConfig) -> Result<Job> {
    let mut job = import_as_drawn(path, config)?;
    place(&mut job, config);
    snap_to_travel(&mut job, config);
    Ok(job)
}

/// How far outside the travel a coordinate is taken for the travel's edge
/// (mm): the rounding of a drawing's own arithmetic (usvg computes in f32,
/// about 1e-6 mm at 300 mm), far below any machine's step.
const TRAVEL_SNAP_MM: f64 = 1e-3;

/// Coordinates within `TRAVEL_SNAP_MM` outside the stage's travel are put on
/// its edge, so a drawing whose outline touches the origin is not refused
/// for a -0.000 (said in the log, with the largest move).
fn snap_to_travel(job: &mut Job, config: &MachineConfig) {
    let (mut count, mut most) = (0usize, 0.0f64);
    let mut snap = |v: &mut f64, travel: f64| {
        let to = if (-TRAVEL_SNAP_MM..0.0).contains(v) { 0.0 } else if *v > travel && *v <= travel + TRAVEL_SNAP_MM { travel } else { return };
        most = most.max((*v - to).abs());
        count += 1;
        *v = to;
    };
    for p in job.geometries.iter_mut().flat_map(|g| g.points.iter_mut()) {
        snap(&mut p.x, config.stage.travel_x);
        snap(&mut p.y, config.stage.travel_y);
    }
    if count > 0 {
        tracing::info!("{}: {count} coordinate(s) within {TRAVEL_SNAP_MM} mm outside the travel put on its edge (moved at most {most:.1e} mm)", job.source);
    }
}

/// Moves the job where `[job] anchor` (`--place`) puts it, saying so.
pub fn place(job: &mut Job, config: &MachineConfig) {
    let (lo, hi) = job.bounds();
    let target = match config.job.anchor {
        Anchor::Drawing => return,
        Anchor::Origin => Point::origin(),
        Anchor::Center => Point::new((config.stage.travel_x - (hi.x - lo.x)) / 2.0, (config.stage.travel_y - (hi.y - lo.y)) / 2.0),
        Anchor::At(x, y) => Point::new(x, y),
    };
    let shift = target - lo;
    for g in &mut job.geometries {
        for p in &mut g.points {
            *p += shift;
        }
    }
    tracing::info!("{}: placed ({}): moved by ({:.3}, {:.3}) mm", job.source, String::from(config.job.anchor), shift.x, shift.y);
}

fn import_as_drawn(path: &Path, config: &MachineConfig) -> Result<Job> {
    let source = path.display().to_string();
    let ext = path.extension().map(|e| e.to_string_lossy().to_lowercase());
    match ext.as_deref() {
        Some("svg") => {
            let bytes = read_capped(path, config.import.max_file_bytes())?;
            // usvg only takes UTF-8 text (compressed .svgz is not enabled in our build).
            let text = String::from_utf8(bytes)
                .map_err(|_| Error::Import(format!("{source}: malformed SVG: the file is not UTF-8 text")))?;
            svg::import_svg(&text, &source, config)
        }
        Some("dxf") => dxf::import_dxf(&read_capped(path, config.import.max_file_bytes())?, &source, config),
        Some("json") => json::import_json(&read_capped(path, config.import.max_file_bytes())?, &source, config),
        Some(e) if gcode::GCODE_EXTENSIONS.contains(&e) => {
            let text = String::from_utf8(read_capped(path, config.import.max_file_bytes())?).map_err(|e| Error::Import(format!("{source}: not G-code: not UTF-8 text (byte {})", e.utf8_error().valid_up_to())))?;
            gcode::import_gcode(&text, &source, config)
        }
        Some(other) => Err(Error::Import(format!("{source}: unsupported job format '.{other}' (supported: .svg, .dxf, .json, G-code)"))),
        None => Err(Error::Import(format!(
            "{source}: unsupported job format: the file name has no extension (supported: .svg, .dxf, .json, G-code)"
        ))),
    }
}

/// Largest coordinate accepted (mm), in every format. No machine has a
/// kilometre of travel, and a curve that large would be flattened into
/// billions of segments at a 0.01 mm tolerance.
pub(crate) const MAX_COORD_MM: f64 = 1e6;

/// Points closer than this (mm) count as the same point.
const SAME_POINT_MM: f64 = 1e-9;

/// A polyline being read, its arcs kept exact beside their flattening
/// (see [`ArcSpan`]): what importers build a [`Geometry`] from.
#[derive(Debug, Clone, Default)]
pub(crate) struct Trace {
    pub points: Vec<Point>,
    pub arcs: Vec<ArcSpan>,
    /// A tag per segment where the importer keeps one (G-code: its process); else empty.
    pub tags: Vec<usize>,
}

impl Trace {
    pub fn of(points: Vec<Point>) -> Trace {
        Trace { points, arcs: Vec::new(), tags: Vec::new() }
    }

    /// Tags every segment with `tag`.
    pub fn tagged(mut self, tag: usize) -> Trace {
        self.tags = vec![tag; self.points.len().saturating_sub(1)];
        self
    }

    /// Adds `points` (which continue from the last point, not repeating it)
    /// as the flattening of an arc of `bulge` from the last point to the
    /// last of `points`; bulge 0: straight segments.
    pub fn arc_to(&mut self, points: impl IntoIterator<Item = Point>, bulge: f64) {
        let started = !self.points.is_empty();
        let from = self.points.len().saturating_sub(1);
        self.points.extend(points);
        let to = self.points.len().saturating_sub(1);
        if bulge != 0.0 && started && to > from {
            self.arcs.push(ArcSpan { from, to, bulge });
        }
    }

    /// Appends `next`, whose first point is this one's last (or stands for it).
    pub fn append(&mut self, next: Trace) {
        let shift = self.points.len().saturating_sub(1);
        if self.points.is_empty() {
            *self = next;
            return;
        }
        self.points.extend(next.points.into_iter().skip(1));
        self.tags.extend(next.tags);
        self.arcs.extend(next.arcs.into_iter().map(|a| ArcSpan { from: a.from + shift, to: a.to + shift, ..a }));
    }

    /// The same path run the other way (an open one).
    pub fn reversed(mut self) -> Trace {
        let last = self.points.len() - 1;
        self.points.reverse();
        self.tags.reverse();
        self.arcs = self.arcs.iter().rev().map(|a| ArcSpan { from: last - a.to, to: last - a.from, bulge: -a.bulge }).collect();
        self
    }
}

/// Removes repeated points and a repeated start point at the end (which
/// closes the shape), keeping the arcs on the points that stay. `None` for
/// fewer than 2 distinct points.
pub(crate) fn clean_polyline(trace: Trace, mut closed: bool) -> Option<(Trace, bool)> {
    let mut out: Vec<Point> = Vec::with_capacity(trace.points.len());
    // Where each point went: the index of the kept point it repeats.
    let mut kept = Vec::with_capacity(trace.points.len());
    for p in trace.points {
        if out.last().is_none_or(|last| (p - last).norm() > SAME_POINT_MM) {
            out.push(p);
        }
        kept.push(out.len() - 1);
    }
    if out.len() >= 2 && (out[out.len() - 1] - out[0]).norm() <= SAME_POINT_MM {
        // The last point is the first again: the closing segment (index n).
        out.pop();
        closed = true;
    }
    if out.len() < 2 {
        return None;
    }
    // Two points closed is a line there and back; mark it once, as an open line.
    if out.len() == 2 {
        closed = false;
    }
    let ends = if closed { out.len() } else { out.len() - 1 };
    let arcs = trace.arcs.iter().map(|a| ArcSpan { from: kept[a.from], to: kept[a.to], ..*a }).filter(|a| a.to > a.from && a.to <= ends).collect();
    // A segment stays where its ends are kept apart (the closing one ends on vertex 0).
    let tags = trace.tags.iter().enumerate().filter(|&(i, _)| kept[i + 1] != kept[i] && kept[i + 1] <= ends).map(|(_, &t)| t).collect();
    Some((Trace { points: out, arcs, tags }, closed))
}

/// The job of `geometries` whose `process` is still an index into the
/// config's layers: the layers used become its processes, in config order.
pub(crate) fn job_of_layers(source: &str, mut geometries: Vec<Geometry>, config: &MachineConfig) -> Job {
    let mut used: Vec<usize> = geometries.iter().map(|g| g.process).collect();
    used.sort_unstable();
    used.dedup();
    let processes = used
        .iter()
        .map(|&i| {
            // Past the layers: a layer's fill process (`fill::fill_process`).
            let fill = i >= config.layers.len();
            let l = &config.layers[i % config.layers.len()];
            Process { layer: l.name.clone(), speed: l.speed, power: l.power, passes: l.passes, fill }
        })
        .collect();
    for g in &mut geometries {
        g.process = used.binary_search(&g.process).unwrap_or(0);
    }
    Job { source: source.to_string(), geometries, processes }
}

/// A job file's bytes, if it is a regular file of at most `max` bytes (a
/// device or a FIFO named like a job file is refused, not read forever).
pub fn read_capped(path: &Path, max: usize) -> Result<Vec<u8>> {
    use std::os::unix::fs::OpenOptionsExt;
    let shown = path.display();
    let file = std::fs::OpenOptions::new().read(true).custom_flags(nix::libc::O_NONBLOCK).open(path).map_err(|e| Error::Import(format!("{shown}: cannot read: {e}")))?;
    read_regular(file, max, &shown.to_string())
}

/// The bytes of an open job file (`shown` in messages), if it is a regular
/// file of at most `max` bytes (open it with `O_NONBLOCK`: a FIFO then
/// never blocks).
pub fn read_regular(file: std::fs::File, max: usize, shown: &str) -> Result<Vec<u8>> {
    use std::io::Read;
    let unreadable = |e: std::io::Error| Error::Import(format!("{shown}: cannot read: {e}"));
    let too_large = || Error::TooLarge(format!("{shown}: more than the {max} bytes a job file may have ([import] max_file_mb)"));
    let meta = file.metadata().map_err(unreadable)?;
    if !meta.is_file() {
        return Err(Error::Import(format!("{shown}: not a regular file")));
    }
    if meta.len() > max as u64 {
        return Err(too_large());
    }
    let mut bytes = Vec::new();
    file.take(max as u64 + 1).read_to_end(&mut bytes).map_err(unreadable)?;
    if bytes.len() > max {
        return Err(too_large());
    }
    Ok(bytes)
}

/// A small machine for the import tests, independent of the shipped config file: the
/// tests depend on its layers only.
#[cfg(test)]
pub(crate) fn test_config() -> MachineConfig {
    let text = r##"
        default_layer = "mark"
        [stage]
        travel_x = 300.0
        travel_y = 300.0
        max_velocity = 500.0
        max_acceleration = 5000.0
        max_jerk = 250000.0
        [laser]
        max_power = 1000.0
        mode = "M4"
        [serial]
        port = "/dev/null"
        baud = 115200
        rx_buffer = 128
        [import]
        tolerance = 0.01
        svg_dpi = 96.0
        [[layer]]
        name = "mark"
        stroke = "#000000"
        speed = 1000.0
        power = 300.0
        [[layer]]
        name = "cut"
        stroke = "#ff0000"
        id = "cut"
        speed = 200.0
        power = 1000.0
        [[layer]]
        name = "engrave"
        stroke = "#0000ff"
        id = "engrave"
        speed = 800.0
        power = 150.0
    "##;
    MachineConfig::parse(text, "test.toml").expect("the test config is valid")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> MachineConfig {
        test_config()
    }

    #[test]
    fn unsupported_extension_is_named() {
        let err = import_job(Path::new("part.step"), &config()).unwrap_err().to_string();
        assert!(err.contains("part.step") && err.contains("'.step'") && err.contains(".svg") && err.contains(".dxf"), "{err}");
        assert!(!err.contains('\n'));
        let err = import_job(Path::new("part"), &config()).unwrap_err().to_string();
        assert!(err.contains("part") && err.contains("no extension"), "{err}");
    }

    #[test]
    fn missing_file_is_one_line_naming_the_file() {
        let err = import_job(Path::new("/nonexistent/dir/job.svg"), &config()).unwrap_err().to_string();
        assert!(err.contains("/nonexistent/dir/job.svg: cannot read:"), "{err}");
        assert!(!err.contains('\n'));
    }

    /// A device or FIFO named like a job file is refused at once, and a file
    /// over `[import] max_file_mb` is not read to its end.
    #[test]
    fn only_regular_files_up_to_the_size_limit_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let zero = dir.path().join("zero.svg");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        let fifo = dir.path().join("fifo.svg");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
        for path in [&zero, &fifo] {
            let err = import_job(path, &config()).unwrap_err().to_string();
            assert!(err.contains("not a regular file"), "{err}");
        }
        let big = dir.path().join("big.svg");
        std::fs::write(&big, vec![b' '; 2000]).unwrap();
        let mut small = config();
        small.import.max_file_mb = 0.001;
        let err = import_job(&big, &small).unwrap_err().to_string();
        assert!(err.contains("big.svg") && err.contains("max_file_mb"), "{err}");
    }

    #[test]
    fn reads_an_svg_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("square.SVG");
        std::fs::write(
            &path,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="10mm" height="10mm" viewBox="0 0 10 10">
                 <rect x="1" y="1" width="2" height="2" fill="none" stroke="black"/></svg>"#,
        )
        .unwrap();
        let job = import_job(&path, &config()).unwrap();
        assert_eq!(job.geometries.len(), 1);
        assert_eq!(job.source, path.display().to_string());
    }

    #[test]
    fn a_job_is_placed_at_the_origin_centred_or_at_an_offset_as_told() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.svg");
        std::fs::write(&path, r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100"><rect x="20" y="30" width="40" height="10" fill="none" stroke="black"/></svg>"#).unwrap();
        let mut config = config();
        let bounds = |config: &MachineConfig| {
            let (lo, hi) = import_job(&path, config).unwrap().bounds();
            [lo.x, lo.y, hi.x, hi.y]
        };
        let near = |a: [f64; 4], b: [f64; 4]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-4);
        // As drawn: the document's bottom-left corner at the origin (y flipped).
        assert!(near(bounds(&config), [20.0, 60.0, 60.0, 70.0]), "{:?}", bounds(&config));
        config.job.anchor = Anchor::Origin;
        assert!(near(bounds(&config), [0.0, 0.0, 40.0, 10.0]), "{:?}", bounds(&config));
        config.job.anchor = Anchor::Center;
        assert!(near(bounds(&config), [130.0, 145.0, 170.0, 155.0]), "on the 300 x 300 bed: {:?}", bounds(&config));
        config.job.anchor = "12.5, 7".parse().unwrap();
        assert!(near(bounds(&config), [12.5, 7.0, 52.5, 17.0]), "{:?}", bounds(&config));
        for bad in ["", "left", "1,", "nan,1", "1e9,0"] {
            assert!(bad.parse::<Anchor>().unwrap_err().contains("no placement"), "{bad}");
        }
    }

    #[test]
    fn an_outline_on_the_origin_computed_a_rounding_below_zero_is_put_on_it() {
        // usvg's f32 arithmetic puts this rectangle's left edge at about
        // -2e-6 mm; planning refused it as outside the machine's reach.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("edge.svg");
        std::fs::write(&path, r#"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300"><g transform="translate(47.11 47.11)"><rect x="-47.11" y="-47.11" width="100" height="100" fill="none" stroke="black"/></g></svg>"#).unwrap();
        let job = import_job(&path, &config()).unwrap();
        let (lo, _) = job.bounds();
        assert_eq!(lo.x, 0.0, "on the edge, not below it");
        // Beyond the snap it stays where it is (and planning names it).
        std::fs::write(&path, r#"<svg xmlns="http://www.w3.org/2000/svg" width="300mm" height="300mm" viewBox="0 0 300 300"><rect x="-0.01" y="10" width="100" height="100" fill="none" stroke="black"/></svg>"#).unwrap();
        assert!(import_job(&path, &config()).unwrap().bounds().0.x < -0.009);
    }

    #[test]
    fn a_trace_keeps_its_arcs_through_appending_reversing_and_cleaning() {
        // A line (0,0)-(10,0), then a half circle up to (0,0) through (5,5)'s side.
        let mut t = Trace::of(vec![Point::new(0.0, 0.0), Point::new(10.0, 0.0)]);
        let half: Vec<Point> = (1..=8).map(|k| {
            let a = std::f64::consts::PI * k as f64 / 8.0;
            Point::new(5.0 + 5.0 * a.cos(), 5.0 * a.sin())
        }).collect();
        let mut arc = Trace::of(vec![Point::new(10.0, 0.0), Point::new(10.0, 0.0)]);
        arc.points.truncate(1);
        arc.arc_to(half, 1.0);
        t.append(arc);
        assert_eq!(t.arcs, vec![ArcSpan { from: 1, to: 9, bulge: 1.0 }]);
        let length = |t: &Trace, closed: bool| Geometry { points: t.points.clone(), closed, arcs: t.arcs.clone(), profile: Vec::new(), process: 0, source: String::new() }.length();
        let want = 10.0 + 5.0 * std::f64::consts::PI;
        assert!((length(&t, false) - want).abs() < 1e-12);
        let back = t.clone().reversed();
        assert_eq!(back.arcs, vec![ArcSpan { from: 0, to: 8, bulge: -1.0 }]);
        assert!((length(&back, false) - want).abs() < 1e-12);
        // Cleaning: a repeated point, and the end on the start, which closes
        // it: the arc then ends on vertex 0 (index = the number of points).
        let mut doubled = t.clone();
        doubled.points.insert(3, doubled.points[3]);
        doubled.arcs[0].to += 1;
        let (clean, closed) = clean_polyline(doubled, false).unwrap();
        assert!(closed && clean.points.len() == 9, "{:?}", clean.points);
        assert_eq!(clean.arcs, vec![ArcSpan { from: 1, to: 9, bulge: 1.0 }]);
        assert!((length(&clean, true) - want).abs() < 1e-12);
        let g = Geometry { points: clean.points, closed: true, arcs: clean.arcs, profile: Vec::new(), process: 0, source: String::new() };
        // Eight chords over a half circle of r = 5 cut 0.096 mm inside it.
        assert!(g.arc_error(0.1).is_none(), "{:?}", g.arc_error(0.1));
        assert!(g.arc_error(0.09).is_some_and(|e| e.contains("chord 9.61e-2 mm inside")));
        let (lo, hi) = g.bounds();
        assert!((lo - Point::new(0.0, 0.0)).norm() < 1e-12 && (hi - Point::new(10.0, 5.0)).norm() < 1e-12, "{lo:?} {hi:?}");
    }
}
