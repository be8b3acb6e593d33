//! Seed 004's genetic algorithm over a route of genes (hatch segments, or
//! grid points as segments of no length), its objective exchangeable.
//!
//! * Initial population: randomised nearest-neighbour routes, each next gene
//!   drawn from the nearest unvisited ones with a probability that halves
//!   with every rank further down their list of link distances; besides
//!   them (our addition, so that the result is never worse than the
//!   yardstick under its own objective) the routes the caller gives.
//! * Fitness: the inverse of the objective. Selection proportionate to it.
//! * Crossover: partially matched (PMX) over a stretch of at most half a
//!   chromosome; a whole generation of offspring replaces its parents (the
//!   best route ever met is kept aside).
//! * Mutation, on every offspring: the seed's "nearest neighbours" mutation,
//!   read as a local search: random genes are joined to one of their
//!   nearest neighbours (by link distance, in its better direction), by a
//!   2-opt move or by moving a chain of up to three genes, and the best of
//!   these moves is kept where it lowers the objective. The constructions
//!   get the same search, longer (our departure: the seed's mutation is
//!   blind, and its Java prototype needed 10-30 s).
//! * Stop: after `stall` generations without a better route, or when the
//!   work budget (gene operations) is spent, or at a time cap if one is set,
//!   or at a route that costs nothing (no objective goes below 0).
//!
//! A move is priced on a few genes around each place it changes, not on the
//! whole route, where the objective is local (`local`): its cost a sum of
//! terms that each see only a few neighbouring genes, the same on a route
//! read backwards. Then the cost of a route is the cost of two overlapping
//! pieces less the cost of their overlap, so the pieces a move leaves alone
//! cancel out.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng as Rand;
use rstar::primitives::GeomWithData;
use rstar::RTree;

use super::{Order, Segment};
use crate::job::Point;
use crate::plan::stop::{SearchStop, TimeCap};

/// The objective over a route or a piece of one (lower is better).
pub type Cost<'a> = dyn Fn(&[(u32, bool)]) -> f64 + Sync + 'a;

/// When each gene of a route is made, in seconds from the route's start.
pub type Starts<'a> = dyn Fn(&[(u32, bool)]) -> Vec<f64> + Sync + 'a;

/// For an objective that is not local but whose terms see only marks made
/// less than `horizon` seconds apart (heat): when each gene of a route is
/// made (`starts`, one per gene). A move is then priced on the genes made
/// within the horizon of the genes it changes.
pub struct Timed<'a> {
    pub horizon: f64,
    pub starts: &'a Starts<'a>,
}

#[derive(Debug, Clone)]
pub struct GaSettings {
    pub population: usize,
    /// Longest PMX stretch, as a share of the chromosome.
    pub max_crossover: f64,
    /// Generations without a better route before it stops.
    pub stall: usize,
    /// Gene operations (copies, moves, evaluations) it may spend.
    pub budget: u64,
    /// Candidates a randomised construction draws the next gene from.
    pub candidates: usize,
    /// Nearest neighbours a mutation tries to join a gene to.
    pub neighbours: usize,
    /// Genes a mutation tries on each offspring, per gene of the route (the
    /// initial population's routes are searched until no move helps).
    pub mutation_tries: f64,
    /// Whether the objective is local (see the module's notes): moves are
    /// priced on the genes around them; else on the whole route.
    pub local: bool,
    pub seed: u64,
}

impl Default for GaSettings {
    fn default() -> Self {
        GaSettings { population: 25, max_crossover: 0.5, stall: 30, budget: 40_000_000, candidates: 6, neighbours: 4, mutation_tries: 0.05, local: true, seed: 1 }
    }
}

/// What a run of the GA did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GaRun {
    pub generations: usize,
    /// The generation that found the best route (0: the initial population).
    pub best_generation: usize,
    pub cost: f64,
    pub stopped_by: SearchStop,
}

