//! The moves every search of the route shares: a run of cuts moved elsewhere
//! in the route, kept or reversed. Or-opt (runs of 1 to 3), 2-opt (a run
//! reversed in place) and path-preserving 3-opt (two neighbouring stretches
//! swapped: the shorter one moved past the other) are all such moves.
//!
//! Move evaluation is where seed 001 lost its time. Here the cost change of a
//! move is O(1), and its feasibility is decided from the contours of the moved
//! run alone: moving a run changes only the order between the run and what it
//! jumps over, so precedences between other contours cannot change.
//! Positions after the move are computed, not applied.

use super::{Cut, Instance};

/// Precedence data indexed for the search.
pub(crate) struct Rules {
    /// Contours each element belongs to (one or two).
    pub(super) contours_of: Vec<Vec<usize>>,
    /// For each contour: the contours it lies inside, and those inside it.
    pub(super) outers: Vec<Vec<usize>>,
    pub(super) inners: Vec<Vec<usize>>,
    /// For each contour: its common cuts and the other contour of each.
    pub(super) shared: Vec<Vec<(usize, usize)>>,
}

impl Rules {
    pub(super) fn new(inst: &Instance) -> Rules {
        let (n, k) = (inst.elements.len(), inst.contours.len());
        let mut contours_of = vec![Vec::new(); n];
        for (c, contour) in inst.contours.iter().enumerate() {
            for &e in contour {
                contours_of[e].push(c);
            }
        }
        let mut outers = vec![Vec::new(); k];
        let mut inners = vec![Vec::new(); k];
        for &(i, o) in &inst.inner_outer {
            outers[i].push(o);
            inners[o].push(i);
        }
        let mut shared = vec![Vec::new(); k];
        for cc in inst.common_cuts() {
            shared[cc.contours.0].push((cc.element, cc.contours.1));
            shared[cc.contours.1].push((cc.element, cc.contours.0));
        }
        Rules { contours_of, outers, inners, shared }
    }
}

/// Cost of going from `a` to `b` (`None`: the depot).
pub(super) fn link(inst: &Instance, a: Option<Cut>, b: Option<Cut>) -> f64 {
    match (a, b) {
        (_, Some(b)) => inst.step(a, b),
        (Some(a), None) => inst.distance(inst.ends(a).1, inst.depot),
        (None, None) => 0.0,
    }
}

pub(super) fn flip(c: Cut) -> Cut {
    Cut { element: c.element, reversed: !c.reversed }
}

/// The route being improved, with every element's position.
pub(super) struct Tour {
    pub(super) cuts: Vec<Cut>,
    pub(super) pos: Vec<usize>,
}

impl Tour {
    pub(super) fn at(&self, i: isize) -> Option<Cut> {
        if i < 0 || i as usize >= self.cuts.len() {
            None
        } else {
            Some(self.cuts[i as usize])
        }
    }
}

/// A run `[from, from + len)` moved to stand before position `to` of the
/// route without it (`to` counts positions of the route with the run taken out),
/// reversed or not.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Move {
    pub(super) from: usize,
    pub(super) len: usize,
    pub(super) to: usize,
    pub(super) reverse: bool,
}

impl Move {
    /// Where element position `p` ends up.
    pub(super) fn new_pos(&self, p: usize) -> usize {
        let (s, l, t) = (self.from, self.len, self.to);
        if p >= s && p < s + l {
            let k = p - s;
            t + if self.reverse { l - 1 - k } else { k }
        } else {
            // Position in the route without the run, then after re-insertion.
            let q = if p >= s + l { p - l } else { p };
            if q >= t {
                q + l
            } else {
                q
            }
        }
    }
}

impl Move {
    /// The positions whose contours hold every rule the move can change.
    /// Only the order between the run and what it jumps over changes (and
    /// the run's own, reversed), so a rule changes only if it has an
    /// element in each: a run kept as it is may be judged by the shorter
    /// of the two (a long stretch moved a little way costs little).
    pub(super) fn judged(&self) -> std::ops::Range<usize> {
        let run = self.from..self.from + self.len;
        if self.reverse {
            return run;
        }
        let jumped = if self.to > self.from { self.from + self.len..self.to + self.len } else { self.to..self.from };
        if jumped.len() < run.len() {
            jumped
        } else {
            run
        }
    }
}

