//! Seed 001's tabu search, kept as the reference the default search
//! (`ils`) is measured against: first-improvement over Or-opt runs and 2-opt
//! reversals with the paper's rules: the best admissible move each iteration,
//! even if it makes the route worse (least-degrading at a local optimum), the
//! links a move breaks tabu for a tenure, a tabu move allowed when it beats the
//! best route found (aspiration), for a budget of iterations (or until the
//! user's time limit, if that comes first).

use std::time::{Duration, Instant};

use crate::plan::stop::{SearchStop, TimeCap};

use rand::{Rng, SeedableRng};

use super::construct::insertion_in_order;
use super::ils::{SearchResult, Start};
use super::moves::{apply, delta, feasible, flip, Move, Neighbours, Rules, Tour};
use super::{Cut, Instance};

/// Options of the tabu search.
#[derive(Debug, Clone)]
pub struct TabuOptions {
    /// Iterations of each search ([`default_iterations`] of the instance).
    pub iterations: u64,
    /// Iterations a broken link stays tabu (seed 001: elements / 4; at least
    /// 10 here, or small instances cycle).
    pub tenure: usize,
    /// Neighbours per element the targets of moves come from.
    pub neighbours: usize,
    /// Stop after this many iterations without a new best (0: never).
    pub max_stall: usize,
    /// Iterations without a new best after which the search goes back to the
    /// best route and shakes it (diversification).
    pub kick_after: usize,
    /// Elements whose moves make up the candidate list at a local optimum.
    pub candidate_list: usize,
    pub seed: u64,
}

impl TabuOptions {
    pub fn new(inst: &Instance) -> TabuOptions {
        let n = inst.elements.len();
        TabuOptions { iterations: default_iterations(n), tenure: (n / 4).clamp(10, 50), neighbours: 10, max_stall: 0, kick_after: 100, candidate_list: 24, seed: 1 }
    }
}

/// Iterations of one search on an instance of `elements` elements: about
/// what a quiet core made in the ten seconds the search used to be given.
pub fn default_iterations(elements: usize) -> u64 {
    (5_000 + 50 * elements as u64).min(20_000)
}

/// The links a move breaks and makes, between cuts (element and direction;
/// the depot as `2n`): tabu search forbids re-making the broken ones for a
/// while, which also keeps a flipped element from flipping straight back.
type Links = [(usize, usize); 3];

fn links(tour: &Tour, mv: &Move) -> (Links, Links) {
    let n = tour.cuts.len();
    let id = |c: Option<Cut>| c.map_or(2 * n, |c| 2 * c.element + usize::from(c.reversed));
    let key = |a: Option<Cut>, b: Option<Cut>| (id(a), id(b));
    let (s, l) = (mv.from as isize, mv.len as isize);
    let first = Some(tour.cuts[mv.from]);
    let last = Some(tour.cuts[mv.from + mv.len - 1]);
    let (before, after) = (tour.at(s - 1), tour.at(s + l));
    let without = |q: isize| if q < s { tour.at(q) } else { tour.at(q + l) };
    let (a, b) = (without(mv.to as isize - 1), without(mv.to as isize));
    let (head, tail) = if mv.reverse { (last.map(flip), first.map(flip)) } else { (first, last) };
    ([key(before, first), key(last, after), key(a, b)], [key(before, after), key(a, head), key(tail, b)])
}

/// Longest stretch a 2-opt move reverses.
const MAX_REVERSAL: usize = 100;

/// The moves that involve element `x`: runs of 1 to 3 cuts starting or
/// ending at it moved next to a neighbour of their ends (kept or reversed, or
/// reversed in place), and 2-opt reversals that bring a neighbour of `x` right
/// after or before it.
fn candidates(x: usize, tour: &Tour, neighbours: &[Vec<usize>], out: &mut Vec<Move>) {
    let n = tour.cuts.len();
    let p = tour.pos[x];
    for len in 1..=3usize.min(n - 1) {
        // The run starting at x, and (longer runs) the one ending at it.
        let starting = (p + len <= n).then_some(p);
        let ending = (len > 1 && p + 1 >= len).then(|| p + 1 - len);
        for from in starting.into_iter().chain(ending) {
            let ends = [tour.cuts[from].element, tour.cuts[from + len - 1].element];
            out.push(Move { from, len, to: from, reverse: true });
            for end in ends {
                for &m in &neighbours[end] {
                    let q = tour.pos[m];
                    if q >= from && q < from + len {
                        continue;
                    }
                    let q = if q > from { q - len } else { q };
                    for to in [q, q + 1] {
                        for reverse in [false, true] {
                            if to != from || reverse {
                                out.push(Move { from, len, to, reverse });
                            }
                        }
                    }
                }
            }
        }
    }
    for &m in &neighbours[x] {
        let q = tour.pos[m];
        // Long reversals rarely keep the precedences and cost most to check.
        if q.abs_diff(p) > MAX_REVERSAL {
            continue;
        }
        if q > p + 1 {
            out.push(Move { from: p + 1, len: q - p, to: p + 1, reverse: true });
        } else if q + 1 < p {
            out.push(Move { from: q, len: p - q, to: q, reverse: true });
        }
    }
}

