//! A job's [`Topology`] as an End-point Cutting Problem [`Instance`]: element
//! k of the instance is the topology's element k, contour k its contour k
//! (the job's geometry k); and a route (cuts of these elements) back to the
//! polylines to mark.

use std::collections::HashMap;

use super::{Cut, Element, Instance, Metric};
use crate::error::{Error, Result};
use crate::job::{Job, Point};
use crate::topology::plate::PlateLayout;
use crate::topology::{Topology, TopologyOptions};

/// A job as a cutting problem: its topology and the instance made of it.
#[derive(Debug, Clone)]
pub struct CuttingModel {
    pub topology: Topology,
    /// Elements, contours, inner/outer pairs and common cuts of the topology;
    /// the depot as given, Euclidean distances.
    pub instance: Instance,
    /// Per instance element: its topology element (the same index without a
    /// plate; with one, the elements on the plate's edge are not cut).
    pub element_of: Vec<usize>,
    /// Per topology element: the job geometries it is marked for (its own,
    /// and the other part of a common cut); none when it is not cut.
    marked_for: Vec<Vec<usize>>,
    /// Per topology element: its length when it lies on the plate's edge
    /// and belongs to a part (what is not cut), else 0.
    edge_saved: Vec<f64>,
}

/// A piece of the route to mark: cut from one start to the next.
#[derive(Debug, Clone, PartialEq)]
pub struct Polyline {
    pub geometry: usize,
    pub points: Vec<Point>,
    /// It starts with a pierce: not where the previous one ended, nor on
    /// the plate's edge.
    pub pierce: bool,
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
            edge_starts: Vec::new(),
            turns: super::Turns::default(),
            penalties: Default::default(),
        };
        let n = topology.elements.len();
        CuttingModel {
            element_of: (0..n).collect(),
            marked_for: topology.elements.iter().map(|e| e.geometries()).collect(),
            edge_saved: vec![0.0; n],
            topology,
            instance,
        }
    }

    /// The instance of `job` (laid out by `plate`) on its plate: the
    /// topology of its parts and the plate's regions, without the elements
    /// on the plate's edge (already cut) and without the rules of fixed
    /// regions (nothing waits for them, nor they for anything); cuts
    /// starting on the edge need no pierce. A region's own
    /// elements are the skeleton and remnant cuts, the job's geometries from
    /// `plate.first_cut` on (after the parts when `plate.scrap_after`).
    pub fn with_plate(job: &Job, plate: &PlateLayout, process: usize, depot: Point, pierce_cost: f64, options: &TopologyOptions) -> Result<CuttingModel> {
        let topology = Topology::build(&plate.topology_job(job, process), options)?;
        let first = plate.first_cut;
        // The cut geometries by their end points (the same elements the
        // layout made them of).
        let key = |a: Point, b: Point| (a.x.to_bits(), a.y.to_bits(), b.x.to_bits(), b.y.to_bits());
        let cut_of: HashMap<_, usize> = (first..job.geometries.len())
            .map(|g| {
                let points = &job.geometries[g].points;
                (key(points[0], points[points.len() - 1]), g)
            })
            .collect();
        let m = topology.elements.len();
        let mut marked_for = Vec::with_capacity(m);
        let mut uncut = Vec::with_capacity(m);
        let mut edge_saved = vec![0.0; m];
        for (i, e) in topology.elements.iter().enumerate() {
            let on_edge = plate.along_edge(&e.points);
            let geometries: Vec<usize> = if e.geometry < first {
                e.geometries().into_iter().filter(|&g| g < first).collect()
            } else if plate.uncut(e) {
                Vec::new()
            } else {
                let g = cut_of.get(&key(e.start(), e.end())).copied();
                vec![g.ok_or_else(|| Error::Plan(format!("plate: a piece of waste at ({:.3}, {:.3}) is no skeleton or remnant cut", e.start().x, e.start().y)))?]
            };
            if on_edge && e.geometry < first {
                edge_saved[i] = e.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
            }
            uncut.push(plate.uncut(e));
            marked_for.push(geometries);
        }
        let fixed: Vec<bool> = (0..topology.contours.len()).map(|c| plate.is_fixed(c)).collect();
        let element_of: Vec<usize> = (0..m).filter(|&e| !uncut[e]).collect();
        let mut index = vec![usize::MAX; m];
        for (i, &e) in element_of.iter().enumerate() {
            index[e] = i;
        }
        let mut owners: Vec<Vec<usize>> = vec![Vec::new(); m];
        for (c, contour) in topology.contours.iter().enumerate() {
            for &e in contour {
                owners[e].push(c);
            }
        }
        // A fixed region keeps only the elements no one else has (so that
        // each is cut as part of some contour) and shares none: no rule.
        let keeps = |c: usize, e: usize| !fixed[c] || owners[e].iter().all(|&o| fixed[o] && o >= c);
        let contours: Vec<Vec<usize>> = topology
            .contours
            .iter()
            .enumerate()
            .map(|(c, contour)| contour.iter().filter(|&&e| !uncut[e] && keeps(c, e)).map(|&e| index[e]).collect())
            .collect();
        let inner_outer = topology
            .inner_outer()
            .into_iter()
            .filter(|&(inner, outer)| !fixed[outer] && !fixed[inner] && !contours[outer].is_empty() && !contours[inner].is_empty())
            .collect();
        let elements = element_of.iter().map(|&e| Element { a: topology.elements[e].start(), b: topology.elements[e].end() }).collect();
        let edge_starts = element_of.iter().map(|&e| [plate.on_edge(topology.elements[e].start()), plate.on_edge(topology.elements[e].end())]).collect();
        let instance = Instance { elements, contours, inner_outer, depot, metric: Metric::Euclidean, pierce_cost, edge_starts, turns: super::Turns::default(), penalties: Default::default() };
        Ok(CuttingModel { topology, instance, element_of, marked_for, edge_saved })
    }

    /// Charges `cost` (mm of air move) for going on through a turn sharper
    /// than `corner_angle` (degrees): the headings of each element's ends.
    pub fn charge_sharp_turns(&mut self, cost: f64, corner_angle: f64) {
        if cost <= 0.0 {
            return;
        }
        let unit = |d: nalgebra::Vector2<f64>| d.try_normalize(1e-12).unwrap_or_else(nalgebra::Vector2::zeros);
        let headings = self
            .element_of
            .iter()
            .map(|&e| {
                let p = &self.topology.elements[e].points;
                match p.len() {
                    0 | 1 => [nalgebra::Vector2::zeros(); 2],
                    n => [unit(p[1] - p[0]), unit(p[n - 1] - p[n - 2])],
                }
            })
            .collect();
        self.instance.turns = super::Turns { headings, cost, cos_sharp: corner_angle.to_radians().cos() };
    }

    /// The length of the parts' outlines lying on the plate's edge, not cut.
    pub fn edge_length_saved(&self) -> f64 {
        self.edge_saved.iter().sum()
    }

    /// A route (cuts of this model's instance elements) as polylines to
    /// mark, each with its geometry: cuts that go on exactly where the
    /// previous one ended, of a geometry they have in common, are one
    /// polyline. A common cut is marked for either of its geometries, so it
    /// joins the polyline of whichever of its two contours it continues.
    pub fn polylines(&self, route: &[Cut]) -> Vec<Polyline> {
        self.polylines_from(route).0
    }

    /// [`Self::polylines`], and where in `route` each starts.
    pub fn polylines_from(&self, route: &[Cut]) -> (Vec<Polyline>, Vec<usize>) {
        let mut out: Vec<Polyline> = Vec::new();
        let mut starts = Vec::new();
        // The geometries the current polyline can still be marked for.
        let mut candidates: Vec<usize> = Vec::new();
        for (k, &cut) in route.iter().enumerate() {
            let e = self.element_of[cut.element];
            let mut points = self.topology.elements[e].points.clone();
            if cut.reversed {
                points.reverse();
            }
            let own = &self.marked_for[e];
            let common: Vec<usize> = candidates.iter().copied().filter(|g| own.contains(g)).collect();
            let here = out.last().map(|l| l.points[l.points.len() - 1]);
            match out.last_mut() {
                Some(line) if !common.is_empty() && here == points.first().copied() => {
                    line.points.extend_from_slice(&points[1..]);
                    line.geometry = common[0];
                    candidates = common;
                }
                _ => {
                    // No pierce where the cut before ended (the kerf is
                    // there) or on the plate's edge.
                    let pierce = here != points.first().copied() && !self.instance.starts_on_edge(cut);
                    out.push(Polyline { geometry: own[0], points, pierce });
                    starts.push(k);
                    candidates = own.clone();
                }
            }
        }
        (out, starts)
    }

    /// The route as topology elements, for the plate's checker.
    pub fn topology_route(&self, route: &[Cut]) -> Vec<Cut> {
        route.iter().map(|c| Cut { element: self.element_of[c.element], ..*c }).collect()
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
        assert_eq!((lines[0].geometry, lines[0].points.len()), (1, 5));
        assert_eq!(lines[0].points[0], lines[0].points[4], "the right part closes");
        assert_eq!((lines[1].geometry, lines[1].points.len()), (0, 4));
        assert!((length(&lines[0].points) + length(&lines[1].points) - 70.0).abs() < 1e-9);
        // A pierce wherever a polyline does not start where the one before ended.
        let pierces_right = |lines: &[Polyline]| {
            lines.iter().enumerate().all(|(i, l)| l.pierce == (i == 0 || lines[i - 1].points.last() != l.points.first()))
        };
        assert!(pierces_right(&lines), "{lines:?}");
        // The left part first: one closed polyline; the right part's rest starts
        // where the common cut ended, which is not where the left part ended.
        let at = b.iter().position(|c| c.element == shared).unwrap();
        let route: Vec<Cut> = a.iter().copied().chain((1..4).map(|s| b[(at + s) % 4])).collect();
        let lines = m.polylines(&route);
        assert_eq!(lines.iter().map(|l| (l.geometry, l.points.len())).collect::<Vec<_>>(), vec![(0, 5), (1, 4)]);
        assert!(pierces_right(&lines), "{lines:?}");
        // The right part's rest, then the left part from the corner where it ended.
        let at_a = a.iter().position(|c| c.element == shared).unwrap();
        let rest_of_b: Vec<Cut> = (1..4).map(|s| b[(at + s) % 4]).collect();
        let end = m.instance.ends(*rest_of_b.last().unwrap()).1;
        let from_there: Vec<Cut> = (0..4).map(|s| a[(at_a + s) % 4]).collect();
        let k = (0..4).find(|&s| m.instance.ends(from_there[s]).0 == end).map(|s| from_there[s..].iter().chain(&from_there[..s]).copied().collect::<Vec<_>>());
        let a_from_end = k.expect("the left part has a corner where the right part's rest ends");
        let lines = m.polylines(&rest_of_b.iter().chain(&a_from_end).copied().collect::<Vec<_>>());
        assert!(!lines[1].pierce && pierces_right(&lines), "the left part starts where the right one's cut ended: {lines:?}");
        // A cut against the direction of the one before: a new polyline.
        let flipped = [a[0], Cut { reversed: !a[1].reversed, ..a[1] }];
        assert_eq!(m.polylines(&flipped).len(), 2);
        // The common cut alone, then the right part's next edge: the polyline
        // is the right part's.
        let at = b.iter().position(|c| c.element == shared).unwrap();
        let lines = m.polylines(&[b[at], b[(at + 1) % 4]]);
        assert_eq!(lines.iter().map(|l| (l.geometry, l.points.len())).collect::<Vec<_>>(), vec![(1, 3)]);
    }

    fn plate_config(width: f64, height: f64, skeleton_piece: f64) -> crate::config::PlateConfig {
        crate::config::PlateConfig { skeleton_piece, ..crate::topology::plate::tests::plate(width, height) }
    }

    #[test]
    fn on_a_plate_edge_elements_are_not_cut_and_cuts_from_the_edge_do_not_pierce() {
        use crate::topology::plate::lay_out;
        let options = TopologyOptions::default();
        // A 40 x 20 part in the lower-left corner and a free 10 x 10 one.
        let j = job(vec![rect(0.0, 0.0, 40.0, 20.0, "corner"), rect(60.0, 60.0, 70.0, 70.0, "free")]);
        let (laid, plate) = lay_out(&j, &[true, true], &plate_config(200.0, 100.0, 0.0), 0, &options).unwrap();
        let m = CuttingModel::with_plate(&laid, &plate, 0, p(0.0, 0.0), 10.0, &options).unwrap();
        assert_eq!(m.instance.elements.len(), 2 + 4, "the corner part's two inner sides and the free part");
        assert!((m.edge_length_saved() - 60.0).abs() < 1e-9);
        // The corner part: its right side starts on the bottom edge, its top
        // ends on the left one.
        let corner = &m.instance.contours[0];
        let edge_ends: usize = corner.iter().map(|&e| m.instance.edge_starts[e].iter().filter(|&&b| b).count()).sum();
        assert_eq!(edge_ends, 2);
        let route = crate::plan::ecp::construct::construct(&m.instance);
        assert_eq!(checker::check_plate(&m.topology, &plate, &m.topology_route(&route), &[]), vec![]);
        let lines = m.polylines(&route);
        let pierced = lines.iter().filter(|l| l.pierce).count();
        assert!(lines.iter().any(|l| !l.pierce && plate.on_edge(l.points[0])), "the corner part is cut from the edge");
        assert_eq!(pierced, 1, "only the free part pierces: {lines:?}");
        // Cutting an edge element, or leaving a cut out, breaks the count.
        let mut bad = m.topology_route(&route);
        bad.pop();
        assert!(!checker::check_plate(&m.topology, &plate, &bad, &[]).is_empty());
    }

    #[test]
    fn a_skeleton_piece_holds_its_parts_unless_clamped() {
        use crate::topology::plate::lay_out;
        let options = TopologyOptions::default();
        // Two 20 x 20 parts on a 200 x 100 plate cut in two by a skeleton cut
        // at x = 100; the larger left piece is fixed (no clamps).
        let j = job(vec![rect(20.0, 40.0, 40.0, 60.0, "left"), rect(150.0, 40.0, 170.0, 60.0, "right")]);
        let (laid, plate) = lay_out(&j, &[true, true], &plate_config(200.0, 100.0, 100.0), 0, &options).unwrap();
        assert_eq!(plate.skeleton_cuts, 1);
        assert_eq!(laid.geometries[2].points.iter().map(|q| q.x).collect::<Vec<_>>(), vec![100.0, 100.0]);
        let m = CuttingModel::with_plate(&laid, &plate, 0, p(0.0, 0.0), 10.0, &options).unwrap();
        let pieces: Vec<usize> = (2..m.topology.contours.len()).collect();
        let free_piece = *pieces.iter().find(|&&c| !plate.is_fixed(c)).unwrap();
        assert!(m.instance.inner_outer.contains(&(1, free_piece)) || m.instance.inner_outer.contains(&(0, free_piece)));
        // The skeleton cut first, then the part inside the piece it frees: broken.
        let cut = m.element_of.iter().position(|&e| m.topology.elements[e].geometry >= 2).unwrap();
        let inside = m.instance.inner_outer.iter().find(|&&(_, o)| o == free_piece).unwrap().0;
        let mut route = vec![Cut { element: cut, reversed: false }];
        for other in 0..m.instance.contours.len() {
            if other != inside {
                route.extend(m.instance.contours[other].iter().filter(|&&e| e != cut).map(|&element| Cut { element, reversed: false }));
            }
        }
        route.extend(m.instance.contours[inside].iter().map(|&element| Cut { element, reversed: false }));
        let broken = checker::check_plate(&m.topology, &plate, &m.topology_route(&route), &[]);
        assert!(broken.iter().any(|v| matches!(v, checker::Violation::InnerAfterOuter { outer, .. } if *outer == free_piece)), "{broken:?}");
        assert_eq!(checker::check(&m.instance, &route).is_empty(), broken.is_empty(), "the instance has the same rules");
        // Clamped on both sides, nothing waits for the pieces.
        let mut clamped = plate_config(200.0, 100.0, 100.0);
        clamped.clamps = vec![crate::config::ClampConfig { x: 0.0, y: 50.0, radius: 5.0 }, crate::config::ClampConfig { x: 200.0, y: 50.0, radius: 5.0 }];
        let (laid, plate) = lay_out(&j, &[true, true], &clamped, 0, &options).unwrap();
        let m = CuttingModel::with_plate(&laid, &plate, 0, p(0.0, 0.0), 10.0, &options).unwrap();
        assert!(m.instance.inner_outer.is_empty() && m.instance.common_cuts().is_empty());
        assert_eq!(checker::check_plate(&m.topology, &plate, &m.topology_route(&route), &[]), vec![]);
    }

    #[test]
    fn an_area_closed_off_by_a_part_and_the_edge_waits_for_what_lies_in_it() {
        use crate::topology::plate::lay_out;
        use crate::topology::tests::shape;
        let options = TopologyOptions::default();
        // An arch standing on the bottom edge (seed 000's Figure 1): legs
        // 10 mm wide, 40 mm apart, 40 mm high; a 10 x 10 part under it.
        let arch = shape(
            &[(20.0, 0.0), (30.0, 0.0), (30.0, 40.0), (70.0, 40.0), (70.0, 0.0), (80.0, 0.0), (80.0, 50.0), (20.0, 50.0)],
            true,
            "arch",
        );
        let j = job(vec![arch, rect(45.0, 10.0, 55.0, 20.0, "under")]);
        let (laid, plate) = lay_out(&j, &[true, true], &plate_config(200.0, 100.0, 0.0), 0, &options).unwrap();
        assert_eq!(laid.geometries.len(), 2, "no skeleton: nothing to add");
        assert_eq!(plate.faces.len(), 2, "the plate around the arch, and the area under it");
        let m = CuttingModel::with_plate(&laid, &plate, 0, p(0.0, 0.0), 10.0, &options).unwrap();
        let under = (2..4).find(|&c| !plate.is_fixed(c)).expect("the area under the arch is not fixed");
        assert!(m.instance.inner_outer.contains(&(1, under)), "{:?}", m.instance.inner_outer);
        // The arch's three inner sides close the area: common cuts with it.
        let shared: Vec<usize> = m.instance.common_cuts().iter().filter(|c| c.contours == (0, under)).map(|c| c.element).collect();
        assert_eq!(shared.len(), 3);
        assert!((m.edge_length_saved() - 20.0).abs() < 1e-9, "the legs' feet");
        // Arch first (its inner sides last of all), then the part under it:
        // the part is cut after its area fell, and a common cut closed both.
        let arch_first: Vec<Cut> = m.instance.contours[0]
            .iter()
            .filter(|e| !shared.contains(e))
            .chain(&shared)
            .chain(&m.instance.contours[1])
            .map(|&element| Cut { element, reversed: false })
            .collect();
        let broken = checker::check_plate(&m.topology, &plate, &m.topology_route(&arch_first), &[]);
        assert!(broken.iter().any(|v| matches!(v, checker::Violation::InnerAfterOuter { inner: 1, .. })), "{broken:?}");
        assert!(broken.iter().any(|v| matches!(v, checker::Violation::ClosesBoth { .. })), "{broken:?}");
        // The search's route keeps both rules.
        let route = crate::plan::ecp::construct::construct(&m.instance);
        assert_eq!(checker::check_plate(&m.topology, &plate, &m.topology_route(&route), &[]), vec![]);
    }
}
