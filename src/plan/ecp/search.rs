//! The search of seed 001, made fast: a feasible construction, dir-opt, and a
//! tabu search over Or-opt moves (a run of 1 to 3 cuts moved elsewhere, kept
//! or reversed, its targets taken from neighbour lists) with the paper's
//! rules: the best admissible move each iteration, even if it makes the route
//! worse (least-degrading at a local optimum), the moved elements tabu for a
//! tenure, a tabu move allowed when it beats the best route found
//! (aspiration), until the time limit.
//!
//! Move evaluation is where seed 001 lost its time. Here the cost change of a
//! move is O(1), and its feasibility is decided from the contours of the moved
//! elements alone: moving a run changes only the order between the run and
//! what it jumps over, so precedences between other contours cannot change.
//! Positions after the move are computed, not applied.

use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};

use super::{Cut, Instance};

/// Precedence data indexed for the search.
struct Rules {
    /// Contours each element belongs to (one or two).
    contours_of: Vec<Vec<usize>>,
    /// For each contour: the contours it lies inside, and those inside it.
    outers: Vec<Vec<usize>>,
    inners: Vec<Vec<usize>>,
    /// For each contour: its common cuts and the other contour of each.
    shared: Vec<Vec<(usize, usize)>>,
}

impl Rules {
    fn new(inst: &Instance) -> Rules {
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
fn link(inst: &Instance, a: Option<Cut>, b: Option<Cut>) -> f64 {
    match (a, b) {
        (_, Some(b)) => inst.step(a, b),
        (Some(a), None) => inst.distance(inst.ends(a).1, inst.depot),
        (None, None) => 0.0,
    }
}

fn flip(c: Cut) -> Cut {
    Cut { element: c.element, reversed: !c.reversed }
}

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

/// Depth of each contour in the inner/outer tree (0: not inside another).
fn contour_depths(inst: &Instance) -> Vec<usize> {
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

/// Options of the tabu search.
#[derive(Debug, Clone)]
pub struct TabuOptions {
    pub time_limit: Duration,
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
    pub fn new(inst: &Instance, time_limit: Duration) -> TabuOptions {
        let n = inst.elements.len();
        TabuOptions { time_limit, tenure: (n / 4).clamp(10, 50), neighbours: 10, max_stall: 0, kick_after: 100, candidate_list: 24, seed: 1 }
    }
}

/// What the search found.
#[derive(Debug, Clone)]
pub struct SearchResult {
    pub route: Vec<Cut>,
    pub cost: f64,
    pub iterations: u64,
    pub time_to_best: Duration,
}

/// The route being improved, with every element's position.
struct Tour {
    cuts: Vec<Cut>,
    pos: Vec<usize>,
}

impl Tour {
    fn at(&self, i: isize) -> Option<Cut> {
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
struct Move {
    from: usize,
    len: usize,
    to: usize,
    reverse: bool,
}

impl Move {
    /// Where element position `p` ends up.
    fn new_pos(&self, p: usize) -> usize {
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

fn feasible(inst: &Instance, rules: &Rules, tour: &Tour, mv: &Move) -> bool {
    let np = |e: usize| mv.new_pos(tour.pos[e]);
    let closes = |k: usize| inst.contours[k].iter().map(|&e| np(e)).max().unwrap_or(0);
    for i in mv.from..mv.from + mv.len {
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
fn delta(inst: &Instance, tour: &Tour, mv: &Move) -> f64 {
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
    // costs inside what it cost before.
    let (head, tail) = if mv.reverse { (flip(last), flip(first)) } else { (first, last) };
    let insertion = link(inst, a, Some(head)) + link(inst, Some(tail), b) - link(inst, a, b);
    insertion - removal
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

fn apply(tour: &mut Tour, mv: &Move) {
    let mut run: Vec<Cut> = tour.cuts.drain(mv.from..mv.from + mv.len).collect();
    if mv.reverse {
        run.reverse();
        run.iter_mut().for_each(|c| *c = flip(*c));
    }
    let at = mv.to;
    tour.cuts.splice(at..at, run);
    let lo = mv.from.min(mv.to);
    let hi = (mv.from + mv.len).max(mv.to + mv.len).min(tour.cuts.len());
    for i in lo..hi {
        tour.pos[tour.cuts[i].element] = i;
    }
}

/// Nearest elements of each element (by the distance between end points).
fn neighbour_lists(inst: &Instance, k: usize) -> Vec<Vec<usize>> {
    let n = inst.elements.len();
    let gap = |x: usize, y: usize| {
        let (p, q) = (&inst.elements[x], &inst.elements[y]);
        [(p.a, q.a), (p.a, q.b), (p.b, q.a), (p.b, q.b)].iter().map(|(u, v)| (v - u).norm()).fold(f64::INFINITY, f64::min)
    };
    (0..n)
        .map(|x| {
            let mut others: Vec<usize> = (0..n).filter(|&y| y != x).collect();
            let k = k.min(others.len());
            if k > 0 {
                others.select_nth_unstable_by(k - 1, |&a, &b| gap(x, a).total_cmp(&gap(x, b)));
            }
            others.truncate(k);
            others
        })
        .collect()
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
pub fn tabu_search(inst: &Instance, start: Vec<Cut>, options: &TabuOptions) -> SearchResult {
    let began = Instant::now();
    let n = inst.elements.len();
    let rules = Rules::new(inst);
    let mut pos = vec![0; n];
    for (i, c) in start.iter().enumerate() {
        pos[c.element] = i;
    }
    let mut tour = Tour { cuts: start, pos };
    let mut cost = inst.cost(&tour.cuts);
    let mut best = SearchResult { route: tour.cuts.clone(), cost, iterations: 0, time_to_best: Duration::ZERO };
    if n < 2 {
        return best;
    }
    let neighbours = neighbour_lists(inst, options.neighbours);
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
    while (options.max_stall == 0 || stall < options.max_stall) && (!iteration.is_multiple_of(64) || began.elapsed() < options.time_limit) {
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
    best
}

/// Independent tabu searches from the same start, one per thread (their
/// random restarts differ), the best route of all: the search's outcome varies
/// from run to run, and the machine's cores are otherwise idle while planning.
pub fn parallel_tabu_search(inst: &Instance, start: &[Cut], options: &TabuOptions, threads: usize) -> SearchResult {
    let threads = threads.max(1);
    std::thread::scope(|scope| {
        let runs: Vec<_> = (0..threads as u64)
            .map(|k| {
                let options = TabuOptions { seed: options.seed.wrapping_add(k), ..options.clone() };
                scope.spawn(move || {
                    // The first search starts from `start`, the others from
                    // insertions in other orders: where a search ends up
                    // depends much on where it starts.
                    let from = if k == 0 { start.to_vec() } else { insertion_in_order(inst, Some(options.seed)) };
                    tabu_search(inst, from, &options)
                })
            })
            .collect();
        runs.into_iter()
            .filter_map(|r| r.join().ok())
            .min_by(|a, b| a.cost.total_cmp(&b.cost))
            .unwrap_or_else(|| SearchResult { cost: inst.cost(start), route: start.to_vec(), iterations: 0, time_to_best: Duration::ZERO })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::{checker::check, exact, tsplib};

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
    fn moves_predict_positions_cost_and_feasibility() {
        for seed in 0..20 {
            let inst = random_instance(9, seed);
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
                for len in 1..=3 {
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
                            assert_eq!(fits, check(&inst, &tour.cuts).is_empty(), "seed {seed} {mv:?}");
                        }
                    }
                }
            }
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

    #[test]
    fn tabu_search_reaches_the_optimum_of_small_instances() {
        let mut solved = 0;
        for seed in 0..30 {
            let inst = random_instance(12, 100 + seed);
            let Some((optimum, _)) = exact::solve(&inst) else { continue };
            let start = construct(&inst);
            let options = TabuOptions { max_stall: 3000, ..TabuOptions::new(&inst, Duration::from_secs(5)) };
            let found = tabu_search(&inst, start, &options);
            assert!(check(&inst, &found.route).is_empty(), "seed {seed}");
            assert!((found.cost - optimum).abs() < 1e-6, "seed {seed}: tabu {} vs optimum {optimum}", found.cost);
            solved += 1;
        }
        assert!(solved >= 20, "only {solved} feasible instances");
    }

    #[test]
    fn a280_improves_on_the_construction_and_stays_feasible() {
        let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/tsplib");
        let tsp = tsplib::read_tsp(&dir.join("a280.tsp")).unwrap();
        let tour = tsplib::read_tour(&dir.join("a280.opt.tour"), 280).unwrap();
        let b = tsplib::bench_instance(&tsp, &tour, 1);
        let start = construct(&b.instance);
        assert!(check(&b.instance, &start).is_empty());
        let found = tabu_search(&b.instance, start.clone(), &TabuOptions::new(&b.instance, Duration::from_millis(500)));
        assert!(check(&b.instance, &found.route).is_empty());
        assert!(found.cost < b.instance.cost(&start));
        assert!(found.cost >= b.optimum, "never below the optimum");
    }
}