/// The best route over `segments` the GA finds from `start` under `cost`
/// (lower is better), with `seeded` routes in the initial population.
pub fn evolve(segments: &[Segment], start: Point, cost: &Cost, timed: Option<&Timed>, seeded: Vec<Order>, settings: &GaSettings, cap: &TimeCap) -> (Order, GaRun) {
    let n = segments.len();
    if n == 0 {
        return (Vec::new(), GaRun::default());
    }
    let mut rng = Rand::seed_from_u64(settings.seed);
    let near = starts(segments);
    let mut search = LocalSearch::new(segments, &near, cost, settings);
    search.timed = timed;
    let mut population: Vec<Order> = seeded.into_iter().filter(|o| o.len() == n).collect();
    let mut constructed = 0;
    while population.len() < settings.population.max(2) {
        // The first construction is the plain nearest neighbour.
        let candidates = if constructed == 0 { 1 } else { settings.candidates };
        population.push(construct(segments, near.clone(), start, candidates, &mut rng));
        constructed += 1;
        search.spent += 20 * n as u64;
    }
    let mut costs: Vec<f64> = Vec::with_capacity(population.len());
    for route in &mut population {
        // Past a route that costs nothing the rest stay as they were built.
        if costs.iter().all(|&c| c > 0.0) {
            search.improve(route, Tries::Sweep, &mut rng, cap);
        }
        costs.push(cost(route));
    }
    search.spent += (population.len() * n) as u64;
    let (mut best, mut best_cost) = best_of(&population, &costs);
    let mut run = GaRun { cost: best_cost, ..GaRun::default() };
    let mut stalled = 0;
    // Every objective is a sum of terms of 0 or more: a route that costs
    // nothing (heat's, with no mark near one made just before) is the best.
    while stalled < settings.stall && best_cost > 0.0 {
        if search.spent >= settings.budget {
            run.stopped_by = SearchStop::Budget;
            break;
        }
        if cap.reached() {
            run.stopped_by = SearchStop::TimeLimit;
            break;
        }
        run.generations += 1;
        let wheel = Wheel::new(&costs);
        let mut offspring = Vec::with_capacity(population.len());
        for _ in 0..population.len() {
            let (a, b) = (wheel.pick(&mut rng), wheel.pick(&mut rng));
            let mut child = pmx(&population[a], &population[b], settings.max_crossover, &mut rng);
            search.spent += 3 * n as u64;
            search.improve(&mut child, Tries::Random((settings.mutation_tries * n as f64).ceil() as usize), &mut rng, cap);
            offspring.push(child);
        }
        costs = offspring.iter().map(|r| cost(r)).collect();
        search.spent += (population.len() * n) as u64;
        population = offspring;
        let (gen_best, gen_cost) = best_of(&population, &costs);
        if gen_cost < best_cost - 1e-12 * best_cost.abs() {
            (best, best_cost) = (gen_best, gen_cost);
            run.best_generation = run.generations;
            stalled = 0;
        } else {
            stalled += 1;
        }
    }
    run.cost = best_cost;
    (best, run)
}

/// The chain a shift `m` moves, as it goes in (turned round where `flip`), onto `out`.
fn chain(out: &mut Vec<(u32, bool)>, route: &Order, m: Move, segments: &[Segment]) {
    if let Move::Shift { s, len, flip, .. } = m {
        if flip {
            out.extend(route[s..s + len].iter().rev().map(|&x| turned(segments, x)));
        } else {
            out.extend_from_slice(&route[s..s + len]);
        }
    }
}

fn best_of(population: &[Order], costs: &[f64]) -> (Order, f64) {
    let k = (0..costs.len()).min_by(|&a, &b| costs[a].total_cmp(&costs[b])).expect("a population");
    (population[k].clone(), costs[k])
}

/// Fitness-proportionate selection: fitness 1 / cost.
struct Wheel {
    cumulative: Vec<f64>,
}

impl Wheel {
    fn new(costs: &[f64]) -> Wheel {
        let mut total = 0.0;
        let cumulative = costs
            .iter()
            .map(|c| {
                total += 1.0 / c.max(1e-12);
                total
            })
            .collect();
        Wheel { cumulative }
    }

    fn pick(&self, rng: &mut Rand) -> usize {
        let total = *self.cumulative.last().expect("a population");
        let x = rng.random::<f64>() * total;
        self.cumulative.partition_point(|&c| c <= x).min(self.cumulative.len() - 1)
    }
}

