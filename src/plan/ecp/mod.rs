//! The End-point Cutting Problem (seed 001): every element (a line or an arc,
//! cut in either direction) is a district of two cities, one per direction;
//! the route visits one city of every district, from a start point back to it,
//! and air moves between the end of one cut and the start of the next are what
//! it minimises. Contours may be pre-empted (left and finished later), under
//! two precedence rules that keep cut-out material from falling before it is
//! done with:
//! * **inner before outer**: every element of an inner contour is cut before
//!   its outer contour is closed (the outer's last element is cut);
//! * **common cut**: an element shared by two contours never closes both at
//!   once (one of them still has an element to cut after it).
//!
//! * [`checker`]: the independent feasibility checker, written from these
//!   definitions alone;
//! * [`exact`]: the optimum of small instances (dynamic programming over
//!   subsets and directions), the reference for the search's tests;
//! * [`construct`]: feasible starting routes (nearest feasible, seed 001's
//!   insertion, contour order) in O(n log n), and dir-opt; `order_list`: the
//!   labelled list the insertion builds its route on;
//! * [`moves`]: the moves of the searches, their O(1) cost changes and
//!   feasibility from the moved run's contours;
//! * [`ils`]: the default search (iterated local search with relaxed starts);
//! * [`tabu`]: seed 001's tabu search, the reference it is measured against;
//! * [`model`]: a job's [`Topology`](crate::topology::Topology) as an
//!   instance, and a route back to polylines.

pub mod checker;
pub mod construct;
pub mod exact;
pub mod ils;
pub mod moves;
pub mod model;
mod order_list;
pub mod tabu;

use crate::config::SearchKind;
use crate::topology::CommonCut;
use crate::job::Point;

/// The best route `kind` finds with the options' budget (`kicks`, for the
/// tabu search its iterations) and time limit, on the options' threads.
pub fn solve(inst: &Instance, kind: SearchKind, options: &ils::SearchOptions) -> ils::SearchResult {
    match kind {
        SearchKind::Ils => ils::search(inst, options),
        SearchKind::Tabu => {
            let start = construct::insertion(inst);
            let defaults = tabu::TabuOptions::new(inst);
            let tabu_options = tabu::TabuOptions { seed: options.seed, iterations: options.kicks.unwrap_or(defaults.iterations), ..defaults };
            tabu::parallel_tabu_search(inst, &start, &tabu_options, options.time_limit, options.searches, options.threads)
        }
    }
}

/// How air-move lengths are measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Metric {
    /// Euclidean distance in mm.
    Euclidean,
    /// TSPLIB's EUC_2D: the Euclidean distance rounded to the nearest integer
    /// (so that a benchmark's optimum is the published one).
    TsplibRounded,
    /// TSPLIB's CEIL_2D: the Euclidean distance rounded up.
    TsplibCeil,
    /// TSPLIB's ATT (pseudo-Euclidean): r = √((dx² + dy²) / 10), rounded to
    /// the nearest integer and up by one where that falls below r. The
    /// points are TSPLIB's coordinates divided by 4 (exact in binary
    /// floating point, so dx and dy come back exactly): the distance is
    /// then never below the Euclidean distance of the stored points, as the
    /// searches' neighbour lists, which prune by that gap, assume.
    TsplibAtt,
    /// TSPLIB's GEO: the points are (latitude, longitude) in radians, as
    /// TSPLIB converts its DDD.MM coordinates; the great-circle distance on
    /// a sphere of radius 6378.388 km, truncated after adding 1 (so at least
    /// 1 between distinct points; 0 from a point to itself, which a tour
    /// never measures but a route from a city as depot does).
    TsplibGeo,
    /// The objective `length·d + time·t·v` of an air move of length `d`
    /// taking `t` at best, rest to rest (`objective::MotionModel`): its
    /// machine time counted as the mm the axes' top speed `v` covers in it,
    /// so that pierce and turn costs keep their unit (mm of air move).
    Machine { length: f64, time: f64, motion: crate::plan::objective::MotionModel },
}

/// One element to cut: a line or arc from `a` to `b` (cut either way), or a
/// point (a == b) such as a TSPLIB city.
#[derive(Debug, Clone, PartialEq)]
pub struct Element {
    pub a: Point,
    pub b: Point,
}

