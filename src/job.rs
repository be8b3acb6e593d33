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
    /// The hatch lines of a fill layer (`[[layer]] mode`): marked at their
    /// speed from end to end, ordered as an area (`plan::area`).
    #[serde(default)]
    pub fill: bool,
}

/// One shape to mark or cut: a polyline, open or closed, whose circular
/// arcs are kept exact beside their flattening.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    /// Vertices in mm. A closed geometry does not repeat its first vertex at the end.
    /// Arcs are here flattened within the import tolerance: the stages that
    /// need points (topology, planning, motion) read these.
    pub points: Vec<Point>,
    pub closed: bool,
    /// The circular arcs among the segments, in order, not overlapping
    /// (DXF arcs, circles and bulges, G-code G2/G3): length and bounds are
    /// theirs, not their chords'. Empty for a plain polyline.
    pub arcs: Vec<ArcSpan>,
    /// The process of each segment where it changes along the geometry (a
    /// raster line's power profile, from G-code); empty: every segment is
    /// `process`'s. Planners order the geometry as one; the plan's paths
    /// are then cut where the process changes.
    pub profile: Vec<usize>,
    /// Index into `Job::processes` (a profile's first segment's).
    pub process: usize,
    /// Where it came from, for messages: e.g. `sample.svg: <path id="p12">` (subpath 2).
    pub source: String,
}

/// A circular arc of a geometry, kept exact: the vertices `from..=to` are
/// its flattening, from `points[from]` to `points[to]` (`to` equal to the
/// number of points: vertex 0, the closing segment of a closed geometry). It
/// bends by `bulge`, the tangent of a quarter of its sweep, positive
/// counter-clockwise (as DXF writes it), at most 1 (a half circle) either way.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ArcSpan {
    pub from: usize,
    pub to: usize,
    pub bulge: f64,
}

/// The circle of an arc from `a` to `b` of `bulge`: centre, radius, the
/// angle of `a` about the centre and the signed sweep (radians).
pub fn arc_circle(a: Point, b: Point, bulge: f64) -> (Point, f64, f64, f64) {
    let sweep = 4.0 * bulge.atan();
    let d = b - a;
    let chord = d.norm();
    let radius = chord / (2.0 * (sweep / 2.0).sin().abs());
    // The centre lies left of the chord for a counter-clockwise arc.
    let offset = radius * (sweep / 2.0).cos() * sweep.signum();
    let centre = a + d / 2.0 + nalgebra::Vector2::new(-d.y, d.x) / chord * offset;
    (centre, radius, (a.y - centre.y).atan2(a.x - centre.x), sweep)
}

/// Segments of an arc of `radius` over `sweep` (radians) whose chords stay
/// within `tolerance` of it: a chord over angle φ lies r·(1 − cos(φ/2))
/// inside the arc. At least one; two or more for a full circle.
pub fn arc_segments(radius: f64, sweep: f64, tolerance: f64) -> f64 {
    let tolerance = tolerance.min(radius);
    let step = if radius > 0.0 { 2.0 * (1.0 - tolerance / radius).clamp(-1.0, 1.0).acos() } else { sweep.abs() };
    (sweep.abs() / step.max(1e-9)).ceil().max(1.0)
}

/// The flattening of the arc from `a` to `b` of `bulge` within `tolerance`:
/// its vertices after `a`, ending on `b` exactly.
pub fn arc_points(a: Point, b: Point, bulge: f64, tolerance: f64) -> Vec<Point> {
    let (centre, radius, start, sweep) = arc_circle(a, b, bulge);
    let n = arc_segments(radius, sweep, tolerance).min(1e6) as usize;
    let mut points: Vec<Point> = (1..n)
        .map(|i| {
            let t = start + sweep * i as f64 / n as f64;
            centre + nalgebra::Vector2::new(t.cos(), t.sin()) * radius
        })
        .collect();
    points.push(b);
    points
}