/// Partially matched crossover: the child is `b` with a stretch of `a` (at
/// most `max_share` of the chromosome) put in place by swaps, so every gene
/// stays once; a gene keeps the direction of the parent it came from.
fn pmx(a: &Order, b: &Order, max_share: f64, rng: &mut Rand) -> Order {
    let n = a.len();
    let mut child = b.clone();
    if n < 2 {
        return child;
    }
    let longest = ((n as f64 * max_share) as usize).clamp(1, n);
    let len = rng.random_range(1..=longest);
    let from = rng.random_range(0..=n - len);
    let mut at = vec![0u32; n];
    for (i, &(g, _)) in child.iter().enumerate() {
        at[g as usize] = i as u32;
    }
    for i in from..from + len {
        let (g, dir) = a[i];
        let j = at[g as usize] as usize;
        if j != i {
            let other = child[i].0;
            child.swap(i, j);
            at[other as usize] = j as u32;
            at[g as usize] = i as u32;
        }
        child[i].1 = dir;
    }
    child
}

/// Genes on either side of a changed place whose cost terms a move is
/// priced with: twice the reach of the widest local term (a hatch mark's
/// time sees the marks beside it; a point route's link, the points two
/// away).
const CONTEXT: usize = 4;

/// A change to a route.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Move {
    /// The genes at `p..=q` reversed and turned round (a 2-opt move).
    Reverse { p: usize, q: usize },
    /// The `len` genes at `s` moved to follow the gene at `after` (turned
    /// round when `flip`).
    Shift { s: usize, len: usize, flip: bool, after: usize },
}

/// Which genes a local search tries.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Tries {
    /// So many, at random (the mutation).
    Random(usize),
    /// Every gene until no move lowers the cost (the constructions).
    Sweep,
}

/// The mutation's local search over one route at a time.
struct LocalSearch<'a> {
    segments: &'a [Segment],
    near: &'a RTree<Start>,
    cost: &'a Cost<'a>,
    local: bool,
    neighbours: usize,
    budget: u64,
    spent: u64,
    /// Each gene's place in the route being searched.
    at: Vec<u32>,
    /// Whether every gene may be marked either way (points or a
    /// bidirectional hatch): then no stretch needs checking.
    all_turn: bool,
    /// A changed piece of the route, being priced.
    new: Vec<(u32, bool)>,
    /// The nearest neighbours of each gene's end either way
    /// (`neighbours` at [(2 gene + reversed) · neighbours ..]), looked up
    /// when first needed: a route is searched many times over.
    near_ends: Vec<(u32, bool)>,
    near_known: Vec<bool>,
    /// Where the objective is timed, and when each gene of the route being
    /// searched is made.
    timed: Option<&'a Timed<'a>>,
    starts: Vec<f64>,
}

impl<'a> LocalSearch<'a> {
    fn new(segments: &'a [Segment], near: &'a RTree<Start>, cost: &'a Cost<'a>, settings: &GaSettings) -> Self {
        let all_turn = segments.iter().all(turns_round);
        let ends = 2 * segments.len();
        LocalSearch {
            segments,
            near,
            cost,
            local: settings.local,
            neighbours: settings.neighbours,
            budget: settings.budget,
            spent: 0,
            at: vec![0; segments.len()],
            all_turn,
            new: Vec::new(),
            near_ends: vec![(u32::MAX, false); ends * settings.neighbours],
            near_known: vec![false; ends],
            timed: None,
            starts: Vec::new(),
        }
    }

    fn turnable(&self, genes: &[(u32, bool)]) -> bool {
        self.all_turn || genes.iter().all(|&(s, _)| turns_round(&self.segments[s as usize]))
    }

