//! Lead-ins, lead-outs, overcut and closing gaps (`[[layer]] lead_in`, …),
//! added to the planned paths once their order is known (`Sequence` →
//! `Sequence`). A pierce leaves a crater, so a cut that starts with one
//! pierces in the waste and runs onto its contour along a line or an arc;
//! it may leave along another into the waste, after cutting past its start
//! (overcut), or stop short of its start so that the part stays in the sheet
//! (closing gap).
//!
//! A lead goes where the waste is ([`Waste`]): its pierce in the waste, at
//! least a clearance (half the kerf and 0.1 mm) from every contour and every
//! other lead, crossing nothing. Where the planned entry has no room, a
//! closed contour is entered at the nearest place along it that has (the
//! report counts those); where no place has, planning fails naming the part
//! and the setting.

use nalgebra::Vector2;
use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};

use super::{PlannedPath, Sequence};
use crate::config::{LeadAt, LeadKind, MachineConfig};
use crate::error::{Error, Result};
use crate::job::{arc_points, lengths_along, piece_along, segment_crossing, segment_distance, Job, Point};
use crate::topology::waste::Waste;

/// One lead's shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lead {
    pub kind: LeadKind,
    pub length: f64,
    /// Line: its angle to the contour; arc: how far it turns (degrees).
    pub angle_deg: f64,
}

/// A process's leads (its layer's settings).
#[derive(Debug, Clone, PartialEq)]
pub struct LeadSettings {
    pub lead_in: Lead,
    pub lead_out: Lead,
    pub at: LeadAt,
    pub overcut: f64,
    pub closing_gap: f64,
    /// The layer's kerf (mm): leads keep half of it (and 0.1 mm) off every contour.
    pub kerf: f64,
    /// A turn sharper than this (degrees) is a corner (`lead_in_at = "corner"`).
    pub corner_angle_deg: f64,
    /// Contours closer than this share their cut (`[cutting]
    /// common_cut_tolerance`): a gap between them is no waste, so the
    /// waste is looked for twice this far from a contour.
    pub common_cut_mm: f64,
    /// The layer's name, for errors.
    pub layer: String,
}

impl LeadSettings {
    /// Whether the layer has any lead, overcut or closing gap.
    pub fn any(&self) -> bool {
        self.lead_in.kind != LeadKind::None || self.lead_out.kind != LeadKind::None || self.overcut > 0.0 || self.closing_gap > 0.0
    }

    fn clearance(&self) -> f64 {
        self.kerf / 2.0 + CLEARANCE_MM
    }
}

/// How far a lead keeps off contours and other leads beyond half the kerf.
const CLEARANCE_MM: f64 = 0.1;

/// A sequence with its leads.
#[derive(Debug, Clone)]
pub struct Leads {
    pub sequence: Sequence,
    pub count: LeadCount,
}

/// How many leads a plan has.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LeadCount {
    pub lead_ins: usize,
    pub lead_outs: usize,
    /// Lead-ins placed away from the planned entry, for want of room there.
    pub moved: usize,
    /// Cuts with a lead left out where no waste touches their start or end
    /// (between parts that share their cuts).
    pub skipped: usize,
}

/// Where a path's leads went.
struct Placement {
    moved: bool,
    skipped: bool,
}

/// Where the machine can go: leads outside it are not placed.
pub type Travel = (Point, Point);

/// The leads of the layers of `job`'s processes, and the machine's travel.
pub fn settings(job: &Job, machine: &MachineConfig) -> (Vec<LeadSettings>, Travel) {
    let settings = job
        .processes
        .iter()
        .map(|p| {
            let l = machine.layer(&p.layer);
            let lead = |kind: Option<LeadKind>, length: f64, angle_deg: f64| Lead { kind: kind.unwrap_or_default(), length, angle_deg };
            LeadSettings {
                lead_in: lead(l.map(|l| l.lead_in), l.map_or(0.0, |l| l.lead_in_length), l.map_or(90.0, |l| l.lead_in_angle)),
                lead_out: lead(l.map(|l| l.lead_out), l.map_or(0.0, |l| l.lead_out_length), l.map_or(90.0, |l| l.lead_out_angle)),
                at: l.map(|l| l.lead_in_at).unwrap_or_default(),
                overcut: l.map_or(0.0, |l| l.overcut),
                closing_gap: l.map_or(0.0, |l| l.closing_gap),
                kerf: l.map_or(0.0, |l| l.kerf),
                corner_angle_deg: machine.cutting.corner_angle,
                common_cut_mm: machine.cutting.common_cut_tolerance,
                layer: p.layer.clone(),
            }
        })
        .collect();
    let travel = (Point::origin(), Point::new(machine.stage.travel_x, machine.stage.travel_y));
    (settings, travel)
}

