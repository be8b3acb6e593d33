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
//! * Mutation, on every offspring: a random gene is joined to its nearest
//!   neighbour (by link distance, in its better direction): the stretch
//!   between them reversed (a 2-opt move), else the neighbour moved.
//! * Stop: after `stall` generations without a better route, or when the
//!   work budget (gene operations) is spent, or at a time cap if one is set.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng as Rand;
use rstar::primitives::GeomWithData;
use rstar::RTree;

use super::{Order, Segment};
use crate::job::Point;
use crate::plan::stop::{SearchStop, TimeCap};

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
    pub seed: u64,
}

impl Default for GaSettings {
    fn default() -> Self {
        GaSettings { population: 25, max_crossover: 0.5, stall: 30, budget: 400_000_000, candidates: 6, seed: 1 }
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
pub fn evolve(segments: &[Segment], start: Point, cost: &(dyn Fn(&Order) -> f64 + Sync), seeded: Vec<Order>, settings: &GaSettings, cap: &TimeCap) -> (Order, GaRun) {
    let n = segments.len();
    if n == 0 {
        return (Vec::new(), GaRun::default());
    }
    let mut rng = Rand::seed_from_u64(settings.seed);
    let near = starts(segments);
    let mut population: Vec<Order> = seeded.into_iter().filter(|o| o.len() == n).collect();
    let mut spent: u64 = 0;
    let mut constructed = 0;
    while population.len() < settings.population.max(2) {
        // The first construction is the plain nearest neighbour.
        let candidates = if constructed == 0 { 1 } else { settings.candidates };
        population.push(construct(segments, near.clone(), start, candidates, &mut rng));
        constructed += 1;
        spent += 20 * n as u64;
    }
    let mut costs: Vec<f64> = population.iter().map(cost).collect();
    spent += (population.len() * n) as u64;
    let (mut best, mut best_cost) = best_of(&population, &costs);
    let mut run = GaRun { cost: best_cost, ..GaRun::default() };
    let per_generation = (population.len() as u64) * (3 * n as u64 + 64);
    let mut stalled = 0;
    while stalled < settings.stall {
        if spent + per_generation > settings.budget {
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
            mutate(&mut child, segments, &near, &mut rng);
            offspring.push(child);
        }
        costs = offspring.iter().map(cost).collect();
        spent += per_generation;
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

/// Nearest-neighbour mutation: a random gene is joined to the nearest
/// neighbour of its end by reversing the stretch between them (a 2-opt move;
/// the reversed genes are marked the other way), or, where a one-way gene
/// lies in that stretch, the neighbour is moved to follow it.
fn mutate(child: &mut Order, segments: &[Segment], near: &RTree<Start>, rng: &mut Rand) {
    let n = child.len();
    if n < 3 {
        return;
    }
    let i = rng.random_range(0..n - 1);
    let (g, reversed) = child[i];
    let end = segments[g as usize].ends(reversed).1;
    let Some((h, h_reversed)) = near.nearest_neighbor_iter([end.x, end.y]).map(|e| e.data).find(|&(s, _)| s != g) else { return };
    let j = child.iter().position(|&(s, _)| s == h).expect("every gene is in the route");
    // h to follow g as h_reversed says: reversing i+1..=j brings it there
    // when it lies after g, turned round.
    let turns_right = j > i && child[j].1 != h_reversed;
    let stretch = i + 1..=j;
    if turns_right && child[stretch.clone()].iter().all(|&(s, _)| segments[s as usize].either_way || segments[s as usize].from == segments[s as usize].to) {
        child[stretch.clone()].reverse();
        for gene in &mut child[stretch] {
            if segments[gene.0 as usize].either_way {
                gene.1 = !gene.1;
            }
        }
        return;
    }
    let gene = child.remove(j);
    let to = if j < i { i } else { i + 1 };
    child.insert(to, (gene.0, h_reversed));
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

    fn valid(order: &Order, segments: &[Segment]) {
        let mut seen = vec![false; segments.len()];
        for &(g, reversed) in order {
            assert!(!seen[g as usize], "gene {g} twice");
            seen[g as usize] = true;
            assert!(!reversed || segments[g as usize].either_way, "a one-way segment reversed");
        }
        assert!(seen.iter().all(|&s| s), "every gene once");
    }

    fn air(order: &Order, segments: &[Segment]) -> f64 {
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
        for _ in 0..200 {
            let mut child = pmx(&a, &b, 0.5, &mut rng);
            valid(&child, &segments);
            mutate(&mut child, &segments, &near, &mut rng);
            valid(&child, &segments);
        }
    }

    #[test]
    fn the_search_is_never_worse_than_what_it_is_given_and_the_same_for_the_same_seed() {
        let segments = grid(80);
        let cost = |o: &Order| air(o, &segments);
        // A poor route given: every other segment first.
        let given: Order = (0..80u32).step_by(2).chain((1..80u32).step_by(2)).map(|g| (g, false)).collect();
        let settings = GaSettings { stall: 10, ..GaSettings::default() };
        let (best, run) = evolve(&segments, Point::origin(), &cost, vec![given.clone()], &settings, &TimeCap::none());
        valid(&best, &segments);
        assert!((cost(&best) - run.cost).abs() < 1e-9 && run.cost <= cost(&given));
        assert!(run.cost < 0.5 * cost(&given), "{} against {}", run.cost, cost(&given));
        let (again, _) = evolve(&segments, Point::origin(), &cost, vec![given], &settings, &TimeCap::none());
        assert_eq!(best, again);
    }
}