/// Tabu search from `start` (a feasible route) until the time limit, with
/// seed 001's first-improvement strategy: each iteration takes the first
/// improving admissible move among those of an element whose surroundings
/// changed lately ("don't look" bits off); at a local optimum, the least
/// degrading admissible move of the whole neighbourhood. Admissible: feasible,
/// and not re-making a link broken within the tenure unless it yields a new
/// best route (aspiration). After a long stall the search restarts from the
/// best route, shaken by a few random feasible moves.
pub fn tabu_search(inst: &Instance, start: Vec<Cut>, options: &TabuOptions, cap: &TimeCap) -> SearchResult {
    let began = Instant::now();
    let n = inst.elements.len();
    let rules = Rules::new(inst);
    let mut pos = vec![0; n];
    for (i, c) in start.iter().enumerate() {
        pos[c.element] = i;
    }
    let mut tour = Tour { cuts: start, pos };
    let mut cost = inst.cost(&tour.cuts);
    let mut best = SearchResult { route: tour.cuts.clone(), cost, iterations: 0, time_to_best: Duration::ZERO, start: Start::Insertion, stopped_by: SearchStop::Budget };
    if n < 2 {
        return best;
    }
    let neighbours: Vec<Vec<usize>> = Neighbours::new(inst, options.neighbours).lists.into_iter().map(|l| l.into_iter().map(|(e, _)| e).collect()).collect();
    // Links broken recently, not to be made again until the given iteration.
    let mut tabu_until: std::collections::HashMap<(usize, usize), u64> = std::collections::HashMap::new();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(options.seed);
    let kick_after = options.kick_after.max(1);
    let mut since_kick = 0usize;
    let mut stall = 0usize;
    let mut iteration = 0u64;
    let mut active: std::collections::VecDeque<usize> = (0..n).collect();
    let mut is_active = vec![true; n];
    let mut moves: Vec<Move> = Vec::new();
    while (options.max_stall == 0 || stall < options.max_stall) && iteration < options.iterations && (!iteration.is_multiple_of(64) || !cap.reached()) {
        iteration += 1;
        let admissible = |mv: &Move, d: f64, tour: &Tour, cost: f64, best: f64| {
            let aspires = cost + d < best - 1e-9;
            (aspires || !links(tour, mv).1.iter().any(|k| tabu_until.get(k).is_some_and(|&t| t > iteration))) && feasible(inst, &rules, tour, mv)
        };
        // First improvement among the active elements.
        let mut chosen: Option<(f64, Move)> = None;
        while let Some(x) = active.pop_front() {
            is_active[x] = false;
            moves.clear();
            candidates(x, &tour, &neighbours, &mut moves);
            if let Some(&mv) = moves.iter().find(|mv| {
                let d = delta(inst, &tour, mv);
                d < -1e-9 && admissible(mv, d, &tour, cost, best.cost)
            }) {
                chosen = Some((delta(inst, &tour, &mv), mv));
                break;
            }
        }
        if chosen.is_none() {
            // A local optimum: the least degrading admissible move of a
            // candidate list (the moves of a random sample of elements; the
            // whole neighbourhood costs too much to scan at every step).
            for _ in 0..n.min(options.candidate_list) {
                let x = rng.random_range(0..n);
                moves.clear();
                candidates(x, &tour, &neighbours, &mut moves);
                for mv in &moves {
                    let d = delta(inst, &tour, mv);
                    if chosen.as_ref().is_none_or(|(c, _)| d < *c) && admissible(mv, d, &tour, cost, best.cost) {
                        chosen = Some((d, *mv));
                    }
                }
            }
        }
        let Some((d, mv)) = chosen else { break };
        for k in links(&tour, &mv).0 {
            tabu_until.insert(k, iteration + options.tenure as u64);
        }
        if tabu_until.len() > 64 * n {
            tabu_until.retain(|_, t| *t > iteration);
        }
        // The elements at the changed links look again.
        let (s, l) = (mv.from as isize, mv.len as isize);
        let touched = [tour.at(s - 1), tour.at(s), tour.at(s + l - 1), tour.at(s + l)];
        apply(&mut tour, &mv);
        let t = mv.to as isize;
        for c in touched.into_iter().chain([tour.at(t - 1), tour.at(t), tour.at(t + l - 1), tour.at(t + l)]).flatten() {
            if !std::mem::replace(&mut is_active[c.element], true) {
                active.push_back(c.element);
            }
        }
        cost += d;
        if cost < best.cost - 1e-9 {
            best.route = tour.cuts.clone();
            best.cost = cost;
            best.time_to_best = began.elapsed();
            stall = 0;
            since_kick = 0;
        } else {
            stall += 1;
            since_kick += 1;
        }
        if since_kick >= kick_after {
            // Stuck in a basin: back to the best route, shaken by a few random
            // feasible moves, with a clean tabu list.
            since_kick = 0;
            let mut pos = vec![0; n];
            for (i, c) in best.route.iter().enumerate() {
                pos[c.element] = i;
            }
            tour = Tour { cuts: best.route.clone(), pos };
            tabu_until.clear();
            // A local double bridge (A B C D -> A C B D with B and C short):
            // a change no single move of the neighbourhood undoes.
            for _ in 0..50 {
                let b_len = rng.random_range(1..=30usize.min(n / 3).max(1));
                let c_len = rng.random_range(1..=30usize.min(n / 3).max(1));
                if b_len + c_len >= n {
                    break;
                }
                let a = rng.random_range(0..=n - b_len - c_len);
                let mut cuts = tour.cuts.clone();
                cuts[a..a + b_len + c_len].rotate_left(b_len);
                if super::checker::check(inst, &cuts).is_empty() {
                    tour.cuts = cuts;
                    for (i, c) in tour.cuts.iter().enumerate() {
                        tour.pos[c.element] = i;
                    }
                    break;
                }
            }
            cost = inst.cost(&tour.cuts);
            // Everything may look again after a shake.
            for (e, flag) in is_active.iter_mut().enumerate() {
                if !std::mem::replace(flag, true) {
                    active.push_back(e);
                }
            }
        }
    }
    // Costs were updated by deltas: settle rounding on the route itself.
    best.cost = inst.cost(&best.route);
    best.iterations = iteration;
    best.stopped_by = cap.stop();
    best
}

