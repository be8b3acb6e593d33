//! A route as the heat model sees it: where and when the laser puts heat
//! into the plate (pierces, cuts at their speed, dwells at sharp corners),
//! and the checks of thermal feasibility (seed 000): an operation is
//! feasible when the plate where it runs is below its feature's critical
//! temperature when its path starts, that is, after everything cut before
//! it (its own path's heat is the technology's, the same in every order).

use super::field::{Field, FieldOptions, Grid, Physics};
use crate::job::Point;

/// What an operation is, for its critical temperature.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Feature {
    Pierce,
    Cut,
    Corner,
}

impl Feature {
    pub fn name(self) -> &'static str {
        match self {
            Feature::Pierce => "pierce",
            Feature::Cut => "cut",
            Feature::Corner => "corner",
        }
    }
}

/// Critical temperatures per feature, °C.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Critical {
    pub pierce: f64,
    pub cut: f64,
    pub corner: f64,
}

impl Critical {
    pub fn of(self, feature: Feature) -> f64 {
        match feature {
            Feature::Pierce => self.pierce,
            Feature::Cut => self.cut,
            Feature::Corner => self.corner,
        }
    }
}

/// One path of a route: its points, when it starts, how it is cut.
#[derive(Debug, Clone)]
pub struct PathHeat<'a> {
    pub points: &'a [Point],
    /// When its pierce (or its cut, without one) starts, s.
    pub start: f64,
    /// Pierce seconds and the heat it puts in, W; none: no pierce.
    pub pierce: Option<(f64, f64)>,
    /// Cutting speed, mm/s, and the heat the cut puts in, W.
    pub speed: f64,
    pub watts: f64,
}

/// How sharp corners are found and cut.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corners {
    /// A turn whose headings' dot product is below this is sharp.
    pub cos_sharp: f64,
    /// Seconds the beam dwells at a sharp corner at cutting power.
    pub dwell: f64,
}

/// Heat put in at a moving (or standing) spot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Source {
    pub start: f64,
    pub duration: f64,
    pub from: Point,
    pub to: Point,
    pub watts: f64,
    /// It leaves a kerf behind (a cut does; a pierce's hole is too small to count).
    pub kerf: bool,
}

impl Source {
    /// Where the spot is at time `t` (within the source's span).
    pub fn at(&self, t: f64) -> Point {
        if self.duration > 0.0 {
            self.from + (self.to - self.from) * ((t - self.start) / self.duration)
        } else {
            self.from
        }
    }
}

/// One operation to check: its feature, its path, and the places it runs over.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    pub feature: Feature,
    pub path: usize,
    pub places: Vec<Point>,
}

/// A route's heat and checks, sources in time order.
#[derive(Debug, Clone, Default)]
pub struct Timeline {
    pub sources: Vec<Source>,
    pub checks: Vec<Check>,
    /// When each path starts.
    pub starts: Vec<f64>,
    /// When the last path ends.
    pub end: f64,
}

impl Timeline {
    /// The timeline of `paths`: each starts when it says, or when the one
    /// before it ends if that is later. Cut checks sample their element
    /// every `spacing` mm.
    pub fn build(paths: &[PathHeat], corners: Corners, spacing: f64) -> Timeline {
        let mut out = Timeline::default();
        let mut clock = 0.0f64;
        for (k, path) in paths.iter().enumerate() {
            clock = clock.max(path.start);
            out.starts.push(clock);
            let Some(&first) = path.points.first() else { continue };
            if let Some((seconds, watts)) = path.pierce {
                out.sources.push(Source { start: clock, duration: seconds, from: first, to: first, watts, kerf: false });
                out.checks.push(Check { feature: Feature::Pierce, path: k, places: vec![first] });
                clock += seconds;
            }
            let mut element = vec![first];
            let mut heading: Option<nalgebra::Vector2<f64>> = None;
            for w in path.points.windows(2) {
                let d = w[1] - w[0];
                let len = d.norm();
                if len <= 0.0 {
                    continue;
                }
                let dir = d / len;
                if heading.is_some_and(|h| h.dot(&dir) < corners.cos_sharp) {
                    out.checks.push(Check { feature: Feature::Cut, path: k, places: sampled(&element, spacing) });
                    out.checks.push(Check { feature: Feature::Corner, path: k, places: vec![w[0]] });
                    if corners.dwell > 0.0 {
                        out.sources.push(Source { start: clock, duration: corners.dwell, from: w[0], to: w[0], watts: path.watts, kerf: false });
                        clock += corners.dwell;
                    }
                    element = vec![w[0]];
                }
                heading = Some(dir);
                let duration = len / path.speed;
                out.sources.push(Source { start: clock, duration, from: w[0], to: w[1], watts: path.watts, kerf: true });
                clock += duration;
                element.push(w[1]);
            }
            if element.len() > 1 {
                out.checks.push(Check { feature: Feature::Cut, path: k, places: sampled(&element, spacing) });
            }
        }
        out.end = clock;
        out
    }
}

