//! The areas of fill layers (`[[layer]] mode = "fill"` or `"fill+line"`).
//!
//! A drawn element's shapes enclose an area by its fill rule (SVG's
//! `fill-rule`; a DXF layer's closed contours by even-odd, nested contours
//! being holes, as CAD programs fill them). The importers give that area as
//! closed contours of the layer's fill process (`Process::fill`): outlines
//! counter-clockwise, holes clockwise, so that the area of all of a layer's
//! contours is where their winding number is not zero (areas of elements that
//! overlap are one area, marked once). The planner hatches them
//! (`plan::area::hatch`); on a `fill+line` layer the drawn shapes are marked
//! as lines besides.

use i_overlay::core::fill_rule::FillRule;
use i_overlay::float::simplify::SimplifyShape;

use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::job::{Geometry, Point};

/// How the shapes of one element enclose their area.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    NonZero,
    EvenOdd,
}

/// The area `shapes` (each implicitly closed, as SVG fills an open subpath)
/// enclose by `rule`, as closed contours: outlines counter-clockwise, holes
/// clockwise. Empty where they enclose none.
pub fn area(shapes: &[&[Point]], rule: Rule) -> Vec<Vec<Point>> {
    let contours: Vec<Vec<[f64; 2]>> = shapes.iter().filter(|s| s.len() >= 3).map(|s| s.iter().map(|p| [p.x, p.y]).collect()).collect();
    if contours.is_empty() {
        return Vec::new();
    }
    let fill_rule = match rule {
        Rule::NonZero => FillRule::NonZero,
        Rule::EvenOdd => FillRule::EvenOdd,
    };
    let mut out = Vec::new();
    for shape in contours.simplify_shape(fill_rule) {
        for (k, contour) in shape.into_iter().enumerate() {
            let mut points: Vec<Point> = contour.into_iter().map(|[x, y]| Point::new(x, y)).collect();
            if points.len() < 3 {
                continue;
            }
            // The first contour of a shape is its outline, the others its holes.
            if (signed_area(&points) > 0.0) != (k == 0) {
                points.reverse();
            }
            out.push(points);
        }
    }
    out
}

/// The signed area of a closed polygon (positive counter-clockwise).
pub fn signed_area(points: &[Point]) -> f64 {
    let n = points.len();
    0.5 * (0..n).map(|i| points[i].x * points[(i + 1) % n].y - points[(i + 1) % n].x * points[i].y).sum::<f64>()
}

/// The process index importers give a fill area of config layer `layer`
/// until `job_of_layers` numbers the job's processes.
pub(crate) fn fill_process(layer: usize, config: &MachineConfig) -> usize {
    layer + config.layers.len()
}

/// The area of `element`'s shapes (`name` in messages) on config layer
/// `layer` as geometries of its fill process; an error where a layer that
/// only fills would mark nothing of the element.
pub(crate) fn element_area(shapes: &[&[Point]], rule: Rule, layer: usize, config: &MachineConfig, name: &str) -> Result<Vec<Geometry>> {
    let contours = area(shapes, rule);
    if contours.is_empty() && !config.layers[layer].mode.lines() {
        return Err(Error::Import(format!(
            "{name}: encloses no area, and its layer '{}' only fills (mode = \"fill\"); put it on a line layer or draw it closed",
            config.layers[layer].name
        )));
    }
    let process = fill_process(layer, config);
    Ok(contours.into_iter().enumerate().map(|(k, points)| Geometry::polyline(points, true, process, format!("{name} (fill area {})", k + 1))).collect())
}

/// `geometries` (processes: config layer indices) with every fill layer's
/// closed shapes as one element filled by even-odd (a DXF drawing's
/// layers); on a layer that only fills, the shapes themselves give way to
/// their area, and an open one is an error naming it.
pub(crate) fn layer_areas(geometries: Vec<Geometry>, config: &MachineConfig, source: &str) -> Result<Vec<Geometry>> {
    let mut out = Vec::with_capacity(geometries.len());
    for (layer, l) in config.layers.iter().enumerate().filter(|(_, l)| l.mode.fills()) {
        let shapes: Vec<&[Point]> = geometries.iter().filter(|g| g.process == layer && g.closed).map(|g| g.points.as_slice()).collect();
        if shapes.is_empty() {
            continue;
        }
        if let Some(open) = geometries.iter().find(|g| g.process == layer && !g.closed && !l.mode.lines()) {
            return Err(Error::Import(format!(
                "{}: is open, and its layer '{}' only fills closed shapes (mode = \"fill\"); close it or put it on a line layer",
                open.source, l.name
            )));
        }
        out.extend(element_area(&shapes, Rule::EvenOdd, layer, config, &format!("{source}: layer '{}'", l.name))?);
    }
    out.extend(geometries.into_iter().filter(|g| config.layers.get(g.process).is_none_or(|l| l.mode.lines())));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x: f64, y: f64, side: f64, ccw: bool) -> Vec<Point> {
        let mut s = vec![Point::new(x, y), Point::new(x + side, y), Point::new(x + side, y + side), Point::new(x, y + side)];
        if !ccw {
            s.reverse();
        }
        s
    }

    fn total_area(contours: &[Vec<Point>]) -> f64 {
        contours.iter().map(|c| signed_area(c)).sum()
    }

    #[test]
    fn the_fill_rule_decides_whether_a_nested_shape_is_a_hole() {
        // Both drawn counter-clockwise: nonzero fills the inner square, even-odd does not.
        let (outer, inner) = (square(0.0, 0.0, 10.0, true), square(3.0, 3.0, 4.0, true));
        let shapes = [outer.as_slice(), inner.as_slice()];
        assert!((total_area(&area(&shapes, Rule::NonZero)) - 100.0).abs() < 1e-6);
        let even_odd = area(&shapes, Rule::EvenOdd);
        assert!((total_area(&even_odd) - 84.0).abs() < 1e-6, "a hole: {even_odd:?}");
        assert_eq!(even_odd.iter().filter(|c| signed_area(c) < 0.0).count(), 1, "the hole runs clockwise");
        // Drawn the other way round, nonzero makes it a hole too.
        let inner_cw = square(3.0, 3.0, 4.0, false);
        assert!((total_area(&area(&[outer.as_slice(), inner_cw.as_slice()], Rule::NonZero)) - 84.0).abs() < 1e-6);
    }

    #[test]
    fn an_island_in_a_hole_is_filled_and_overlapping_shapes_are_one_area() {
        let (outer, hole, island) = (square(0.0, 0.0, 10.0, true), square(2.0, 2.0, 6.0, true), square(4.0, 4.0, 2.0, true));
        let a = area(&[outer.as_slice(), hole.as_slice(), island.as_slice()], Rule::EvenOdd);
        assert!((total_area(&a) - (100.0 - 36.0 + 4.0)).abs() < 1e-6);
        let (left, right) = (square(0.0, 0.0, 4.0, true), square(2.0, 0.0, 4.0, false));
        let union = area(&[left.as_slice(), right.as_slice()], Rule::NonZero);
        // Opposite windings cancel under nonzero where they overlap: as SVG renders it.
        assert!((total_area(&union) - 16.0).abs() < 1e-6, "{union:?}");
    }

    #[test]
    fn a_line_encloses_no_area() {
        let line = [Point::new(0.0, 0.0), Point::new(5.0, 0.0), Point::new(10.0, 0.0)];
        assert!(area(&[line.as_slice()], Rule::NonZero).is_empty());
    }
}