/// `searches` independent tabu searches (their random restarts differ) on
/// `threads` threads, the best route of all, ties to the first search: the
/// search's outcome varies with its seed, and the machine's cores are
/// otherwise idle while planning. `time_limit`: the user's cap.
pub fn parallel_tabu_search(inst: &Instance, start: &[Cut], options: &TabuOptions, time_limit: Option<Duration>, searches: usize, threads: usize) -> SearchResult {
    let cap = TimeCap::after(time_limit);
    let runs = crate::parallel::tasks(searches.max(1), threads, |k| {
        let options = TabuOptions { seed: options.seed.wrapping_add(k as u64), ..options.clone() };
        // The first search starts from `start`, the others from insertions in
        // other orders: where a search ends up depends much on where it starts.
        let from = if k == 0 { start.to_vec() } else { insertion_in_order(inst, Some(options.seed)) };
        tabu_search(inst, from, &options, &cap)
    });
    super::ils::best_of(runs, &cap)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::{checker::check, construct::construct};

    #[test]
    fn tabu_search_reaches_the_optimum_of_small_instances() {
        for (seed, inst, optimum) in crate::plan::ecp::small_instances_with_optimum() {
            let start = construct(&inst);
            let options = TabuOptions { max_stall: 3000, ..TabuOptions::new(&inst) };
            let found = tabu_search(&inst, start, &options, &TimeCap::none());
            assert!(check(&inst, &found.route).is_empty(), "seed {seed}");
            assert!((found.cost - optimum).abs() < 1e-6, "seed {seed}: tabu {} vs optimum {optimum}", found.cost);
        }
    }

}
