//! The optimum of a small instance: dynamic programming over the set of
//! elements cut so far and the last cut (element and direction). Both
//! precedence rules can be decided when an element is appended after a set:
//! * appending `f` closes contour `O` when the rest of `O` is in the set; then
//!   every element of each inner contour of `O` must already be in it;
//! * appending a common cut closes both its contours when the rest of both is
//!   in the set, which is forbidden.
//!
//! States: 2^n · 2n; fine up to about 16 elements (the tests use ≤ 12).

use super::{Cut, Instance};

/// Largest instance [`solve`] takes.
pub const MAX_ELEMENTS: usize = 16;

/// The cheapest feasible route and its cost, `None` if no route is feasible.
/// Panics on more than [`MAX_ELEMENTS`] elements (a caller's mistake).
pub fn solve(inst: &Instance) -> Option<(f64, Vec<Cut>)> {
    let n = inst.elements.len();
    assert!(n <= MAX_ELEMENTS, "exact::solve takes at most {MAX_ELEMENTS} elements, got {n}");
    if n == 0 {
        return Some((inst.cost(&[]), Vec::new()));
    }
    let mask_of = |elements: &[usize]| elements.iter().fold(0u32, |m, &e| m | (1 << e));
    // For each element: the contours it may close (rest of the contour, elements
    // that must come before it), and the pairs of contour rests of its common cuts.
    let mut closing: Vec<Vec<(u32, u32)>> = vec![Vec::new(); n];
    for (k, contour) in inst.contours.iter().enumerate() {
        let inner: u32 = inst.inner_outer.iter().filter(|(_, o)| *o == k).map(|(i, _)| mask_of(&inst.contours[*i])).fold(0, |a, b| a | b);
        for &f in contour {
            closing[f].push((mask_of(contour) & !(1 << f), inner));
        }
    }
    let mut both: Vec<Vec<(u32, u32)>> = vec![Vec::new(); n];
    for cc in inst.common_cuts() {
        let rest = |k: usize| mask_of(&inst.contours[k]) & !(1 << cc.element);
        both[cc.element].push((rest(cc.contours.0), rest(cc.contours.1)));
    }
    let allowed = |set: u32, f: usize| {
        closing[f].iter().all(|&(rest, inner)| rest & !set != 0 || (inner & !set == 0 && inner & (1 << f) == 0))
            && both[f].iter().all(|&(a, b)| a & !set != 0 || b & !set != 0)
    };
    let cut = |c: usize| Cut { element: c / 2, reversed: c % 2 == 1 };
    let full = (1u32 << n) - 1;
    let states = 1usize << n;
    let mut best = vec![f64::INFINITY; states * 2 * n];
    let mut from = vec![u32::MAX; states * 2 * n];
    for c in 0..2 * n {
        if allowed(0, c / 2) {
            best[(1usize << (c / 2)) * 2 * n + c] = inst.step(None, cut(c));
        }
    }
    for set in 1..=full {
        for last in 0..2 * n {
            let here = best[set as usize * 2 * n + last];
            if !here.is_finite() {
                continue;
            }
            for next in 0..2 * n {
                let f = next / 2;
                if set & (1 << f) != 0 || !allowed(set, f) {
                    continue;
                }
                let to = (set | (1 << f)) as usize * 2 * n + next;
                let cost = here + inst.step(Some(cut(last)), cut(next));
                if cost < best[to] {
                    best[to] = cost;
                    from[to] = last as u32;
                }
            }
        }
    }
    let (last, total) = (0..2 * n)
        .map(|c| {
            let (_, end) = inst.ends(cut(c));
            (c, best[full as usize * 2 * n + c] + inst.distance(end, inst.depot))
        })
        .filter(|(_, t)| t.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let mut route = Vec::with_capacity(n);
    let (mut set, mut c) = (full, last);
    while set != 0 {
        route.push(cut(c));
        let prev = from[set as usize * 2 * n + c];
        set &= !(1 << (c / 2));
        c = prev as usize;
    }
    route.reverse();
    Some((total, route))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::checker::check;

    /// Every ordering and direction, the slow way.
    fn brute_force(inst: &Instance) -> Option<f64> {
        fn go(inst: &Instance, route: &mut Vec<Cut>, used: &mut Vec<bool>, best: &mut Option<f64>) {
            if route.len() == inst.elements.len() {
                if check(inst, route).is_empty() {
                    let c = inst.cost(route);
                    if best.is_none_or(|b| c < b) {
                        *best = Some(c);
                    }
                }
                return;
            }
            for e in 0..inst.elements.len() {
                if used[e] {
                    continue;
                }
                used[e] = true;
                for reversed in [false, true] {
                    route.push(Cut { element: e, reversed });
                    go(inst, route, used, best);
                    route.pop();
                }
                used[e] = false;
            }
        }
        let mut best = None;
        go(inst, &mut Vec::new(), &mut vec![false; inst.elements.len()], &mut best);
        best
    }

    /// Contours of 1 to 3 elements.
    fn random_instance(n: usize, seed: u64) -> Instance {
        crate::plan::ecp::random_instance(n, seed, 1..=3, 5.0)
    }

    #[test]
    fn matches_brute_force_and_the_checker() {
        for seed in 0..40 {
            let inst = random_instance(5, seed);
            let exact = solve(&inst);
            let brute = brute_force(&inst);
            match (exact, brute) {
                (Some((cost, route)), Some(b)) => {
                    assert!((cost - b).abs() < 1e-9, "seed {seed}: {cost} vs {b}");
                    assert!(check(&inst, &route).is_empty(), "seed {seed}: {:?}", check(&inst, &route));
                    assert!((inst.cost(&route) - cost).abs() < 1e-9);
                }
                (None, None) => {}
                other => panic!("seed {seed}: {other:?}"),
            }
        }
    }

    #[test]
    fn twelve_elements_solve() {
        let inst = random_instance(12, 7);
        let (cost, route) = solve(&inst).expect("feasible");
        assert_eq!(route.len(), 12);
        assert!(check(&inst, &route).is_empty());
        assert!((inst.cost(&route) - cost).abs() < 1e-9);
    }
}
