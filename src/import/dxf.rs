//! DXF import: the model space's curves become polylines in machine mm.
//!
//! Read by the `dxf` crate (ASCII and binary DXF). Entities: LINE, ARC,
//! CIRCLE, LWPOLYLINE and 2D POLYLINE with bulges, ELLIPSE (and elliptic
//! arcs), SPLINE (NURBS, flattened), INSERT of blocks (nested, scaled,
//! rotated, mirrored; MINSERT arrays). POINT is ignored with a note; text,
//! dimensions, hatches, images and 3D entities are skipped with one warning
//! per kind naming the count and a handle.
//!
//! Units: `$INSUNITS` (mm, cm, m, inch, foot, µm); unitless or absent is
//! read as mm. Axes: DXF's Y runs up like the machine's, so coordinates are
//! taken as they are; the drawing's origin is the machine origin.
//!
//! CAD programs often write a part's outline as separate LINE and ARC
//! entities: open pieces of one layer whose ends meet within `CHAIN_MM` are
//! chained into one contour (closed where its ends meet); a chain whose ends
//! come within `ALMOST_CLOSED_MM` without meeting is reported.
//!
//! Curves are flattened within `import.tolerance` in machine mm, whatever
//! the block scaling. Nothing the file says may read another file, recurse
//! without end or grow without bound: inserts nest at most `MAX_DEPTH`
//! deep, a block that inserts itself is an error, and the expanded entities
//! and points are capped by `import.max_elements` and `import.max_points`.

use std::collections::HashMap;

use dxf::entities::{Entity, EntityType};
use dxf::enums::Units;
use kurbo::Affine;

use crate::config::{parse_hex_colour, DrawingUnit, MachineConfig};
use crate::error::{Error, Result};
use super::{Trace, MAX_COORD_MM};
use crate::job::{Geometry, Job, Point};

/// Ends of open pieces closer than this (mm) are joined.
const CHAIN_MM: f64 = 1e-3;

/// A chain whose ends are this close (mm) but not joined is reported.
const ALMOST_CLOSED_MM: f64 = 0.5;

/// Most levels of blocks inserted in blocks.
const MAX_DEPTH: usize = 32;


/// Highest spline degree accepted (CAD programs write 2, 3 and 5).
const MAX_SPLINE_DEGREE: i32 = 7;

/// Parses DXF `bytes` (ASCII or binary) and converts the model space to a
/// job; `source` names the file in messages.
pub fn import_dxf(bytes: &[u8], source: &str, config: &MachineConfig) -> Result<Job> {
    check_version(bytes, source)?;
    let drawing = parse(bytes, source)?;
    let header_mm = unit_mm(drawing.header.default_drawing_units);
    let mm = match (config.import.units, header_mm) {
        (Some(unit), _) => unit.mm(),
        (None, Some(mm)) => mm,
        (None, None) => {
            return Err(Error::Import(format!(
                "{source}: $INSUNITS {:?} is not a length laserd takes (mm, cm, m, inch, foot, µm, or none); give the drawing's unit with --units",
                drawing.header.default_drawing_units
            )))
        }
    };
    let blocks: HashMap<String, &dxf::Block> = drawing.blocks().map(|b| (b.name.to_uppercase(), b)).collect();
    let layer_colours: HashMap<String, Option<u8>> =
        drawing.layers().map(|l| (l.name.to_uppercase(), l.color.index().filter(|_| l.color.is_index()))).collect();
    let mut reader = Reader {
        source,
        config,
        blocks,
        layer_colours,
        pieces: Vec::new(),
        elements: 0,
        points: 0,
        skipped: Vec::new(),
        ignored_points: 0,
        top: String::new(),
    };
    let top = Affine::scale(mm);
    let entities: Vec<&Entity> = drawing.entities().collect();
    reader.entities(&entities, &top, &mut Vec::new(), None)?;
    for (kind, count, handle) in &reader.skipped {
        tracing::warn!("{source}: {count} {kind} entit{} skipped (handle {handle}): only curves are cut or marked", if *count == 1 { "y" } else { "ies" });
    }
    if reader.ignored_points > 0 {
        tracing::info!("{source}: {} POINT entit{} ignored (a point is no path)", reader.ignored_points, if reader.ignored_points == 1 { "y" } else { "ies" });
    }
    let pieces = chain(std::mem::take(&mut reader.pieces), source);
    if pieces.is_empty() {
        return Err(Error::Import(format!("{source}: nothing to mark: no curve in the model space with two distinct points")));
    }
    check_extents(&drawing.header, mm, &pieces, source);
    if config.import.units.is_none() {
        check_size(&pieces, mm, source, config)?;
    }
    job_of(pieces, source, config)
}

/// The drawing, or an error naming the file; the parser's own panics on a
/// hostile file are caught and reported as malformed input.
fn parse(bytes: &[u8], source: &str) -> Result<dxf::Drawing> {
    let loaded = std::panic::catch_unwind(|| dxf::Drawing::load(&mut std::io::Cursor::new(bytes)));
    match loaded {
        Ok(Ok(d)) => Ok(d),
        Ok(Err(e)) => Err(Error::Import(format!("{source}: malformed DXF: {}", one_line(&e.to_string())))),
        Err(_) => Err(Error::Import(format!("{source}: malformed DXF: the reader gave up on it"))),
    }
}

/// The DXF versions laserd reads: AutoCAD R10 (AC1006) to 2018 (AC1032).
const VERSIONS: [&str; 10] = ["AC1006", "AC1009", "AC1012", "AC1014", "AC1015", "AC1018", "AC1021", "AC1024", "AC1027", "AC1032"];

/// An ASCII file's `$ACADVER`, where it names one, must be a version
/// laserd knows (the reader would take any other for its default and read
/// the file by rules it was not written by). Files without it are R12 and
/// older.
fn check_version(bytes: &[u8], source: &str) -> Result<()> {
    let Some(at) = bytes.windows(8).position(|w| w == b"$ACADVER") else { return Ok(()) };
    let after = &bytes[at + 8..bytes.len().min(at + 200)];
    let text = String::from_utf8_lossy(after);
    // The next group: a code line (1) then the value line.
    let mut lines = text.lines().map(str::trim).skip(1);
    let (Some("1"), Some(version)) = (lines.next(), lines.next()) else { return Ok(()) };
    if VERSIONS.contains(&version) {
        Ok(())
    } else {
        Err(Error::Import(format!("{source}: unknown DXF version '{version}' ($ACADVER); laserd reads {} to {}", VERSIONS[0], VERSIONS[VERSIONS.len() - 1])))
    }
}

fn one_line(s: &str) -> String {
    s.lines().collect::<Vec<_>>().join(" ")
}