/// Points along a polyline `spacing` apart, its ends included.
fn sampled(line: &[Point], spacing: f64) -> Vec<Point> {
    let mut out = vec![line[0]];
    for w in line.windows(2) {
        let len = (w[1] - w[0]).norm();
        let n = (len / spacing).ceil().max(1.0) as usize;
        out.extend((1..=n).map(|k| w[0] + (w[1] - w[0]) * (k as f64 / n as f64)));
    }
    out
}

/// How a timeline is assessed.
#[derive(Debug, Clone, Default)]
pub struct AssessOptions {
    pub field: FieldOptions,
    /// Wait before a path whose checks fail until they hold (the last
    /// resort: the machine stands with the laser off).
    pub waits: bool,
    /// Keep the plate's temperatures every this many seconds (and at the end).
    pub snapshot_every: Option<f64>,
    /// Keep them also when this path starts.
    pub snapshot_path: Option<usize>,
}

/// The plate's temperatures at a time, °C, row by row from the grid's origin.
#[derive(Debug, Clone)]
pub struct Snapshot {
    pub time: f64,
    pub celsius: Vec<f32>,
}

/// The operation nearest to (or furthest over) its critical temperature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hottest {
    pub check: usize,
    pub time: f64,
    pub at: Point,
    pub celsius: f64,
    pub critical: f64,
}

/// What the heat model found for a timeline.
#[derive(Debug, Clone)]
pub struct Assessment {
    pub grid: Grid,
    /// Per check: the temperature it met (the hottest of its places), °C.
    pub celsius: Vec<f64>,
    /// Per check: when it was checked (its path's start, waits included), s.
    pub times: Vec<f64>,
    /// Checks over their critical temperature.
    pub violations: Vec<usize>,
    /// The largest excess over a critical temperature, °C (0: none).
    pub max_overheat: f64,
    pub hottest: Option<Hottest>,
    /// With waits: the checks that were over their critical temperature
    /// before their path's wait, and the temperature they met then.
    pub waited: Vec<(usize, f64)>,
    /// Per path: the wait before it, s (all 0 without waits).
    pub waits: Vec<f64>,
    pub wait: f64,
    pub steps: u64,
    pub cell_updates: u64,
    pub snapshots: Vec<Snapshot>,
    /// The end of the job, waits included, s.
    pub end: f64,
}

/// Most a single wait may last before the planner gives up on it, s.
pub const MAX_WAIT: f64 = 3_600.0;

