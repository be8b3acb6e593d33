//! Areas (seed 004): filled shapes marked as hatch lines, in the order an
//! objective prefers.
//!
//! * [`hatch`]: a fill layer's areas become hatch lines (the job's
//!   geometries of its fill process, each one straight segment).
//! * Here: the hatch lines as genes (a segment and the way it is marked), the
//!   plain raster order (line after line across the whole job, what
//!   LightBurn does by default), and the fill planner.

pub mod hatch;

use super::PlannedPath;
use crate::config::MachineConfig;
use crate::job::{Job, Point};
use nalgebra::Vector2;

/// A hatch line to mark: a straight geometry of a fill process.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub geometry: usize,
    /// Its ends, `from` to `to` the hatch's way.
    pub from: Point,
    pub to: Point,
    /// Whether it may be marked `to` to `from` (a bidirectional fill).
    pub either_way: bool,
    /// Where its line lies across the hatch (the hatch's lines in order).
    pub across: f64,
}

impl Segment {
    /// Its ends in the way it is marked (`reversed`: `to` first).
    pub fn ends(&self, reversed: bool) -> (Point, Point) {
        if reversed {
            (self.to, self.from)
        } else {
            (self.from, self.to)
        }
    }

    pub fn length(&self) -> f64 {
        (self.to - self.from).norm()
    }

    /// The hatch's direction (a unit vector).
    pub fn direction(&self) -> Vector2<f64> {
        (self.to - self.from) / self.length().max(1e-300)
    }
}

/// The hatch lines among `which` (geometries of `job`), in the job's order.
pub fn segments(job: &Job, which: &[usize], machine: &MachineConfig) -> Vec<Segment> {
    which
        .iter()
        .filter_map(|&g| {
            let geometry = &job.geometries[g];
            let process = &job.processes[geometry.process];
            if !process.fill || geometry.closed || geometry.points.len() != 2 {
                return None;
            }
            let either_way = machine.layers.iter().find(|l| l.name == process.layer).is_none_or(|l| l.bidirectional);
            let (from, to) = (geometry.points[0], geometry.points[1]);
            let d = (to - from).normalize();
            Some(Segment { geometry: g, from, to, either_way, across: d.perp(&from.coords) })
        })
        .collect()
}

/// A route over segments: each by its index and whether it is marked reversed.
pub type Order = Vec<(u32, bool)>;

/// The plain raster: the segments line after line as hatching made them,
/// along each line the hatch's way, a bidirectional hatch's lines turning
/// back one after the other.
pub fn raster(segments: &[Segment]) -> Order {
    let mut order = Vec::with_capacity(segments.len());
    let mut line_start = 0;
    let mut back = false;
    for k in 0..=segments.len() {
        let new_line = k == segments.len() || (k > line_start && !same_line(&segments[k], &segments[line_start]));
        if !new_line {
            continue;
        }
        let line = line_start..k;
        if back && segments[line_start].either_way {
            order.extend(line.rev().map(|i| (i as u32, true)));
        } else {
            order.extend(line.map(|i| (i as u32, false)));
        }
        back = !back;
        line_start = k;
    }
    order
}

/// Whether two segments lie on one hatch line.
fn same_line(a: &Segment, b: &Segment) -> bool {
    (a.across - b.across).abs() <= 1e-6 * (1.0 + a.across.abs()) && a.direction().dot(&b.direction()) > 1.0 - 1e-9
}

/// `order` as planned paths (fills never pierce).
pub fn paths(job: &Job, segments: &[Segment], order: &Order) -> Vec<PlannedPath> {
    order
        .iter()
        .map(|&(i, reversed)| {
            let s = &segments[i as usize];
            let (a, b) = s.ends(reversed);
            PlannedPath::new(s.geometry, vec![a, b], job.geometries[s.geometry].process, false)
        })
        .collect()
}
