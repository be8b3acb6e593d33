//! Bridges (seed 000, "Bridges"; `[cutting] bridge_max`): a post-optimisation
//! of the cutting order. Where one cut ends near where the next begins with
//! a pierce, the laser may go on cutting straight across the waste to it,
//! instead of stopping, moving with the laser off and piercing again. A
//! bridge is taken where it is shorter than `bridge_max` and saves machine
//! time by the machine's own figures: the bridge cut at the layer's speed
//! against the air move at the stage's limits plus the pierce.
//!
//! A bridge cuts the waste, so it may cut a piece of it free (seed 000's
//! Figure 5: the bridge and the contours it joins close a new contour, and
//! whatever lies inside must be cut before it). Bridges are taken only where
//! they close no such contour: between contours not yet joined, by bridges
//! or by touching (common cuts, one inside another), so the bridges and the
//! groups of contours they join form a forest, the waste stays in one piece
//! around them and no precedence rule is added or broken. A bridge runs
//! through the waste at the leads' clearance from every contour, crossing no
//! lead and no other bridge.

use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};

use super::{PlannedPath, Sequence};
use crate::config::MachineConfig;
use crate::job::{segment_crossing, segment_distance, Job, Point};
use crate::topology::waste::Waste;

/// How far a bridge keeps off contours, leads and other bridges between its
/// ends (mm), beyond half the kerf: the leads' clearance.
const CLEARANCE_MM: f64 = 0.1;

/// What the bridges saved.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BridgeCount {
    pub bridges: usize,
    pub pierces_saved: usize,
}

/// `sequence` with bridges where they pay (see the module). `groups` per
/// geometry: which contours already touch (the topology's groups); `None`
/// when no layer bridges.
pub fn add_bridges(job: &Job, mut sequence: Sequence, machine: &MachineConfig, waste: &Waste, groups: &[usize]) -> (Sequence, BridgeCount) {
    let max = machine.cutting.bridge_max;
    let mut count = BridgeCount::default();
    // Bridges join consecutive paths of one stage-only run of cuts.
    if max <= 0.0 || sequence.groups.len() != 1 || sequence.groups[0].field_center.is_some() {
        return (sequence, count);
    }
    let paths = &mut sequence.groups[0].paths;
    let mut joined = UnionFind::new(groups.iter().copied().max().map_or(0, |g| g + 1));
    let mut drawn = Drawn { tree: RTree::new() };
    for p in paths.iter() {
        drawn.add_leads(p);
    }
    for i in 1..paths.len() {
        let (prev, next) = (&paths[i - 1], &paths[i]);
        let layer = &job.processes[next.process].layer;
        // A cooling wait stays where the heat model put it: before an air
        // move's pierce.
        if !next.pierce || next.cooling_wait > 0.0 || prev.process != next.process || !machine.pierce(layer).active() {
            continue;
        }
        let (from, to) = (prev.end(), next.start());
        let length = (to - from).norm();
        if length > max || length < 1e-6 {
            continue;
        }
        let (a, b) = (groups.get(prev.geometry).copied(), groups.get(next.geometry).copied());
        let (Some(a), Some(b)) = (a, b) else { continue };
        if joined.find(a) == joined.find(b) || !pays(length, job.processes[next.process].speed, machine, layer) {
            continue;
        }
        let kerf = machine.layers.iter().find(|l| &l.name == layer).map_or(0.0, |l| l.kerf);
        let reach = kerf / 2.0 + CLEARANCE_MM;
        if !clear(from, to, reach, waste, &drawn) {
            continue;
        }
        joined.join(a, b);
        drawn.add(from, to);
        let next = &mut paths[i];
        next.points.insert(0, from);
        next.lead_in += 1;
        next.pierce = false;
        next.bridge = true;
        count.bridges += 1;
        count.pierces_saved += 1;
    }
    (sequence, count)
}

