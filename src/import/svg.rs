//! SVG import: every visible path of the document becomes polylines in machine mm.
//!
//! Units: usvg resolves lengths, the viewBox and all transforms to px (CSS px, 96 per
//! inch, or `import.svg_dpi` per inch for unitless sizes); one px is 25.4 / dpi mm.
//!
//! Axes: SVG's y runs down from the top edge of the document; the machine's Y runs up
//! (away from the operator). We map `y_machine = doc_height_mm - y_svg_mm`, so the
//! document's bottom-left corner is the machine origin and the drawing lies on the
//! sheet the way it looks on screen (not mirrored). `x_machine = x_svg_mm`.
//!
//! Curves are transformed to machine mm first and flattened afterwards, so the
//! flattening tolerance `import.tolerance` is a distance in mm on the workpiece, whatever
//! scaling the document applies.

use kurbo::{BezPath, PathEl};
use usvg::tiny_skia_path::{self, PathSegment};

use crate::config::{parse_hex_colour, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{Geometry, Job, Point};

use super::MAX_COORD_MM;

/// Largest number in a geometry attribute (user units). Far beyond any
/// drawing's need (1e9 µm is 1 km), far below where usvg's f32 arithmetic
/// fails: an arc to 1e30 spins in its conversion for seconds, and a 1e308
/// becomes infinite and its path vanishes.
const MAX_RAW_NUMBER: f64 = 1e9;

/// Attributes that place or shape geometry (markers are drawn as paths too).
/// usvg reads an unreadable one as absent: 0, or no transform, so each is
/// checked here first.
const GEOMETRY_ATTRIBUTES: [&str; 23] = [
    "d", "points", "transform", "transform-origin", "viewBox", "preserveAspectRatio", "x", "y", "width", "height", "rx", "ry", "r", "cx", "cy",
    "x1", "y1", "x2", "y2", "refX", "refY", "markerWidth", "markerHeight",
];

/// CSS properties that place geometry (usvg takes these two from style
/// sheets and `style` attributes as well as from attributes).
const GEOMETRY_STYLE: [&str; 2] = ["transform", "transform-origin"];

/// Parses SVG `text` and converts it to a job; `source` names the file in messages.
/// Nothing outside `text` is read: images by path or URL are refused.
pub fn import_svg(text: &str, source: &str, config: &MachineConfig) -> Result<Job> {
    check_raw_geometry(text, source, config)?;
    let options = usvg::Options {
        dpi: config.import.svg_dpi as f32,
        resources_dir: None,
        // Images are not marked; loading one would read a file named by the
        // upload (or block on a FIFO, or read a device), so none is loaded.
        image_href_resolver: usvg::ImageHrefResolver { resolve_data: Box::new(|_, _, _| None), resolve_string: Box::new(|_, _| None) },
        ..usvg::Options::default()
    };
    let tree = usvg::Tree::from_str(text, &options)
        .map_err(|e| Error::Import(format!("{source}: malformed SVG: {}", parse_error_message(&e))))?;

    let mm_per_px = 25.4 / config.import.svg_dpi;
    let mut importer = Importer {
        source,
        config,
        mm_per_px,
        doc_height_mm: tree.size().height() as f64 * mm_per_px,
        paths_seen: 0,
        points: 0,
        geometries: Vec::new(),
    };
    importer.walk(tree.root(), &mut Vec::new())?;

    if importer.geometries.is_empty() {
        return Err(Error::Import(format!(
            "{source}: nothing to mark: no visible path with at least two distinct points \
             (text must be converted to paths)"
        )));
    }

    Ok(super::job_of_layers(source, importer.geometries, config))
}

/// usvg's message for a parse failure, on one line. For XML errors we use roxmltree's
/// own text, which ends in "at line:col", without usvg's "parsing failed cause" prefix.
fn parse_error_message(e: &usvg::Error) -> String {
    let msg = match e {
        usvg::Error::ParsingFailed(xml) => xml.to_string(),
        other => other.to_string(),
    };
    msg.lines().collect::<Vec<_>>().join(" ")
}

/// Checks the raw document before usvg reads it: what it repeats into
/// (`svg_size`), and the geometry attributes: numbers out of
/// any drawing's range, path data or transforms it would cut short or drop
/// (a browser draws up to the error; a laser must not), each an error naming
/// the element. Warns of what is not marked: `<text>` (usvg is built without
/// fonts) and `<image>`.
fn check_raw_geometry(text: &str, source: &str, config: &MachineConfig) -> Result<()> {
    let options = usvg::roxmltree::ParsingOptions { allow_dtd: true, ..Default::default() };
    // A document roxmltree cannot read, usvg cannot either: it says why.
    let Ok(doc) = usvg::roxmltree::Document::parse_with_options(text, options) else { return Ok(()) };
    super::svg_size::check(&doc, source, &config.import)?;
    let (mut texts, mut images) = (Vec::new(), 0);
    for node in doc.descendants().filter(|n| n.is_element()) {
        match node.tag_name().name() {
            "text" => {
                // Named by id or line, with what it says: the operator can
                // find each one to convert it to paths.
                let words: String = node.descendants().filter(|n| n.is_text()).filter_map(|n| n.text()).collect::<Vec<_>>().join(" ").split_whitespace().collect::<Vec<_>>().join(" ");
                let shown: String = words.chars().take(40).map(|c| if c.is_control() { ' ' } else { c }).collect();
                let line = doc.text_pos_at(node.range().start).row;
                texts.push(match node.attribute("id") {
                    Some(id) => format!("<text id=\"{}\"> (line {line}) \"{shown}\"", id.chars().take(40).collect::<String>()),
                    None => format!("<text> at line {line} \"{shown}\""),
                });
            }
            "image" => images += 1,
            _ => {}
        }
        let attributes = node.attributes().map(|a| (a.name(), a.value()));
        // `style="transform: …"` and a `<style>` sheet's rules set the same
        // transform as the attribute, read as usvg reads them.
        let mut styled: Vec<(&str, &str)> = match node.attribute("style") {
            Some(style) => simplecss::DeclarationTokenizer::from(style).map(|d| (d.name, d.value)).collect(),
            None => vec![],
        };
        if node.has_tag_name("style") {
            let sheet = simplecss::StyleSheet::parse(node.text().unwrap_or(""));
            styled.extend(sheet.rules.iter().flat_map(|r| r.declarations.iter()).map(|d| (d.name, d.value)));
        }
        for (attribute, value) in attributes.chain(styled.into_iter().filter(|(n, _)| GEOMETRY_STYLE.contains(n))) {
            if !GEOMETRY_ATTRIBUTES.contains(&attribute) {
                continue;
            }
            let name = || {
                let at = doc.text_pos_at(node.range().start);
                match node.attribute("id") {
                    Some(id) => format!("{} '{id}' (line {})", node.tag_name().name(), at.row),
                    None => format!("{} at line {}", node.tag_name().name(), at.row),
                }
            };
            let bad = |why: String| Error::Import(format!("{source}: {}: {attribute}=\"{}\": {why}", name(), value.chars().take(40).map(|c| if c.is_control() { ' ' } else { c }).collect::<String>()));
            let numbers = numbers_of(attribute, value).map_err(bad)?;
            if let Some(n) = numbers.iter().find(|n| !(n.is_finite() && n.abs() <= MAX_RAW_NUMBER)) {
                return Err(bad(format!("the number {n:e} is out of range (at most {MAX_RAW_NUMBER:e} in magnitude)")));
            }
        }
    }
    const LISTED: usize = 20;
    for text in texts.iter().take(LISTED) {
        tracing::warn!("{source}: {text} ignored: convert text to paths to mark it");
    }
    if texts.len() > LISTED {
        tracing::warn!("{source}: and {} more <text> element(s) ignored", texts.len() - LISTED);
    }
    if images > 0 {
        tracing::warn!("{source}: {images} <image> element(s) ignored (only paths are marked)");
    }
    Ok(())
}

/// The numbers of a geometry attribute, read by usvg's own parsers
/// (svgtypes): path data, a transform's matrix, a list of numbers, a length.
/// A value usvg would cut short, ignore or read as 0 is an error (a browser
/// draws the element elsewhere or not at all; a laser must not guess).
fn numbers_of(attribute: &str, value: &str) -> std::result::Result<Vec<f64>, String> {
    use svgtypes::PathSegment as S;
    match attribute {
        "d" => {
            let mut numbers = Vec::new();
            for segment in svgtypes::PathParser::from(value) {
                let segment = segment.map_err(|e| format!("unreadable path data ({e}); nothing after the error would be marked"))?;
                numbers.extend_from_slice(&match segment {
                    S::MoveTo { x, y, .. } | S::LineTo { x, y, .. } | S::SmoothQuadratic { x, y, .. } => vec![x, y],
                    S::HorizontalLineTo { x, .. } => vec![x],
                    S::VerticalLineTo { y, .. } => vec![y],
                    S::CurveTo { x1, y1, x2, y2, x, y, .. } => vec![x1, y1, x2, y2, x, y],
                    S::SmoothCurveTo { x2, y2, x, y, .. } => vec![x2, y2, x, y],
                    S::Quadratic { x1, y1, x, y, .. } => vec![x1, y1, x, y],
                    S::EllipticalArc { rx, ry, x_axis_rotation, x, y, .. } => vec![rx, ry, x_axis_rotation, x, y],
                    S::ClosePath { .. } => vec![],
                });
            }
            Ok(numbers)
        }
        "transform" => {
            let t: svgtypes::Transform = value.parse().map_err(|e| format!("unreadable transform ({e})"))?;
            // usvg replaces a transform that collapses an axis (scale(0)) by
            // none at all, as tiny-skia judges it (in f32).
            let collapsed = |a: f64, b: f64| (a.hypot(b) as f32) <= f32::EPSILON;
            if collapsed(t.a, t.c) || collapsed(t.b, t.d) {
                return Err("the transform collapses the drawing to a line or a point".into());
            }
            Ok(vec![t.a, t.b, t.c, t.d, t.e, t.f])
        }
        "transform-origin" => {
            value.parse::<svgtypes::TransformOrigin>().map_err(|e| format!("unreadable transform origin ({e})"))?;
            Ok(vec![])
        }
        "preserveAspectRatio" => {
            value.parse::<svgtypes::AspectRatio>().map_err(|e| format!("unreadable aspect ratio ({e})"))?;
            Ok(vec![])
        }
        "points" | "viewBox" => {
            let numbers = svgtypes::NumberListParser::from(value).collect::<std::result::Result<Vec<f64>, _>>();
            match numbers {
                Ok(n) if attribute == "viewBox" || n.len() % 2 == 0 => Ok(n),
                _ if attribute == "points" => Err("unreadable point list (pairs of numbers expected)".into()),
                _ => Err("unreadable viewBox (four numbers expected)".into()),
            }
        }
        _ => value.parse::<svgtypes::Length>().map(|l| vec![l.number]).map_err(|_| "unreadable length (a number with an optional unit expected)".into()),
    }
}

struct Importer<'a> {
    source: &'a str,
    config: &'a MachineConfig,
    mm_per_px: f64,
    doc_height_mm: f64,
    /// Paths met so far in document order; names paths without an id in messages.
    paths_seen: usize,
    /// Points flattened so far, against `[import] max_points`.
    points: u64,
    /// `process` holds the config layer index until `import_svg` renumbers it.
    geometries: Vec<Geometry>,
}

