//! Pieces that may tip (seed 000, collision avoidance): a closed contour of a
//! layer that cuts parts, smaller than twice the bed's support grid
//! (`[plate] support_grid`) in both directions, is no longer carried once its
//! whole outline has been cut: it may drop between the supports and tip, one
//! edge standing up. Parts held by tabs or a closing gap stay.
//!
//! Each path records the pieces it cuts free ([`PlannedPath::falls`]: the
//! path that cuts the last of a piece's outline, whichever geometry it
//! belongs to, as common cuts share outlines); motion lifts the head over them
//! from then on (`motion::lift`).

use rstar::primitives::GeomWithData;
use rstar::{RTree, AABB};

use super::Sequence;
use crate::config::MachineConfig;
use crate::job::{bounds_of, points_around, segment_distance, Geometry, Job};

/// Outline points are checked at most this far apart (mm).
const SAMPLE_SPACING: f64 = 1.0;

/// Whether geometry `g` of `job` is small enough to tip once cut free: a
/// closed contour of a layer that cuts parts, smaller than twice `grid` both
/// ways (the rule the figures' collision count uses too).
pub fn small(job: &Job, g: &Geometry, machine: &MachineConfig, grid: f64) -> bool {
    let (lo, hi) = bounds_of(g.points.iter());
    g.closed && g.points.len() >= 3 && machine.cuts_parts(&job.processes[g.process].layer) && (hi.x - lo.x).max(hi.y - lo.y) < 2.0 * grid
}

/// The geometries of `job` that may tip once cut free: `small`, not `held`
/// by tabs, and not on a layer whose closing gap keeps its parts in.
pub fn pieces(job: &Job, machine: &MachineConfig, grid: f64, held: &[bool]) -> Vec<usize> {
    let stays = |process: usize| machine.layers.iter().any(|l| l.name == job.processes[process].layer && l.closing_gap > 0.0);
    job.geometries
        .iter()
        .enumerate()
        .filter(|(k, g)| small(job, g, machine, grid) && !held.get(*k).copied().unwrap_or(false) && !stays(g.process))
        .map(|(k, _)| k)
        .collect()
}

/// `sequence` with each path's `falls` set: the pieces (`pieces` of `job`)
/// whose outline it finishes cutting, a cut within `on_cut` mm of every
/// point of it. A piece never cut whole falls nowhere.
pub fn mark_falls(job: &Job, mut sequence: Sequence, machine: &MachineConfig, pieces: &[usize], on_cut: f64) -> Sequence {
    if pieces.is_empty() {
        return sequence;
    }
    // Points along every piece's outline: (piece, sample).
    let mut owner = Vec::new();
    let mut points = Vec::new();
    for (i, &g) in pieces.iter().enumerate() {
        let around = points_around(&job.geometries[g].points, SAMPLE_SPACING);
        owner.extend(std::iter::repeat_n(i, around.len()));
        points.extend(around);
    }
    let tree = RTree::bulk_load(points.iter().enumerate().map(|(s, p)| GeomWithData::new([p.x, p.y], s)).collect());
    let mut cut_by: Vec<Option<usize>> = vec![None; points.len()];
    let cuts = |process: usize| machine.cuts_parts(&job.processes[process].layer);
    for (k, path) in sequence.paths().enumerate().filter(|(_, p)| cuts(p.process)) {
        for w in path.points.windows(2) {
            let (a, b) = (w[0], w[1]);
            let query = AABB::from_corners([a.x.min(b.x) - on_cut, a.y.min(b.y) - on_cut], [a.x.max(b.x) + on_cut, a.y.max(b.y) + on_cut]);
            for s in tree.locate_in_envelope_intersecting(query) {
                if cut_by[s.data].is_none() && segment_distance(points[s.data], points[s.data], a, b) <= on_cut {
                    cut_by[s.data] = Some(k);
                }
            }
        }
    }
    // Per piece: the path after which all of it is cut.
    let mut last: Vec<Option<usize>> = vec![Some(0); pieces.len()];
    for (s, by) in cut_by.iter().enumerate() {
        let i = owner[s];
        last[i] = match (last[i], by) {
            (Some(l), Some(k)) => Some(l.max(*k)),
            _ => None,
        };
    }
    let mut falls_at: Vec<Vec<usize>> = vec![Vec::new(); sequence.paths().count()];
    for (i, l) in last.iter().enumerate() {
        if let Some(k) = l {
            falls_at[*k].push(pieces[i]);
        }
    }
    let mut k = 0;
    for group in &mut sequence.groups {
        for path in &mut group.paths {
            path.falls = std::mem::take(&mut falls_at[k]);
            k += 1;
        }
    }
    sequence
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{Point, Process};
    use crate::plan::{PathGroup, PlannedPath};

    fn square(x: f64, size: f64) -> Vec<Point> {
        vec![Point::new(x, 0.0), Point::new(x + size, 0.0), Point::new(x + size, size), Point::new(x, size)]
    }

    fn cutter() -> MachineConfig {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/flatbed-cutter.toml")).unwrap();
        MachineConfig::parse(&text, "flatbed-cutter.toml").unwrap()
    }

    /// Small squares fall with the path that closes them, split or not; a
    /// large one is carried by the grid; an outline left open falls nowhere.
    #[test]
    fn a_small_piece_falls_with_the_path_that_finishes_its_outline() {
        let machine = cutter();
        let layer = machine.layers.iter().find(|l| machine.pierce(&l.name).active()).unwrap().name.clone();
        let outlines = [square(0.0, 10.0), square(20.0, 100.0), square(200.0, 10.0), square(300.0, 10.0)];
        let job = Job {
            source: "t".into(),
            geometries: outlines.iter().enumerate().map(|(k, o)| Geometry { arcs: Vec::new(), profile: Vec::new(), points: o.clone(), closed: true, process: 0, source: format!("g{k}") }).collect(),
            processes: vec![Process { layer, speed: 20.0, power: 1000.0, passes: 1, fill: false }],
        };
        let pieces = pieces(&job, &machine, 30.0, &[false; 4]);
        assert_eq!(pieces, vec![0, 2, 3], "the 100 mm square is carried by a 30 mm grid");
        let ring = |o: &[Point]| o.iter().chain(&o[..1]).copied().collect::<Vec<_>>();
        let r0 = ring(&outlines[0]);
        // g0 cut in two pieces (the second last), g1 whole, g2 whole, g3 with a side left.
        let paths = vec![
            PlannedPath::new(0, r0[..3].to_vec(), 0, true),
            PlannedPath::new(1, ring(&outlines[1]), 0, true),
            PlannedPath::new(0, r0[2..].to_vec(), 0, true),
            PlannedPath::new(2, ring(&outlines[2]), 0, true),
            PlannedPath::new(3, ring(&outlines[3])[..4].to_vec(), 0, true),
        ];
        let sequence = Sequence { groups: vec![PathGroup { field_center: None, paths }] };
        let marked = mark_falls(&job, sequence, &machine, &pieces, 1e-3);
        let falls: Vec<Vec<usize>> = marked.paths().map(|p| p.falls.clone()).collect();
        assert_eq!(falls, vec![vec![], vec![], vec![0], vec![2], vec![]]);
    }
}