/// Millimetres per drawing unit.
fn unit_mm(units: Units) -> Option<f64> {
    Some(match units {
        Units::Unitless | Units::Millimeters => 1.0,
        Units::Centimeters => 10.0,
        Units::Meters => 1000.0,
        Units::Inches => 25.4,
        Units::Feet => 304.8,
        Units::Microns => 1e-3,
        Units::Decimeters => 100.0,
        Units::Mils => 0.0254,
        Units::Microinches => 25.4e-6,
        _ => return None,
    })
}

/// `map` applied to (x, y) of the drawing: a point in machine mm.
fn apply(map: &Affine, x: f64, y: f64) -> Point {
    let p = *map * kurbo::Point::new(x, y);
    Point::new(p.x, p.y)
}

/// Whether `map` keeps circles round (a turn, a uniform scale and a
/// move): 1, or -1 where it also mirrors (arcs then turn the other way).
fn similarity(map: &Affine) -> Option<f64> {
    let [a, b, c, d, _, _] = map.as_coeffs();
    let scale = (a * a + b * b).sqrt().max(1e-300);
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * scale;
    if close(a, d) && close(b, -c) {
        Some(1.0)
    } else if close(a, -d) && close(b, c) {
        Some(-1.0)
    } else {
        None
    }
}

/// An upper bound of how much `map` stretches a length (the Frobenius norm
/// of its linear part).
fn stretch(map: &Affine) -> f64 {
    map.as_coeffs()[..4].iter().map(|c| c * c).sum::<f64>().sqrt()
}

/// Whether an entity with this extrusion direction lies in the XY plane
/// mirrored (-Z: its object coordinates mirrored in X); None out of the plane.
fn mirrored(normal: &dxf::Vector) -> Option<bool> {
    (normal.x.abs() <= 1e-9 && normal.y.abs() <= 1e-9 && normal.z != 0.0).then_some(normal.z < 0.0)
}

/// The mirror of a -Z extrusion, in object coordinates.
const MIRROR_X: Affine = Affine::scale_non_uniform(-1.0, 1.0);

/// An open or closed polyline read from the file, in machine mm, with its
/// layer (index into the config's layers) and where it came from.
struct Piece {
    trace: Trace,
    closed: bool,
    layer: usize,
    source: String,
}

struct Reader<'a> {
    source: &'a str,
    config: &'a MachineConfig,
    blocks: HashMap<String, &'a dxf::Block>,
    /// Each layer's ACI colour (for entities coloured BYLAYER).
    layer_colours: HashMap<String, Option<u8>>,
    pieces: Vec<Piece>,
    elements: u64,
    points: u64,
    /// Per skipped kind: its count and the handle of its first entity.
    skipped: Vec<(String, usize, String)>,
    ignored_points: usize,
    /// Handle of the model-space entity being read (inside blocks the
    /// reader may number entities anew, so errors there name this one too).
    top: String,
}

/// Entity colour as read for layer matching: ACI index or 24-bit RGB.
#[derive(Clone, Copy)]
struct Colour {
    index: Option<u8>,
    rgb: Option<u32>,
}

impl<'a> Reader<'a> {
    /// Reads `entities` under `map`; `inserting` is the chain of block names
    /// being inserted (a block inserting itself is refused); `inherited` is
    /// the layer an entity on layer "0" takes inside a block.
    fn entities(&mut self, entities: &[&'a Entity], map: &Affine, inserting: &mut Vec<String>, inherited: Option<(&'a str, Colour)>) -> Result<()> {
        for e in entities {
            self.elements += 1;
            if self.elements > self.config.import.max_elements {
                return Err(Error::TooLarge(format!(
                    "{}: more than {} entities once blocks are inserted ([import] max_elements)",
                    self.source, self.config.import.max_elements
                )));
            }
            if inserting.is_empty() {
                self.top = format!("{:X}", e.common.handle.0);
            }
            self.entity(e, map, inserting, inherited)?;
        }
        Ok(())
    }

