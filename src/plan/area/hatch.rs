//! Hatching: the areas of fill layers (`import::fill`) become hatch lines.
//!
//! Lines run at the layer's `hatch_angle`, `hatch_spacing` apart, on a grid
//! fixed to the machine's origin (line k at (k + ½)·spacing across the
//! hatch), so that neighbouring shapes' hatches line up and a rectangle is
//! covered edge to edge. Each line is clipped to the layer's area by
//! `i_overlay` (nonzero winding of the areas' oriented contours, their
//! boundaries outside): a hatch line is one straight geometry of the fill
//! process, running the hatch's way. A cross-hatch adds a second hatch at
//! right angles. A shape too thin for any line of the grid gets one line
//! through its middle: nothing drawn is left unmarked.

use i_overlay::core::fill_rule::FillRule;
use i_overlay::float::clip::FloatClip;
use i_overlay::float::simplify::SimplifyShape;
use i_overlay::string::clip::ClipRule;
use nalgebra::{Rotation2, Vector2};

use crate::config::{LayerConfig, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{Geometry, Job, Point};

/// What hatching made of a job's fill areas.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HatchCount {
    /// Separate areas (an outline with its holes) filled.
    pub areas: usize,
    pub lines: usize,
    /// Areas too thin for the grid, given one line through their middle.
    pub thin_areas: usize,
}

/// Lines clipped at once: bounds the clipper's memory on a large fill.
const LINES_PER_CLIP: usize = 4096;

/// `job` with the closed geometries of every fill process replaced by
/// their hatch lines (after the job's other geometries, in hatch order:
/// angle, line, along the line).
pub fn hatch(job: Job, machine: &MachineConfig) -> Result<(Job, HatchCount)> {
    let mut count = HatchCount::default();
    if !job.processes.iter().any(|p| p.fill) {
        return Ok((job, count));
    }
    let Job { source, geometries, processes } = job;
    let (areas, mut kept): (Vec<Geometry>, Vec<Geometry>) = geometries.into_iter().partition(|g| processes[g.process].fill && g.closed);
    let budget = machine.import.max_points / 2;
    for (p, process) in processes.iter().enumerate().filter(|(_, p)| p.fill) {
        let layer = machine.layer(&process.layer).ok_or_else(|| {
            Error::Import(format!("{source}: the fill of layer '{}' takes its hatch from a [[layer]] of that name, and the config has none", process.layer))
        })?;
        let contours: Vec<&[Point]> = areas.iter().filter(|g| g.process == p).map(|g| g.points.as_slice()).collect();
        let mut angles = vec![layer.hatch_angle];
        if layer.cross_hatch {
            angles.push(layer.hatch_angle + 90.0);
        }
        for (a, &angle) in angles.iter().enumerate() {
            let name = |k: i64| format!("{source}: layer '{}' {}line {k}", process.layer, if a == 0 { "fill " } else { "cross-hatch " });
            let room = budget.saturating_sub(kept.len() as u64);
            let Some(lines) = hatch_lines(&contours, angle, layer.hatch_spacing, machine.import.tolerance, room, &mut count, a == 0) else {
                return Err(too_many(&source, layer, machine));
            };
            kept.extend(lines.into_iter().map(|(k, from, to)| Geometry::polyline(vec![from, to], false, p, name(k))));
        }
    }
    count.lines = kept.iter().filter(|g| processes[g.process].fill).count();
    // Beside each fill, its laser off: a line's motion runs through the
    // gaps between its segments at the fill's speed (`super::off_process`).
    let mut processes = processes;
    for p in 0..processes.len() {
        if processes[p].fill {
            processes.push(crate::job::Process { power: 0.0, ..processes[p].clone() });
        }
    }
    Ok((Job { source, geometries: kept, processes }, count))
}

fn too_many(source: &str, layer: &LayerConfig, machine: &MachineConfig) -> Error {
    Error::TooLarge(format!(
        "{source}: the fill of layer '{}' at hatch_spacing = {} mm makes more than the {} hatch lines [import] max_points = {} allows (2 points each); widen the spacing or raise the limit",
        layer.name,
        layer.hatch_spacing,
        machine.import.max_points / 2,
        machine.import.max_points
    ))
}