/// A precedence-constrained cutting instance.
#[derive(Debug, Clone)]
pub struct Instance {
    pub elements: Vec<Element>,
    /// Each contour's elements. An element on two contours is a common cut.
    pub contours: Vec<Vec<usize>>,
    /// (inner, outer): every element of `inner` is cut before `outer` closes.
    pub inner_outer: Vec<(usize, usize)>,
    /// Where the route starts and ends.
    pub depot: Point,
    pub metric: Metric,
    /// Cost of starting a cut anywhere but where the previous cut ended (a
    /// pierce), in the same unit as the air moves.
    pub pierce_cost: f64,
    /// Per element, for its ends a and b: a cut starting there needs no
    /// pierce (it lies on the plate's edge). Empty: every start pierces.
    pub edge_starts: Vec<[bool; 2]>,
    /// What going on through a sharp turn costs (none by default).
    pub turns: Turns,
    /// What going from one cut straight to another costs besides (seed
    /// 000's thermal penalties; none by default).
    pub penalties: Penalties,
}

/// Costs of going from one cut to another, in the unit of the air moves,
/// few and learnt (seed 000: the thermal planner raises those of the
/// decisions that led to a thermal violation). Symmetric as the metrics
/// are: going from `a` to `b` costs what going from `b` reversed to `a`
/// reversed does (the same two cuts side by side in a reversed run).
#[derive(Debug, Clone, Default)]
pub struct Penalties {
    /// Per cut (element·2 + reversed): the cuts after it that cost, and
    /// what, sorted by cut (looked up by bisection: the search asks often).
    by_from: Vec<Vec<(u32, f64)>>,
    count: usize,
}

impl Penalties {
    fn id(cut: Cut) -> usize {
        2 * cut.element + usize::from(cut.reversed)
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// How many pairs of cuts carry a penalty.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn get(&self, from: Cut, to: Cut) -> f64 {
        let to = Self::id(to) as u32;
        match self.by_from.get(Self::id(from)) {
            Some(list) if !list.is_empty() => list.binary_search_by_key(&to, |e| e.0).map_or(0.0, |k| list[k].1),
            _ => 0.0,
        }
    }

    /// Adds `amount` to going from `from` to `to`, and from `to` reversed
    /// to `from` reversed.
    pub fn add(&mut self, from: Cut, to: Cut, amount: f64) {
        let flip = |c: Cut| Cut { reversed: !c.reversed, ..c };
        self.add_one(from, to, amount);
        if flip(to) != from {
            self.add_one(flip(to), flip(from), amount);
        }
    }

    fn add_one(&mut self, from: Cut, to: Cut, amount: f64) {
        let (f, t) = (Self::id(from), Self::id(to) as u32);
        if self.by_from.len() <= f {
            self.by_from.resize(f + 1, Vec::new());
        }
        let list = &mut self.by_from[f];
        match list.binary_search_by_key(&t, |e| e.0) {
            Ok(k) => list[k].1 += amount,
            Err(k) => {
                list.insert(k, (t, amount));
                self.count += 1;
            }
        }
    }
}

/// Sharp-angle macros in the cutting model (seed 000): going on from one cut
/// onto the next through a turn sharper than the corner angle costs `cost`
/// (in the unit of the air moves, as a pierce does). The turn is the same
/// whichever way the two are cut, so costs stay symmetric.
#[derive(Debug, Clone, Default)]
pub struct Turns {
    /// Per element: its unit heading where it leaves `a` and where it
    /// arrives at `b`. Empty: no turn costs anything.
    pub headings: Vec<[nalgebra::Vector2<f64>; 2]>,
    pub cost: f64,
    /// The cosine of the corner angle: a turn whose headings' dot product
    /// is below it is sharp.
    pub cos_sharp: f64,
}

/// One element cut in one direction: from `a` to `b`, or from `b` to `a` when reversed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Cut {
    pub element: usize,
    pub reversed: bool,
}

