//! `Job`: the output of import and the input of planning. Geometry in machine
//! millimetres (X right, Y away from the operator), each shape with the process
//! parameters of its layer.

use nalgebra::Point2;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

pub type Point = Point2<f64>;

/// Process parameters a layer gives its geometries.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Process {
    /// Layer name from the config.
    pub layer: String,
    /// Marking speed, mm/s (the machine may cap it).
    pub speed: f64,
    /// Laser power as the S value.
    pub power: f64,
    pub passes: u32,
}

/// One shape to mark or cut: a polyline, open or closed.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    /// Vertices in mm. A closed geometry does not repeat its first vertex at the end.
    pub points: Vec<Point>,
    pub closed: bool,
    /// Index into `Job::processes`.
    pub process: usize,
    /// Where it came from, for messages: e.g. `sample.svg: <path id="p12">` (subpath 2).
    pub source: String,
}

impl Geometry {
    /// Length of the marked path (including the closing segment of a closed shape).
    pub fn length(&self) -> f64 {
        let n = self.points.len();
        let mut len: f64 = self.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        if self.closed && n > 2 {
            len += (self.points[0] - self.points[n - 1]).norm();
        }
        len
    }

    /// Axis-aligned bounds (min, max).
    pub fn bounds(&self) -> (Point, Point) {
        bounds_of(self.points.iter())
    }
}

pub fn bounds_of<'a>(points: impl Iterator<Item = &'a Point>) -> (Point, Point) {
    let mut lo = Point::new(f64::INFINITY, f64::INFINITY);
    let mut hi = Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in points {
        lo.x = lo.x.min(p.x);
        lo.y = lo.y.min(p.y);
        hi.x = hi.x.max(p.x);
        hi.y = hi.y.max(p.y);
    }
    (lo, hi)
}

#[derive(Debug, Clone)]
pub struct Job {
    /// Path of the job file as given.
    pub source: String,
    pub geometries: Vec<Geometry>,
    pub processes: Vec<Process>,
}

impl Job {
    pub fn mark_length(&self) -> f64 {
        self.geometries
            .iter()
            .map(|g| g.length() * self.processes[g.process].passes as f64)
            .sum()
    }

    pub fn bounds(&self) -> (Point, Point) {
        bounds_of(self.geometries.iter().flat_map(|g| g.points.iter()))
    }
}