    fn entity(&mut self, e: &'a Entity, map: &Affine, inserting: &mut Vec<String>, inherited: Option<(&'a str, Colour)>) -> Result<()> {
        let handle = format!("{:X}", e.common.handle.0);
        let name = |kind: &str| format!("{kind} (handle {handle})");
        // Entities on layer 0 inside a block take the inserting entity's layer.
        let own_layer = e.common.layer.as_str();
        let colour = Colour {
            index: if e.common.color.is_index() { e.common.color.index() } else { None },
            rgb: u32::try_from(e.common.color_24_bit).ok().filter(|&c| c > 0).map(|c| c & 0xff_ffff),
        };
        let by_layer = e.common.color.is_by_layer() || e.common.color.is_by_block();
        let (layer_name, colour) = match inherited {
            Some((l, c)) if own_layer == "0" => (l, if by_layer { c } else { colour }),
            _ => (own_layer, if by_layer && colour.rgb.is_none() { Colour { index: self.layer_colours.get(&own_layer.to_uppercase()).copied().flatten(), rgb: None } } else { colour }),
        };
        // The map of the entity's object coordinates.
        let ocs = |normal: &dxf::Vector| match mirrored(normal) {
            Some(true) => Ok(*map * MIRROR_X),
            Some(false) => Ok(*map),
            None => Err(Error::Import(format!("{}: {} is not in the XY plane (its extrusion is {:.3},{:.3},{:.3})", self.source, name("entity"), normal.x, normal.y, normal.z))),
        };
        match &e.specific {
            EntityType::Line(l) => {
                let pts = Trace::of(vec![apply(map, l.p1.x, l.p1.y), apply(map, l.p2.x, l.p2.y)]);
                self.push(pts, false, layer_name, colour, name("LINE"))?;
            }
            EntityType::Circle(c) => {
                let m = ocs(&c.normal)?;
                let pts = self.arc_points(&m, (c.center.x, c.center.y), c.radius, 0.0, std::f64::consts::TAU, &name("CIRCLE"))?;
                self.push(pts, true, layer_name, colour, name("CIRCLE"))?;
            }
            EntityType::Arc(a) => {
                let m = ocs(&a.normal)?;
                let start = a.start_angle.to_radians();
                let mut sweep = (a.end_angle - a.start_angle).rem_euclid(360.0).to_radians();
                if sweep == 0.0 {
                    sweep = std::f64::consts::TAU;
                }
                let pts = self.arc_points(&m, (a.center.x, a.center.y), a.radius, start, sweep, &name("ARC"))?;
                self.push(pts, false, layer_name, colour, name("ARC"))?;
            }
            EntityType::LwPolyline(p) => {
                let m = ocs(&p.extrusion_direction)?;
                let vertices: Vec<(f64, f64, f64)> = p.vertices.iter().map(|v| (v.x, v.y, v.bulge)).collect();
                let closed = p.flags & 1 != 0;
                let pts = self.bulged(&m, &vertices, closed, &name("LWPOLYLINE"))?;
                self.push(pts, closed, layer_name, colour, name("LWPOLYLINE"))?;
            }
            EntityType::Polyline(p) => {
                // 8: 3D polyline, 16: polygon mesh, 64: polyface mesh.
                if p.flags & (16 | 64) != 0 {
                    self.skip("POLYLINE mesh", &handle);
                    return Ok(());
                }
                let m = if p.flags & 8 != 0 { *map } else { ocs(&p.normal)? };
                // Spline-fit control frames (vertex flag 16) are not on the curve.
                let vertices: Vec<(f64, f64, f64)> = p.vertices().filter(|v| v.flags & 16 == 0).map(|v| (v.location.x, v.location.y, v.bulge)).collect();
                let closed = p.flags & 1 != 0;
                let pts = self.bulged(&m, &vertices, closed, &name("POLYLINE"))?;
                self.push(pts, closed, layer_name, colour, name("POLYLINE"))?;
            }
            EntityType::Ellipse(el) => {
                let pts = Trace::of(self.ellipse_points(map, el, &name("ELLIPSE"))?);
                let full = (el.end_parameter - el.start_parameter).rem_euclid(std::f64::consts::TAU) < 1e-9;
                self.push(pts, full, layer_name, colour, name("ELLIPSE"))?;
            }
            EntityType::Spline(s) => {
                let (pts, closed) = self.spline_points(map, s, &name("SPLINE"))?;
                let pts = Trace::of(pts);
                self.push(pts, closed, layer_name, colour, name("SPLINE"))?;
            }
            EntityType::Insert(ins) => self.insert(ins, map, inserting, (layer_name, colour), &handle)?,
            EntityType::ModelPoint(_) => self.ignored_points += 1,
            other => self.skip(kind_name(other), &handle),
        }
        Ok(())
    }

    fn skip(&mut self, kind: &str, handle: &str) {
        match self.skipped.iter_mut().find(|(k, _, _)| k == kind) {
            Some(entry) => entry.1 += 1,
            None => self.skipped.push((kind.to_string(), 1, handle.to_string())),
        }
    }

    fn insert(&mut self, ins: &'a dxf::entities::Insert, map: &Affine, inserting: &mut Vec<String>, layer: (&'a str, Colour), handle: &str) -> Result<()> {
        let key = ins.name.to_uppercase();
        let Some(block) = self.blocks.get(&key).copied() else {
            return Err(Error::Import(format!("{}: INSERT (handle {handle}) names block '{}', which the file does not define", self.source, ins.name)));
        };
        if inserting.contains(&key) {
            return Err(Error::Import(format!(
                "{}: block '{}' inserts itself (blocks {} > {}, inserted by the model space's INSERT handle {})",
                self.source,
                ins.name,
                inserting.join(" > "),
                ins.name.to_uppercase(),
                self.top
            )));
        }
        if inserting.len() >= MAX_DEPTH {
            return Err(Error::Import(format!("{}: blocks nested more than {MAX_DEPTH} deep at INSERT (handle {handle})", self.source)));
        }
        let Some(mirror) = mirrored(&ins.extrusion_direction) else {
            return Err(Error::Import(format!("{}: INSERT (handle {handle}) is not in the XY plane", self.source)));
        };
        for (what, v) in [("x scale", ins.x_scale_factor), ("y scale", ins.y_scale_factor), ("rotation", ins.rotation), ("column spacing", ins.column_spacing), ("row spacing", ins.row_spacing)] {
            if !v.is_finite() || v.abs() > MAX_COORD_MM {
                return Err(Error::Import(format!("{}: INSERT (handle {handle}): {what} {v} is out of range", self.source)));
            }
        }
        let (columns, rows) = (ins.column_count.max(1) as usize, ins.row_count.max(1) as usize);
        let flip = if mirror { MIRROR_X } else { Affine::IDENTITY };
        let entities: Vec<&'a Entity> = block.entities.iter().collect();
        inserting.push(key);
        for row in 0..rows {
            for column in 0..columns {
                // Array offsets are in the insert's rotated frame, unscaled.
                let place = *map
                    * flip
                    * Affine::translate((ins.location.x, ins.location.y))
                    * Affine::rotate(ins.rotation.to_radians())
                    * Affine::translate((column as f64 * ins.column_spacing, row as f64 * ins.row_spacing))
                    * Affine::scale_non_uniform(ins.x_scale_factor, ins.y_scale_factor)
                    * Affine::translate((-block.base_point.x, -block.base_point.y));
                self.entities(&entities, &place, inserting, Some(layer))?;
            }
        }
        inserting.pop();
        Ok(())
    }

    /// The tolerance in the entity's own units under `map`.
    fn local_tolerance(&self, map: &Affine) -> f64 {
        self.config.import.tolerance / stretch(map).max(1e-12)
    }

    /// Checks a count of points against the import's cap before they are made.
    fn room_for(&mut self, n: f64, what: &str) -> Result<usize> {
        if !n.is_finite() || self.points as f64 + n > self.config.import.max_points as f64 {
            return Err(Error::TooLarge(format!(
                "{}: {what} flattens to more than the {} points an import may have ([import] max_points)",
                self.source, self.config.import.max_points
            )));
        }
        self.points += n as u64;
        Ok(n as usize)
    }

    /// An arc of `radius` about `centre` from angle `start` over `sweep`
    /// (radians, negative: clockwise), flattened within the tolerance. It
    /// stays an arc (in pieces of at most a half circle) where `map` keeps
    /// circles round; under a stretch it is an ellipse, kept as its points.
    fn arc_points(&mut self, map: &Affine, centre: (f64, f64), radius: f64, start: f64, sweep: f64, what: &str) -> Result<Trace> {
        if !(radius.is_finite() && centre.0.is_finite() && centre.1.is_finite() && start.is_finite() && sweep.is_finite()) || radius.abs() > MAX_COORD_MM {
            return Err(Error::Import(format!("{}: {what} has a coordinate that is not a number or out of range", self.source)));
        }
        let radius = radius.abs();
        let pieces = (sweep.abs() / std::f64::consts::PI - 1e-9).ceil().max(1.0) as usize;
        let n = super::arc_segments(radius, sweep, self.local_tolerance(map));
        let n = (n / pieces as f64).ceil() * pieces as f64;
        let n = self.room_for(n + 1.0, what)? - 1;
        let at = |k: usize| {
            let a = start + sweep * k as f64 / n as f64;
            apply(map, centre.0 + radius * a.cos(), centre.1 + radius * a.sin())
        };
        let mut trace = Trace::of(vec![at(0)]);
        let bulge = similarity(map).map_or(0.0, |turn| turn * (sweep / pieces as f64 / 4.0).tan());
        let per = n / pieces;
        for piece in 0..pieces {
            trace.arc_to((piece * per + 1..=(piece + 1) * per).map(at), bulge);
        }
        Ok(trace)
    }

    /// A polyline whose vertices carry bulges (tan of a quarter of each
    /// segment's arc angle, positive counter-clockwise).
    fn bulged(&mut self, map: &Affine, vertices: &[(f64, f64, f64)], closed: bool, what: &str) -> Result<Trace> {
        if vertices.iter().any(|(x, y, b)| !(x.is_finite() && y.is_finite() && b.is_finite())) {
            return Err(Error::Import(format!("{}: {what} has a coordinate that is not a number", self.source)));
        }
        let n = vertices.len();
        let segments = if closed { n } else { n.saturating_sub(1) };
        let mut out = Trace::default();
        if let Some(&(x, y, _)) = vertices.first() {
            out.points.push(apply(map, x, y));
        }
        self.room_for(n as f64, what)?;
        for i in 0..segments {
            let (x0, y0, bulge) = vertices[i];
            let (x1, y1, _) = vertices[(i + 1) % n];
            let chord = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
            if bulge.abs() < 1e-12 || chord == 0.0 {
                out.points.push(apply(map, x1, y1));
                continue;
            }
            let (c, radius, start, sweep) = crate::job::arc_circle(Point::new(x0, y0), Point::new(x1, y1), bulge);
            let mut arc = self.arc_points(map, (c.x, c.y), radius, start, sweep, what)?;
            // Up to a half circle the arc is one piece: keep the file's bulge as written.
            if let ([piece], Some(turn)) = (&mut arc.arcs[..], similarity(map)) {
                piece.bulge = bulge * turn;
            }
            out.append(arc);
        }
        Ok(out)
    }

    fn ellipse_points(&mut self, map: &Affine, el: &dxf::entities::Ellipse, what: &str) -> Result<Vec<Point>> {
        let (cx, cy, mx, my, ratio) = (el.center.x, el.center.y, el.major_axis.x, el.major_axis.y, el.minor_axis_ratio);
        if ![cx, cy, mx, my, ratio, el.start_parameter, el.end_parameter].iter().all(|v| v.is_finite()) || el.major_axis.z.abs() > 1e-9 {
            return Err(Error::Import(format!("{}: {what} has a coordinate that is not a number, or is not in the XY plane", self.source)));
        }
        let flip = if el.normal.z < 0.0 { -1.0 } else { 1.0 };
        // Minor axis: the major one turned a quarter counter-clockwise about the normal.
        let (nx, ny) = (-my * ratio * flip, mx * ratio * flip);
        let a = (mx * mx + my * my).sqrt();
        let mut sweep = (el.end_parameter - el.start_parameter).rem_euclid(std::f64::consts::TAU);
        if sweep < 1e-9 {
            sweep = std::f64::consts::TAU;
        }
        // Steps sized for the sharpest bend, as for a circle of the major radius
        // with a margin for the flattening at the minor vertices.
        let tol = self.local_tolerance(map).min(a.max(1e-12));
        let step = 2.0 * (1.0 - tol / a.max(1e-12)).clamp(-1.0, 1.0).acos() * ratio.abs().clamp(0.05, 1.0);
        let n = (sweep / step.max(1e-9)).ceil().max(1.0);
        let n = self.room_for(n + 1.0, what)? - 1;
        Ok((0..=n)
            .map(|k| {
                let t = el.start_parameter + sweep * k as f64 / n as f64;
                let (c, s) = (t.cos(), t.sin());
                apply(map, cx + mx * c + nx * s, cy + my * c + ny * s)
            })
            .collect())
    }

    fn spline_points(&mut self, map: &Affine, s: &dxf::entities::Spline, what: &str) -> Result<(Vec<Point>, bool)> {
        let degree = s.degree_of_curve;
        let control: Vec<(f64, f64)> = s.control_points.iter().map(|p| (p.x, p.y)).collect();
        let closed = s.flags & 1 != 0;
        if control.is_empty() {
            // Fit points only: the curve passes through them (`fit_spline`).
            if s.fit_points.len() < 2 {
                return Err(Error::Import(format!("{}: {what} has neither control points nor fit points", self.source)));
            }
            // The cubic CAD programs draw through them (whatever degree the
            // file says), leaving along the end tangents where both are given.
            let fit: Vec<(f64, f64)> = s.fit_points.iter().map(|p| (p.x, p.y)).collect();
            let (a, b) = (&s.start_tangent, &s.end_tangent);
            let given = |t: &dxf::Point| t.x != 0.0 || t.y != 0.0;
            let tangents = (given(a) && given(b)).then_some(((a.x, a.y), (b.x, b.y)));
            if fit.iter().chain(tangents.iter().flat_map(|(a, b)| [a, b])).any(|(x, y)| !(x.is_finite() && y.is_finite() && x.abs() <= MAX_COORD_MM && y.abs() <= MAX_COORD_MM)) {
                return Err(Error::Import(format!("{}: {what} has a fit point or tangent that is not a usable number", self.source)));
            }
            let tol = self.local_tolerance(map);
            let pts = super::fit_spline::flatten(&fit, tangents, tol, |n| self.room_for(n, what).map(|_| ()))?;
            return Ok((pts.into_iter().map(|(x, y)| apply(map, x, y)).collect(), closed));
        }
        if !(1..=MAX_SPLINE_DEGREE).contains(&degree) {
            return Err(Error::Import(format!("{}: {what} has degree {degree}; laserd takes 1 to {MAX_SPLINE_DEGREE}", self.source)));
        }
        let p = degree as usize;
        let knots = &s.knot_values;
        if knots.len() != control.len() + p + 1 || knots.windows(2).any(|w| w[1] < w[0] || w[1].is_nan()) || control.len() <= p {
            return Err(Error::Import(format!(
                "{}: {what}: {} knots for {} control points of degree {degree} (needs {}, non-decreasing)",
                self.source,
                knots.len(),
                control.len(),
                control.len() + p + 1
            )));
        }
        let weights: Vec<f64> = if s.weight_values.len() == control.len() { s.weight_values.clone() } else { vec![1.0; control.len()] };
        if control.iter().any(|(x, y)| !(x.is_finite() && y.is_finite())) || weights.iter().any(|w| !(w.is_finite() && *w > 0.0)) || knots.iter().any(|k| !k.is_finite()) {
            return Err(Error::Import(format!("{}: {what} has a coordinate, knot or weight that is not a usable number", self.source)));
        }
        // Samples per knot span from the control polygon's turning: the
        // chord of a span is within the tolerance once its control legs are
        // cut finely enough (a polygon bound on the curve's second derivative).
        let tol = self.local_tolerance(map);
        let mut pts = Vec::new();
        let (lo, hi) = (knots[p], knots[control.len()]);
        for span in p..control.len() {
            let (u0, u1) = (knots[span], knots[span + 1]);
            if u1 <= u0 || u0 < lo || u1 > hi {
                continue;
            }
            let legs = &control[span - p..=span];
            let bend = legs.windows(3).map(|w| ((w[0].0 - 2.0 * w[1].0 + w[2].0).powi(2) + (w[0].1 - 2.0 * w[1].1 + w[2].1).powi(2)).sqrt()).fold(0.0, f64::max);
            let wspread = weights[span - p..=span].iter().cloned().fold(0.0, f64::max) / weights[span - p..=span].iter().cloned().fold(f64::INFINITY, f64::min);
            let n = ((p * p) as f64 * bend * wspread / (8.0 * tol)).sqrt().ceil().clamp(1.0, 1e7) * 2.0;
            let n = self.room_for(n, what)?;
            let first = if pts.is_empty() { 0 } else { 1 };
            for k in first..=n {
                let u = u0 + (u1 - u0) * k as f64 / n as f64;
                let (x, y) = de_boor(span, u, p, knots, &control, &weights);
                pts.push(apply(map, x, y));
            }
        }
        Ok((pts, closed))
    }

    fn push(&mut self, trace: Trace, closed: bool, layer: &str, colour: Colour, what: String) -> Result<()> {
        if trace.points.iter().any(|p| !(p.x.is_finite() && p.y.is_finite()) || p.x.abs() > MAX_COORD_MM || p.y.abs() > MAX_COORD_MM) {
            return Err(Error::Import(format!("{}: {what} lies beyond {MAX_COORD_MM} mm or is not a number", self.source)));
        }
        let layer = self.layer_for(layer, colour);
        if let Some((trace, closed)) = super::clean_polyline(trace, closed) {
            self.pieces.push(Piece { trace, closed, layer, source: format!("{}: {what}", self.source) });
        }
        Ok(())
    }

    /// The first config layer naming this DXF layer (`dxf_layer`, case
    /// insensitive as in DXF), else the first of the same name, else the
    /// first whose `color` is the entity's ACI colour or whose `stroke` is
    /// its true colour; else the default.
    fn layer_for(&self, dxf_layer: &str, colour: Colour) -> usize {
        let layers = &self.config.layers;
        layers
            .iter()
            .position(|l| l.dxf_layer.as_deref().is_some_and(|n| n.eq_ignore_ascii_case(dxf_layer)))
            .or_else(|| layers.iter().position(|l| l.dxf_layer.is_none() && l.name.eq_ignore_ascii_case(dxf_layer)))
            .or_else(|| {
                layers.iter().position(|l| {
                    let by_index = l.color.is_some() && l.color == colour.index.map(u16::from);
                    let by_rgb = colour.rgb.is_some() && l.stroke.as_deref().and_then(parse_hex_colour).map(|[r, g, b]| (u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b)) == colour.rgb;
                    by_index || by_rgb
                })
            })
            .unwrap_or_else(|| self.config.default_layer_index())
    }
}