/// Where segments `a`-`b` and `c`-`d` cross properly (each strictly
/// between the other's ends), if they do.
pub fn segment_crossing(a: Point, b: Point, c: Point, d: Point) -> Option<Point> {
    let cross = |o: Point, p: Point, q: Point| (p - o).perp(&(q - o));
    let (d1, d2, d3, d4) = (cross(c, d, a), cross(c, d, b), cross(a, b, c), cross(a, b, d));
    (d1 * d2 < 0.0 && d3 * d4 < 0.0).then(|| a + (b - a) * (d1 / (d1 - d2)))
}

/// The distance between two segments.
pub fn segment_distance(a: Point, b: Point, c: Point, d: Point) -> f64 {
    if segment_crossing(a, b, c, d).is_some() {
        return 0.0;
    }
    let to = |p: Point, s: Point, e: Point| {
        let v = e - s;
        let t = if v.norm_squared() > 0.0 { ((p - s).dot(&v) / v.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
        (s + v * t - p).norm()
    };
    to(a, c, d).min(to(b, c, d)).min(to(c, a, b)).min(to(d, a, b))
}

/// Distances along a polyline to each of its vertices.
pub fn lengths_along(points: &[Point]) -> Vec<f64> {
    let mut along = Vec::with_capacity(points.len());
    let mut total = 0.0;
    along.push(0.0);
    for w in points.windows(2) {
        total += (w[1] - w[0]).norm();
        along.push(total);
    }
    along
}

/// The point `s` along a polyline.
pub fn point_along(points: &[Point], along: &[f64], s: f64) -> Point {
    let i = along.partition_point(|&a| a <= s).clamp(1, points.len() - 1) - 1;
    let span = along[i + 1] - along[i];
    if span <= 0.0 {
        return points[i];
    }
    points[i] + (points[i + 1] - points[i]) * ((s - along[i]) / span).clamp(0.0, 1.0)
}

/// The piece of a polyline from `a` to `b` along it, its vertices kept.
/// Vertices closer than a nanometre to a cut end are one point.
pub fn piece_along(points: &[Point], along: &[f64], a: f64, b: f64) -> Vec<Point> {
    let mut out = vec![point_along(points, along, a)];
    for (i, &p) in points.iter().enumerate() {
        if along[i] > a + 1e-9 && along[i] < b - 1e-9 {
            out.push(p);
        }
    }
    out.push(point_along(points, along, b));
    out
}

/// Points around a closed outline at most `spacing` apart, its vertices
/// among them (each side cut into equal steps).
pub fn points_around(outline: &[Point], spacing: f64) -> Vec<Point> {
    let n = outline.len();
    let mut out = Vec::new();
    for k in 0..n {
        let (a, b) = (outline[k], outline[(k + 1) % n]);
        let steps = ((b - a).norm() / spacing).ceil().max(1.0) as usize;
        out.extend((0..steps).map(|s| a + (b - a) * (s as f64 / steps as f64)));
    }
    out
}

/// Length of the arc from `a` to `b` of `bulge` (the chord for bulge 0).
pub fn arc_length(a: Point, b: Point, bulge: f64) -> f64 {
    let chord = (b - a).norm();
    if bulge == 0.0 || chord == 0.0 {
        return chord;
    }
    let half = 2.0 * bulge.atan().abs();
    chord * half / half.sin()
}

impl Geometry {
    /// A polyline with no arcs.
    pub fn polyline(points: Vec<Point>, closed: bool, process: usize, source: String) -> Geometry {
        Geometry { points, closed, arcs: Vec::new(), profile: Vec::new(), process, source }
    }

    /// Vertex `i`, counting on past the last to the first.
    fn vertex(&self, i: usize) -> Point {
        self.points[i % self.points.len()]
    }

    /// Segments of the polyline (the closing one of a closed shape included).
    pub fn segments(&self) -> usize {
        let n = self.points.len();
        if self.closed && n > 2 { n } else { n.saturating_sub(1) }
    }

    /// Length of the marked path (including the closing segment of a closed
    /// shape), its arcs along the arcs.
    pub fn length(&self) -> f64 {
        let mut len = 0.0;
        let mut arcs = self.arcs.iter().peekable();
        let mut i = 0;
        while i < self.segments() {
            match arcs.next_if(|a| a.from == i) {
                Some(a) => {
                    len += arc_length(self.vertex(a.from), self.vertex(a.to), a.bulge);
                    i = a.to.max(i + 1);
                }
                None => {
                    len += (self.vertex(i + 1) - self.vertex(i)).norm();
                    i += 1;
                }
            }
        }
        len
    }

    /// Axis-aligned bounds (min, max), its arcs' extremes included.
    pub fn bounds(&self) -> (Point, Point) {
        let (mut lo, mut hi) = bounds_of(self.points.iter());
        for a in &self.arcs {
            let (centre, radius, start, sweep) = arc_circle(self.vertex(a.from), self.vertex(a.to), a.bulge);
            // The arc reaches an axis direction k·90° where its sweep passes it.
            for k in 0..4 {
                let axis = k as f64 * std::f64::consts::FRAC_PI_2;
                let past = if sweep >= 0.0 { (axis - start).rem_euclid(std::f64::consts::TAU) } else { (start - axis).rem_euclid(std::f64::consts::TAU) };
                if past <= sweep.abs() {
                    let p = centre + nalgebra::Vector2::new(axis.cos(), axis.sin()) * radius;
                    lo = Point::new(lo.x.min(p.x), lo.y.min(p.y));
                    hi = Point::new(hi.x.max(p.x), hi.y.max(p.y));
                }
            }
        }
        (lo, hi)
    }

    /// What is wrong with the arcs, if anything: out of order or range, a
    /// bulge beyond a half circle, or vertices further than `tolerance` from
    /// the arc they flatten (off its circle, or chords cutting inside it by
    /// more). A job file's arcs are checked so, as any upload is.
    pub fn arc_error(&self, tolerance: f64) -> Option<String> {
        let n = self.points.len();
        let mut next = 0;
        for (k, a) in self.arcs.iter().enumerate() {
            if a.from < next || a.to <= a.from || a.to > self.segments() {
                return Some(format!("arc {k} (vertices {} to {}) is out of order or beyond the {n} vertices", a.from, a.to));
            }
            if !(a.bulge.is_finite() && a.bulge != 0.0 && a.bulge.abs() <= 1.0) {
                return Some(format!("arc {k}: bulge {} is not within -1 to 1 (a half circle) or is 0", a.bulge));
            }
            if (self.vertex(a.to) - self.vertex(a.from)).norm() < 1e-9 {
                return Some(format!("arc {k} ends where it starts (vertices {} and {})", a.from, a.to));
            }
            let (centre, radius, _, sweep) = arc_circle(self.vertex(a.from), self.vertex(a.to), a.bulge);
            let mut turned = 0.0;
            for i in a.from..a.to {
                let (p, q) = (self.vertex(i), self.vertex(i + 1));
                let off = ((q - centre).norm() - radius).abs();
                let step = (p - centre).perp(&(q - centre)).atan2((p - centre).dot(&(q - centre)));
                let sagitta = radius * (1.0 - (step / 2.0).cos());
                if off > tolerance || sagitta > tolerance + 1e-9 || step * sweep < 0.0 {
                    return Some(format!("arc {k}: vertex {} is {:.2e} mm off the arc, its chord {sagitta:.2e} mm inside it (tolerance {tolerance} mm)", i + 1, off));
                }
                turned += step;
            }
            if (turned - sweep).abs() > 1e-6 {
                return Some(format!("arc {k}: its vertices turn {turned:.6} rad, its bulge {sweep:.6} rad"));
            }
            next = a.to;
        }
        None
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
        self.geometries.iter().map(Geometry::bounds).fold(bounds_of(std::iter::empty()), |(lo, hi), (a, b)| {
            (Point::new(lo.x.min(a.x), lo.y.min(a.y)), Point::new(hi.x.max(b.x), hi.y.max(b.y)))
        })
    }
}