impl Instance {
    pub fn distance(&self, p: Point, q: Point) -> f64 {
        let d = (q - p).norm();
        match self.metric {
            Metric::Euclidean => d,
            // Truncating a non-negative number is its floor, without the
            // library call `floor` is on baseline x86-64 (the search's
            // hottest line on TSPLIB instances).
            Metric::TsplibRounded => (d + 0.5) as i64 as f64,
            Metric::TsplibCeil => d.ceil(),
            Metric::TsplibAtt => {
                let (dx, dy) = (4.0 * (q.x - p.x), 4.0 * (q.y - p.y));
                let r = ((dx * dx + dy * dy) / 10.0).sqrt();
                let t = (r + 0.5).floor();
                if t < r {
                    t + 1.0
                } else {
                    t
                }
            }
            Metric::TsplibGeo if p == q => 0.0,
            Metric::TsplibGeo => {
                const RRR: f64 = 6378.388;
                let q1 = (p.y - q.y).cos();
                let q2 = (p.x - q.x).cos();
                let q3 = (p.x + q.x).cos();
                (RRR * (0.5 * ((1.0 + q1) * q2 - (1.0 - q1) * q3)).clamp(-1.0, 1.0).acos() + 1.0).trunc()
            }
            Metric::Machine { length, time, motion } => {
                let rest = nalgebra::Vector2::zeros();
                let moving = if time > 0.0 { time * motion.move_time(p, rest, q, rest) * motion.axis.velocity } else { 0.0 };
                length * d + moving
            }
        }
    }

    /// Where a cut starts and ends.
    pub fn ends(&self, cut: Cut) -> (Point, Point) {
        let e = &self.elements[cut.element];
        if cut.reversed {
            (e.b, e.a)
        } else {
            (e.a, e.b)
        }
    }

    /// Cost of moving from the end of `from` (or the depot) to the start of
    /// `to`: the air move, and a pierce unless the cut goes on where it was.
    pub fn step(&self, from: Option<Cut>, to: Cut) -> f64 {
        let here = from.map_or(self.depot, |c| self.ends(c).1);
        let (start, _) = self.ends(to);
        let air = self.distance(here, start);
        let penalty = match from {
            Some(from) if !self.penalties.is_empty() => self.penalties.get(from, to),
            _ => 0.0,
        };
        penalty
            + match from {
                Some(from) if air <= 0.0 => self.turn(from, to),
                _ => air + self.pierce_at(to),
            }
    }

    /// What going on from `from` straight into `to` costs: a sharp-angle
    /// macro where the turn between them is sharp.
    pub fn turn(&self, from: Cut, to: Cut) -> f64 {
        let t = &self.turns;
        if t.cost <= 0.0 || t.headings.is_empty() {
            return 0.0;
        }
        let (f, g) = (&t.headings[from.element], &t.headings[to.element]);
        let out = if from.reversed { -f[0] } else { f[1] };
        let into = if to.reversed { -g[1] } else { g[0] };
        if out.norm_squared() > 0.0 && into.norm_squared() > 0.0 && out.dot(&into) < t.cos_sharp {
            t.cost
        } else {
            0.0
        }
    }

    /// What starting `cut` costs after an air move: a pierce, or nothing
    /// where it starts on the plate's edge.
    pub fn pierce_at(&self, cut: Cut) -> f64 {
        if self.starts_on_edge(cut) {
            0.0
        } else {
            self.pierce_cost
        }
    }

    /// Whether `cut` starts on the plate's edge (no pierce there).
    pub fn starts_on_edge(&self, cut: Cut) -> bool {
        self.edge_starts.get(cut.element).is_some_and(|ends| ends[usize::from(cut.reversed)])
    }

    /// Air length plus pierce costs of a route, back to the depot included.
    pub fn cost(&self, route: &[Cut]) -> f64 {
        let mut total = 0.0;
        let mut prev = None;
        for &c in route {
            total += self.step(prev, c);
            prev = Some(c);
        }
        let end = prev.map_or(self.depot, |c| self.ends(c).1);
        total + self.distance(end, self.depot)
    }

    /// The air length alone (no pierce costs).
    pub fn air_length(&self, route: &[Cut]) -> f64 {
        let mut here = self.depot;
        let mut total = 0.0;
        for &c in route {
            let (s, e) = self.ends(c);
            total += self.distance(here, s);
            here = e;
        }
        total + self.distance(here, self.depot)
    }