    /// Genes (`tries`) each joined to the nearest neighbour
    /// where that lowers the cost (the best move of those it tries).
    fn improve(&mut self, route: &mut Order, tries: Tries, rng: &mut Rand, cap: &TimeCap) {
        let n = route.len();
        if n < 3 {
            return;
        }
        for (k, &(g, _)) in route.iter().enumerate() {
            self.at[g as usize] = k as u32;
        }
        // Priced on the whole route, a move costs n: a few random tries only.
        let tries = if self.local || self.timed.is_some() { tries } else { Tries::Random(2) };
        self.time_route(route);
        let mut current = if self.local { 0.0 } else { (self.cost)(route) };
        let mut moves = Vec::with_capacity(8 * self.neighbours);
        // A sweep tries every gene, and again every gene beside a change.
        let (mut queue, mut queued): (std::collections::VecDeque<u32>, Vec<bool>) = match tries {
            Tries::Sweep => (route.iter().map(|g| g.0).collect(), vec![true; n]),
            Tries::Random(_) => Default::default(),
        };
        let most = match tries {
            Tries::Sweep => 4 * n,
            Tries::Random(count) => count,
        };
        for t in 0..most {
            // (A route that costs nothing cannot be bettered.)
            if self.spent >= self.budget || (t % 256 == 255 && cap.reached()) || (!self.local && current <= 0.0) {
                return;
            }
            let i = match tries {
                Tries::Random(_) => rng.random_range(0..n),
                Tries::Sweep => {
                    let Some(g) = queue.pop_front() else { return };
                    queued[g as usize] = false;
                    self.at[g as usize] as usize
                }
            };
            moves.clear();
            self.moves_joining(route, i, &mut moves);
            let mut best: Option<(f64, Move)> = None;
            for &m in &moves {
                let delta = self.delta(route, m, current);
                if delta < best.map_or(0.0, |b| b.0) {
                    best = Some((delta, m));
                }
            }
            if let Some((delta, m)) = best {
                if matches!(tries, Tries::Sweep) {
                    let places: &[usize] = match m {
                        Move::Reverse { p, q } => &[i, p.wrapping_sub(1), p, q, q + 1],
                        Move::Shift { s, len, after, .. } => &[after, after + 1, s.wrapping_sub(1), s, s + len - 1, s + len],
                    };
                    for &k in places.iter().filter(|&&k| k < n) {
                        let g = route[k].0;
                        if !queued[g as usize] {
                            queued[g as usize] = true;
                            queue.push_back(g);
                        }
                    }
                }
                self.apply(route, m);
                self.time_route(route);
                current += delta;
            }
        }
    }

    /// The moves that make the gene at `i` go on to one of its nearest
    /// neighbours: a 2-opt move where the neighbour lies after it, and the
    /// neighbour moved there with up to two genes beside it.
    fn moves_joining(&mut self, route: &Order, i: usize, out: &mut Vec<Move>) {
        let n = route.len();
        let (g, reversed) = route[i];
        let (slot, k) = (2 * g as usize + reversed as usize, self.neighbours);
        if !self.near_known[slot] {
            let end = self.segments[g as usize].ends(reversed).1;
            let found = self.near.nearest_neighbor_iter([end.x, end.y]).map(|e| e.data).filter(|&(s, _)| s != g).take(k);
            for (place, near) in self.near_ends[slot * k..(slot + 1) * k].iter_mut().zip(found) {
                *place = near;
            }
            self.near_known[slot] = true;
        }
        for e in slot * k..(slot + 1) * k {
            let (h, h_reversed) = self.near_ends[e];
            if h == u32::MAX {
                break;
            }
            let j = self.at[h as usize] as usize;
            let point = is_point(&self.segments[h as usize]);
            let (as_is, turned) = (point || route[j].1 == h_reversed, point || route[j].1 != h_reversed);
            if j > i && turned && self.turnable(&route[i + 1..=j]) && !(point && j == i + 1) {
                out.push(Move::Reverse { p: i + 1, q: j });
            }
            for len in 1..=3 {
                // h and the genes after it as they are ...
                if as_is && j + len <= n && !(j..j + len).contains(&i) && j != i + 1 {
                    out.push(Move::Shift { s: j, len, flip: false, after: i });
                }
                // ... or h and the genes before it turned round.
                if turned && j + 1 >= len && !(point && len == 1) {
                    let s = j + 1 - len;
                    if !(s..=j).contains(&i) && self.turnable(&route[s..=j]) {
                        out.push(Move::Shift { s, len, flip: true, after: i });
                    }
                }
            }
        }
    }