/// The point of a NURBS curve at `u` in knot span `span` (de Boor's
/// algorithm on the homogeneous control points).
fn de_boor(span: usize, u: f64, p: usize, knots: &[f64], control: &[(f64, f64)], weights: &[f64]) -> (f64, f64) {
    let mut d: Vec<[f64; 3]> = (0..=p).map(|j| {
        let (x, y) = control[j + span - p];
        let w = weights[j + span - p];
        [x * w, y * w, w]
    }).collect();
    for r in 1..=p {
        for j in (r..=p).rev() {
            let i = j + span - p;
            let denom = knots[i + 1 + p - r] - knots[i];
            let alpha = if denom > 0.0 { (u - knots[i]) / denom } else { 0.0 };
            let before = d[j - 1];
            for (c, b) in d[j].iter_mut().zip(before) {
                *c = (1.0 - alpha) * b + alpha * *c;
            }
        }
    }
    let [x, y, w] = d[p];
    (x / w, y / w)
}

/// The DXF name of a kind of entity that is skipped.
fn kind_name(e: &EntityType) -> &'static str {
    match e {
        EntityType::Text(_) => "TEXT",
        EntityType::MText(_) => "MTEXT",
        EntityType::Attribute(_) | EntityType::AttributeDefinition(_) => "ATTRIB",
        EntityType::RotatedDimension(_) | EntityType::RadialDimension(_) | EntityType::DiameterDimension(_) | EntityType::AngularThreePointDimension(_) | EntityType::OrdinateDimension(_) => "DIMENSION",
        EntityType::Leader(_) => "LEADER",
        EntityType::Image(_) => "IMAGE",
        EntityType::Face3D(_) | EntityType::Solid3D(_) | EntityType::Body(_) | EntityType::Region(_) | EntityType::Solid(_) | EntityType::Trace(_) => "3D or filled",
        EntityType::Ray(_) | EntityType::XLine(_) => "construction line",
        _ => "other",
    }
}

