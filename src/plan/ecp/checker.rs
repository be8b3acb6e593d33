//! The independent feasibility checker: written from the rules alone (see the
//! module above), sharing nothing with the search but the instance, so a
//! planner's bug cannot hide in it. Used by tests and by `bench ecp`.

use super::{Cut, Instance};
use crate::topology::plate::PlateLayout;
use crate::topology::Topology;

/// What is wrong with a route, one entry per broken rule.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Violation {
    /// An element that is not cut at all, or cut more than once.
    CutCount { element: usize, times: usize },
    /// An element index that does not exist.
    UnknownElement { element: usize },
    /// An element of `inner` is cut after `outer` closed (or as it closes it).
    InnerAfterOuter { inner: usize, outer: usize },
    /// A common cut that closes both of its contours.
    ClosesBoth { element: usize, contours: (usize, usize) },
}

/// Each element's position in `route`, and the route's unknown elements and
/// elements not cut as often as `wanted` says (once, or never).
fn positions(route: &[Cut], wanted: &[usize]) -> (Vec<Option<usize>>, Vec<Violation>) {
    let n = wanted.len();
    let mut violations = Vec::new();
    let mut position = vec![None; n];
    let mut times = vec![0usize; n];
    for (i, c) in route.iter().enumerate() {
        if c.element >= n {
            violations.push(Violation::UnknownElement { element: c.element });
            continue;
        }
        times[c.element] += 1;
        position[c.element] = Some(i);
    }
    for (element, &t) in times.iter().enumerate() {
        if t != wanted[element] {
            violations.push(Violation::CutCount { element, times: t });
        }
    }
    (position, violations)
}

/// Every rule the route breaks (empty: feasible).
pub fn check(inst: &Instance, route: &[Cut]) -> Vec<Violation> {
    let (position, mut violations) = positions(route, &vec![1; inst.elements.len()]);
    if !violations.is_empty() {
        return violations;
    }
    let pos = |e: usize| position[e].unwrap_or(usize::MAX);
    // Where a contour closes: the position of its last element.
    let closes: Vec<usize> = inst.contours.iter().map(|c| c.iter().map(|&e| pos(e)).max().unwrap_or(0)).collect();
    for &(inner, outer) in &inst.inner_outer {
        if inst.contours[inner].iter().any(|&e| pos(e) >= closes[outer]) {
            violations.push(Violation::InnerAfterOuter { inner, outer });
        }
    }
    for cc in inst.common_cuts() {
        let (a, b) = cc.contours;
        if closes[a] == pos(cc.element) && closes[b] == pos(cc.element) {
            violations.push(Violation::ClosesBoth { element: cc.element, contours: cc.contours });
        }
    }
    violations
}

/// Every rule a route breaks on a plate, derived from the plate's topology
/// alone (seed 000's "removing complexity"): `topology` is the plate's
/// (`PlateLayout::topology_job`), `route` cuts its elements. Elements on the
/// plate's edge, and the regions' own ones when the plate's skeleton is cut
/// after the parts, count as cut before the route starts and must not be in
/// it; a contour closes at its last element cut; no rule binds a fixed
/// region (clamped, the remnant, the largest without clamps, all of them
/// when cut after the parts): neither what waits for it, nor it waiting
/// inside another, nor its common cuts. Nothing waits for a contour `held`
/// in the sheet by tabs either (per contour; missing: not held).
pub fn check_plate(topology: &Topology, plate: &PlateLayout, route: &[Cut], held: &[bool]) -> Vec<Violation> {
    let uncut: Vec<bool> = topology.elements.iter().map(|e| plate.uncut(e)).collect();
    let fixed: Vec<bool> = (0..topology.contours.len()).map(|c| plate.is_fixed(c)).collect();
    let (position, mut violations) = positions(route, &uncut.iter().map(|&u| usize::from(!u)).collect::<Vec<_>>());
    if !violations.is_empty() {
        return violations;
    }
    // Positions with the uncut elements before the route: -1.
    let pos = |e: usize| position[e].map_or(-1, |p| p as i64);
    let closes: Vec<i64> = topology.contours.iter().map(|c| c.iter().map(|&e| pos(e)).max().unwrap_or(-1)).collect();
    for (inner, outer) in topology.inner_outer() {
        if fixed[outer] || fixed[inner] || closes[outer] < 0 || held.get(outer).copied().unwrap_or(false) {
            continue;
        }
        if topology.contours[inner].iter().any(|&e| position[e].is_some() && pos(e) >= closes[outer]) {
            violations.push(Violation::InnerAfterOuter { inner, outer });
        }
    }
    for cc in &topology.common_cuts {
        let (a, b) = cc.contours;
        if fixed[a] || fixed[b] || uncut[cc.element] {
            continue;
        }
        if closes[a] == pos(cc.element) && closes[b] == pos(cc.element) {
            violations.push(Violation::ClosesBoth { element: cc.element, contours: cc.contours });
        }
    }
    violations
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::Point;
    use crate::plan::ecp::{Element, Metric};

    /// Two squares side by side sharing the edge 1 (a common cut), and a point
    /// element 7 inside the left square (contour 2, inner of contour 0).
    fn two_parts() -> Instance {
        let p = |x: f64, y: f64| Point::new(x, y);
        let seg = |a: Point, b: Point| Element { a, b };
        Instance {
            elements: vec![
                seg(p(0.0, 0.0), p(10.0, 0.0)),
                seg(p(10.0, 0.0), p(10.0, 10.0)),
                seg(p(10.0, 10.0), p(0.0, 10.0)),
                seg(p(0.0, 10.0), p(0.0, 0.0)),
                seg(p(10.0, 0.0), p(20.0, 0.0)),
                seg(p(20.0, 0.0), p(20.0, 10.0)),
                seg(p(20.0, 10.0), p(10.0, 10.0)),
                seg(p(5.0, 5.0), p(5.0, 5.0)),
            ],
            contours: vec![vec![0, 1, 2, 3], vec![4, 5, 6, 1], vec![7]],
            inner_outer: vec![(2, 0)],
            depot: p(0.0, 0.0),
            metric: Metric::Euclidean,
            pierce_cost: 0.0,
            edge_starts: Vec::new(),
            turns: crate::plan::ecp::Turns::default(),
            penalties: Default::default(),
        }
    }

    fn route(order: &[usize]) -> Vec<Cut> {
        order.iter().map(|&element| Cut { element, reversed: false }).collect()
    }

    #[test]
    fn finds_each_broken_rule() {
        let inst = two_parts();
        assert_eq!(inst.precedences(), 2);
        assert!(check(&inst, &route(&[7, 0, 2, 3, 1, 4, 5, 6])).is_empty());
        // The hole after its part closed.
        assert_eq!(check(&inst, &route(&[0, 2, 3, 1, 7, 4, 5, 6])), vec![Violation::InnerAfterOuter { inner: 2, outer: 0 }]);
        // The shared edge last of both squares.
        assert_eq!(
            check(&inst, &route(&[7, 0, 2, 3, 4, 5, 6, 1])),
            vec![Violation::ClosesBoth { element: 1, contours: (0, 1) }]
        );
        // Missing, repeated and unknown elements.
        let v = check(&inst, &route(&[7, 0, 0, 2, 3, 1, 4, 5, 9]));
        assert!(v.contains(&Violation::CutCount { element: 0, times: 2 }));
        assert!(v.contains(&Violation::CutCount { element: 6, times: 0 }));
        assert!(v.contains(&Violation::UnknownElement { element: 9 }));
    }
}