    /// How much `m` changes the cost of `route` (whose cost is `current`
    /// where the objective is not local).
    fn delta(&mut self, route: &Order, m: Move, current: f64) -> f64 {
        let n = route.len();
        if let Some(timed) = self.timed {
            return self.delta_in_time(route, m, timed.horizon);
        }
        if !self.local {
            let mut changed = route.clone();
            let mut at = std::mem::take(&mut self.at);
            apply(&mut changed, &mut at, m, self.segments);
            // `apply` moved the places; put them back.
            for (k, &(g, _)) in route.iter().enumerate() {
                at[g as usize] = k as u32;
            }
            self.at = at;
            self.spent += 2 * n as u64;
            return (self.cost)(&changed) - current;
        }
        let (c, segments) = (CONTEXT, self.segments);
        let turn = |&x: &(u32, bool)| turned(segments, x);
        match m {
            Move::Reverse { p, q } if q + 1 - p >= 2 * c => {
                // Two places apart: the stretch's own cost reads the same backwards.
                let left = p.saturating_sub(c)..(p + c);
                let right = (q + 1 - c)..(q + 1 + c).min(n);
                self.new.clear();
                let mut d = self.price_old(route, left.clone()) + self.price_old(route, right.clone());
                self.new.extend_from_slice(&route[left.start..p]);
                self.new.extend(route[q + 1 - c..=q].iter().rev().map(turn));
                d = self.price_new() - d;
                self.new.clear();
                self.new.extend(route[p..p + c].iter().rev().map(turn));
                self.new.extend_from_slice(&route[q + 1..right.end]);
                d + self.price_new()
            }
            Move::Reverse { p, q } => {
                let span = p.saturating_sub(c)..(q + 1 + c).min(n);
                let old = self.price_old(route, span.clone());
                self.changed_span(route, m, span);
                self.price_new() - old
            }
            Move::Shift { s, len, after, .. } => {
                // Where the chain leaves and where it goes in (before the gene after `after`).
                let (out_lo, out_hi) = (s.saturating_sub(c), (s + len + c).min(n));
                let (in_lo, in_hi) = ((after + 1).saturating_sub(c), (after + 1 + c).min(n));
                let apart = if after < s { in_hi <= out_lo } else { out_hi <= in_lo };
                let old;
                self.new.clear();
                if apart {
                    old = self.price_old(route, out_lo..out_hi) + self.price_old(route, in_lo..in_hi);
                    self.new.extend_from_slice(&route[out_lo..s]);
                    self.new.extend_from_slice(&route[s + len..out_hi]);
                    let left = self.price_new();
                    self.new.clear();
                    self.new.extend_from_slice(&route[in_lo..=after]);
                    chain(&mut self.new, route, m, segments);
                    self.new.extend_from_slice(&route[after + 1..in_hi]);
                    return (left - old) + self.price_new();
                }
                let span = out_lo.min(in_lo)..out_hi.max(in_hi);
                old = self.price_old(route, span.clone());
                self.changed_span(route, m, span);
                self.price_new() - old
            }
        }
    }

    /// `route[span]` as `m` leaves it, into `new` (`span` holds every gene
    /// `m` moves, and the place it moves them to).
    fn changed_span(&mut self, route: &Order, m: Move, span: std::ops::Range<usize>) {
        let (lo, hi, segments) = (span.start, span.end, self.segments);
        let turn = |&x: &(u32, bool)| turned(segments, x);
        let new = &mut self.new;
        new.clear();
        match m {
            Move::Reverse { p, q } => {
                new.extend_from_slice(&route[lo..p]);
                new.extend(route[p..=q].iter().rev().map(turn));
                new.extend_from_slice(&route[q + 1..hi]);
            }
            Move::Shift { s, len, after, .. } => {
                if after < s {
                    new.extend_from_slice(&route[lo..=after]);
                    chain(new, route, m, segments);
                    new.extend_from_slice(&route[after + 1..s]);
                    new.extend_from_slice(&route[s + len..hi]);
                } else {
                    new.extend_from_slice(&route[lo..s]);
                    new.extend_from_slice(&route[s + len..=after]);
                    chain(new, route, m, segments);
                    new.extend_from_slice(&route[after + 1..hi]);
                }
            }
        }
    }

    /// When each gene of `route` is made, where the objective is timed.
    fn time_route(&mut self, route: &Order) {
        if let Some(timed) = self.timed {
            self.starts = (timed.starts)(route);
            debug_assert_eq!(self.starts.len(), route.len(), "one start per gene");
            self.spent += route.len() as u64;
        }
    }