pub(super) fn feasible(inst: &Instance, rules: &Rules, tour: &Tour, mv: &Move) -> bool {
    let np = |e: usize| mv.new_pos(tour.pos[e]);
    let closes = |k: usize| inst.contours[k].iter().map(|&e| np(e)).max().unwrap_or(0);
    for i in mv.judged() {
        for &k in &rules.contours_of[tour.cuts[i].element] {
            let ck = closes(k);
            if rules.outers[k].iter().any(|&o| ck >= closes(o)) || rules.inners[k].iter().any(|&i| closes(i) >= ck) {
                return false;
            }
            if rules.shared[k].iter().any(|&(c, other)| np(c) == ck && np(c) == closes(other)) {
                return false;
            }
        }
    }
    true
}

/// Cost change of a move (negative: better).
pub(super) fn delta(inst: &Instance, tour: &Tour, mv: &Move) -> f64 {
    let (s, l) = (mv.from as isize, mv.len as isize);
    let first = tour.cuts[mv.from];
    let last = tour.cuts[mv.from + mv.len - 1];
    let before = tour.at(s - 1);
    let after = tour.at(s + l);
    let removal = link(inst, before, Some(first)) + link(inst, Some(last), after) - link(inst, before, after);
    // Neighbours at the target, in the route without the run.
    let without = |q: isize| if q < s { tour.at(q) } else { tour.at(q + l) };
    let (a, b) = (without(mv.to as isize - 1), without(mv.to as isize));
    // Both metrics are symmetric, and so is the pierce rule: a reversed run
    // costs inside what it cost before; except on a plate, where a cut
    // starting on its edge needs no pierce, so the run's inside is summed
    // (penalties are symmetric too).
    let (head, tail) = if mv.reverse { (flip(last), flip(first)) } else { (first, last) };
    let insertion = link(inst, a, Some(head)) + link(inst, Some(tail), b) - link(inst, a, b);
    let inside = if mv.reverse && !inst.edge_starts.is_empty() {
        let run = &tour.cuts[mv.from..mv.from + mv.len];
        run.windows(2).map(|w| inst.step(Some(flip(w[1])), flip(w[0])) - inst.step(Some(w[0]), w[1])).sum()
    } else {
        0.0
    };
    insertion - removal + inside
}

pub(super) fn apply(tour: &mut Tour, mv: &Move) {
    // Only the stretch between the run's old and new places moves: rotated
    // in place, in time proportional to it, not to the route.
    if mv.to > mv.from {
        tour.cuts[mv.from..mv.to + mv.len].rotate_left(mv.len);
    } else if mv.to < mv.from {
        tour.cuts[mv.to..mv.from + mv.len].rotate_right(mv.len);
    }
    if mv.reverse {
        let run = &mut tour.cuts[mv.to..mv.to + mv.len];
        run.reverse();
        run.iter_mut().for_each(|c| *c = flip(*c));
    }
    let lo = mv.from.min(mv.to);
    let hi = (mv.from + mv.len).max(mv.to + mv.len).min(tour.cuts.len());
    for i in lo..hi {
        tour.pos[tour.cuts[i].element] = i;
    }
}

/// Nearest elements of each element, nearest first, with the gap (the
/// shortest distance between their end points).
pub(super) struct Neighbours {
    pub lists: Vec<Vec<(usize, f64)>>,
}

impl Neighbours {
    /// From an R-tree of end points: an element's k nearest by gap are among
    /// the k nearest elements of either of its end points (an element nearer
    /// to that end point is nearer by gap too), so two walks of the tree
    /// find them, in O(n log n) for the whole instance.
    pub fn new(inst: &Instance, k: usize) -> Neighbours {
        let n = inst.elements.len();
        let tree = end_tree(inst);
        let k = k.min(n.saturating_sub(1));
        let lists = (0..n)
            .map(|x| {
                let el = &inst.elements[x];
                let mut found: Vec<usize> = Vec::with_capacity(2 * k);
                for end in [el.a, el.b] {
                    let mut distinct = 0;
                    for hit in tree.nearest_neighbor_iter([end.x, end.y]) {
                        if distinct == k {
                            break;
                        }
                        if hit.data != x && !found.contains(&hit.data) {
                            found.push(hit.data);
                            distinct += 1;
                        }
                    }
                }
                let mut near: Vec<(usize, f64)> = found.into_iter().map(|y| (y, gap(inst, x, y))).collect();
                near.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                near.truncate(k);
                near
            })
            .collect();
        Neighbours { lists }
    }