/// The waste of `job` on `machine`: the closed contours of the layers that
/// cut parts out hold the material.
pub fn waste(job: &Job, machine: &MachineConfig) -> Waste {
    let cuts: Vec<bool> = job.processes.iter().map(|p| machine.cuts_parts(&p.layer)).collect();
    Waste::new(job, &cuts)
}

/// `sequence` with the leads of `settings` (per process) added to every path
/// that starts with a pierce.
pub fn add_leads(job: &Job, sequence: Sequence, settings: &[LeadSettings], waste: &Waste, travel: Travel, tolerance: f64) -> Result<Leads> {
    let mut placed = Placed { tree: RTree::new() };
    let mut out = Leads { sequence, count: LeadCount::default() };
    let mut number = 0;
    for group in &mut out.sequence.groups {
        for path in &mut group.paths {
            number += 1;
            let Some(s) = settings.get(path.process).filter(|s| s.any() && path.pierce && path.lead_in == 0) else { continue };
            let context = Context { job, waste, travel, tolerance, settings: s, placed: &placed, path: number };
            let (leaded, placement) = context.lead(path)?;
            out.count.lead_ins += usize::from(leaded.lead_in > 0);
            out.count.lead_outs += usize::from(leaded.lead_out > 0);
            out.count.moved += usize::from(placement.moved);
            out.count.skipped += usize::from(placement.skipped);
            placed.add(&leaded, number);
            *path = leaded;
        }
    }
    Ok(out)
}

/// The leads placed so far, piece by piece, with their path's number and
/// the contour point they lead to or from.
struct Placed {
    tree: RTree<PlacedPiece>,
}

/// A lead's piece: its ends, its path's number, its contour point.
type PlacedPiece = GeomWithData<Rectangle<[f64; 2]>, (Point, Point, usize, Point)>;

impl Placed {
    fn add(&mut self, path: &PlannedPath, number: usize) {
        let (lead_in, lead_out) = (path.lead_in_points(), path.lead_out_points());
        let (entry, exit) = (lead_in[lead_in.len() - 1], lead_out[0]);
        let pieces = lead_in.windows(2).map(|w| (w, entry)).chain(lead_out.windows(2).map(|w| (w, exit)));
        for (w, on) in pieces {
            let (a, b) = (w[0], w[1]);
            self.tree.insert(GeomWithData::new(Rectangle::from_corners([a.x.min(b.x), a.y.min(b.y)], [a.x.max(b.x), a.y.max(b.y)]), (a, b, number, on)));
        }
    }

    /// Whether a piece comes within `reach` of another path's lead, other
    /// than one to or from the same contour point `on` (a cut that stopped
    /// there and one that starts there share their waste).
    fn near(&self, a: Point, b: Point, reach: f64, own: usize, on: Point) -> bool {
        let query = AABB::from_corners([a.x.min(b.x) - reach, a.y.min(b.y) - reach], [a.x.max(b.x) + reach, a.y.max(b.y) + reach]);
        self.tree.locate_in_envelope_intersecting(query).any(|p| {
            let (c, d, number, at) = p.data;
            number != own && (at - on).norm() > 1e-9 && segment_distance(a, b, c, d) < reach
        })
    }
}

/// Whether a lead fits at a place.
enum Fit {
    Lead(Vec<Point>),
    /// There is waste, but not room for the lead.
    NoRoom,
    /// No waste touches the place (between parts sharing their cuts).
    NoWaste,
}

/// Where the waste is beside a cut.
enum Side {
    /// On one side, this normal's.
    One(Vector2<f64>),
    /// On both: a cut through the waste (a skeleton cut) needs no lead.
    Both,
    /// On neither: between two parts.
    None,
}