    /// Elements shared by two contours, with the two contours.
    pub fn common_cuts(&self) -> Vec<CommonCut> {
        crate::topology::common_cuts(&self.contours, self.elements.len())
    }

    /// Precedence relations in all: inner/outer pairs plus common cuts.
    pub fn precedences(&self) -> usize {
        self.inner_outer.len() + self.common_cuts().len()
    }
}

/// Random instances for the tests of the planner's parts: `n` segments in a
/// 100 mm square, contours of `sizes` consecutive elements, up to two common
/// cuts and three inner/outer pairs (each contour inside one other at most).
#[cfg(test)]
pub(crate) fn random_instance(n: usize, seed: u64, sizes: std::ops::RangeInclusive<usize>, pierce_cost: f64) -> Instance {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let pt = |rng: &mut rand_chacha::ChaCha8Rng| Point::new(rng.random_range(0.0..100.0), rng.random_range(0.0..100.0));
    let elements: Vec<Element> = (0..n).map(|_| Element { a: pt(&mut rng), b: pt(&mut rng) }).collect();
    let mut contours: Vec<Vec<usize>> = Vec::new();
    let mut e = 0;
    while e < n {
        let len = rng.random_range(sizes.clone()).min(n - e);
        contours.push((e..e + len).collect());
        e += len;
    }
    let k = contours.len();
    for _ in 0..2 {
        let (a, b) = (rng.random_range(0..k), rng.random_range(0..k));
        let shared = contours[a][0];
        if a != b && !contours[b].contains(&shared) && contours.iter().filter(|c| c.contains(&shared)).count() == 1 {
            contours[b].push(shared);
        }
    }
    let mut inner_outer = Vec::new();
    for _ in 0..3 {
        let (i, o) = (rng.random_range(0..k), rng.random_range(0..k));
        if i != o && !inner_outer.iter().any(|&(x, y)| (x, y) == (i, o) || (x, y) == (o, i)) && !inner_outer.iter().any(|&(x, _)| x == i) {
            inner_outer.push((i, o));
        }
    }
    Instance { elements, contours, inner_outer, depot: Point::new(0.0, 0.0), metric: Metric::Euclidean, pierce_cost, edge_starts: Vec::new(), turns: Turns::default(), penalties: Penalties::default() }
}