impl<'a> Importer<'a> {
    /// Visits the group's children in document order; `groups` holds the ids of the
    /// enclosing groups (SVG layers) for layer selection.
    fn walk<'t>(&mut self, group: &'t usvg::Group, groups: &mut Vec<&'t str>) -> Result<()> {
        for node in group.children() {
            match node {
                usvg::Node::Group(g) => {
                    let named = !g.id().is_empty();
                    if named {
                        groups.push(g.id());
                    }
                    self.walk(g, groups)?;
                    if named {
                        groups.pop();
                    }
                }
                usvg::Node::Path(p) => self.add_path(p, groups)?,
                // Counted and warned of by `check_raw_geometry`.
                usvg::Node::Image(_) | usvg::Node::Text(_) => {}
            }
        }
        Ok(())
    }

    fn add_path(&mut self, path: &usvg::Path, groups: &[&str]) -> Result<()> {
        self.paths_seen += 1;
        // visibility="hidden" hides a path from the drawing; marking it would surprise.
        if !path.is_visible() {
            return Ok(());
        }
        let name =
            if path.id().is_empty() { format!("path #{}", self.paths_seen) } else { format!("path '{}'", path.id()) };
        let bez = self.to_machine_mm(path.data(), path.abs_transform(), &name)?;
        let layer = self.layer_for(path, groups);

        let import = &self.config.import;
        let room = import.max_points.saturating_sub(self.points);
        let Some(subpaths) = flatten(&bez, import.tolerance, room) else {
            return Err(Error::Import(format!(
                "{}: {name}: the drawing flattens to more than [import] max_points = {} points at \
                 [import] tolerance = {} mm; simplify it or raise the limit",
                self.source, import.max_points, import.tolerance
            )));
        };
        self.points += subpaths.iter().map(|(p, _)| p.len() as u64).sum::<u64>();
        let mut lines = Vec::with_capacity(subpaths.len());
        for (i, (points, closed)) in subpaths.into_iter().enumerate() {
            // usvg gives every curve as Béziers: SVG arcs come in as points.
            if let Some((trace, closed)) = super::clean_polyline(super::Trace::of(points.into_iter().map(|p| Point::new(p.x, p.y)).collect()), closed) {
                lines.push(Geometry {
                    points: trace.points,
                    arcs: Vec::new(), profile: Vec::new(),
                    closed,
                    process: layer,
                    source: format!("{}: {} subpath {}", self.source, name, i + 1),
                });
            }
        }
        let mode = self.config.layers[layer].mode;
        if mode.fills() && !lines.is_empty() {
            // SVG's fill rule (nonzero unless the path says even-odd), whether or not the drawing fills it.
            let rule = match path.fill().map(|f| f.rule()) {
                Some(usvg::FillRule::EvenOdd) => super::fill::Rule::EvenOdd,
                _ => super::fill::Rule::NonZero,
            };
            let shapes: Vec<&[Point]> = lines.iter().map(|g| g.points.as_slice()).collect();
            let area = super::fill::element_area(&shapes, rule, layer, self.config, &format!("{}: {name}", self.source))?;
            self.geometries.extend(area);
        }
        if mode.lines() {
            self.geometries.extend(lines);
        }
        Ok(())
    }

    /// The path's outline in machine mm (transform, px → mm, y flip), still with curves.
    fn to_machine_mm(&self, data: &tiny_skia_path::Path, ts: usvg::Transform, name: &str) -> Result<BezPath> {
        let (sx, kx, tx) = (ts.sx as f64, ts.kx as f64, ts.tx as f64);
        let (ky, sy, ty) = (ts.ky as f64, ts.sy as f64, ts.ty as f64);
        let mut bad = None;
        let mut map = |p: tiny_skia_path::Point| {
            let (x, y) = (p.x as f64, p.y as f64);
            let mx = (sx * x + kx * y + tx) * self.mm_per_px;
            let my = self.doc_height_mm - (ky * x + sy * y + ty) * self.mm_per_px;
            if !(mx.is_finite() && my.is_finite()) {
                bad.get_or_insert("is not a finite number");
            } else if mx.abs() > MAX_COORD_MM || my.abs() > MAX_COORD_MM {
                bad.get_or_insert("is out of range (beyond 1 km)");
            }
            kurbo::Point::new(mx, my)
        };
        let mut bez = BezPath::new();
        for seg in data.segments() {
            match seg {
                PathSegment::MoveTo(p) => bez.move_to(map(p)),
                PathSegment::LineTo(p) => bez.line_to(map(p)),
                PathSegment::QuadTo(p1, p2) => bez.quad_to(map(p1), map(p2)),
                PathSegment::CubicTo(p1, p2, p3) => bez.curve_to(map(p1), map(p2), map(p3)),
                PathSegment::Close => bez.close_path(),
            }
        }
        match bad {
            Some(why) => Err(Error::Import(format!("{}: {name}: a coordinate {why}", self.source))),
            None => Ok(bez),
        }
    }

    /// Index of the config layer for a path: the first layer whose colour
    /// (`stroke`) is the path's solid stroke (a path without a stroke: its
    /// solid fill, as a design program colours a filled shape) or whose id
    /// names an enclosing group; else the default layer.
    fn layer_for(&self, path: &usvg::Path, groups: &[&str]) -> usize {
        let solid = |paint: &usvg::Paint| match paint {
            usvg::Paint::Color(c) => Some([c.red, c.green, c.blue]),
            _ => None,
        };
        let stroke = match path.stroke() {
            Some(s) => solid(s.paint()),
            None => path.fill().and_then(|f| solid(f.paint())),
        };
        self.config
            .layers
            .iter()
            .position(|layer| {
                let by_colour = stroke.is_some() && layer.stroke.as_deref().and_then(parse_hex_colour) == stroke;
                let by_group = layer.id.as_deref().is_some_and(|id| groups.contains(&id));
                by_colour || by_group
            })
            .unwrap_or_else(|| self.config.default_layer_index())
    }
}