/// Ends of open pieces on a grid of `CHAIN_MM` cells: (layer, cell) to
/// (piece, whether it is the piece's start).
type Ends = HashMap<(usize, (i64, i64)), Vec<(usize, bool)>>;

/// Open pieces of one layer joined end to end where their ends meet within
/// `CHAIN_MM`; closed where a chain's ends meet. Chains that almost close
/// are reported, naming their pieces.
fn chain(pieces: Vec<Piece>, source: &str) -> Vec<Piece> {
    let (mut out, open): (Vec<Piece>, Vec<Piece>) = pieces.into_iter().partition(|p| p.closed);
    // Ends on a grid of CHAIN_MM cells: (layer, cell) -> (piece, at its start?).
    let cell = |p: &Point| ((p.x / CHAIN_MM).round() as i64, (p.y / CHAIN_MM).round() as i64);
    let mut ends: Ends = HashMap::new();
    for (i, p) in open.iter().enumerate() {
        ends.entry((p.layer, cell(&p.trace.points[0]))).or_default().push((i, true));
        ends.entry((p.layer, cell(p.trace.points.last().unwrap()))).or_default().push((i, false));
    }
    // The unused piece ends at `at`. Where several meet (a corner two parts
    // share), the chain takes the one that turns most from `heading` short
    // of going back: a part's outline turns at its corner, where the
    // neighbour's edge runs on straight or doubles back along the shared one.
    let near = |ends: &Ends, layer: usize, at: &Point, heading: nalgebra::Vector2<f64>, used: &[bool]| -> Option<(usize, bool)> {
        let (cx, cy) = cell(at);
        let mut best: Option<((usize, bool), f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &(i, start) in ends.get(&(layer, (cx + dx, cy + dy))).into_iter().flatten() {
                    let pts = &open[i].trace.points;
                    let (q, away) = if start { (pts[0], pts[1] - pts[0]) } else { (pts[pts.len() - 1], pts[pts.len() - 2] - pts[pts.len() - 1]) };
                    if used[i] || (q - at).norm() > CHAIN_MM {
                        continue;
                    }
                    let turn = heading.perp(&away).atan2(heading.dot(&away)).abs();
                    // Doubling back (within 5°) only when nothing else meets here.
                    let score = if turn > std::f64::consts::PI - 0.09 { -1.0 } else { turn };
                    if best.is_none_or(|(_, b)| score > b) {
                        best = Some(((i, start), score));
                    }
                }
            }
        }
        best.map(|(c, _)| c)
    };
    let mut used = vec![false; open.len()];
    // Contours that end near their start: said once, naming the first few.
    let mut almost: Vec<String> = Vec::new();
    for first in 0..open.len() {
        if used[first] {
            continue;
        }
        used[first] = true;
        let layer = open[first].layer;
        let mut trace = open[first].trace.clone();
        let mut sources = vec![open[first].source.clone()];
        // Grow forward from the end, then backward from the start.
        for forward in [true, false] {
            loop {
                let points = &trace.points;
                let at = if forward { *points.last().unwrap() } else { points[0] };
                if (points.len() > 2) && (points[0] - points[points.len() - 1]).norm() <= CHAIN_MM {
                    break;
                }
                let n = points.len();
                let heading = if forward { points[n - 1] - points[n - 2] } else { points[0] - points[1] };
                let Some((i, at_start)) = near(&ends, layer, &at, heading, &used) else { break };
                used[i] = true;
                let mut next = open[i].trace.clone();
                // Orient the next piece to continue from `at`.
                if forward != at_start {
                    next = next.reversed();
                }
                if forward {
                    trace.append(next);
                } else {
                    next.append(std::mem::take(&mut trace));
                    trace = next;
                }
                sources.push(open[i].source.clone());
            }
        }
        let points = &mut trace.points;
        let gap = (points[0] - points[points.len() - 1]).norm();
        let closed = points.len() > 2 && gap <= CHAIN_MM;
        if closed {
            // An arc that ended on the dropped point now ends on vertex 0.
            points.pop();
        } else if points.len() > 2 && gap <= ALMOST_CLOSED_MM {
            let first = sources[0].strip_prefix(source).and_then(|s| s.strip_prefix(": ")).unwrap_or(&sources[0]);
            almost.push(format!("{first} ({} piece(s), {gap:.4} mm)", sources.len()));
        }
        let source = if sources.len() == 1 { sources.remove(0) } else { format!("{} (+{} chained)", sources[0], sources.len() - 1) };
        out.push(Piece { trace, closed, layer, source });
    }
    if !almost.is_empty() {
        const SHOWN: usize = 5;
        let more = if almost.len() > SHOWN { format!(" and {} more", almost.len() - SHOWN) } else { String::new() };
        tracing::warn!(
            "{source}: {} contour(s) end within {ALMOST_CLOSED_MM} mm of their start and are left open: {}{more}",
            almost.len(),
            almost[..almost.len().min(SHOWN)].join(", ")
        );
    }
    out
}