/// Random instances of 12 elements (contours of 2 to 4, pierce cost 3) that
/// have a feasible route, with their exact optimum: what the searches' tests
/// must reach.
#[cfg(test)]
pub(crate) fn small_instances_with_optimum() -> Vec<(u64, Instance, f64)> {
    let found: Vec<_> = (0..30u64)
        .filter_map(|k| {
            let inst = random_instance(12, 100 + k, 2..=4, 3.0);
            exact::solve(&inst).map(|(optimum, _)| (100 + k, inst, optimum))
        })
        .collect();
    assert!(found.len() >= 20, "only {} feasible instances", found.len());
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn costs_count_air_moves_and_pierces() {
        let p = |x: f64, y: f64| Point::new(x, y);
        let inst = Instance {
            elements: vec![Element { a: p(0.0, 0.0), b: p(10.0, 0.0) }, Element { a: p(10.0, 0.0), b: p(10.0, 10.0) }],
            contours: vec![vec![0, 1]],
            inner_outer: vec![],
            depot: p(0.0, 0.0),
            metric: Metric::Euclidean,
            pierce_cost: 2.0,
            edge_starts: Vec::new(),
            turns: Turns::default(),
            penalties: Penalties::default(),
        };
        let forward = [Cut { element: 0, reversed: false }, Cut { element: 1, reversed: false }];
        // One pierce at the start, the second cut goes on where the first ended,
        // then 10·√2 back home.
        assert!((inst.cost(&forward) - (2.0 + 200f64.sqrt())).abs() < 1e-12);
        assert!((inst.air_length(&forward) - 200f64.sqrt()).abs() < 1e-12);
        // The same two cuts the other way round cost the same.
        let back = [Cut { element: 1, reversed: true }, Cut { element: 0, reversed: true }];
        assert!((inst.cost(&back) - inst.cost(&forward)).abs() < 1e-12);
        // Cutting the second element against the first: an air move and a pierce more.
        let broken = [Cut { element: 0, reversed: false }, Cut { element: 1, reversed: true }];
        assert!((inst.cost(&broken) - (2.0 + 10.0 + 2.0 + 10.0)).abs() < 1e-12);
        assert!((inst.air_length(&broken) - 20.0).abs() < 1e-12);
        // A sharp-angle macro where the cut goes on round the right angle
        // (sharper than 30°), either way round; none on a straight run on.
        let v = nalgebra::Vector2::new;
        let turns = Turns { headings: vec![[v(1.0, 0.0), v(1.0, 0.0)], [v(0.0, 1.0), v(0.0, 1.0)]], cost: 3.0, cos_sharp: 30f64.to_radians().cos() };
        let sharp = Instance { turns, ..inst.clone() };
        assert!((sharp.cost(&forward) - inst.cost(&forward) - 3.0).abs() < 1e-12);
        assert!((sharp.cost(&back) - sharp.cost(&forward)).abs() < 1e-12);
        assert_eq!(sharp.cost(&broken), inst.cost(&broken), "no turn where an air move comes between");
        let straight = Instance { turns: Turns { headings: vec![[v(1.0, 0.0); 2], [v(1.0, 0.0); 2]], ..sharp.turns.clone() }, ..sharp.clone() };
        assert_eq!(straight.turn(forward[0], forward[1]), 0.0);
        let rounded = Instance { metric: Metric::TsplibRounded, ..inst };
        assert_eq!(rounded.distance(p(0.0, 0.0), p(1.0, 1.0)), 1.0);
        assert_eq!(rounded.distance(p(0.0, 0.0), p(1.5, 0.0)), 2.0);
    }

    /// Under machine time an air move costs its time, rest to rest, as the
    /// mm the top speed covers in it: axes that move at once make a move 7
    /// mm along both quicker than one 9 mm along one, which length ranks
    /// the other way round; the route's cost follows.
    #[test]
    fn under_machine_time_air_moves_cost_their_time() {
        use crate::config::Limits;
        use crate::plan::objective::MotionModel;
        let p = |x: f64, y: f64| Point::new(x, y);
        let motion = MotionModel { axis: Limits { velocity: 100.0, acceleration: 1000.0, jerk: 1e6 }, bridges: false };
        let (a, b, c) = (p(0.0, 0.0), p(7.0, 7.0), p(9.0, 0.0));
        let inst = |metric| Instance {
            elements: vec![Element { a: b, b: c }],
            contours: vec![vec![0]],
            inner_outer: vec![],
            depot: a,
            metric,
            pierce_cost: 5.0,
            edge_starts: Vec::new(),
            turns: Turns::default(),
            penalties: Penalties::default(),
        };
        let rest = nalgebra::Vector2::zeros();
        let t = |q: Point| motion.move_time(a, rest, q, rest);
        assert!(t(b) < t(c) && (b - a).norm() > (c - a).norm());
        let (length, time, mix) = (inst(Metric::Euclidean), inst(Metric::Machine { length: 0.0, time: 1.0, motion }), inst(Metric::Machine { length: 0.5, time: 2.0, motion }));
        assert!((time.distance(a, b) - 100.0 * t(b)).abs() < 1e-12);
        assert!((mix.distance(a, c) - (0.5 * 9.0 + 200.0 * t(c))).abs() < 1e-12);
        assert_eq!(time.distance(b, b), 0.0);
        assert_eq!(Instance { metric: Metric::Machine { length: 1.0, time: 0.0, motion }, ..length.clone() }.distance(a, b), (b - a).norm());
        // Entering the element at b: cheaper under time, dearer under length.
        let (from_b, from_c) = ([Cut { element: 0, reversed: false }], [Cut { element: 0, reversed: true }]);
        let out = |inst: &Instance, route: &[Cut]| inst.cost(route) - inst.distance(inst.ends(route[0]).1, a);
        assert!(out(&time, &from_b) < out(&time, &from_c));
        assert!(out(&length, &from_b) > out(&length, &from_c));
        assert!((out(&time, &from_b) - (100.0 * t(b) + 5.0)).abs() < 1e-9, "the pierce keeps its mm");
    }
}