/// Flattens a path to polylines within `tolerance`: one (points, closed) per
/// subpath; `None` past `max_points` (found out within one curve: the rest of
/// the path is not flattened).
fn flatten(bez: &BezPath, tolerance: f64, max_points: u64) -> Option<Vec<(Vec<kurbo::Point>, bool)>> {
    let over = std::cell::Cell::new(false);
    let mut count = 0u64;
    let mut subpaths: Vec<(Vec<kurbo::Point>, bool)> = Vec::new();
    let mut current: Vec<kurbo::Point> = Vec::new();
    // SVG allows drawing on after a Z without a new M; such a subpath starts where the
    // closed one did.
    let mut start = kurbo::Point::ZERO;
    kurbo::flatten(bez.iter().take_while(|_| !over.get()), tolerance, |el| {
        count += 1;
        if count > max_points {
            over.set(true);
            return;
        }
        match el {
            PathEl::MoveTo(p) => {
                if !current.is_empty() {
                    subpaths.push((std::mem::take(&mut current), false));
                }
                start = p;
                current.push(p);
            }
            PathEl::LineTo(p) => {
                if current.is_empty() {
                    current.push(start);
                }
                current.push(p);
            }
            PathEl::ClosePath => {
                if !current.is_empty() {
                    subpaths.push((std::mem::take(&mut current), true));
                }
            }
            // kurbo::flatten emits only the three above; curves are already lines.
            PathEl::QuadTo(..) | PathEl::CurveTo(..) => {}
        }
    });
    if over.get() {
        return None;
    }
    if !current.is_empty() {
        subpaths.push((current, false));
    }
    Some(subpaths)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> MachineConfig {
        crate::import::test_config()
    }

    /// A 100 x 100 mm document with one user unit per mm.
    fn svg(body: &str) -> String {
        format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">{body}</svg>"#
        )
    }

    fn import(text: &str) -> Job {
        import_svg(text, "t.svg", &config()).unwrap()
    }

    fn close(a: f64, b: f64) -> bool {
        // usvg computes in f32: about 1e-5 mm at 100 mm.
        (a - b).abs() < 1e-4
    }

    #[test]
    fn viewbox_scales_user_units_to_mm() {
        let job = import(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 10 10">
               <rect x="2" y="3" width="1" height="1" fill="none" stroke="black"/></svg>"#,
        );
        let g = &job.geometries[0];
        assert!(g.closed);
        assert_eq!(g.points.len(), 4);
        let (lo, hi) = g.bounds();
        assert!(close(hi.x - lo.x, 10.0) && close(hi.y - lo.y, 10.0), "{lo} {hi}");
        // x 20..30; SVG y 30..40 from the top is machine y 60..70 from the bottom.
        assert!(close(lo.x, 20.0) && close(lo.y, 60.0), "{lo}");
    }

    #[test]
    fn unitless_size_uses_the_dpi() {
        // 96 px at 96 dpi is one inch.
        let job = import(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="96" height="96">
               <path d="M 0 0 L 96 0" stroke="black"/></svg>"#,
        );
        assert!(close(job.geometries[0].length(), 25.4));
    }

    #[test]
    fn y_axis_is_flipped() {
        let job = import(&svg(r#"<path d="M 10 10 L 20 30" stroke="black"/>"#));
        let p = &job.geometries[0].points;
        assert!(close(p[0].x, 10.0) && close(p[0].y, 90.0), "{}", p[0]);
        assert!(close(p[1].x, 20.0) && close(p[1].y, 70.0), "{}", p[1]);
    }

    #[test]
    fn group_transforms_apply() {
        let job = import(&svg(
            r#"<g transform="translate(5 7)"><g transform="scale(2)"><path d="M 1 1 L 2 1" stroke="black"/></g></g>"#,
        ));
        let p = &job.geometries[0].points;
        assert!(close(p[0].x, 7.0) && close(p[0].y, 100.0 - 9.0), "{}", p[0]);
        assert!(close(p[1].x, 9.0) && close(p[1].y, 100.0 - 9.0), "{}", p[1]);
    }

    #[test]
    fn circle_is_flattened_within_tolerance() {
        let cfg = config();
        let tol = cfg.import.tolerance;
        let job = import(&svg(r#"<circle cx="50" cy="50" r="10" fill="none" stroke="black"/>"#));
        assert_eq!(job.geometries.len(), 1);
        let g = &job.geometries[0];
        assert!(g.closed);
        let centre = Point::new(50.0, 50.0);
        for p in &g.points {
            let r = (p - centre).norm();
            assert!((r - 10.0).abs() <= tol, "vertex at radius {r}");
        }
        // Chord midpoints too: the segments stay within the tolerance of the circle.
        let n = g.points.len();
        for i in 0..n {
            let mid = Point::from((g.points[i].coords + g.points[(i + 1) % n].coords) / 2.0);
            assert!(((mid - centre).norm() - 10.0).abs() <= tol + 1e-6);
        }
        // A chord of sagitta t spans 2*acos(1 - t/r): about 70 segments here.
        let ideal = std::f64::consts::PI / (1.0 - tol / 10.0).acos();
        assert!(n as f64 >= ideal * 0.9 && (n as f64) <= ideal * 3.0, "{n} vertices, ideal {ideal}");
        assert!((g.length() - 2.0 * std::f64::consts::PI * 10.0).abs() < 0.05);
    }

    #[test]
    fn open_and_closed_subpaths() {
        let job = import(&svg(r#"<path id="p" stroke="black" fill="none"
                 d="M 0 0 L 10 0 L 10 10 Z  M 20 0 L 30 0 L 30 10  M 40 0 L 50 0 L 50 10 L 40 0
                    M 60 0 L 60 0  M 70 0 L 70 0 L 80 0"/>"#));
        let g = &job.geometries;
        assert_eq!(g.len(), 4, "{g:?}");
        assert!(g[0].closed && g[0].points.len() == 3);
        assert!(!g[1].closed && g[1].points.len() == 3);
        // Ends on its start: closed, without the repeated point.
        assert!(g[2].closed && g[2].points.len() == 3);
        // The single-point subpath 4 is skipped; the duplicate in subpath 5 is removed.
        assert!(!g[3].closed && g[3].points.len() == 2);
        assert_eq!(g[0].source, "t.svg: path 'p' subpath 1");
        assert_eq!(g[3].source, "t.svg: path 'p' subpath 5");
    }

    #[test]
    fn paths_without_id_are_named_by_index() {
        let job = import(&svg(r#"<path d="M 0 0 L 1 1" stroke="black"/><path d="M 0 0 L 2 2" stroke="black"/>"#));
        assert_eq!(job.geometries[1].source, "t.svg: path #2 subpath 1");
    }

    #[test]
    fn stroke_colour_selects_the_layer() {
        let job = import(&svg(r##"<path d="M 0 0 L 1 1" stroke="#ff0000"/>
               <path d="M 0 0 L 2 2" stroke="rgb(0,0,255)"/>
               <path d="M 0 0 L 3 3" stroke="#00ff00"/>
               <rect x="1" y="1" width="5" height="5" fill="red"/>
               <rect x="1" y="1" width="5" height="5" fill="#123456"/>
               <rect x="1" y="1" width="5" height="5" fill="red" stroke="#00ff00"/>"##));
        let layer = |i: usize| job.processes[job.geometries[i].process].layer.as_str();
        assert_eq!(layer(0), "cut");
        assert_eq!(layer(1), "engrave");
        // Unknown colour: the default layer.
        assert_eq!(layer(2), "mark");
        // A filled shape without a stroke by its fill's colour; with one, by its stroke's.
        assert_eq!(layer(3), "cut");
        assert_eq!(layer(4), "mark");
        assert_eq!(layer(5), "mark");
        assert!(job.geometries[3].closed);
        assert_eq!(job.processes.len(), 3);
        let cut = job.processes.iter().find(|p| p.layer == "cut").unwrap();
        assert_eq!((cut.speed, cut.power, cut.passes), (200.0, 1000.0, 1));
    }

    #[test]
    fn group_id_selects_the_layer() {
        let job = import(&svg(r##"<g id="engrave"><g id="inner"><path d="M 0 0 L 1 1" stroke="#00ff00"/></g></g>
               <g id="other"><path d="M 0 0 L 2 2" stroke="#00ff00"/></g>"##));
        assert_eq!(job.processes[job.geometries[0].process].layer, "engrave");
        assert_eq!(job.processes[job.geometries[1].process].layer, "mark");
        // Only the used layers are listed.
        assert_eq!(job.processes.len(), 2);
    }

    #[test]
    fn malformed_svg_is_one_line_with_position() {
        let err =
            import_svg("<svg xmlns=\"http://www.w3.org/2000/svg\">\n<path d=\"M 0 0\"</svg>", "bad.svg", &config())
                .unwrap_err()
                .to_string();
        assert!(err.contains("bad.svg: malformed SVG"), "{err}");
        assert!(err.contains("2:"), "{err}");
        assert!(!err.contains('\n'));
        let err = import_svg("not xml at all", "bad.svg", &config()).unwrap_err().to_string();
        assert!(err.contains("malformed SVG"), "{err}");
    }

    #[test]
    fn empty_job_is_an_error() {
        let err = import_svg(&svg(r#"<path d="M 5 5" stroke="black"/>"#), "e.svg", &config()).unwrap_err().to_string();
        assert!(err.contains("e.svg") && err.contains("nothing to mark"), "{err}");
    }

    #[test]
    fn huge_or_infinite_coordinates_are_rejected() {
        let err = import_svg(&svg(r#"<path id="big" d="M 0 0 L 1e30 0" stroke="black"/>"#), "h.svg", &config())
            .unwrap_err()
            .to_string();
        assert!(err.contains("h.svg") && err.contains("path 'big'") && err.contains("1e30"), "{err}");
        // Beyond f32 (usvg's numbers): once dropped silently with its path.
        for d in ["M 0 0 L 1e39 0", "M 1e308 10 L 20 20", "M 0 0 L 10 10 L -1e308 0"] {
            let err = import_svg(&svg(&format!(r#"<path d="{d}" stroke="black"/>"#)), "h.svg", &config()).unwrap_err().to_string();
            assert!(err.contains("path at line 1") && err.contains("out of range"), "{d}: {err}");
        }
        // Transformed beyond reach: caught in machine mm, naming the path.
        let err = import_svg(&svg(r#"<g transform="scale(1e8)"><path id="far" d="M 0 0 L 100 0" stroke="black"/></g>"#), "h.svg", &config()).unwrap_err().to_string();
        assert!(err.contains("path 'far'") && err.contains("beyond 1 km"), "{err}");
    }

    /// An arc to a far point once spun for minutes in usvg's conversion: a
    /// 150-byte upload took the planning thread.
    #[test]
    fn an_arc_to_a_far_point_is_refused_at_once() {
        let text = svg(r#"<path id="arc" d="M 10 10 A 2.5 2.5 0 0 1 1e38 10" stroke="black"/>"#);
        let started = std::time::Instant::now();
        let err = import_svg(&text, "a.svg", &config()).unwrap_err().to_string();
        assert!(err.contains("path 'arc'") && err.contains("out of range"), "{err}");
        assert!(started.elapsed() < std::time::Duration::from_secs(1), "refused before any arc is converted");
    }

    /// Path data, transforms and point lists that usvg would cut short or
    /// ignore are errors naming the element, not geometry lost in silence.
    #[test]
    fn unreadable_geometry_is_an_error_naming_the_element() {
        for (body, element, what) in [
            (r#"<path id="p1" d="M 10 10 L 20 20 L NaN 5" stroke="black"/>"#, "path 'p1'", "unreadable path data"),
            (r#"<path id="p2" d="M 10 10 L 20 20 Q" stroke="black"/>"#, "path 'p2'", "unreadable path data"),
            (r#"<g id="g1" transform="rotate(30"><path d="M 0 0 L 1 1" stroke="black"/></g>"#, "g 'g1'", "unreadable transform"),
            (r#"<polyline id="l1" points="0,0 10,10 20" stroke="black" fill="none"/>"#, "polyline 'l1'", "unreadable point list"),
            (r#"<polyline points="0,0 10,x" stroke="black" fill="none"/>"#, "polyline at line 1", "unreadable point list"),
        ] {
            let err = import_svg(&svg(body), "u.svg", &config()).unwrap_err().to_string();
            assert!(err.contains("u.svg") && err.contains(element) && err.contains(what), "{body}: {err}");
        }
        // What SVG allows still imports: packed numbers, exponents, flags.
        let job = import(&svg(r#"<path d="M1.5.5L2e1-3.5a1 1 0 01 1 1z" stroke="black"/><polyline points="0,0 1e1,1E1" stroke="black" fill="none"/>"#));
        assert_eq!(job.geometries.len(), 2);
    }

    /// Issue 17, point 6: a coordinate usvg cannot read it takes as 0 (a
    /// circle with cx="inf" was marked at cx=0), a transform it cannot use as
    /// none: each is an error naming the element and the attribute.
    #[test]
    fn non_finite_or_unreadable_coordinates_are_errors_naming_the_element() {
        for (body, element, what) in [
            (r#"<circle id="c" cx="inf" cy="10" r="5" stroke="black"/>"#, r#"circle 'c' (line 1): cx="inf""#, "unreadable length"),
            (r#"<circle cx="10" cy="NaN" r="5" stroke="black"/>"#, r#"circle at line 1: cy="NaN""#, "unreadable length"),
            // Read as infinite or refused by the number parser: either way named.
            (r#"<rect id="r" x="1" y="1" width="1e999" height="5" stroke="black"/>"#, r#"rect 'r' (line 1): width="1e999""#, ""),
            (r#"<line id="l" x1="0" y1="0" x2="10 mm" y2="5" stroke="black"/>"#, r#"line 'l' (line 1): x2="10 mm""#, "unreadable length"),
            (r#"<ellipse id="e" cx="5" cy="5" rx="-inf" ry="2" stroke="black"/>"#, "ellipse 'e'", "unreadable length"),
            (r#"<g id="s" style="fill:none; transform: scale(inf)"><path d="M 0 0 L 1 1" stroke="black"/></g>"#, r#"g 's' (line 1): transform="scale(inf)""#, "unreadable transform"),
            (r#"<style>g.far { fill: none; transform: translate(1e999, 0) }</style><g class="far"><path d="M 0 0 L 1 1" stroke="black"/></g>"#, r#"style at line 1: transform="translate(1e999, 0)""#, ""),
            (r#"<g id="z" transform="scale(0)"><path d="M 0 0 L 1 1" stroke="black"/></g>"#, "g 'z'", "collapses the drawing"),
            (r#"<g id="o" transform-origin="left wobble" transform="rotate(5)"><path d="M 0 0 L 1 1" stroke="black"/></g>"#, "g 'o'", "unreadable transform origin"),
            (r#"<marker id="m" refX="x" markerWidth="3"><path d="M 0 0 L 1 1"/></marker>"#, "marker 'm'", "unreadable length"),
        ] {
            let err = import_svg(&svg(body), "n.svg", &config()).unwrap_err().to_string();
            assert!(err.contains("n.svg") && err.contains(element) && err.contains(what), "{body}: {err}");
        }
        // Readable lengths with units, percentages and a style without geometry still import.
        let job = import(&svg(r#"<circle cx="10" cy="50%" r="5" stroke="black" style="stroke-width: 2"/><rect x=" 1" y="1" width="3" height="3" stroke="black"/>"#));
        assert_eq!(job.geometries.len(), 2);
        assert!(close(job.geometries[0].points.iter().map(|p| p.x).fold(f64::MAX, f64::min), 5.0), "the circle reaches from x = 10 - 5 mm");
    }

    /// `<image>` is never loaded: not a file (a device, a FIFO that would
    /// block, the controller's own port), not a data URL.
    #[test]
    fn images_are_never_read() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
        let body = format!(
            r#"<image href="{}" width="10" height="10"/><image href="/dev/zero" width="10" height="10"/><image href="data:image/svg+xml;base64,PHN2Zy8+" width="1" height="1"/><path d="M 0 0 L 10 0" stroke="black"/>"#,
            fifo.display()
        );
        let (done, result) = std::sync::mpsc::channel();
        std::thread::spawn(move || done.send(import_svg(&svg(&body), "i.svg", &config()).map(|j| j.geometries.len()).map_err(|e| e.to_string())));
        let imported = result.recv_timeout(std::time::Duration::from_secs(10)).expect("the import does not block on a FIFO or read a device");
        assert_eq!(imported, Ok(1), "the path is marked, the images are not");
    }

    /// The committed sample jobs import cleanly and keep the limits they promise.
    #[test]
    fn samples_import() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples");
        let cfg = config();
        for (file, layer, min, max) in [
            ("marking-300.svg", "mark", 300, 500),
            ("nested-sheet.svg", "cut", 40, 120),
            ("one-field.svg", "engrave", 15, 30),
        ] {
            let job = crate::import::import_job(&dir.join(file), &cfg).unwrap();
            let n = job.geometries.len();
            assert!((min..=max).contains(&n), "{file}: {n} geometries");
            assert_eq!(job.processes.len(), 1, "{file}");
            assert_eq!(job.processes[0].layer, layer, "{file}");
            for g in &job.geometries {
                let (lo, hi) = g.bounds();
                assert!(hi.x - lo.x <= 60.0 && hi.y - lo.y <= 60.0, "{}", g.source);
                assert!(lo.x >= 5.0 && lo.y >= 5.0 && hi.x <= 295.0 && hi.y <= 295.0, "{}", g.source);
            }
            let (lo, hi) = job.bounds();
            println!(
                "{file}: {n} geometries, extent ({:.2}, {:.2})..({:.2}, {:.2}) mm, mark length {:.1} mm",
                lo.x,
                lo.y,
                hi.x,
                hi.y,
                job.mark_length()
            );
            if file == "one-field.svg" {
                assert!(lo.x >= 125.0 && lo.y >= 125.0 && hi.x <= 175.0 && hi.y <= 175.0);
                assert!(job.mark_length() <= 600.0);
            }
        }
    }
}
