//! Feasible starting routes (seed 001's constructions) and dir-opt.

use rand::SeedableRng;

use super::moves::{link, Rules};
use super::{Cut, Instance};

/// Directions for a fixed order of elements, optimal by dynamic programming
/// over the two directions of each (seed 001's dir-opt; linear time).
pub fn dir_opt(inst: &Instance, order: &[usize]) -> Vec<Cut> {
    if order.is_empty() {
        return Vec::new();
    }
    let cut = |i: usize, d: usize| Cut { element: order[i], reversed: d == 1 };
    let n = order.len();
    let mut best = vec![[0.0f64; 2]; n];
    let mut from = vec![[0usize; 2]; n];
    best[0] = [0, 1].map(|d| link(inst, None, Some(cut(0, d))));
    for i in 1..n {
        for d in 0..2 {
            let (p, c) = (0..2)
                .map(|p| (p, best[i - 1][p] + link(inst, Some(cut(i - 1, p)), Some(cut(i, d)))))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            best[i][d] = c;
            from[i][d] = p;
        }
    }
    let mut d = (0..2).min_by(|&a, &b| (best[n - 1][a] + link(inst, Some(cut(n - 1, a)), None)).total_cmp(&(best[n - 1][b] + link(inst, Some(cut(n - 1, b)), None)))).unwrap();
    let mut route = vec![cut(n - 1, d); n];
    for i in (1..n).rev() {
        d = from[i][d];
        route[i - 1] = cut(i - 1, d);
    }
    route
}

/// A feasible order: nearest neighbour among the elements that may come next.
/// An element may not close a contour before the contour's inner contours are
/// cut, nor be the last element cut of the rest of a common cut's two contours
/// while that common cut waits (it could never be cut then). Falls back to
/// cutting contour by contour, innermost first, should it ever get stuck.
pub fn construct(inst: &Instance) -> Vec<Cut> {
    let n = inst.elements.len();
    let rules = Rules::new(inst);
    let mut left: Vec<usize> = inst.contours.iter().map(Vec::len).collect();
    let mut done = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut here = inst.depot;
    for _ in 0..n {
        let allowed = |f: usize| -> bool {
            for &k in &rules.contours_of[f] {
                if left[k] == 1 && rules.inners[k].iter().any(|&i| left[i] > 0) {
                    return false;
                }
                for &(c, other) in &rules.shared[k] {
                    if c == f {
                        // Closing both at once.
                        if left[k] == 1 && left[other] == 1 {
                            return false;
                        }
                    } else if !done[c] && left[k] == 2 && left[other] == 1 {
                        // The last of the rest while the common cut waits.
                        return false;
                    }
                }
            }
            true
        };
        let next = (0..n)
            .filter(|&e| !done[e] && allowed(e))
            .min_by(|&a, &b| {
                let d = |e: usize| {
                    let el = &inst.elements[e];
                    inst.distance(here, el.a).min(inst.distance(here, el.b))
                };
                d(a).total_cmp(&d(b))
            });
        let Some(f) = next else { return dir_opt(inst, &contour_order(inst)) };
        done[f] = true;
        for &k in &rules.contours_of[f] {
            left[k] -= 1;
        }
        let el = &inst.elements[f];
        here = if inst.distance(here, el.a) <= inst.distance(here, el.b) { el.b } else { el.a };
        order.push(f);
    }
    dir_opt(inst, &order)
}

/// Seed 001's insertion-based construction (IB): elements in order of their
/// contour's depth, innermost first, each inserted (in its better direction)
/// where it adds least to the route among the positions that keep every rule
/// whose elements are all in the route. Inserting never changes the order of
/// what is already there, so a rule once kept stays kept; and with inner
/// contours complete before their outer one starts, every rule is decided
/// when its last element comes in, with the route's end always open to it.
/// Common cuts come first within a depth, so the last element into a contour
/// only ever has to come after things. Falls back to the nearest-neighbour
/// construction should a rule still leave no position.
pub fn insertion(inst: &Instance) -> Vec<Cut> {
    insertion_in_order(inst, None)
}