/// Warns when the header's $EXTMIN/$EXTMAX (where written) disagree with
/// what was read by more than a millimetre: a sign of entities laserd did
/// not read, or of a header left stale by the program that wrote it.
fn check_extents(header: &dxf::Header, mm: f64, pieces: &[Piece], source: &str) {
    let (lo, hi) = (&header.minimum_drawing_extents, &header.maximum_drawing_extents);
    if !(lo.x.is_finite() && hi.x.is_finite()) || lo.x > hi.x || lo.x.abs() > 1e19 || hi.x.abs() > 1e19 || (lo.x == 0.0 && hi.x == 0.0 && lo.y == 0.0 && hi.y == 0.0) {
        return;
    }
    let (rlo, rhi) = crate::job::bounds_of(pieces.iter().flat_map(|p| p.trace.points.iter()));
    let off = [(rlo.x - lo.x * mm), (rlo.y - lo.y * mm), (rhi.x - hi.x * mm), (rhi.y - hi.y * mm)].iter().fold(0.0f64, |m, d| m.max(d.abs()));
    if off > 1.0 {
        tracing::warn!(
            "{source}: the header's extents ({:.3},{:.3})-({:.3},{:.3}) mm differ from what was read ({:.3},{:.3})-({:.3},{:.3}) mm",
            lo.x * mm,
            lo.y * mm,
            hi.x * mm,
            hi.y * mm,
            rlo.x,
            rlo.y,
            rhi.x,
            rhi.y
        );
    }
}

/// Real exports get units wrong (a header saying inch over a drawing made in
/// mm, or none over one made in inches): a drawing larger than the machine's
/// travel in its header's unit, that would fit in another, is refused with
/// the flag that reads it in that unit.
fn check_size(pieces: &[Piece], mm: f64, source: &str, config: &MachineConfig) -> Result<()> {
    let (lo, hi) = crate::job::bounds_of(pieces.iter().flat_map(|p| p.trace.points.iter()));
    let (w, h) = (hi.x - lo.x, hi.y - lo.y);
    let (tx, ty) = (config.stage.travel_x, config.stage.travel_y);
    let fits = |k: f64| w * k <= tx && h * k <= ty;
    if fits(1.0) {
        return Ok(());
    }
    let Some(unit) = DrawingUnit::ALL.iter().find(|u| fits(u.mm() / mm)) else { return Ok(()) };
    let k = unit.mm() / mm;
    let header = DrawingUnit::ALL.iter().find(|u| u.mm() == mm).map_or_else(|| format!("{mm} mm per unit"), |u| u.as_str().to_string());
    Err(Error::Import(format!(
        "{source}: the drawing is {w:.1} x {h:.1} mm read in its header's unit ({header}), larger than the machine's travel of {tx} x {ty} mm; \
         read in {} it is {:.1} x {:.1} mm and fits: if it was drawn in {}, give --units {}",
        unit.as_str(),
        w * k,
        h * k,
        unit.as_str(),
        unit.as_str()
    )))
}