struct Context<'a> {
    job: &'a Job,
    waste: &'a Waste,
    travel: Travel,
    tolerance: f64,
    settings: &'a LeadSettings,
    placed: &'a Placed,
    path: usize,
}

impl Context<'_> {
    /// `path` with its leads, and where they went.
    fn lead(&self, path: &PlannedPath) -> Result<(PlannedPath, Placement)> {
        let s = self.settings;
        let g = &self.job.geometries[path.geometry];
        // The polyline's length (its chords), as the path's points are.
        let outline = g.closed.then(|| (0..g.points.len()).map(|i| (g.points[(i + 1) % g.points.len()] - g.points[i]).norm()).sum());
        let closed_loop = is_loop(path, outline);
        let mut points = path.points.clone();
        if closed_loop {
            match s.at {
                LeadAt::Entry => {}
                LeadAt::Corner => points = rotate_to(&points, nearest_corner(&points, s.corner_angle_deg)),
                LeadAt::Longest => points = start_on_longest_side(&points),
            }
        }
        let mut lead_in = Vec::new();
        let (mut moved, mut skipped) = (false, false);
        let through_waste = matches!(self.waste_side(points[0], points[1]), Side::Both);
        if s.lead_in.kind != LeadKind::None && !through_waste {
            let starts = if closed_loop { loop_starts(&points) } else { vec![0] };
            let mut no_room = false;
            let found = starts.iter().find_map(|&h| {
                let candidate = start_at(&points, h);
                match self.lead_in(&candidate, path.geometry) {
                    Fit::Lead(lead) => Some((h, candidate, lead)),
                    Fit::NoRoom => {
                        no_room = true;
                        None
                    }
                    Fit::NoWaste => None,
                }
            });
            match found {
                Some((h, candidate, lead)) => {
                    moved = h != 0;
                    points = candidate;
                    lead_in = lead;
                }
                None if no_room => {
                    let room = self.room(&points, &starts, path.geometry);
                    let place = if closed_loop { " anywhere along its contour".to_string() } else { format!(" at ({:.3}, {:.3})", points[0].x, points[0].y) };
                    return Err(Error::Plan(format!(
                        "{}: no room in the waste for a lead-in of {} mm at {}° (layer '{}': lead_in_length, lead_in_angle){place}, {room}: shorten it",
                        g.source, s.lead_in.length, s.lead_in.angle_deg, s.layer
                    )));
                }
                // Between parts that share their cuts: no lead can go here.
                None => skipped = true,
            }
        }
        if closed_loop && s.closing_gap > 0.0 {
            let along = lengths_along(&points);
            let length = along[along.len() - 1];
            if s.closing_gap >= length / 2.0 {
                return Err(Error::Plan(format!(
                    "{}: a closing gap of {} mm (layer '{}': closing_gap) leaves less than half of its {length:.3} mm contour cut",
                    g.source, s.closing_gap, s.layer
                )));
            }
            points = piece_along(&points, &along, 0.0, length - s.closing_gap);
        }
        if closed_loop && s.overcut > 0.0 {
            let past = piece_along(&points, &lengths_along(&points), 0.0, s.overcut);
            points.extend(past.into_iter().skip(1));
        }
        let contour = points.len();
        if s.lead_out.kind != LeadKind::None && s.closing_gap == 0.0 && !through_waste {
            match self.lead_out(&points, &lead_in, path.geometry) {
                Fit::Lead(lead) => points.extend(lead),
                Fit::NoRoom => {
                    let end = points[points.len() - 1];
                    return Err(Error::Plan(format!(
                        "{}: no room in the waste for a lead-out of {} mm at {}° at ({:.3}, {:.3}) (layer '{}': lead_out_length, lead_out_angle): shorten it",
                        g.source, s.lead_out.length, s.lead_out.angle_deg, end.x, end.y, s.layer
                    )));
                }
                Fit::NoWaste => skipped = true,
            }
        }
        let (before, after) = (lead_in.len(), points.len() - contour);
        lead_in.extend(points);
        Ok((PlannedPath { points: lead_in, lead_in: before, lead_out: after, ..path.clone() }, Placement { moved, skipped }))
    }

    /// The lead-in points before `points[0]` (the first is the pierce),
    /// if one fits: the setting's shape, else (a line) its mirror image, else
    /// a line straight into the middle of the waste around the start (at a
    /// corner, or where the path begins between two parts).
    fn lead_in(&self, points: &[Point], own: usize) -> Fit {
        let Some(t) = direction(points[0], points[1]) else { return Fit::NoWaste };
        let start = points[0];
        let candidates = self.candidates(self.settings.lead_in, start, t, points[1], true);
        if candidates.is_empty() {
            return Fit::NoWaste;
        }
        let found = candidates.into_iter().find_map(|mut pts| {
            pts.push(start);
            self.fits(&pts, pts[0], start, own, &[]).then(|| {
                pts.pop();
                pts
            })
        });
        found.map_or(Fit::NoRoom, Fit::Lead)
    }

    /// The leads to try at contour point `on` (the path runs along `t`
    /// there, its neighbouring vertex `beside`), lead-in or lead-out
    /// (`into`): the setting's shape on the waste side, (a line) its mirror
    /// image, then a line straight into the middle of the waste around `on`.
    /// None where no waste touches `on`.
    fn candidates(&self, lead: Lead, on: Point, t: Vector2<f64>, beside: Point, into: bool) -> Vec<Vec<Point>> {
        let mut candidates = Vec::new();
        if let Side::One(n) = self.waste_side(on, beside) {
            candidates.push(shape(lead, on, t, n, into, false, self.tolerance));
            if lead.kind == LeadKind::Line {
                candidates.push(shape(lead, on, t, n, into, true, self.tolerance));
            }
        }
        if let Some(u) = self.waste_direction(on) {
            candidates.push(vec![on + u * lead.length]);
        }
        candidates
    }

    /// In words, the longest lead-in that fits at any of `starts` (to
    /// 0.01 mm), for an error that says how far to shorten it.
    fn room(&self, points: &[Point], starts: &[usize], own: usize) -> String {
        let fits_at = |length: f64| {
            let settings = LeadSettings { lead_in: Lead { length, ..self.settings.lead_in }, ..self.settings.clone() };
            let context = Context { settings: &settings, ..*self };
            starts.iter().any(|&h| matches!(context.lead_in(&start_at(points, h), own), Fit::Lead(_)))
        };
        let (mut lo, mut hi) = (0.0, self.settings.lead_in.length);
        while hi - lo > 0.01 {
            let mid = (lo + hi) / 2.0;
            if fits_at(mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        if lo > 0.0 {
            format!("where {lo:.2} mm would fit")
        } else {
            "where no lead-in fits".to_string()
        }
    }

    /// The direction from `at` into the middle of the widest wedge of waste
    /// around it (looked for twice the common-cut tolerance away, every 5°).
    fn waste_direction(&self, at: Point) -> Option<Vector2<f64>> {
        const STEPS: usize = 72;
        let unit = |i: usize| {
            let a = i as f64 / STEPS as f64 * std::f64::consts::TAU;
            Vector2::new(a.cos(), a.sin())
        };
        let away = 2.0 * self.settings.common_cut_mm;
        let waste: Vec<bool> = (0..STEPS).map(|i| self.clear_waste(at + unit(i) * away)).collect();
        let first_solid = waste.iter().position(|w| !w)?;
        // Runs of waste, walking once round from a direction that is not.
        let (mut best, mut run) = ((0, 0), (0, 0));
        for j in 1..=STEPS {
            let i = (first_solid + j) % STEPS;
            if waste[i] {
                run = if run.1 == 0 { (j, 1) } else { (run.0, run.1 + 1) };
                if run.1 > best.1 {
                    best = run;
                }
            } else {
                run = (0, 0);
            }
        }
        (best.1 > 0).then(|| {
            let middle = first_solid as f64 + best.0 as f64 + (best.1 as f64 - 1.0) / 2.0;
            let a = middle / STEPS as f64 * std::f64::consts::TAU;
            Vector2::new(a.cos(), a.sin())
        })
    }

    /// The lead-out points after the last of `points`, if one fits (the
    /// same choices as a lead-in's, from the end).
    fn lead_out(&self, points: &[Point], lead_in: &[Point], own: usize) -> Fit {
        let k = points.len();
        let Some(t) = direction(points[k - 2], points[k - 1]) else { return Fit::NoWaste };
        let end = points[k - 1];
        let candidates = self.candidates(self.settings.lead_out, end, t, points[k - 2], false);
        if candidates.is_empty() {
            return Fit::NoWaste;
        }
        let found = candidates.into_iter().find_map(|lead| {
            let mut pts = vec![end];
            pts.extend(lead);
            self.fits(&pts, pts[pts.len() - 1], end, own, lead_in).then(|| pts.split_off(1))
        });
        found.map_or(Fit::NoRoom, Fit::Lead)
    }

    /// Whether `p` lies in the waste, and not in a sliver between contours
    /// that share a cut.
    fn clear_waste(&self, p: Point) -> bool {
        self.waste.in_waste(p) && self.waste.near(p, p, self.settings.common_cut_mm).next().is_none()
    }

    /// Which side of the segment from `at` to (or from) `other` is waste.
    fn waste_side(&self, at: Point, other: Point) -> Side {
        let Some(t) = direction(at, other) else { return Side::None };
        let len = (other - at).norm();
        let left = Vector2::new(-t.y, t.x);
        let probe = at + t * (len / 2.0).min(1e-3);
        let step = 2.0 * self.settings.common_cut_mm;
        match (self.clear_waste(probe + left * step), self.clear_waste(probe - left * step)) {
            (true, false) => Side::One(left),
            (false, true) => Side::One(-left),
            (true, true) => Side::Both,
            (false, false) => Side::None,
        }
    }

    /// Whether lead `pts` fits: inside the travel, its end `far` (away from
    /// the contour point `on`) in the waste and at the clearance from every
    /// contour; crossing no contour (its own geometry `own` near `on`, and
    /// any that passes through `on`, it may only meet at `on`), and at the
    /// clearance from every other contour and every other path's lead.
    fn fits(&self, pts: &[Point], far: Point, on: Point, own: usize, own_lead: &[Point]) -> bool {
        let (lo, hi) = self.travel;
        let length = (far - on).norm().max(self.settings.clearance());
        if pts.iter().any(|p| p.x < lo.x || p.y < lo.y || p.x > hi.x || p.y > hi.y) || !self.waste.in_waste(far) {
            return false;
        }
        let reach = self.settings.clearance();
        if self.waste.near(far, far, reach).next().is_some() {
            return false;
        }
        pts.windows(2).all(|w| {
            let (a, b) = (w[0], w[1]);
            let clear = self.waste.near(a, b, reach).all(|(geometry, c, d, _)| {
                // The contour the lead runs onto, near where it does.
                let entered = segment_distance(on, on, c, d);
                let own_contour = (geometry == own && entered < length) || entered < 1e-6;
                own_contour && !crosses_away_from(a, b, c, d, on)
            });
            clear && !self.placed.near(a, b, reach, self.path, on) && !own_lead.windows(2).any(|v| crosses_away_from(a, b, v[0], v[1], on))
        })
    }
}

/// Whether segments `a`-`b` and `c`-`d` cross at a point other than `at`.
fn crosses_away_from(a: Point, b: Point, c: Point, d: Point, at: Point) -> bool {
    segment_crossing(a, b, c, d).is_some_and(|x| (x - at).norm() > 1e-6)
}

/// A lead's points from the contour point `on` (excluded), whose path runs
/// along `t` there, into the waste on side `n`: a lead-in's in cutting order
/// (ending just before `on`), a lead-out's from just after it.
fn shape(lead: Lead, on: Point, t: Vector2<f64>, n: Vector2<f64>, into: bool, mirrored: bool, tolerance: f64) -> Vec<Point> {
    let a = lead.angle_deg.to_radians();
    // Along the path (+1) or against it (-1): a lead-in comes from behind, a lead-out goes ahead.
    let ahead = if into != mirrored { -1.0 } else { 1.0 };
    match lead.kind {
        LeadKind::None => Vec::new(),
        LeadKind::Line => vec![on + (n * a.sin() + t * ahead * a.cos()) * lead.length],
        LeadKind::Arc => {
            let radius = lead.length / a;
            let centre = on + n * radius;
            // The arc's turn about its centre in the direction of travel.
            let turn = (on - centre).perp(&t).signum();
            let rotate = |p: Point, by: f64| {
                let v = p - centre;
                centre + Vector2::new(v.x * by.cos() - v.y * by.sin(), v.x * by.sin() + v.y * by.cos())
            };
            if into {
                let from = rotate(on, -turn * a);
                let mut pts = vec![from];
                pts.extend(arc_points(from, on, (turn * a / 4.0).tan(), tolerance));
                pts.pop();
                pts
            } else {
                let to = rotate(on, turn * a);
                arc_points(on, to, (turn * a / 4.0).tan(), tolerance)
            }
        }
    }
}

fn direction(a: Point, b: Point) -> Option<Vector2<f64>> {
    let v = b - a;
    let len = v.norm();
    (len > 1e-9).then(|| v / len)
}

/// Whether `path` cuts a closed contour of `length` (its polyline's) whole,
/// ending where it started.
fn is_loop(path: &PlannedPath, length: Option<f64>) -> bool {
    let (first, last) = (path.points[0], path.points[path.points.len() - 1]);
    let cut: f64 = path.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    length.is_some_and(|l| (first - last).norm() < 1e-9 && path.points.len() > 3 && (cut - l).abs() <= 1e-3 * l.max(1.0))
}

/// Where a loop can start: its vertices and the middles of its segments
/// (as the half-segment index `2·k` or `2·k + 1`), the planned start first,
/// then by their distance along the loop from it, both ways.
fn loop_starts(points: &[Point]) -> Vec<usize> {
    let n = points.len() - 1;
    let mut along = vec![0.0; 2 * n + 1];
    for i in 0..n {
        let step = (points[i + 1] - points[i]).norm() / 2.0;
        along[2 * i + 1] = along[2 * i] + step;
        along[2 * i + 2] = along[2 * i + 1] + step;
    }
    let total = along[2 * n];
    let mut order: Vec<usize> = (0..2 * n).collect();
    order.sort_by(|&a, &b| along[a].min(total - along[a]).total_cmp(&along[b].min(total - along[b])).then(a.cmp(&b)));
    order
}

/// A loop (`points` ending on its first) started at half-segment index
/// `h` of [`loop_starts`]: a vertex, or the middle of a segment.
fn start_at(points: &[Point], h: usize) -> Vec<Point> {
    let k = h / 2;
    if h.is_multiple_of(2) {
        return rotate_to(points, k);
    }
    let mut with_middle = points[..=k].to_vec();
    with_middle.push(nalgebra::center(&points[k], &points[k + 1]));
    with_middle.extend_from_slice(&points[k + 1..]);
    rotate_to(&with_middle, k + 1)
}

/// A loop (`points` ending on its first) started at vertex `k` instead.
fn rotate_to(points: &[Point], k: usize) -> Vec<Point> {
    if k == 0 {
        return points.to_vec();
    }
    let n = points.len() - 1;
    (0..=n).map(|i| points[(k + i) % n]).collect()
}

/// The vertex of a loop nearest its start where it turns by more than `angle_deg`.
fn nearest_corner(points: &[Point], angle_deg: f64) -> usize {
    let n = points.len() - 1;
    let cos = angle_deg.to_radians().cos();
    let turns = |i: usize| {
        let (a, b) = (direction(points[(i + n - 1) % n], points[i]), direction(points[i], points[(i + 1) % n]));
        a.zip(b).is_some_and(|(a, b)| a.dot(&b) < cos)
    };
    loop_starts(points).into_iter().filter(|h| h % 2 == 0).map(|h| h / 2).find(|&i| turns(i)).unwrap_or(0)
}

/// A loop started at the middle of its longest segment.
fn start_on_longest_side(points: &[Point]) -> Vec<Point> {
    let n = points.len() - 1;
    let k = (0..n).max_by(|&a, &b| (points[a + 1] - points[a]).norm().total_cmp(&(points[b + 1] - points[b]).norm())).unwrap_or(0);
    start_at(points, 2 * k + 1)
}

#[cfg(test)]
mod tests;
