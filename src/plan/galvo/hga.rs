//! The hybrid genetic algorithm of seed 003 (`--planner hga`).
//!
//! A chromosome is the order of all geometries (seed 003's sub-cluster order)
//! with each geometry's entry choice (its vertex order) and field. Decoding
//! makes the fields contiguous (each field where its first geometry comes,
//! its geometries in chromosome order), which is what seed 003's penalty on
//! field-crossing jumps achieves. Every new chromosome is enhanced (seed 003's
//! CEA): here our route search with a few kicks, then the exact entry choice.
//!
//! Population: 3 × 32 at the start (random orders and choices, two with all
//! choices at the first and at the last vertex, and, our addition, the HHA
//! route); the best 20 % survive; 0.5 × 0.8 × ps order crossovers of random
//! pairs of survivors each give two children; a child mutates with
//! probability 0.3 (every geometry of one random field gets a random entry).
//! The population grows by half (at most 48) after a generation without
//! progress and shrinks by a fifth (at least 16) after one with; the search
//! stops after five generations without progress (at most 200 generations),
//! or at the user's time limit if that comes first. Children are enhanced in
//! parallel, each from its own seed, so the cores do not change the result.

use super::route::{neighbours, Route, Stop};
use super::{GalvoSettings, Layout};
use crate::job::Job;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use crate::plan::stop::TimeCap;

/// Order, entry choice per stop and field per stop.
#[derive(Debug, Clone)]
struct Chromosome {
    order: Vec<u32>,
    choice: Vec<u32>,
    field: Vec<u32>,
    length: f64,
}

/// A chromosome before its enhancement: order, entry choices, fields, and
/// the seed of its search.
type Raw = (Vec<u32>, Vec<u32>, Vec<u32>, u64);

const START_POPULATION: usize = 32;
const MIN_POPULATION: usize = 16;
const MAX_POPULATION: usize = 48;
const ELITE_SHARE: f64 = 0.2;
const MUTATION: f64 = 0.3;
const STALL_GENERATIONS: usize = 5;
/// A bound on the work however long the search keeps finding better routes.
const MAX_GENERATIONS: usize = 200;

struct Search<'a> {
    layout: &'a Layout,
    near: Vec<Vec<u32>>,
    cap: &'a TimeCap,
    /// Kicks of the enhancement per geometry.
    kicks: usize,
}

impl Search<'_> {
    /// Seed 003's CEA: the chromosome decoded into a route with contiguous
    /// fields, then improved.
    fn enhance(&self, order: Vec<u32>, choice: Vec<u32>, field: Vec<u32>, seed: u64) -> Chromosome {
        let stops = &self.layout.stops;
        let fields = self.layout.fields.len();
        // Fields in order of first appearance, each holding its stops in order.
        let mut rank = vec![u32::MAX; fields];
        let mut next = 0;
        for &s in &order {
            let f = field[s as usize] as usize;
            if rank[f] == u32::MAX {
                rank[f] = next;
                next += 1;
            }
        }
        let mut grouped = order;
        grouped.sort_by_key(|&s| rank[field[s as usize] as usize]);
        let route = Route::new(stops, grouped, choice, field, fields);
        let route = route.search(&self.near, self.kicks * stops.len(), self.cap, seed);
        Chromosome { length: route.length(), order: route.order().to_vec(), choice: route.choices().to_vec(), field: route.fields().to_vec() }
    }

    /// Enhances a batch on every core, in order.
    fn enhance_all(&self, raw: Vec<Raw>, threads: usize) -> Vec<Chromosome> {
        crate::parallel::tasks(raw.len(), threads, |k| {
            let (order, choice, field, seed) = raw[k].clone();
            self.enhance(order, choice, field, seed)
        })
    }
}

/// A random entry choice for a stop.
fn random_choice(stop: &Stop, rng: &mut ChaCha8Rng) -> u32 {
    if stop.closed {
        rng.random_range(0..stop.vertices.len() as u32)
    } else {
        rng.random_range(0..2)
    }
}

/// Seed 003's order crossover: the child keeps `a`'s genes at positions
/// i..=j and takes the others in `b`'s order around them; each gene brings
/// its entry choice and field from the parent it comes from.
fn crossover(a: &Chromosome, b: &Chromosome, i: usize, j: usize) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let n = a.order.len();
    let mut from_a = vec![false; n];
    for &s in &a.order[i..=j] {
        from_a[s as usize] = true;
    }
    let mut rest = b.order.iter().copied().filter(|&s| !from_a[s as usize]);
    let mut order = Vec::with_capacity(n);
    order.extend(rest.by_ref().take(i));
    order.extend_from_slice(&a.order[i..=j]);
    order.extend(rest);
    let pick = |s: usize, of: fn(&Chromosome) -> &Vec<u32>| if from_a[s] { of(a)[s] } else { of(b)[s] };
    let choice = (0..n).map(|s| pick(s, |c| &c.choice)).collect();
    let field = (0..n).map(|s| pick(s, |c| &c.field)).collect();
    (order, choice, field)
}