    /// [`Self::new`]'s `k` nearest, and also the `q` nearest elements in
    /// each quadrant around each end point: on clustered plates (a drilling
    /// job's rows of holes) the nearest all lie in the same row, and the
    /// links between rows the route needs would never be tried.
    pub fn with_quadrants(inst: &Instance, k: usize, q: usize) -> Neighbours {
        let mut near = Neighbours::new(inst, k);
        if q == 0 {
            return near;
        }
        let tree = end_tree(inst);
        for (x, list) in near.lists.iter_mut().enumerate() {
            let el = &inst.elements[x];
            // Local directions only: a link many times the local spacing is
            // one a good route makes rarely (between clusters of parts), and
            // offered at every end it made the thermal search's cooled routes
            // slower (tests/thermal.rs: 100.5 s against the plain 93.3 s).
            let reach = match list.last() {
                Some(&(_, kth)) if list.len() == k => QUADRANT_REACH * kth,
                _ => f64::INFINITY,
            };
            for end in [el.a, el.b] {
                // Two sets of quadrants: split at the axes, and half-open
                // turning about the end point; holes on a grid lie on the
                // axes, which either alone leaves a row or a diagonal out.
                let mut found = [0usize; 8];
                // A bounded walk: a quadrant with nothing in it (a plate's
                // corner) must not make the walk visit every element.
                for hit in tree.nearest_neighbor_iter([end.x, end.y]).take(QUADRANT_WALK) {
                    let y = hit.data;
                    let (dx, dy) = (hit.geom()[0] - end.x, hit.geom()[1] - end.y);
                    if dx.hypot(dy) > reach {
                        break;
                    }
                    if y == x || (dx == 0.0 && dy == 0.0) {
                        continue;
                    }
                    let split = usize::from(dx < 0.0) + 2 * usize::from(dy < 0.0);
                    let turning = match (dx > 0.0, dy > 0.0, dx < 0.0) {
                        (true, _, _) if dy >= 0.0 => 4,
                        (false, true, _) => 5,
                        (_, _, true) => 6,
                        _ => 7,
                    };
                    let mut wanted = false;
                    for quadrant in [split, turning] {
                        if found[quadrant] < q {
                            found[quadrant] += 1;
                            wanted = true;
                        }
                    }
                    if wanted && !list.iter().any(|&(m, _)| m == y) {
                        list.push((y, gap(inst, x, y)));
                    }
                    if found.iter().all(|&f| f == q) {
                        break;
                    }
                }
            }
            list.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        }
        near
    }
}

/// Every element's two end points, each with its element.
fn end_tree(inst: &Instance) -> rstar::RTree<rstar::primitives::GeomWithData<[f64; 2], usize>> {
    use rstar::primitives::GeomWithData;
    rstar::RTree::bulk_load(inst.elements.iter().enumerate().flat_map(|(e, el)| [GeomWithData::new([el.a.x, el.a.y], e), GeomWithData::new([el.b.x, el.b.y], e)]).collect())
}

/// The shortest distance between an end of `x` and an end of `y`.
fn gap(inst: &Instance, x: usize, y: usize) -> f64 {
    let (p, q) = (&inst.elements[x], &inst.elements[y]);
    [(p.a, q.a), (p.a, q.b), (p.b, q.a), (p.b, q.b)].iter().map(|(u, v)| (v - u).norm()).fold(f64::INFINITY, f64::min)
}

/// End points a quadrant search looks at, at most, around each end point.
const QUADRANT_WALK: usize = 200;

