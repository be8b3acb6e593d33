//! A job's [`Topology`] as an End-point Cutting Problem [`Instance`]: element
//! k of the instance is the topology's element k, contour k its contour k
//! (the job's geometry k); and a route (cuts of these elements) back to the
//! polylines to mark.

use super::{Cut, Element, Instance, Metric};
use crate::job::Point;
use crate::topology::Topology;

/// A job as a cutting problem: its topology and the instance made of it.
#[derive(Debug, Clone)]
pub struct CuttingModel {
    pub topology: Topology,
    /// Elements, contours, inner/outer pairs and common cuts of the topology;
    /// the depot as given, Euclidean distances.
    pub instance: Instance,
}

impl CuttingModel {
    /// The instance of `topology`, the route starting and ending at `depot`,
    /// each pierce costing `pierce_cost` (mm of air move).
    pub fn new(topology: Topology, depot: Point, pierce_cost: f64) -> CuttingModel {
        let elements = topology.elements.iter().map(|e| Element { a: e.start(), b: e.end() }).collect();
        let instance = Instance {
            elements,
            contours: topology.contours.clone(),
            inner_outer: topology.inner_outer(),
            depot,
            metric: Metric::Euclidean,
            pierce_cost,
        };
        CuttingModel { topology, instance }
    }

    /// A route (cuts of this model's elements) as polylines to mark, each with
    /// its geometry: cuts that go on exactly where the previous one ended, of a
    /// geometry they have in common, are one polyline (no pierce between
    /// them). A common cut is marked for either of its geometries, so it joins
    /// the polyline of whichever of its two contours it continues.
    pub fn polylines(&self, route: &[Cut]) -> Vec<(usize, Vec<Point>)> {
        let mut out: Vec<(usize, Vec<Point>)> = Vec::new();
        // The geometries the current polyline can still be marked for.
        let mut candidates: Vec<usize> = Vec::new();
        for &cut in route {
            let element = &self.topology.elements[cut.element];
            let mut points = element.points.clone();
            if cut.reversed {
                points.reverse();
            }
            let own = element.geometries();
            let common: Vec<usize> = candidates.iter().copied().filter(|g| own.contains(g)).collect();
            match out.last_mut() {
                Some((geometry, line)) if !common.is_empty() && line.last() == points.first() => {
                    line.extend_from_slice(&points[1..]);
                    *geometry = common[0];
                    candidates = common;
                }
                _ => {
                    out.push((own[0], points));
                    candidates = own;
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::checker;
    use crate::topology::tests::{job, length, p, rect, ring};
    use crate::topology::TopologyOptions;

    #[test]
    fn instance_elements_are_the_topology_elements_ends() {
        let j = job(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 0.0, 20.0, 10.0, "b"), rect(2.0, 2.0, 8.0, 8.0, "hole")]);
        let m = CuttingModel::new(Topology::build(&j, &TopologyOptions::default()).unwrap(), p(1.0, 2.0), 3.5);
        let (inst, topology) = (&m.instance, &m.topology);
        assert_eq!(inst.elements.len(), topology.elements.len());
        for (e, element) in inst.elements.iter().zip(&topology.elements) {
            assert_eq!((e.a, e.b), (element.start(), element.end()));
        }
        assert_eq!(inst.contours, topology.contours);
        assert_eq!(inst.inner_outer, vec![(2, 0)]);
        assert_eq!(inst.common_cuts(), topology.common_cuts);
        assert_eq!((inst.depot, inst.metric, inst.pierce_cost), (p(1.0, 2.0), Metric::Euclidean, 3.5));
    }

    #[test]
    fn route_polylines_merge_continuing_cuts() {
        let j = job(vec![rect(0.0, 0.0, 10.0, 10.0, "a"), rect(10.0, 0.0, 20.0, 10.0, "b")]);
        let topology = Topology::build(&j, &TopologyOptions::default()).unwrap();
        let cuts = |k: usize| -> Vec<Cut> { ring(&topology, &j, k).into_iter().map(|(element, reversed)| Cut { element, reversed }).collect() };
        let (a, b) = (cuts(0), cuts(1));
        let m = CuttingModel::new(topology, p(0.0, 0.0), 0.0);
        let shared = m.instance.common_cuts()[0].element;
        // The right part first, all round, its common cut (the left part's
        // piece) included; then the rest of the left part, from where the
        // common cut left it.
        let at = a.iter().position(|c| c.element == shared).unwrap();
        let rest_of_a: Vec<Cut> = (1..4).map(|s| a[(at + s) % 4]).collect();
        let route: Vec<Cut> = b.iter().chain(&rest_of_a).copied().collect();
        assert_eq!(checker::check(&m.instance, &route), vec![]);
        let lines = m.polylines(&route);
        assert_eq!(lines.len(), 2);
        assert_eq!((lines[0].0, lines[0].1.len()), (1, 5));
        assert_eq!(lines[0].1[0], lines[0].1[4], "the right part closes");
        assert_eq!((lines[1].0, lines[1].1.len()), (0, 4));
        assert!((length(&lines[0].1) + length(&lines[1].1) - 70.0).abs() < 1e-9);
        // The left part first: one closed polyline; the right part's rest starts
        // where the common cut ended, which is not where the left part ended.
        let at = b.iter().position(|c| c.element == shared).unwrap();
        let route: Vec<Cut> = a.iter().copied().chain((1..4).map(|s| b[(at + s) % 4])).collect();
        let lines = m.polylines(&route);
        assert_eq!(lines.iter().map(|(g, l)| (*g, l.len())).collect::<Vec<_>>(), vec![(0, 5), (1, 4)]);
        // A cut against the direction of the one before: a new polyline.
        let flipped = [a[0], Cut { reversed: !a[1].reversed, ..a[1] }];
        assert_eq!(m.polylines(&flipped).len(), 2);
        // The common cut alone, then the right part's next edge: the polyline
        // is the right part's.
        let at = b.iter().position(|c| c.element == shared).unwrap();
        let lines = m.polylines(&[b[at], b[(at + 1) % 4]]);
        assert_eq!(lines.iter().map(|(g, l)| (*g, l.len())).collect::<Vec<_>>(), vec![(1, 3)]);
    }
}
