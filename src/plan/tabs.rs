//! Tabs (micro-joints, `[[layer]] tabs`, `tab_spacing`, `tab_width`): short
//! pieces of a part's outline left uncut, so that the part stays in the sheet
//! until it is broken out by hand. Tabs go on part outlines (the even levels
//! of the cutting contours), evenly along them, slid off corners; holes get
//! none (their slugs should fall).
//!
//! A tabbed part does not fall when its outline is cut, so the precedence
//! rules that keep its holes before its outline do not bind
//! ([`held`]): the cutting planner and the checker both drop them. After
//! the order is found (and the leads added), each tab is cut out of the path
//! that runs over it ([`cut_tabs`]); the cut starts again past it with a
//! pierce.

use super::{PlannedPath, Sequence};
use crate::config::MachineConfig;
use crate::error::{Error, Result};
use crate::job::{lengths_along, piece_along, point_along, Job, Point};

/// One tab: the middle of the uncut piece, on its outline, and its length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tab {
    pub centre: Point,
    pub width: f64,
}

/// Per geometry of `job`: the tabs on it (none but on the part outlines of
/// layers with tabs). Errors naming the part and the setting where the tabs
/// would leave less than half of the outline cut.
pub fn place(job: &Job, machine: &MachineConfig) -> Result<Vec<Vec<Tab>>> {
    let layer = |process: usize| machine.layer(&job.processes[process].layer);
    let wanted = |process: usize| layer(process).is_some_and(|l| l.tabs > 0 || l.tab_spacing > 0.0);
    if !job.geometries.iter().any(|g| g.closed && wanted(g.process)) {
        return Ok(vec![Vec::new(); job.geometries.len()]);
    }
    let cuts: Vec<bool> = job.processes.iter().map(|p| machine.cuts_parts(&p.layer)).collect();
    let levels = crate::topology::part_levels(job, &cuts)?;
    let corner_cos = machine.cutting.corner_angle.to_radians().cos();
    job.geometries
        .iter()
        .enumerate()
        .map(|(k, g)| {
            let Some(l) = layer(g.process).filter(|_| wanted(g.process) && levels[k].is_some_and(|v| v.is_multiple_of(2))) else { return Ok(Vec::new()) };
            let mut ring = g.points.clone();
            ring.push(g.points[0]);
            let along = lengths_along(&ring);
            let length = along[along.len() - 1];
            let count = if l.tab_spacing > 0.0 { ((length / l.tab_spacing).floor() as usize).max(1) } else { l.tabs as usize };
            if count as f64 * l.tab_width >= length / 2.0 {
                return Err(Error::Plan(format!(
                    "{}: {count} tab(s) of {} mm (layer '{}': tabs or tab_spacing, tab_width) would leave less than half of its {length:.3} mm outline cut",
                    g.source, l.tab_width, l.name
                )));
            }
            let corners = corners_along(&ring, &along, corner_cos);
            Ok((0..count)
                .map(|i| {
                    let spacing = length / count as f64;
                    let at = slide_off_corners((i as f64 + 0.5) * spacing, l.tab_width, spacing / 2.0, &corners, length);
                    Tab { centre: point_along(&ring, &along, at), width: l.tab_width }
                })
                .collect())
        })
        .collect()
}

/// Per geometry: whether it is held in the sheet by tabs.
pub fn held(tabs: &[Vec<Tab>]) -> Vec<bool> {
    tabs.iter().map(|t| !t.is_empty()).collect()
}

/// `sequence` with every tab cut out of the paths that run over it, and how
/// many tabs were (one where two pieces of a cut meet counts once). `on_cut` (mm): how near a path must pass a tab's centre to
/// run over it (the common-cut tolerance).
pub fn cut_tabs(sequence: Sequence, tabs: &[Vec<Tab>], on_cut: f64) -> (Sequence, usize) {
    let all: Vec<Tab> = tabs.iter().flatten().copied().collect();
    if all.is_empty() {
        return (sequence, 0);
    }
    let mut hit = vec![false; all.len()];
    let groups = sequence
        .groups
        .into_iter()
        .map(|mut group| {
            group.paths = group
                .paths
                .into_iter()
                .flat_map(|path| {
                    let (pieces, cut) = split_at_tabs(path, &all, on_cut);
                    cut.into_iter().for_each(|t| hit[t] = true);
                    pieces
                })
                .collect();
            group
        })
        .collect();
    (Sequence { groups }, hit.iter().filter(|&&h| h).count())
}