/// Steps the plate through `timeline` and checks every operation.
pub fn assess(grid: Grid, physics: &Physics, critical: Critical, timeline: &Timeline, options: &AssessOptions) -> Assessment {
    let mut field = Field::new(grid, physics.clone(), options.field);
    let dt = field.dt();
    let mut out = Assessment {
        grid,
        celsius: vec![f64::NAN; timeline.checks.len()],
        times: vec![0.0; timeline.checks.len()],
        violations: Vec::new(),
        max_overheat: 0.0,
        hottest: None,
        waited: Vec::new(),
        waits: vec![0.0; timeline.starts.len()],
        wait: 0.0,
        steps: 0,
        cell_updates: 0,
        snapshots: Vec::new(),
        end: 0.0,
    };
    // Time is the timeline's; the field runs `shift` (the waits so far) behind it.
    let mut shift = 0.0;
    let mut next_source = 0;
    let mut active: Vec<usize> = Vec::new();
    let mut next_snapshot = options.snapshot_every.map(|_| 0.0);
    let mut check = 0;
    let run_to = |field: &mut Field, until: f64, shift: f64, next_source: &mut usize, active: &mut Vec<usize>, snapshots: &mut Vec<Snapshot>, next_snapshot: &mut Option<f64>| {
        // Steps while a whole step fits before `until` (field time).
        while field.time() + dt <= until + 1e-12 {
            let (t0, t1) = (field.time() - shift, field.time() + dt - shift);
            while *next_source < timeline.sources.len() && timeline.sources[*next_source].start < t1 {
                active.push(*next_source);
                *next_source += 1;
            }
            active.retain(|&s| {
                let src = &timeline.sources[s];
                let end = src.start + src.duration;
                let (a, b) = (t0.max(src.start), t1.min(end));
                if b > a || (src.duration == 0.0 && src.start >= t0 && src.start < t1) {
                    let joules = src.watts * (b - a).max(0.0);
                    let (p, q) = (src.at(a), src.at(b));
                    if joules > 0.0 {
                        if p == q { field.deposit(p, joules) } else { field.deposit_along(p, q, joules) }
                    }
                    if src.kerf {
                        field.cut_kerf(p, q);
                    }
                }
                end > t1
            });
            field.step();
            if let Some(at) = next_snapshot.as_mut() {
                if field.time() >= *at {
                    snapshots.push(Snapshot { time: field.time(), celsius: field.celsius_rows() });
                    *at += options.snapshot_every.unwrap_or(f64::INFINITY);
                }
            }
        }
    };
    for (p, &start) in timeline.starts.iter().enumerate() {
        run_to(&mut field, start + shift, shift, &mut next_source, &mut active, &mut out.snapshots, &mut next_snapshot);
        let first = check;
        while check < timeline.checks.len() && timeline.checks[check].path == p {
            check += 1;
        }
        let checks = first..check;
        let measure = |field: &Field, c: usize| timeline.checks[c].places.iter().map(|&q| field.celsius_at(q)).fold(f64::NEG_INFINITY, f64::max);
        let over = |field: &Field| checks.clone().any(|c| measure(field, c) >= critical.of(timeline.checks[c].feature));
        if options.waits && over(&field) {
            for c in checks.clone() {
                let t = measure(&field, c);
                if t >= critical.of(timeline.checks[c].feature) {
                    out.waited.push((c, t));
                }
            }
            let began = field.time();
            // Cool, the laser off, to a degree under every critical temperature.
            let cool = |field: &Field| checks.clone().all(|c| measure(field, c) < critical.of(timeline.checks[c].feature) - 1.0);
            // Every path before this one has ended: nothing heats the plate.
            while !cool(&field) && field.time() - began < MAX_WAIT {
                field.step();
            }
            let waited = field.time() - began;
            out.waits[p] = waited;
            shift += waited;
        }
        if options.snapshot_path == Some(p) {
            out.snapshots.push(Snapshot { time: field.time(), celsius: field.celsius_rows() });
        }
        for c in checks {
            let t = measure(&field, c);
            let limit = critical.of(timeline.checks[c].feature);
            out.celsius[c] = t;
            out.times[c] = start + shift;
            if t >= limit {
                out.violations.push(c);
                out.max_overheat = out.max_overheat.max(t - limit);
            }
            if out.hottest.is_none_or(|h| t - limit > h.celsius - h.critical) {
                let at = timeline.checks[c].places.iter().copied().max_by(|a, b| field.celsius_at(*a).total_cmp(&field.celsius_at(*b))).unwrap_or(Point::origin());
                out.hottest = Some(Hottest { check: c, time: start + shift, at, celsius: t, critical: limit });
            }
        }
    }
    run_to(&mut field, timeline.end + shift, shift, &mut next_source, &mut active, &mut out.snapshots, &mut next_snapshot);
    out.wait = shift;
    out.end = timeline.end + shift;
    out.steps = (field.time() / dt).round() as u64;
    out.cell_updates = field.cell_updates();
    out
}