    /// `delta` for a timed objective: priced on the genes from `horizon`
    /// before the first gene `m` changes to `horizon` after the last (and
    /// `CONTEXT` more either side, for the terms that see neighbours). Pairs
    /// of marks further apart add nothing, before the move or after it: the
    /// genes before the change keep their times, and those after it all
    /// shift by the same amount.
    fn delta_in_time(&mut self, route: &Order, m: Move, horizon: f64) -> f64 {
        let n = route.len();
        let (first, last) = match m {
            Move::Reverse { p, q } => (p, q),
            Move::Shift { s, len, after, .. } if after < s => (after + 1, s + len - 1),
            Move::Shift { s, after, .. } => (s, after),
        };
        let starts = &self.starts;
        let (before, after) = (first.saturating_sub(1), (last + 1).min(n - 1));
        let mut lo = before;
        while lo > 0 && starts[before] - starts[lo] < horizon {
            lo -= 1;
        }
        let mut hi = after;
        while hi + 1 < n && starts[hi] - starts[after] < horizon {
            hi += 1;
        }
        let span = lo.saturating_sub(CONTEXT)..(hi + 1 + CONTEXT).min(n);
        let old = self.price_old(route, span.clone());
        self.changed_span(route, m, span);
        self.price_new() - old
    }

    fn price_old(&mut self, route: &Order, span: std::ops::Range<usize>) -> f64 {
        self.spent += span.len() as u64;
        (self.cost)(&route[span])
    }

    fn price_new(&mut self) -> f64 {
        self.spent += self.new.len() as u64;
        (self.cost)(&self.new)
    }

    fn apply(&mut self, route: &mut Order, m: Move) {
        self.spent += apply(route, &mut self.at, m, self.segments) as u64;
    }
}

/// Makes move `m` on `route`, keeping `at` (each gene's place) true; the
/// genes it moved.
fn apply(route: &mut Order, at: &mut [u32], m: Move, segments: &[Segment]) -> usize {
    let turn = |gene: &mut (u32, bool)| *gene = turned(segments, *gene);
    let span = match m {
        Move::Reverse { p, q } => {
            route[p..=q].reverse();
            route[p..=q].iter_mut().for_each(turn);
            p..q + 1
        }
        Move::Shift { s, len, flip, after } => {
            let chain = if after < s {
                route[after + 1..s + len].rotate_right(len);
                after + 1..after + 1 + len
            } else {
                route[s..=after].rotate_left(len);
                after + 1 - len..after + 1
            };
            if flip {
                route[chain.clone()].reverse();
                route[chain.clone()].iter_mut().for_each(turn);
            }
            if after < s {
                after + 1..s + len
            } else {
                s..after + 1
            }
        }
    };
    for k in span.clone() {
        at[route[k].0 as usize] = k as u32;
    }
    span.len()
}

/// `gene` marked the other way round (a point stays as it is).
fn turned(segments: &[Segment], gene: (u32, bool)) -> (u32, bool) {
    (gene.0, gene.1 != segments[gene.0 as usize].either_way)
}

/// A grid point: a gene with no length, the same either way.
fn is_point(s: &Segment) -> bool {
    s.from == s.to
}

fn turns_round(s: &Segment) -> bool {
    s.either_way || is_point(s)
}

/// The segments' possible starts (a one-way segment's only), for
/// nearest-neighbour queries: (segment, reversed) at each.
type Start = GeomWithData<[f64; 2], (u32, bool)>;

fn starts(segments: &[Segment]) -> RTree<Start> {
    let starts: Vec<Start> = segments
        .iter()
        .enumerate()
        .flat_map(|(k, s)| std::iter::once((s.from, false)).chain(s.either_way.then_some((s.to, true))).map(move |(p, r)| Start::new([p.x, p.y], (k as u32, r))))
        .collect();
    RTree::bulk_load(starts)
}