/// [`insertion`] with the elements of each depth taken in a random order
/// (`seed`), or in index order (`None`): different starts for parallel searches.
pub fn insertion_in_order(inst: &Instance, seed: Option<u64>) -> Vec<Cut> {
    let n = inst.elements.len();
    let rules = Rules::new(inst);
    let depth = contour_depths(inst);
    let mut order: Vec<usize> = (0..n).collect();
    if let Some(seed) = seed {
        use rand::seq::SliceRandom;
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
    }
    let element_depth = |e: usize| rules.contours_of[e].iter().map(|&k| depth[k]).max().unwrap_or(0);
    // Common cuts before the other elements of their depth: then the last
    // element to come into a contour is never a common cut, and every rule on
    // it only asks it to come after something, which the route's end allows.
    order.sort_by_key(|&e| (std::cmp::Reverse(element_depth(e)), rules.contours_of[e].len() == 1));
    let mut present = vec![false; n];
    let mut route: Vec<Cut> = Vec::with_capacity(n);
    let mut pos = vec![usize::MAX; n];
    let complete = |k: usize, present: &[bool]| inst.contours[k].iter().all(|&e| present[e]);
    for &f in &order {
        present[f] = true;
        // Rules decided once f is in: those of f's contours whose elements are all present.
        let np = |e: usize, p: usize| if e == f { p } else if pos[e] >= p { pos[e] + 1 } else { pos[e] };
        let closes = |k: usize, p: usize| inst.contours[k].iter().map(|&e| np(e, p)).max().unwrap_or(0);
        let keeps = |p: usize| -> bool {
            for &k in &rules.contours_of[f] {
                if !complete(k, &present) {
                    continue;
                }
                let ck = closes(k, p);
                if rules.outers[k].iter().any(|&o| complete(o, &present) && ck >= closes(o, p)) {
                    return false;
                }
                if rules.inners[k].iter().any(|&i| complete(i, &present) && closes(i, p) >= ck) {
                    return false;
                }
                if rules.shared[k].iter().any(|&(c, other)| complete(other, &present) && np(c, p) == ck && np(c, p) == closes(other, p)) {
                    return false;
                }
            }
            true
        };
        let mut best: Option<(f64, usize, Cut)> = None;
        for p in 0..=route.len() {
            let (a, b) = (if p == 0 { None } else { Some(route[p - 1]) }, route.get(p).copied());
            for reversed in [false, true] {
                let c = Cut { element: f, reversed };
                let d = link(inst, a, Some(c)) + link(inst, Some(c), b) - link(inst, a, b);
                if best.as_ref().is_none_or(|(bd, _, _)| d < *bd) && keeps(p) {
                    best = Some((d, p, c));
                }
            }
        }
        let Some((_, p, c)) = best else { return construct(inst) };
        route.insert(p, c);
        for (i, cut) in route.iter().enumerate().skip(p) {
            pos[cut.element] = i;
        }
    }
    let elements: Vec<usize> = route.iter().map(|c| c.element).collect();
    dir_opt(inst, &elements)
}