/// The hatch of the area `contours` enclose (nonzero winding) at `angle`
/// degrees, `spacing` apart: (line number, start, end), each running the
/// angle's way, in line order then along the line; pieces shorter than
/// `graze` (the import tolerance: they only touch a vertex or a curve's
/// top) left out; `None` past `room` lines (checked on the grid's lines
/// before any is clipped). `count` takes the areas
/// (when `count_areas`) and the thin ones.
pub fn hatch_lines(contours: &[&[Point]], angle: f64, spacing: f64, graze: f64, room: u64, count: &mut HatchCount, count_areas: bool) -> Option<Vec<(i64, Point, Point)>> {
    let to_hatch = Rotation2::new(-angle.to_radians());
    let back = to_hatch.inverse();
    let rotated: Vec<Vec<[f64; 2]>> = contours.iter().map(|c| c.iter().map(|p| to_hatch * p.coords).map(|v| [v.x, v.y]).collect()).collect();
    // The area as separate shapes (outline and holes), overlaps merged.
    let shapes = rotated.simplify_shape(FillRule::NonZero);
    if count_areas {
        count.areas += shapes.len();
    }
    let (mut lo, mut hi) = (Vector2::repeat(f64::INFINITY), Vector2::repeat(f64::NEG_INFINITY));
    for p in shapes.iter().flatten().flatten() {
        lo = lo.inf(&Vector2::new(p[0], p[1]));
        hi = hi.sup(&Vector2::new(p[0], p[1]));
    }
    if shapes.is_empty() {
        return Some(Vec::new());
    }
    let line_of = |y: f64| (y / spacing - 0.5).round() as i64;
    let y_of = |k: i64| (k as f64 + 0.5) * spacing;
    let (first, last) = ((lo.y / spacing - 0.5).ceil() as i64, (hi.y / spacing - 0.5).floor() as i64);
    // Refused before any is clipped when the grid alone has more lines than
    // there is room for (a drawing scaled up a thousandfold).
    if (last - first + 1).max(0) as u64 > room {
        return None;
    }
    let (x0, x1) = (lo.x - 1.0, hi.x + 1.0);
    let rule = ClipRule { invert: false, boundary_included: false };
    // (line number, the line's place across the hatch, from, to along it).
    let mut pieces: Vec<(i64, f64, f64, f64)> = Vec::new();
    let clip = |ys: &[(i64, f64)], pieces: &mut Vec<(i64, f64, f64, f64)>| {
        let lines: Vec<Vec<[f64; 2]>> = ys.iter().map(|&(_, y)| vec![[x0, y], [x1, y]]).collect();
        for piece in lines.clip_by(&shapes, FillRule::NonZero, rule) {
            let y = piece.iter().map(|p| p[1]).sum::<f64>() / piece.len() as f64;
            let (a, b) = piece.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p[0]), b.max(p[0])));
            // The line it lies on (the clipper rounds to its own grid).
            let &(k, y) = ys.iter().min_by(|u, v| (u.1 - y).abs().total_cmp(&(v.1 - y).abs())).expect("clipped lines come from ys");
            pieces.push((k, y, a, b));
        }
    };
    let mut k = first;
    while k <= last {
        let ys: Vec<(i64, f64)> = (k..=last.min(k + LINES_PER_CLIP as i64 - 1)).map(|k| (k, y_of(k))).collect();
        clip(&ys, &mut pieces);
        if pieces.len() as u64 > room {
            return None;
        }
        k += LINES_PER_CLIP as i64;
    }
    // Shapes no line of the grid crosses: one line through the middle,
    // numbered as the grid line nearest it.
    let thin: Vec<(i64, f64)> = shapes
        .iter()
        .filter_map(|shape| {
            let (a, b) = shape.iter().flatten().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p[1]), b.max(p[1])));
            ((a / spacing - 0.5).ceil() > (b / spacing - 0.5).floor()).then(|| (line_of(0.5 * (a + b)), 0.5 * (a + b)))
        })
        .collect();
    count.thin_areas += thin.len();
    for t in thin {
        clip(&[t], &mut pieces);
    }
    pieces.sort_by(|p, q| p.0.cmp(&q.0).then(p.1.total_cmp(&q.1)).then(p.2.total_cmp(&q.2)));
    // Pieces of one line that touch (the clipper splits at vertices) are one.
    let mut merged: Vec<(i64, f64, f64, f64)> = Vec::with_capacity(pieces.len());
    for (k, y, a, b) in pieces {
        match merged.last_mut() {
            Some(m) if m.0 == k && m.1 == y && a <= m.3 + 1e-9 * (1.0 + a.abs()) => m.3 = m.3.max(b),
            _ => merged.push((k, y, a, b)),
        }
    }
    if merged.len() as u64 > room {
        return None;
    }
    let lines = merged
        .into_iter()
        // A line grazing a vertex or a curve's top touches the area over
        // less than the drawing's own precision: nothing to mark there.
        .filter(|&(_, _, a, b)| b - a >= graze)
        .map(|(k, y, a, b)| (k, Point::from(back * Vector2::new(a, y)), Point::from(back * Vector2::new(b, y))))
        .collect();
    Some(lines)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::fill::{area, Rule};

    fn square(x: f64, y: f64, side: f64) -> Vec<Point> {
        vec![Point::new(x, y), Point::new(x + side, y), Point::new(x + side, y + side), Point::new(x, y + side)]
    }

    fn lines(contours: &[Vec<Point>], angle: f64, spacing: f64) -> (Vec<(i64, Point, Point)>, HatchCount) {
        let refs: Vec<&[Point]> = contours.iter().map(|c| c.as_slice()).collect();
        let mut count = HatchCount::default();
        (hatch_lines(&refs, angle, spacing, 1e-3, u64::MAX, &mut count, true).unwrap(), count)
    }

    #[test]
    fn a_square_is_hatched_edge_to_edge_on_the_machines_grid_and_its_hole_is_left() {
        let (got, count) = lines(&[square(0.0, 0.0, 10.0)], 0.0, 0.5);
        assert_eq!((got.len(), count.areas, count.thin_areas), (20, 1, 0));
        for (i, (k, a, b)) in got.iter().enumerate() {
            assert_eq!(*k, i as i64);
            assert!((a.y - (i as f64 + 0.5) * 0.5).abs() < 1e-9 && (a.y - b.y).abs() < 1e-12);
            assert!(a.x.abs() < 1e-6 && (b.x - 10.0).abs() < 1e-6, "runs edge to edge, the hatch's way: {a} {b}");
        }
        // A hole (even-odd) splits the lines crossing it in two; the others stay whole.
        let ring = area(&[square(0.0, 0.0, 10.0).as_slice(), square(3.0, 3.0, 4.0).as_slice()], Rule::EvenOdd);
        let (got, _) = lines(&ring, 0.0, 0.5);
        let crossing = got.iter().filter(|(_, a, _)| (3.0..7.0).contains(&a.y)).count();
        assert_eq!(got.len(), 20 + 8, "8 lines cross the hole");
        assert_eq!(crossing, 16);
        assert!(got.iter().all(|(_, a, b)| !(a.x < 5.0 && b.x > 5.0 && (3.0..7.0).contains(&a.y))), "nothing marked in the hole");
        let marked: f64 = got.iter().map(|(_, a, b)| (b - a).norm()).sum::<f64>() * 0.5;
        assert!((marked - 84.0).abs() < 1e-6, "line length times spacing is the area: {marked}");
    }

    #[test]
    fn hatches_at_an_angle_and_a_cross_hatch_cover_the_area_alike() {
        let shape = area(&[square(10.0, 20.0, 8.0).as_slice()], Rule::NonZero);
        for angle in [0.0, 30.0, 45.0, 90.0, -60.0, 135.0] {
            let (got, _) = lines(&shape, angle, 0.1);
            let d = Vector2::new(angle.to_radians().cos(), angle.to_radians().sin());
            for (_, a, b) in &got {
                let u = (b - a).normalize();
                assert!((u - d).norm() < 1e-9, "runs the hatch's way at {angle}°");
                for p in [a, b] {
                    assert!(p.x > 10.0 - 1e-6 && p.x < 18.0 + 1e-6 && p.y > 20.0 - 1e-6 && p.y < 28.0 + 1e-6);
                }
            }
            let covered: f64 = got.iter().map(|(_, a, b)| (b - a).norm()).sum::<f64>() * 0.1;
            assert!((covered - 64.0).abs() < 0.1 * 8.0 * 2.0, "{angle}°: {covered} mm² of 64");
        }
    }

    #[test]
    fn a_shape_thinner_than_the_spacing_gets_one_line_through_its_middle() {
        // 0.05 mm high, between grid lines at 0.25 and 0.75.
        let sliver = vec![Point::new(0.0, 0.4), Point::new(5.0, 0.4), Point::new(5.0, 0.45), Point::new(0.0, 0.45)];
        let (got, count) = lines(&[sliver, square(10.0, 0.0, 2.0)], 0.0, 0.5);
        assert_eq!((count.areas, count.thin_areas), (2, 1));
        let thin: Vec<_> = got.iter().filter(|(_, a, _)| a.x < 6.0).collect();
        assert_eq!(thin.len(), 1);
        assert!((thin[0].1.y - 0.425).abs() < 1e-6 && (thin[0].2.x - 5.0).abs() < 1e-6, "{thin:?}");
    }

    #[test]
    fn overlapping_areas_are_hatched_once() {
        let (got, _) = lines(&[square(0.0, 0.0, 4.0), square(2.0, 0.0, 4.0)], 0.0, 1.0);
        assert_eq!(got.len(), 4, "one line per row across both");
        assert!(got.iter().all(|(_, a, b)| a.x.abs() < 1e-6 && (b.x - 6.0).abs() < 1e-6));
    }
}