/// The HGA's route, starting from the HHA's (`hha`).
pub fn plan_route<'a>(job: &Job, layout: &'a Layout, hha: Route<'a>, settings: &GalvoSettings, cap: &'a TimeCap) -> Route<'a> {
    let n = job.geometries.len();
    let stops = &layout.stops;
    if n < 4 {
        return hha;
    }
    let search = Search { layout, near: neighbours(stops, 8), cap, kicks: 2 };
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let threads = settings.threads.max(1);

    // The start: random orders and choices (each stop in one of its fields),
    // two with extreme choices, and the HHA route.
    let random_field = |s: &Stop, rng: &mut ChaCha8Rng| s.fields[rng.random_range(0..s.fields.len())];
    let mut raw = Vec::new();
    for k in 0..3 * START_POPULATION - 1 {
        let mut order: Vec<u32> = (0..n as u32).collect();
        order.shuffle(&mut rng);
        let choice: Vec<u32> = match k {
            0 => vec![0; n],
            1 => stops.iter().map(|s| if s.closed { s.vertices.len() as u32 - 1 } else { 1 }).collect(),
            _ => stops.iter().map(|s| random_choice(s, &mut rng)).collect(),
        };
        let field = stops.iter().map(|s| random_field(s, &mut rng)).collect();
        raw.push((order, choice, field, rng.random()));
    }
    let mut population = vec![Chromosome { length: hha.length(), order: hha.order().to_vec(), choice: hha.choices().to_vec(), field: hha.fields().to_vec() }];
    population.extend(search.enhance_all(raw, threads));
    population.sort_by(|a, b| a.length.total_cmp(&b.length));

    let mut size = START_POPULATION;
    let mut stalled = 0;
    let mut best = population[0].length;
    for _ in 0..MAX_GENERATIONS {
        if stalled >= STALL_GENERATIONS || cap.reached() {
            break;
        }
        let elite = ((ELITE_SHARE * size as f64).round() as usize).clamp(2, population.len());
        population.truncate(elite);
        let pairs = (0.5 * 0.8 * size as f64).round().max(1.0) as usize;
        let mut raw = Vec::with_capacity(2 * pairs);
        for _ in 0..pairs {
            let a = rng.random_range(0..elite);
            let b = (a + rng.random_range(1..elite)) % elite;
            let mut cut = [rng.random_range(0..n), rng.random_range(0..n)];
            cut.sort_unstable();
            for (x, y) in [(a, b), (b, a)] {
                let (order, mut choice, field) = crossover(&population[x], &population[y], cut[0], cut[1]);
                if rng.random_bool(MUTATION) {
                    // Every geometry of one field (as the child has them) gets a random entry.
                    let f = field[order[rng.random_range(0..n)] as usize];
                    for s in 0..n {
                        if field[s] == f {
                            choice[s] = random_choice(&stops[s], &mut rng);
                        }
                    }
                }
                raw.push((order, choice, field, rng.random()));
            }
        }
        population.extend(search.enhance_all(raw, threads));
        population.sort_by(|a, b| a.length.total_cmp(&b.length));
        if population[0].length < best - 1e-9 {
            best = population[0].length;
            stalled = 0;
            size = ((size as f64 * 0.8) as usize).max(MIN_POPULATION);
        } else {
            stalled += 1;
            size = ((size as f64 * 1.5) as usize).min(MAX_POPULATION);
        }
    }
    let best = population.swap_remove(0);
    let route = Route::new(stops, best.order, best.choice, best.field, layout.fields.len());
    if route.length() <= hha.length() {
        route
    } else {
        hha
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chromosome(order: Vec<u32>) -> Chromosome {
        let n = order.len();
        let tag = order[0] * 100;
        Chromosome { choice: (0..n as u32).map(|s| tag + s).collect(), field: vec![tag; n], order, length: 0.0 }
    }

    #[test]
    fn the_order_crossover_keeps_one_parents_run_and_the_others_order() {
        let a = chromosome(vec![1, 0, 2, 3, 5, 6, 4]);
        let b = chromosome(vec![0, 1, 6, 4, 5, 2, 3]);
        let (order, choice, field) = crossover(&a, &b, 2, 4);
        // a's genes at 2..=4 stay; the rest in b's order around them.
        assert_eq!(order, vec![0, 1, 2, 3, 5, 6, 4]);
        for s in 0..7u32 {
            let from_a = [2, 3, 5].contains(&s);
            let parent = if from_a { &a } else { &b };
            assert_eq!(choice[s as usize], parent.choice[s as usize]);
            assert_eq!(field[s as usize], parent.field[s as usize]);
        }
        let (order, ..) = crossover(&b, &a, 0, 6);
        assert_eq!(order, b.order);
    }
}