/// Whether cutting a bridge of `length` at `speed` (capped by the stage)
/// is faster than an air move of that length at the stage's limits and a
/// pierce.
fn pays(length: f64, speed: f64, machine: &MachineConfig, layer: &str) -> bool {
    let stage = &machine.stage;
    let cut = length / speed.min(stage.max_velocity);
    let (v, a) = (stage.max_velocity, stage.max_acceleration);
    // A move from rest to rest: a triangle of speed when too short to reach v.
    let air = if length < v * v / a { 2.0 * (length / a).sqrt() } else { length / v + v / a };
    cut < air + machine.pierce(layer).time
}

/// Whether the bridge `from`-`to` runs through the waste: its middle in the
/// waste, its inside (beyond `reach` of its ends) at `reach` from every
/// contour, and crossing no lead or bridge.
fn clear(from: Point, to: Point, reach: f64, waste: &Waste, drawn: &Drawn) -> bool {
    let length = (to - from).norm();
    if !waste.in_waste(nalgebra::center(&from, &to)) {
        return false;
    }
    if length > 2.0 * reach {
        let u = (to - from) / length;
        let (a, b) = (from + u * reach, to - u * reach);
        if waste.near(a, b, reach).next().is_some() || drawn.near(a, b, reach) {
            return false;
        }
    }
    // Near its ends it may touch the contours it joins, not cross them.
    !waste.near(from, to, 0.0).any(|(_, c, d, _)| crosses_inside(from, to, c, d)) && !drawn.crosses(from, to)
}

/// Whether segments `a`-`b` and `c`-`d` cross properly, away from `a` and `b`.
fn crosses_inside(a: Point, b: Point, c: Point, d: Point) -> bool {
    segment_crossing(a, b, c, d).is_some_and(|x| (x - a).norm() > 1e-6 && (x - b).norm() > 1e-6)
}

/// A drawn segment in the R-tree: its ends.
type Piece = GeomWithData<Rectangle<[f64; 2]>, (Point, Point)>;

/// Leads and bridges already drawn, piece by piece.
struct Drawn {
    tree: RTree<Piece>,
}

impl Drawn {
    fn add(&mut self, a: Point, b: Point) {
        self.tree.insert(GeomWithData::new(Rectangle::from_corners([a.x.min(b.x), a.y.min(b.y)], [a.x.max(b.x), a.y.max(b.y)]), (a, b)));
    }

    fn add_leads(&mut self, p: &PlannedPath) {
        for w in p.lead_in_points().windows(2).chain(p.lead_out_points().windows(2)) {
            self.add(w[0], w[1]);
        }
    }

    fn near(&self, a: Point, b: Point, reach: f64) -> bool {
        let query = AABB::from_corners([a.x.min(b.x) - reach, a.y.min(b.y) - reach], [a.x.max(b.x) + reach, a.y.max(b.y) + reach]);
        self.tree.locate_in_envelope_intersecting(query).any(|p| segment_distance(a, b, p.data.0, p.data.1) < reach)
    }

    fn crosses(&self, a: Point, b: Point) -> bool {
        let query = AABB::from_corners([a.x.min(b.x), a.y.min(b.y)], [a.x.max(b.x), a.y.max(b.y)]);
        self.tree.locate_in_envelope_intersecting(query).any(|p| crosses_inside(a, b, p.data.0, p.data.1))
    }
}

/// Disjoint sets of contour groups, joined by bridges.
struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    fn new(n: usize) -> UnionFind {
        UnionFind { parent: (0..n).collect() }
    }

    fn find(&mut self, mut k: usize) -> usize {
        while self.parent[k] != k {
            self.parent[k] = self.parent[self.parent[k]];
            k = self.parent[k];
        }
        k
    }

    fn join(&mut self, a: usize, b: usize) {
        let (a, b) = (self.find(a), self.find(b));
        self.parent[a.max(b)] = a.min(b);
    }
}