/// How far a quadrant neighbour may be, in gaps of the k-th nearest (on
/// d1291, 90 % of the quadrant neighbours beyond the 10 nearest lie within
/// 2.5 times its gap, 95 % within 3.3).
const QUADRANT_REACH: f64 = 4.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::{checker::check, construct::construct, exact};

    fn random_instance(n: usize, seed: u64) -> Instance {
        crate::plan::ecp::random_instance(n, seed, 2..=4, 3.0)
    }

    #[test]
    fn neighbour_lists_are_the_nearest_by_gap() {
        let inst = crate::plan::ecp::random_instance(60, 4, 2..=4, 0.0);
        let near = Neighbours::new(&inst, 8);
        let gap = |x: usize, y: usize| {
            let (p, q) = (&inst.elements[x], &inst.elements[y]);
            [(p.a, q.a), (p.a, q.b), (p.b, q.a), (p.b, q.b)].iter().map(|(u, v)| (v - u).norm()).fold(f64::INFINITY, f64::min)
        };
        for x in 0..60 {
            let mut all: Vec<f64> = (0..60).filter(|&y| y != x).map(|y| gap(x, y)).collect();
            all.sort_by(f64::total_cmp);
            let got: Vec<f64> = near.lists[x].iter().map(|&(_, g)| g).collect();
            assert_eq!(got, all[..8].to_vec(), "element {x}");
        }
    }

    #[test]
    fn quadrant_lists_add_the_nearest_of_each_quadrant() {
        // Three rows of points, two near each other and one far: the
        // nearest all lie in a point's own row, the quadrant neighbours reach
        // the near other row, never the far one.
        let mut inst = crate::plan::ecp::random_instance(60, 5, 2..=4, 0.0);
        for (i, e) in inst.elements.iter_mut().enumerate() {
            let p = crate::job::Point::new((i % 20) as f64, [0.0, 10.0, 100.0][i / 20]);
            e.a = p;
            e.b = p;
        }
        let plain = Neighbours::new(&inst, 6);
        let quad = Neighbours::with_quadrants(&inst, 6, 2);
        let row = |e: usize| e / 20;
        for x in 0..60 {
            assert_eq!(quad.lists[x][..6], plain.lists[x][..], "element {x}: the nearest come first");
            assert!(plain.lists[x].iter().all(|&(y, _)| row(y) == row(x)), "element {x}");
            assert!(quad.lists[x].windows(2).all(|w| w[0].1 <= w[1].1), "sorted by gap");
            assert!(quad.lists[x].iter().all(|&(y, _)| (row(y) == 2) == (row(x) == 2)), "element {x} reaches the far row: {:?}", quad.lists[x]);
            if row(x) < 2 {
                let other_row = quad.lists[x].iter().filter(|&&(y, _)| row(y) != row(x)).count();
                assert!(other_row >= 1, "element {x} has no neighbour in the other row: {:?}", quad.lists[x]);
            }
        }
        // No nearest asked for: no bound either, the quadrants' own alone.
        let alone = Neighbours::with_quadrants(&inst, 0, 1);
        assert!(alone.lists.iter().all(|l| !l.is_empty() && l.len() <= 8));
    }

    #[test]
    fn moves_predict_positions_cost_and_feasibility() {
        let mut turned = 0;
        for seed in 0..60 {
            let mut inst = random_instance(9, seed % 20);
            if (20..40).contains(&seed) {
                // Some ends on a plate's edge: starts there need no pierce.
                inst.edge_starts = (0..9).map(|e| [e % 3 == 0, e % 4 == 1]).collect();
            }
            if seed >= 40 {
                // Elements end to end, and sharp turns charged where a cut
                // goes on into the next (either way round).
                for e in 1..9 {
                    inst.elements[e].a = inst.elements[e - 1].b;
                }
                let heading = |e: &crate::plan::ecp::Element| (e.b - e.a).normalize();
                let headings = inst.elements.iter().map(|e| [heading(e), heading(e)]).collect();
                inst.turns = crate::plan::ecp::Turns { headings, cost: 2.5, cos_sharp: 30f64.to_radians().cos() };
            }
            if exact::solve(&inst).is_none() {
                continue;
            }
            let start = construct(&inst);
            assert!(check(&inst, &start).is_empty());
            let mut pos = vec![0; 9];
            for (i, c) in start.iter().enumerate() {
                pos[c.element] = i;
            }
            let rules = Rules::new(&inst);
            for from in 0..9 {
                // Runs of every length: a long one kept is judged by the
                // shorter stretch it jumps.
                for len in 1..=8 {
                    if from + len > 9 {
                        continue;
                    }
                    for to in 0..=9 - len {
                        for reverse in [false, true] {
                            let mv = Move { from, len, to, reverse };
                            let mut tour = Tour { cuts: start.clone(), pos: pos.clone() };
                            let predicted: Vec<usize> = (0..9).map(|e| mv.new_pos(pos[e])).collect();
                            let d = delta(&inst, &tour, &mv);
                            let fits = feasible(&inst, &rules, &tour, &mv);
                            apply(&mut tour, &mv);
                            assert_eq!(predicted, tour.pos, "{mv:?}");
                            assert!((inst.cost(&tour.cuts) - inst.cost(&start) - d).abs() < 1e-9, "{mv:?}");
                            let plain = Instance { turns: Default::default(), ..inst.clone() };
                            turned += usize::from(inst.cost(&tour.cuts) > plain.cost(&tour.cuts) + 1e-9);
                            assert_eq!(fits, check(&inst, &tour.cuts).is_empty(), "seed {seed} {mv:?}");
                        }
                    }
                }
            }
        }
        assert!(turned > 0, "some moved route goes on through a sharp turn");
    }
}