/// Seed 001's contour-order construction (COB): contours cut whole, one
/// after the other. Contours linked by common cuts or nesting form a group;
/// groups are visited nearest first, and inside a group the deepest contours
/// come first (holes and parts in holes before the part around them), then
/// the highest rank (a contour all of whose edges are shared before those
/// around it, so its common cuts never close two contours), nearest first
/// within that. Each contour is entered at its element nearest to where the
/// previous one ended and cut element by element, nearest first; then
/// dir-opt. Falls back to [`contour_order`] if a rule still breaks.
pub fn contour_order_construction(inst: &Instance) -> Vec<Cut> {
    let k = inst.contours.len();
    let depth = contour_depths(inst);
    let rules = Rules::new(inst);
    // Groups: union-find over nesting and common cuts.
    let mut parent: Vec<usize> = (0..k).collect();
    fn root(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let common = inst.common_cuts();
    for (a, b) in inst.inner_outer.iter().copied().chain(common.iter().map(|c| c.contours)) {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        parent[ra] = rb;
    }
    let group: Vec<usize> = (0..k).map(|c| root(&mut parent, c)).collect();
    // Ranks: 0 for a contour with an element of its own, else one more than
    // the lowest rank among the contours it shares a cut with.
    let mut rank = vec![usize::MAX; k];
    let mut queue: std::collections::VecDeque<usize> = (0..k)
        .filter(|&c| inst.contours[c].iter().any(|&e| rules.contours_of[e].len() == 1) || rules.shared[c].is_empty())
        .collect();
    for &c in &queue {
        rank[c] = 0;
    }
    while let Some(c) = queue.pop_front() {
        for &(_, other) in &rules.shared[c] {
            if rank[other] == usize::MAX {
                rank[other] = rank[c] + 1;
                queue.push_back(other);
            }
        }
    }
    let distance_to = |here: crate::job::Point, e: usize| {
        let el = &inst.elements[e];
        inst.distance(here, el.a).min(inst.distance(here, el.b))
    };
    let mut done = vec![false; inst.elements.len()];
    let mut contour_done = vec![false; k];
    let mut order = Vec::with_capacity(inst.elements.len());
    let mut here = inst.depot;
    let mut groups_left: Vec<usize> = (0..k).filter(|&c| group[c] == c).collect();
    while !groups_left.is_empty() {
        // The nearest group, by its nearest element.
        let (gi, _) = groups_left
            .iter()
            .enumerate()
            .map(|(i, &g)| {
                let d = (0..k).filter(|&c| group[c] == g).flat_map(|c| inst.contours[c].iter()).map(|&e| distance_to(here, e)).fold(f64::INFINITY, f64::min);
                (i, d)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        let g = groups_left.swap_remove(gi);
        loop {
            let next = (0..k)
                .filter(|&c| group[c] == g && !contour_done[c])
                .map(|c| {
                    let d = inst.contours[c].iter().filter(|&&e| !done[e]).map(|&e| distance_to(here, e)).fold(f64::INFINITY, f64::min);
                    (std::cmp::Reverse(depth[c]), std::cmp::Reverse(rank[c]), d, c)
                })
                .min_by(|a, b| (a.0, a.1).cmp(&(b.0, b.1)).then(a.2.total_cmp(&b.2)));
            let Some((_, _, _, c)) = next else { break };
            contour_done[c] = true;
            let mut left: Vec<usize> = inst.contours[c].iter().copied().filter(|&e| !done[e]).collect();
            while !left.is_empty() {
                let (i, _) = left.iter().enumerate().map(|(i, &e)| (i, distance_to(here, e))).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
                let e = left.remove(i);
                done[e] = true;
                let el = &inst.elements[e];
                here = if inst.distance(here, el.a) <= inst.distance(here, el.b) { el.b } else { el.a };
                order.push(e);
            }
        }
    }
    let route = dir_opt(inst, &order);
    if super::checker::check(inst, &route).is_empty() {
        route
    } else {
        dir_opt(inst, &contour_order(inst))
    }
}

/// Depth of each contour in the inner/outer tree (0: not inside another).
pub(super) fn contour_depths(inst: &Instance) -> Vec<usize> {
    let k = inst.contours.len();
    let mut depth = vec![0usize; k];
    for _ in 0..k {
        let mut changed = false;
        for &(i, o) in &inst.inner_outer {
            if depth[i] < depth[o] + 1 && depth[o] < k {
                depth[i] = depth[o] + 1;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    depth
}

/// Contour by contour, innermost first (each element with its first contour).
fn contour_order(inst: &Instance) -> Vec<usize> {
    let k = inst.contours.len();
    let depth = contour_depths(inst);
    let mut contours: Vec<usize> = (0..k).collect();
    contours.sort_by_key(|&c| std::cmp::Reverse(depth[c]));
    let mut done = vec![false; inst.elements.len()];
    let mut order = Vec::new();
    for c in contours {
        // Common cuts first, so that they never close this contour.
        let mut elements = inst.contours[c].clone();
        elements.sort_by_key(|&e| inst.contours.iter().filter(|k| k.contains(&e)).count() == 1);
        for e in elements {
            if !std::mem::replace(&mut done[e], true) {
                order.push(e);
            }
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::{checker::check, exact};

    fn random_instance(n: usize, seed: u64) -> Instance {
        crate::plan::ecp::random_instance(n, seed, 2..=4, 3.0)
    }

    #[test]
    fn dir_opt_is_optimal_for_its_order() {
        let inst = random_instance(8, 3);
        let order: Vec<usize> = (0..8).collect();
        let best = dir_opt(&inst, &order);
        for mask in 0..256u32 {
            let route: Vec<Cut> = order.iter().map(|&e| Cut { element: e, reversed: mask & (1 << e) != 0 }).collect();
            assert!(inst.cost(&best) <= inst.cost(&route) + 1e-9);
        }
    }

    #[test]
    fn contour_order_construction_is_feasible_and_cuts_contours_whole() {
        for seed in 0..200 {
            let inst = random_instance(12, seed);
            if exact::solve(&inst).is_none() {
                continue;
            }
            let route = contour_order_construction(&inst);
            assert!(check(&inst, &route).is_empty(), "seed {seed}: {:?}", check(&inst, &route));
        }
    }

    #[test]
    fn construction_is_always_feasible() {
        for seed in 0..200 {
            let inst = random_instance(12, seed);
            if exact::solve(&inst).is_none() {
                continue;
            }
            let route = construct(&inst);
            assert!(check(&inst, &route).is_empty(), "seed {seed}: {:?}", check(&inst, &route));
        }
    }
}