/// The job: the layers used, in config order, as processes (fill layers as their areas, `fill::layer_areas`).
fn job_of(pieces: Vec<Piece>, source: &str, config: &MachineConfig) -> Result<Job> {
    let geometries = pieces.into_iter().map(|p| Geometry { process: p.layer, points: p.trace.points, arcs: p.trace.arcs, profile: Vec::new(), closed: p.closed, source: p.source }).collect();
    Ok(super::job_of_layers(source, super::fill::layer_areas(geometries, config, source)?, config))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> MachineConfig {
        crate::import::test_config()
    }

    /// An ASCII DXF of `entities` (group lines) in the ENTITIES section,
    /// after `before` (whole sections).
    fn dxf(before: &str, entities: &str) -> Vec<u8> {
        format!("{before}0\nSECTION\n2\nENTITIES\n{entities}0\nENDSEC\n0\nEOF\n").into_bytes()
    }

    fn line(handle: &str, layer: &str, (x0, y0): (f64, f64), (x1, y1): (f64, f64)) -> String {
        format!("0\nLINE\n5\n{handle}\n8\n{layer}\n10\n{x0}\n20\n{y0}\n11\n{x1}\n21\n{y1}\n")
    }

    fn import(bytes: &[u8]) -> Result<Job> {
        import_dxf(bytes, "t.dxf", &config())
    }

    #[test]
    fn lines_that_meet_end_to_end_in_any_direction_are_one_closed_contour() {
        // A square as four lines, two of them drawn backwards, and a line apart.
        let body = [
            line("A1", "0", (0.0, 0.0), (10.0, 0.0)),
            line("A2", "0", (10.0, 10.0), (10.0, 0.0)),
            line("A3", "0", (10.0, 10.0), (0.0, 10.0)),
            line("A4", "0", (0.0, 0.0), (0.0, 10.0)),
            line("A5", "0", (20.0, 0.0), (30.0, 0.0)),
        ]
        .concat();
        let job = import(&dxf("", &body)).unwrap();
        assert_eq!(job.geometries.len(), 2);
        let square = job.geometries.iter().find(|g| g.closed).expect("the square is closed");
        assert_eq!(square.points.len(), 4);
        assert!((square.length() - 40.0).abs() < 1e-9);
        assert!(square.source.contains("handle A1") && square.source.contains("+3 chained"), "{}", square.source);
    }

    #[test]
    fn two_parts_that_share_an_edge_chain_into_their_own_outlines() {
        // Each part's outline drawn on its own: the edge x = 90 twice, and
        // three line ends meet at each of its corners.
        // Each outline counter-clockwise or clockwise; the two parts' lines
        // in the file one after the other or interleaved (A0 B0 A1 B1 ...).
        let rect = |h: &str, x0: f64, x1: f64, clockwise: bool| {
            let corners = [(x0, 10.0), (x1, 10.0), (x1, 60.0), (x0, 60.0)];
            (0..4)
                .map(|k| {
                    let (a, b) = (corners[k], corners[(k + 1) % 4]);
                    let (a, b) = if clockwise { (b, a) } else { (a, b) };
                    line(&format!("{h}{k}"), "0", a, b)
                })
                .collect::<Vec<String>>()
        };
        for (interleaved, clockwise) in [(false, false), (true, false), (false, true), (true, true)] {
            let (a, b) = (rect("A", 10.0, 90.0, clockwise), rect("B", 90.0, 150.0, clockwise));
            let body: String = if interleaved { a.iter().zip(&b).flat_map(|(x, y)| [x.clone(), y.clone()]).collect() } else { [a, b].concat().concat() };
            let job = import(&dxf("", &body)).unwrap();
            let mut perimeters: Vec<f64> = job.geometries.iter().map(|g| g.length()).collect();
            perimeters.sort_by(f64::total_cmp);
            assert!(job.geometries.iter().all(|g| g.closed && g.points.len() == 4), "interleaved {interleaved}, clockwise {clockwise}: {:?}", job.geometries);
            assert_eq!(perimeters, vec![220.0, 260.0], "interleaved {interleaved}, clockwise {clockwise}");
        }
    }

    #[test]
    fn a_bulge_of_one_is_a_half_circle_to_the_left() {
        // From (0,0) to (10,0) with bulge 1: a half circle of r = 5 below
        // the chord, counter-clockwise about (5,0).
        let body = "0\nLWPOLYLINE\n5\nB1\n8\n0\n90\n2\n70\n0\n10\n0\n20\n0\n42\n1\n10\n10\n20\n0\n";
        let job = import(&dxf("", body)).unwrap();
        let g = &job.geometries[0];
        assert!((g.length() - 5.0 * std::f64::consts::PI).abs() < 1e-9, "kept as an arc: {}", g.length());
        assert_eq!(g.arcs, vec![crate::job::ArcSpan { from: 0, to: g.points.len() - 1, bulge: 1.0 }]);
        let (lo, hi) = g.bounds();
        assert!((lo.y + 5.0).abs() < 1e-9 && hi.y.abs() < 1e-9, "below the chord: {lo:?} {hi:?}");
        assert!(g.points.iter().all(|p| ((p - Point::new(5.0, 0.0)).norm() - 5.0).abs() < 1e-9));
    }

    #[test]
    fn a_block_is_inserted_moved_rotated_scaled_and_arrayed_and_its_layer_0_takes_the_inserts() {
        let blocks = "0\nSECTION\n2\nBLOCKS\n0\nBLOCK\n8\n0\n2\nP\n70\n0\n10\n1\n20\n0\n0\nLINE\n5\nC1\n8\n0\n10\n1\n20\n0\n11\n2\n21\n0\n0\nENDBLK\n0\nENDSEC\n";
        // Base point (1,0); the line from the base 1 unit along x, scaled 3,
        // turned 90°, at (50,50); 2 columns 10 apart in the turned frame.
        let insert = "0\nINSERT\n5\nD1\n8\ncut\n2\nP\n10\n50\n20\n50\n41\n3\n42\n3\n50\n90\n70\n2\n71\n1\n44\n10\n";
        let job = import(&dxf(blocks, insert)).unwrap();
        assert_eq!(job.geometries.len(), 2);
        let mut starts: Vec<(f64, f64)> = job.geometries.iter().map(|g| (g.points[0].x, g.points[0].y)).collect();
        starts.sort_by(|a, b| a.1.total_cmp(&b.1));
        // Columns run along the turned x axis, i.e. up the machine's y.
        assert!((starts[0].0 - 50.0).abs() < 1e-9 && (starts[0].1 - 50.0).abs() < 1e-9, "{starts:?}");
        assert!((starts[1].0 - 50.0).abs() < 1e-9 && (starts[1].1 - 60.0).abs() < 1e-9, "{starts:?}");
        let end = job.geometries[0].points[1];
        assert!((end.x - 50.0).abs() < 1e-9 && (end.y - 53.0).abs() < 1e-9, "{end:?}");
        // Entities on layer 0 in a block take the INSERT's layer ("cut" here).
        assert!(job.processes.iter().all(|p| p.layer == "cut"), "{:?}", job.processes);
    }

    #[test]
    fn a_layer_takes_entities_by_aci_colour_and_by_true_colour() {
        let mut config = config();
        config.layers[1].color = Some(1); // "cut": ACI 1 (red)
        // ACI 1 on the entity; true colour 0x0000ff (group 420) matches
        // "engrave"'s stroke #0000ff; no colour: the default layer.
        let body = "0\nLINE\n8\nA\n62\n1\n10\n0\n20\n0\n11\n1\n21\n0\n\
                    0\nLINE\n8\nA\n420\n255\n10\n0\n20\n5\n11\n1\n21\n5\n\
                    0\nLINE\n8\nA\n10\n0\n20\n9\n11\n1\n21\n9\n";
        let job = import_dxf(&dxf("", body), "t.dxf", &config).unwrap();
        let layers: Vec<&str> = job.geometries.iter().map(|g| job.processes[g.process].layer.as_str()).collect();
        assert_eq!(layers, vec!["cut", "engrave", "mark"]);
    }

    #[test]
    fn inches_are_read_as_inches() {
        let header = "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n1\n0\nENDSEC\n";
        let job = import(&dxf(header, &line("E1", "0", (1.0, 1.0), (2.0, 1.0)))).unwrap();
        assert!((job.geometries[0].points[0].x - 25.4).abs() < 1e-9 && (job.geometries[0].length() - 25.4).abs() < 1e-9);
    }

    #[test]
    fn a_header_unit_that_makes_the_drawing_larger_than_the_machine_names_the_unit_that_fits() {
        // A MakerCase-style box: the header says inch, the numbers are mm.
        let header = "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n1\n0\nENDSEC\n";
        let body = [line("D1", "0", (10.0, 10.0), (210.0, 10.0)), line("D2", "0", (210.0, 10.0), (210.0, 160.0))].concat();
        let file = dxf(header, &body);
        let err = import(&file).unwrap_err().to_string();
        assert!(err.contains("5080.0 x 3810.0 mm") && err.contains("(inch)") && err.contains("--units mm") && err.contains("200.0 x 150.0 mm"), "{err}");
        let mut config = config();
        config.import.units = Some(DrawingUnit::Mm);
        let job = import_dxf(&file, "t.dxf", &config).unwrap();
        assert!((job.geometries[0].length() - 350.0).abs() < 1e-9, "read in mm as told");
    }

    #[test]
    fn bad_files_are_errors_naming_the_file_and_the_entity() {
        let error = |bytes: &[u8]| import(bytes).unwrap_err().to_string();
        let garbage: Vec<u8> = (0..4000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
        assert!(error(&garbage).contains("t.dxf: malformed DXF"), "{}", error(&garbage));
        let whole = dxf("", &line("F1", "0", (0.0, 0.0), (1.0, 1.0)));
        let truncated = error(&whole[..whole.len() / 2]);
        assert!(truncated.contains("t.dxf: malformed DXF"), "{truncated}");
        let version = error(&dxf("0\nSECTION\n2\nHEADER\n9\n$ACADVER\n1\nAC9999\n0\nENDSEC\n", &line("F2", "0", (0.0, 0.0), (1.0, 1.0))));
        assert!(version.contains("unknown DXF version 'AC9999'"), "{version}");
        let nan = error(&dxf("", "0\nLINE\n5\nF3\n8\n0\n10\n0\n20\n0\n11\nnan\n21\n1\n"));
        assert!(nan.contains("LINE (handle F3)") && nan.contains("not a number"), "{nan}");
        let degree = error(&dxf("", "0\nSPLINE\n5\nF4\n8\n0\n71\n9\n10\n0\n20\n0\n30\n0\n10\n1\n20\n1\n30\n0\n"));
        assert!(degree.contains("SPLINE (handle F4) has degree 9"), "{degree}");
        let blocks = "0\nSECTION\n2\nBLOCKS\n0\nBLOCK\n8\n0\n2\nA\n70\n0\n10\n0\n20\n0\n0\nINSERT\n8\n0\n2\nA\n10\n1\n20\n1\n0\nENDBLK\n0\nENDSEC\n";
        let recursive = error(&dxf(blocks, "0\nINSERT\n5\nF5\n8\n0\n2\nA\n10\n0\n20\n0\n"));
        assert!(recursive.contains("block 'A' inserts itself") && recursive.contains("handle F5"), "{recursive}");
        let missing = error(&dxf("", "0\nINSERT\n5\nF6\n8\n0\n2\nNOPE\n10\n0\n20\n0\n"));
        assert!(missing.contains("INSERT (handle F6) names block 'NOPE'"), "{missing}");
        let fit = error(&dxf("", "0\nSPLINE\n5\nF7\n8\n0\n71\n3\n11\n0\n21\n0\n31\n0\n11\n1e300\n21\n1\n31\n0\n"));
        assert!(fit.contains("SPLINE (handle F7) has a fit point or tangent that is not a usable number"), "{fit}");
    }

    #[test]
    fn an_array_beyond_the_element_cap_is_refused_before_it_is_expanded() {
        let blocks = "0\nSECTION\n2\nBLOCKS\n0\nBLOCK\n8\n0\n2\nP\n70\n0\n10\n0\n20\n0\n0\nLINE\n8\n0\n10\n0\n20\n0\n11\n1\n21\n0\n0\nENDBLK\n0\nENDSEC\n";
        let insert = "0\nINSERT\n5\nA71\n8\n0\n2\nP\n10\n0\n20\n0\n70\n32767\n71\n32767\n44\n1\n45\n1\n";
        let started = std::time::Instant::now();
        let err = import(&dxf(blocks, insert)).unwrap_err().to_string();
        assert!(err.contains("max_elements"), "{err}");
        assert!(started.elapsed().as_secs() < 10, "refused in bounded time");
    }

    #[test]
    fn text_and_points_are_skipped_and_the_curves_kept() {
        let body = format!("0\nTEXT\n5\nB81\n8\n0\n10\n0\n20\n0\n40\n2\n1\nHI\n0\nPOINT\n5\nB82\n8\n0\n10\n5\n20\n5\n{}", line("B83", "0", (0.0, 0.0), (3.0, 4.0)));
        let job = import(&dxf("", &body)).unwrap();
        assert_eq!(job.geometries.len(), 1);
        assert!((job.geometries[0].length() - 5.0).abs() < 1e-12);
    }
}