/// A path cut where it runs over tabs: its pieces, and which tabs.
fn split_at_tabs(path: PlannedPath, tabs: &[Tab], on_cut: f64) -> (Vec<PlannedPath>, Vec<usize>) {
    let n = path.points.len();
    let along = lengths_along(&path.points);
    // The contour's own part, between the leads.
    let (from, to) = (along[path.lead_in], along[n - 1 - path.lead_out]);
    let mut windows: Vec<(f64, f64)> = Vec::new();
    let mut cut = Vec::new();
    for (k, tab) in tabs.iter().enumerate() {
        let hit = (path.lead_in..n - 1 - path.lead_out).find_map(|i| {
            let (a, b) = (path.points[i], path.points[i + 1]);
            let v = b - a;
            let t = if v.norm_squared() > 0.0 { ((tab.centre - a).dot(&v) / v.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
            ((a + v * t - tab.centre).norm() <= on_cut).then(|| along[i] + t * v.norm())
        });
        if let Some(s) = hit {
            windows.push(((s - tab.width / 2.0).max(from), (s + tab.width / 2.0).min(to)));
            cut.push(k);
        }
    }
    if windows.is_empty() {
        return (vec![path], cut);
    }
    windows.sort_by(|a, b| a.0.total_cmp(&b.0));
    // The pieces between the windows: the first keeps the lead-in, the last the lead-out.
    let mut bounds = vec![0.0];
    for (a, b) in &windows {
        bounds.push(*a);
        bounds.push(*b);
    }
    bounds.push(along[n - 1]);
    let last = bounds.len() / 2 - 1;
    let pieces = bounds
        .chunks(2)
        .enumerate()
        .filter(|(_, w)| w[1] - w[0] > 1e-9)
        .map(|(j, w)| {
            let points = piece_along(&path.points, &along, w[0], w[1]);
            let lead_in = if j == 0 { path.lead_in } else { 0 };
            let lead_out = if j == last { path.lead_out } else { 0 };
            PlannedPath { points, pierce: if j == 0 { path.pierce } else { true }, lead_in, lead_out, bridge: j == 0 && path.bridge, cooling_wait: if j == 0 { path.cooling_wait } else { 0.0 }, ..path.clone() }
        })
        .collect();
    (pieces, cut)
}

/// Distances along a closed ring to its corners (turns sharper than the
/// corner angle).
fn corners_along(ring: &[Point], along: &[f64], corner_cos: f64) -> Vec<f64> {
    let n = ring.len() - 1;
    (0..n)
        .filter(|&i| {
            let (p, q, r) = (ring[(i + n - 1) % n], ring[i], ring[(i + 1) % n]);
            let (u, v) = (q - p, r - q);
            u.norm() > 0.0 && v.norm() > 0.0 && u.dot(&v) / (u.norm() * v.norm()) < corner_cos
        })
        .map(|i| along[i])
        .collect()
}

/// `at`, or the nearest place within `room` of it whose tab (of `width`)
/// keeps clear of every corner, on a ring of `length`.
fn slide_off_corners(at: f64, width: f64, room: f64, corners: &[f64], length: f64) -> f64 {
    let clear = |s: f64| {
        corners.iter().all(|&c| {
            let d = (s - c).rem_euclid(length);
            d.min(length - d) > width
        })
    };
    let step = width / 4.0;
    (0..)
        .map(|k| k as f64 * step)
        .take_while(|&d| d <= room)
        .flat_map(|d| [at + d, at - d])
        .find(|&s| clear(s))
        .map_or(at, |s| s.rem_euclid(length))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::PathGroup;

    #[test]
    fn a_tab_is_cut_out_of_the_path_that_runs_over_it_and_the_cut_goes_on_past_it() {
        let square: Vec<Point> = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0), (0.0, 0.0)].iter().map(|&(x, y)| Point::new(x, y)).collect();
        let path = PlannedPath::new(0, square, 0, true);
        let tabs = vec![vec![Tab { centre: Point::new(5.0, 0.0), width: 1.0 }, Tab { centre: Point::new(0.0, 5.0), width: 1.0 }]];
        let (cut, count) = cut_tabs(Sequence { groups: vec![PathGroup { field_center: None, paths: vec![path] }] }, &tabs, 0.01);
        assert_eq!(count, 2);
        let paths: Vec<_> = cut.paths().collect();
        assert_eq!(paths.len(), 3);
        assert_eq!(paths[0].points, vec![Point::new(0.0, 0.0), Point::new(4.5, 0.0)]);
        assert_eq!(paths[1].points[0], Point::new(5.5, 0.0));
        assert!(paths[1].pierce, "the cut starts again past a tab");
        assert!((paths[2].points[0] - Point::new(0.0, 4.5)).norm() < 1e-12 && paths[2].points.len() == 2);
        let length: f64 = paths.iter().map(|p| lengths_along(&p.points).last().copied().unwrap()).sum();
        assert!((length - 38.0).abs() < 1e-9, "{length}");
    }

    #[test]
    fn tabs_slide_off_corners() {
        let corners = [0.0, 10.0, 20.0, 30.0];
        let at = slide_off_corners(10.2, 0.5, 5.0, &corners, 40.0);
        assert!((at - 10.0).abs() > 0.5 && (at - 10.2).abs() <= 0.5, "{at}");
    }
}