/// A randomised nearest-neighbour route from `start`: the next gene drawn
/// from the `candidates` nearest unvisited starts, the nearest with
/// probability ½, the next ¼, and so on (1: always the nearest).
/// `tree`: the segments' `starts`, taken out as they are visited.
fn construct(segments: &[Segment], mut tree: RTree<Start>, start: Point, candidates: usize, rng: &mut Rand) -> Order {
    let mut order = Vec::with_capacity(segments.len());
    let mut at = start;
    let mut options: Vec<(u32, bool)> = Vec::with_capacity(candidates);
    while order.len() < segments.len() {
        options.clear();
        options.extend(tree.nearest_neighbor_iter([at.x, at.y]).take(candidates.max(1)).map(|e| e.data));
        let mut pick = 0;
        while pick + 1 < options.len() && rng.random::<bool>() {
            pick += 1;
        }
        let (s, reversed) = options[pick];
        let seg = &segments[s as usize];
        tree.remove(&Start::new([seg.from.x, seg.from.y], (s, false)));
        if seg.either_way {
            tree.remove(&Start::new([seg.to.x, seg.to.y], (s, true)));
        }
        order.push((s, reversed));
        at = seg.ends(reversed).1;
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> Vec<Segment> {
        // Short segments on a grid, some one way only.
        (0..n)
            .map(|k| {
                let (x, y) = ((k % 10) as f64 * 3.0, (k / 10) as f64 * 2.0);
                let (from, to) = (Point::new(x, y), Point::new(x + 1.0, y));
                Segment { geometry: k, from, to, either_way: k % 3 != 0, across: y }
            })
            .collect()
    }

    fn valid(order: &[(u32, bool)], segments: &[Segment]) {
        let mut seen = vec![false; segments.len()];
        for &(g, reversed) in order {
            assert!(!seen[g as usize], "gene {g} twice");
            seen[g as usize] = true;
            assert!(!reversed || segments[g as usize].either_way, "a one-way segment reversed");
        }
        assert!(seen.iter().all(|&s| s), "every gene once");
    }

    fn air(order: &[(u32, bool)], segments: &[Segment]) -> f64 {
        order.windows(2).map(|w| (segments[w[1].0 as usize].ends(w[1].1).0 - segments[w[0].0 as usize].ends(w[0].1).1).norm()).sum()
    }

    #[test]
    fn crossover_mutation_and_construction_keep_every_gene_once_in_an_allowed_direction() {
        let segments = grid(60);
        let mut rng = Rand::seed_from_u64(3);
        let a = construct(&segments, starts(&segments), Point::origin(), 1, &mut rng);
        let b = construct(&segments, starts(&segments), Point::new(30.0, 12.0), 6, &mut rng);
        valid(&a, &segments);
        valid(&b, &segments);
        let near = starts(&segments);
        let cost = |o: &[(u32, bool)]| air(o, &segments);
        let mut search = LocalSearch::new(&segments, &near, &cost, &GaSettings::default());
        for _ in 0..200 {
            let mut child = pmx(&a, &b, 0.5, &mut rng);
            valid(&child, &segments);
            let before = cost(&child);
            search.improve(&mut child, Tries::Random(20), &mut rng, &TimeCap::none());
            valid(&child, &segments);
            assert!(cost(&child) <= before + 1e-9);
        }
    }

    /// Every move the mutation tries, priced on the genes around it, against
    /// the whole route's cost before and after it.
    fn moves_priced_locally_cost_what_they_cost(segments: &[Segment], cost: &Cost, timed: Option<&Timed>, seed: u64) {
        let mut rng = Rand::seed_from_u64(seed);
        let near = starts(segments);
        let mut search = LocalSearch::new(segments, &near, cost, &GaSettings::default());
        search.timed = timed;
        let mut route = construct(segments, near.clone(), Point::origin(), 6, &mut rng);
        for (k, &(g, _)) in route.iter().enumerate() {
            search.at[g as usize] = k as u32;
        }
        search.time_route(&route);
        let (mut tried, mut kinds) = (0, [0usize; 2]);
        for _ in 0..300 {
            let i = rng.random_range(0..route.len());
            let mut moves = Vec::new();
            search.moves_joining(&route, i, &mut moves);
            for &m in &moves {
                let mut changed = route.clone();
                let mut at = search.at.clone();
                apply(&mut changed, &mut at, m, segments);
                valid(&changed, segments);
                let (whole, local) = (cost(&changed) - cost(&route), search.delta(&route, m, 0.0));
                assert!((whole - local).abs() <= 1e-9 * (1.0 + cost(&route)), "{m:?}: {whole} on the route, {local} around the move");
                tried += 1;
                kinds[matches!(m, Move::Shift { .. }) as usize] += 1;
            }
            // Walk on: the first move, if any.
            if let Some(&m) = moves.first() {
                search.apply(&mut route, m);
                search.time_route(&route);
            }
        }
        assert!(tried > 500 && kinds.iter().all(|&k| k > 50), "{tried} moves, {kinds:?}");
    }

    #[test]
    fn a_move_priced_around_it_costs_what_it_costs_on_the_whole_route() {
        use crate::config::Limits;
        use crate::plan::objective::{parse, Mark, MotionModel, ObjectiveContext};
        let ctx = ObjectiveContext { motion: MotionModel { axis: Limits { velocity: 300.0, acceleration: 2500.0, jerk: 1e5 }, bridges: true }, heat_radius: 1.0, cooling_time: 1.0 };
        // Hatch segments, a few one way, marked at speed (overscan) and from rest.
        let hatch = grid(120);
        for at_speed in [true, false] {
            let forward: Vec<Mark> = hatch.iter().map(|s| Mark::straight(s.from, s.to, 200.0, at_speed)).collect();
            for spec in ["time", "turns", "length", "time+0.3*turns"] {
                let objective = parse(spec).unwrap();
                let cost = |o: &[(u32, bool)]| super::super::price(super::super::marks(o, &forward), objective.as_ref(), &ctx);
                moves_priced_locally_cost_what_they_cost(&hatch, &cost, None, 7);
            }
            // Heat, and heat with time, priced on the marks made within the
            // cooling time (a few of the route's hundred, its neighbours near).
            let ctx = ObjectiveContext { heat_radius: 4.0, cooling_time: 1.0, ..ctx };
            let starts = |o: &[(u32, bool)]| ctx.motion.timeline(&super::super::marks(o, &forward).collect::<Vec<_>>()).0;
            for spec in ["heat", "time+3*heat"] {
                let objective = parse(spec).unwrap();
                let cost = |o: &[(u32, bool)]| super::super::price(super::super::marks(o, &forward), objective.as_ref(), &ctx);
                let whole = cost(&(0..hatch.len() as u32).map(|g| (g, false)).collect::<Vec<_>>());
                let took = *starts(&(0..hatch.len() as u32).map(|g| (g, false)).collect::<Vec<_>>()).last().unwrap();
                assert!(whole > 1.0 && took > 5.0, "near marks heat each other ({whole}), the route takes many cooling times ({took} s)");
                let timed = Timed { horizon: objective.horizon(&ctx).unwrap(), starts: &starts };
                moves_priced_locally_cost_what_they_cost(&hatch, &cost, Some(&timed), 5);
            }
        }
        // Grid points, the route's links marked rest to rest, going on straight through a point.
        let points: Vec<Segment> = (0..150).map(|k| Point::new((k % 15) as f64 * 2.0, (k / 15) as f64 * 2.0)).map(|p| Segment { geometry: 0, from: p, to: p, either_way: false, across: p.y }).collect();
        for spec in ["time", "turns", "length"] {
            let objective = parse(spec).unwrap();
            let cost = |o: &[(u32, bool)]| {
                let links: Vec<Mark> = o.windows(2).map(|w| Mark::straight(points[w[0].0 as usize].from, points[w[1].0 as usize].from, 200.0, false)).collect();
                objective.cost(&links, &ctx)
            };
            moves_priced_locally_cost_what_they_cost(&points, &cost, None, 11);
        }
    }

    #[test]
    fn the_search_is_never_worse_than_what_it_is_given_and_the_same_for_the_same_seed() {
        let segments = grid(80);
        let cost = |o: &[(u32, bool)]| air(o, &segments);
        // A poor route given: every other segment first.
        let given: Order = (0..80u32).step_by(2).chain((1..80u32).step_by(2)).map(|g| (g, false)).collect();
        let settings = GaSettings { stall: 10, ..GaSettings::default() };
        let (best, run) = evolve(&segments, Point::origin(), &cost, None, vec![given.clone()], &settings, &TimeCap::none());
        valid(&best, &segments);
        assert!((cost(&best) - run.cost).abs() < 1e-9 && run.cost <= cost(&given));
        assert!(run.cost < 0.5 * cost(&given), "{} against {}", run.cost, cost(&given));
        let (again, _) = evolve(&segments, Point::origin(), &cost, None, vec![given], &settings, &TimeCap::none());
        assert_eq!(best, again);
    }
}
