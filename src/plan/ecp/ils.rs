//! The default search: iterated local search (ILS) over the moves of
//! [`super::moves`], independent searches one per core.
//!
//! * **Descent**: first improvement with don't-look bits (only elements whose
//!   links changed look again), over Or-opt runs of 1 to 3, 2-opt reversals and
//!   3-opt (the stretch between an element and a neighbour, any length, moved
//!   next to a neighbour of either of its ends, kept or reversed), each
//!   generated from neighbour lists (the nearest, and the nearest in each
//!   quadrant around each end: rows of holes need the links between rows)
//!   and cut short by the gain criterion: the new link at an element must be
//!   shorter than the one it replaces. A move's rules are judged from the
//!   shorter of the run and what it jumps.
//! * **Kicks**: a random double bridge (two neighbouring stretches of random,
//!   log-uniform length swapped) that keeps every rule, then descent; the
//!   result is kept if no worse than the best, else its moves are undone.
//! * **Starts.** Seed 001's insertion (IB) is feasible but sets the route's
//!   general direction early, and the rules then pin it: from it the search
//!   stays several % off on a thousand cities. So every search starts
//!   *relaxed*: the same search without rules for a share of the kicks (and
//!   of the time left, under a time limit), the result's better end taken (a
//!   route and its reverse cost the same, they break different rules), then
//!   the search again under a penalty per broken rule that doubles until none
//!   is broken, and what is still broken mended by moving single cuts (the
//!   fewest broken rules, then the cheapest), and each contour's last cut
//!   past its inner contours where no single move mends one. The insertion
//!   is the fallback should that fail.
//! * **Stop.** Each search makes a budget of kicks that grows with the
//!   instance ([`default_kicks`]), so the route does not depend on the load
//!   or the cores; a time limit the user sets may end it first.
//!
//! Seed 001's tabu search ([`super::tabu`]) stays as the reference this is
//! measured against.

use std::time::{Duration, Instant};

use crate::plan::stop::{SearchStop, TimeCap};

use rand::{Rng, SeedableRng};

use super::construct::{contour_depths, contour_order_construction, insertion_within};
use super::moves::{apply, delta, feasible, flip, link, Move, Neighbours, Rules, Tour};
use super::{Cut, Instance};

/// A precedence rule, to count the broken ones while a relaxed search may break them.
#[derive(Debug, Clone, Copy)]
enum Rule {
    Nest { inner: usize, outer: usize },
    Common { element: usize, a: usize, b: usize },
}

struct RuleBook {
    rules: Vec<Rule>,
    /// The rules each contour takes part in.
    of_contour: Vec<Vec<usize>>,
}

impl RuleBook {
    fn new(inst: &Instance) -> RuleBook {
        let mut rules: Vec<Rule> = inst.inner_outer.iter().map(|&(inner, outer)| Rule::Nest { inner, outer }).collect();
        rules.extend(inst.common_cuts().iter().map(|c| Rule::Common { element: c.element, a: c.contours.0, b: c.contours.1 }));
        let mut of_contour = vec![Vec::new(); inst.contours.len()];
        for (r, rule) in rules.iter().enumerate() {
            let (a, b) = contours_of_rule(rule);
            of_contour[a].push(r);
            of_contour[b].push(r);
        }
        RuleBook { rules, of_contour }
    }

    /// Whether rule `r` is broken with elements at positions `pos`.
    fn broken(&self, inst: &Instance, r: usize, pos: impl Fn(usize) -> usize) -> bool {
        let closes = |k: usize| inst.contours[k].iter().map(|&e| pos(e)).max().unwrap_or(0);
        match self.rules[r] {
            Rule::Nest { inner, outer } => closes(inner) >= closes(outer),
            Rule::Common { element, a, b } => {
                let p = pos(element);
                closes(a) == p && closes(b) == p
            }
        }
    }
}

fn contours_of_rule(rule: &Rule) -> (usize, usize) {
    match *rule {
        Rule::Nest { inner, outer } => (inner, outer),
        Rule::Common { a, b, .. } => (a, b),
    }
}

/// Slack on neighbour-list pruning: TSPLIB rounding may make a link up to
/// half a unit longer than the gap between two elements.
const SLACK: f64 = 0.5;
/// Longest stretch a 2-opt move reverses or a 3-opt move carries (longer
/// ones rarely keep the rules, and cost their length to apply).
const MAX_REVERSAL: usize = 1000;
/// The same while broken rules cost a finite penalty.
const MAX_PENALISED: usize = 50;
/// Cost changes below this are rounding.
const EPS: f64 = 1e-7;

/// A route under local search.
struct Descent<'a> {
    inst: &'a Instance,
    rules: Rules,
    near: Neighbours,
    tour: Tour,
    cost: f64,
    /// Elements to look at again (don't-look bits off).
    queue: std::collections::VecDeque<usize>,
    queued: Vec<bool>,
    book: RuleBook,
    broken: Vec<bool>,
    /// Rules broken now, in all and per contour.
    violations: usize,
    broken_at: Vec<u32>,
    /// What a broken rule costs: infinite while every rule must hold (moves
    /// that break one are not taken), 0 for a search without rules.
    penalty: f64,
    scratch: std::cell::RefCell<Vec<usize>>,
    /// The moves applied since the last kick began, with their cost
    /// changes, while `recording`: a rejected kick is undone from them, in
    /// the time its moves took, not the route's length.
    journal: Vec<(Move, f64)>,
    recording: bool,
}

impl<'a> Descent<'a> {
    fn new(inst: &'a Instance, start: Vec<Cut>, near: Neighbours) -> Descent<'a> {
        let n = inst.elements.len();
        let mut pos = vec![0; n];
        for (i, c) in start.iter().enumerate() {
            pos[c.element] = i;
        }
        let cost = inst.cost(&start);
        let mut descent = Descent {
            inst,
            rules: Rules::new(inst),
            near,
            tour: Tour { cuts: start, pos },
            cost,
            queue: (0..n).collect(),
            queued: vec![true; n],
            book: RuleBook::new(inst),
            broken: Vec::new(),
            violations: 0,
            broken_at: vec![0; inst.contours.len()],
            penalty: f64::INFINITY,
            scratch: Default::default(),
            journal: Vec::new(),
            recording: false,
        };
        descent.recount();
        descent
    }

    fn lk(&self, p: isize, q: isize) -> f64 {
        link(self.inst, self.tour.at(p), self.tour.at(q))
    }

    fn wake(&mut self, e: usize) {
        if !std::mem::replace(&mut self.queued[e], true) {
            self.queue.push_back(e);
        }
    }

    fn wake_all(&mut self) {
        for e in 0..self.queued.len() {
            self.wake(e);
        }
    }

    /// Counts the broken rules afresh.
    fn recount(&mut self) {
        let pos = &self.tour.pos;
        self.broken = (0..self.book.rules.len()).map(|r| self.book.broken(self.inst, r, |e| pos[e])).collect();
        self.violations = self.broken.iter().filter(|&&b| b).count();
        self.broken_at.iter_mut().for_each(|b| *b = 0);
        for r in 0..self.broken.len() {
            if self.broken[r] {
                let (a, b) = contours_of_rule(&self.book.rules[r]);
                self.broken_at[a] += 1;
                self.broken_at[b] += 1;
            }
        }
    }

    /// The rules a move may change: those of the moved run's contours.
    fn touched_rules(&self, mv: &Move, out: &mut Vec<usize>) {
        out.clear();
        for i in mv.judged() {
            for &k in &self.rules.contours_of[self.tour.cuts[i].element] {
                out.extend_from_slice(&self.book.of_contour[k]);
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    /// How many more rules are broken after the move.
    fn violation_delta(&self, mv: &Move) -> isize {
        let mut rules = self.scratch.borrow_mut();
        self.touched_rules(mv, &mut rules);
        let pos = &self.tour.pos;
        rules.iter().map(|&r| self.book.broken(self.inst, r, |e| mv.new_pos(pos[e])) as isize - self.broken[r] as isize).sum()
    }

    /// Applies `mv` (cost change `d`) and wakes the elements at the links it changed.
    fn apply(&mut self, mv: &Move, d: f64) {
        let mut rules = std::mem::take(&mut *self.scratch.borrow_mut());
        if self.penalty.is_finite() {
            self.touched_rules(mv, &mut rules);
        } else {
            rules.clear();
        }
        let (s, l) = (mv.from as isize, mv.len as isize);
        let before = [self.tour.at(s - 1), self.tour.at(s), self.tour.at(s + l - 1), self.tour.at(s + l)];
        apply(&mut self.tour, mv);
        if self.recording {
            self.journal.push((*mv, d));
        }
        let t = mv.to as isize;
        let after = [self.tour.at(t - 1), self.tour.at(t), self.tour.at(t + l - 1), self.tour.at(t + l)];
        for c in before.into_iter().chain(after).flatten() {
            self.wake(c.element);
        }
        self.cost += d;
        for &r in &rules {
            let now = self.book.broken(self.inst, r, |e| self.tour.pos[e]);
            if now != std::mem::replace(&mut self.broken[r], now) {
                let (a, b) = contours_of_rule(&self.book.rules[r]);
                if now {
                    self.violations += 1;
                    self.broken_at[a] += 1;
                    self.broken_at[b] += 1;
                } else {
                    self.violations -= 1;
                    self.broken_at[a] -= 1;
                    self.broken_at[b] -= 1;
                }
            }
        }
        *self.scratch.borrow_mut() = rules;
    }

    /// `mv` with its cost change, if it improves the route (cost plus the
    /// penalty of broken rules) and, with an infinite penalty, keeps every rule.
    fn try_move(&self, mv: Move) -> Option<(Move, f64)> {
        let d = delta(self.inst, &self.tour, &mv);
        if self.penalty.is_infinite() {
            return (d < -EPS && feasible(self.inst, &self.rules, &self.tour, &mv)).then_some((mv, d));
        }
        // A move pays for itself by air, or by mending one broken rule at
        // most (a move that mends several at once for more is rare, and not
        // worth judging every candidate's rules for).
        let mendable = if self.violations > 0 { self.penalty } else { 0.0 };
        if d - mendable >= -EPS {
            return None;
        }
        let touches_broken = || mv.judged().any(|i| self.rules.contours_of[self.tour.cuts[i].element].iter().any(|&k| self.broken_at[k] > 0));
        if d >= -EPS && !touches_broken() {
            return None;
        }
        let dv = if self.penalty > 0.0 { self.violation_delta(&mv) } else { 0 };
        (d + self.penalty * (dv as f64) < -EPS).then_some((mv, d))
    }

    /// The first improving move that changes a link at `x`.
    fn improving_move(&self, x: usize) -> Option<(Move, f64)> {
        let n = self.tour.cuts.len();
        let p = self.tour.pos[x];
        let pi = p as isize;
        let near = &self.near.lists;
        // Under a finite penalty every candidate's rules are counted, in
        // time with its length: long stretches are left to the search
        // that keeps the rules.
        let longest = if self.penalty.is_finite() && self.penalty > 0.0 { MAX_PENALISED } else { MAX_REVERSAL };
        // Or-opt: runs of 1 to 3 starting or ending at x, next to a neighbour of an end.
        for len in 1..=3usize.min(n - 1) {
            let starting = (p + len <= n).then_some(p);
            let ending = (len > 1 && p + 1 >= len).then(|| p + 1 - len);
            for from in starting.into_iter().chain(ending) {
                let (f, l) = (from as isize, len as isize);
                let gain = self.lk(f - 1, f) + self.lk(f + l - 1, f + l) - self.lk(f - 1, f + l);
                if gain <= 1e-7 {
                    continue;
                }
                if let Some(m) = self.try_move(Move { from, len, to: from, reverse: true }) {
                    return Some(m);
                }
                for end in [self.tour.cuts[from].element, self.tour.cuts[from + len - 1].element] {
                    for &(m, g) in &near[end] {
                        if g > gain + SLACK {
                            break;
                        }
                        let q = self.tour.pos[m];
                        if q >= from && q < from + len {
                            continue;
                        }
                        let q = if q > from { q - len } else { q };
                        for to in [q, q + 1] {
                            for reverse in [false, true] {
                                if to != from || reverse {
                                    if let Some(found) = self.try_move(Move { from, len, to, reverse }) {
                                        return Some(found);
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        // 2-opt: a neighbour of x brought next to it by reversing what lies between.
        let succ = self.lk(pi, pi + 1);
        let pred = self.lk(pi - 1, pi);
        for &(m, g) in &near[x] {
            if g > succ.max(pred) + SLACK {
                break;
            }
            let q = self.tour.pos[m];
            if q > p + 1 && q - p <= longest && g <= succ + SLACK {
                if let Some(found) = self.try_move(Move { from: p + 1, len: q - p, to: p + 1, reverse: true }) {
                    return Some(found);
                }
            } else if q + 1 < p && p - q <= longest && g <= pred + SLACK {
                if let Some(found) = self.try_move(Move { from: q, len: p - q, to: q, reverse: true }) {
                    return Some(found);
                }
            }
        }
        // 3-opt: x brought next to a neighbour y by moving the stretch
        // between them (any length) next to a neighbour of one of its ends,
        // kept or reversed so that that end meets it.
        for &(y, g) in &near[x] {
            if g > succ.max(pred) + SLACK {
                break;
            }
            let q = self.tour.pos[y];
            // The stretch after x up to y, or after y up to x.
            let (from, to_end) = if q > p + 1 && g <= succ + SLACK { (p + 1, q) } else if q + 1 < p && g <= pred + SLACK { (q + 1, p) } else { continue };
            let len = to_end - from;
            if len > longest || len + 1 >= n {
                continue;
            }
            let (f, l) = (from as isize, len as isize);
            let gain = self.lk(f - 1, f) + self.lk(f + l - 1, f + l) - self.lk(f - 1, f + l);
            if gain <= EPS {
                continue;
            }
            let (first, last) = (self.tour.cuts[from].element, self.tour.cuts[to_end - 1].element);
            for (end, is_first) in [(first, true), (last, false)] {
                for &(z, gz) in &near[end] {
                    if gz > gain + SLACK {
                        break;
                    }
                    let r = self.tour.pos[z];
                    if r >= from && r < to_end {
                        continue;
                    }
                    // z's place in the route without the stretch.
                    let r = if r >= to_end { r - len } else { r };
                    // The first end after z or the last before it, kept;
                    // the first before z or the last after it, reversed.
                    for (to, reverse) in [(r + 1, !is_first), (r, is_first)] {
                        if to == from && !reverse {
                            continue;
                        }
                        if let Some(found) = self.try_move(Move { from, len, to, reverse }) {
                            return Some(found);
                        }
                    }
                }
            }
        }
        None
    }

    /// First-improvement descent from the woken elements until none improves.
    fn descend(&mut self) {
        while let Some(x) = self.queue.pop_front() {
            self.queued[x] = false;
            if let Some((mv, d)) = self.improving_move(x) {
                self.apply(&mv, d);
                self.wake(x);
            }
        }
    }

    /// Back to `route` (cost `cost`), every element asleep.
    fn reset_to(&mut self, route: &[Cut], cost: f64) {
        self.tour.cuts.copy_from_slice(route);
        for (i, c) in route.iter().enumerate() {
            self.tour.pos[c.element] = i;
        }
        self.cost = cost;
        if self.penalty.is_finite() {
            self.recount();
        }
        self.queue.clear();
        self.queued.iter_mut().for_each(|q| *q = false);
    }

    /// What the search minimises: the cost, plus the penalty of the rules
    /// broken while they may be.
    fn objective(&self) -> f64 {
        if self.penalty.is_finite() && self.penalty > 0.0 {
            self.cost + self.penalty * self.violations as f64
        } else {
            self.cost
        }
    }

    /// Starts recording the moves applied, for [`Self::undo`].
    fn record(&mut self) {
        self.journal.clear();
        self.recording = true;
    }

    /// Takes back every move applied since [`Self::record`], last first
    /// (each run moved back where it came from), every element asleep.
    fn undo(&mut self) {
        self.recording = false;
        let mut journal = std::mem::take(&mut self.journal);
        while let Some((mv, d)) = journal.pop() {
            self.apply(&Move { from: mv.to, len: mv.len, to: mv.from, reverse: mv.reverse }, -d);
        }
        self.journal = journal;
        while let Some(e) = self.queue.pop_front() {
            self.queued[e] = false;
        }
    }

    /// A random double bridge, or now and then a random stretch reversed
    /// (directions the descent's moves rarely flip), that keeps the rules
    /// (or any, without rules).
    fn kick(&mut self, rng: &mut impl Rng) -> bool {
        let n = self.tour.cuts.len();
        if n < 4 {
            return false;
        }
        let top = MAX_KICK.min(n / 3).max(1) as f64;
        for _ in 0..20 {
            let l1 = top.powf(rng.random::<f64>()).round().max(1.0) as usize;
            let l2 = top.powf(rng.random::<f64>()).round().max(1.0) as usize;
            if l1 + l2 >= n {
                continue;
            }
            let a = rng.random_range(0..=n - l1 - l2);
            let mv = if rng.random_ratio(1, 8) { Move { from: a, len: l1 + l2, to: a, reverse: true } } else { swap(a, a + l1, a + l1 + l2) };
            if self.penalty.is_finite() || feasible(self.inst, &self.rules, &self.tour, &mv) {
                let d = delta(self.inst, &self.tour, &mv);
                self.apply(&mv, d);
                return true;
            }
        }
        false
    }

    /// The route turned end for end (the same cost on a symmetric metric).
    fn reverse_route(&mut self) {
        self.tour.cuts.reverse();
        for (i, c) in self.tour.cuts.iter_mut().enumerate() {
            *c = flip(*c);
            self.tour.pos[c.element] = i;
        }
        self.cost = self.inst.cost(&self.tour.cuts);
        self.recount();
    }

    /// Mends broken rules one at a time: a cut of the rule's two contours
    /// moved, the move mending most rules (in all), then the cheapest; where
    /// no single move mends any, each contour's last cut moved past its inner
    /// contours. A cut is tried next to its neighbours (the neighbour lists'),
    /// next to the rule's contours' cuts, at the route's start and end: O(1)
    /// places, not the whole route, so that thousands of broken rules mend in
    /// a moment; the few (at most [`WIDE_REPAIR`]) that none of these mends
    /// are tried at every place. Gives up once `cap` is reached. Returns
    /// whether every rule holds.
    fn repair(&mut self, cap: &TimeCap) -> bool {
        let n = self.tour.cuts.len();
        self.penalty = 1.0;
        let mut pushes = 0;
        let mut wide = false;
        let mut targets: Vec<usize> = Vec::new();
        let mut marks: Vec<usize> = Vec::new();
        while self.violations > 0 {
            let mut mended = false;
            for r in 0..self.broken.len() {
                if !self.broken[r] {
                    continue;
                }
                if cap.reached() {
                    return false;
                }
                let (a, b) = contours_of_rule(&self.book.rules[r]);
                let pos = &self.tour.pos;
                let members = || self.inst.contours[a].iter().chain(&self.inst.contours[b]);
                marks.clear();
                marks.extend(members().map(|&e| pos[e]));
                let mut best: Option<(isize, f64, Move)> = None;
                for &e in members() {
                    let from = pos[e];
                    // Places counted in the route without the moved cut.
                    let without = |q: usize| if q > from { q - 1 } else { q };
                    targets.clear();
                    if wide {
                        targets.extend(0..n);
                    } else {
                        targets.extend([0, n - 1]);
                        for q in marks.iter().copied().chain(self.near.lists[e].iter().map(|&(m, _)| pos[m])) {
                            targets.extend([without(q), without(q) + 1]);
                        }
                        targets.sort_unstable();
                        targets.dedup();
                    }
                    for &to in targets.iter().filter(|&&to| to < n) {
                        for reverse in [false, true] {
                            if to == from && !reverse {
                                continue;
                            }
                            let mv = Move { from, len: 1, to, reverse };
                            let dv = self.violation_delta(&mv);
                            if dv >= 0 {
                                continue;
                            }
                            let d = delta(self.inst, &self.tour, &mv);
                            if best.as_ref().is_none_or(|(bv, bd, _)| (dv, d) < (*bv, *bd)) {
                                best = Some((dv, d, mv));
                            }
                        }
                    }
                }
                if let Some((_, d, mv)) = best {
                    self.apply(&mv, d);
                    mended = true;
                }
            }
            if !mended {
                if pushes == 3 {
                    if wide || self.violations > WIDE_REPAIR {
                        break;
                    }
                    wide = true;
                    continue;
                }
                pushes += 1;
                self.push_closings();
            }
        }
        self.violations == 0
    }

    /// Each contour closed before an inner one gets its last cut moved to the
    /// best place after its inner contours close, innermost first (moving a
    /// cut later never breaks a rule of the contours inside): right after
    /// them, next to one of the cut's neighbours further on, or at the end.
    fn push_closings(&mut self) {
        let n = self.tour.cuts.len();
        let depth = contour_depths(self.inst);
        let mut order: Vec<usize> = (0..self.inst.contours.len()).collect();
        order.sort_by_key(|&k| std::cmp::Reverse(depth[k]));
        let mut targets: Vec<usize> = Vec::new();
        for &k in &order {
            let closes = |k: usize| self.inst.contours[k].iter().map(|&e| self.tour.pos[e]).max().unwrap_or(0);
            let Some(need) = self.rules.inners[k].iter().map(|&i| closes(i)).max() else { continue };
            let from = closes(k);
            if from > need {
                continue;
            }
            // Targets counted in the route without the moved cut: `need` is
            // the place right after the inner contour's last cut.
            let without = |q: usize| if q > from { q - 1 } else { q };
            targets.clear();
            targets.extend([need, n - 1]);
            for &(m, _) in &self.near.lists[self.tour.cuts[from].element] {
                let q = without(self.tour.pos[m]);
                targets.extend([q, q + 1]);
            }
            targets.sort_unstable();
            targets.dedup();
            let best = targets
                .iter()
                .filter(|&&to| to >= need && to < n)
                .flat_map(|&to| [false, true].map(|reverse| Move { from, len: 1, to, reverse }))
                .map(|mv| (delta(self.inst, &self.tour, &mv), mv))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((d, mv)) = best {
                self.apply(&mv, d);
            }
        }
    }
}

/// Broken rules few enough, once nothing else mends them, to try each of
/// their cuts at every place of the route.
const WIDE_REPAIR: usize = 8;

/// Longest stretch a kick moves.
const MAX_KICK: usize = 100;

/// Swapping the neighbouring stretches `[a, b)` and `[b, c)`, as the move of
/// the shorter one (feasibility is checked from the moved run's contours).
fn swap(a: usize, b: usize, c: usize) -> Move {
    if b - a <= c - b {
        Move { from: a, len: b - a, to: a + (c - b), reverse: false }
    } else {
        Move { from: b, len: c - b, to: a, reverse: false }
    }
}

/// Where a search starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// Seed 001's constructions: the cheaper of insertion (IB; elements of a
    /// depth in index order, or shuffled by the seed) and contour order (COB).
    Insertion,
    /// The search without rules for a share of the kicks, then mended.
    Relaxed,
}

/// Options of the search.
#[derive(Debug, Clone)]
pub struct SearchOptions {
    /// Kicks each search makes (`None`: [`default_kicks`] of the instance).
    pub kicks: Option<u64>,
    /// A wall-clock cap the user set (`None`: the kicks alone end a search).
    pub time_limit: Option<Duration>,
    /// Stop after this many kicks in a row that found nothing better (0: never).
    pub max_stall: u64,
    /// Kicks in a row finding nothing better after which a search starts
    /// afresh (`None`: 100 per element, at least 10 000).
    pub restart_after: Option<u64>,
    /// Share of the kicks a relaxed start searches without rules.
    pub relaxed_share: f64,
    /// Neighbours per element that moves are taken from.
    pub neighbours: usize,
    /// Besides those, the nearest elements in each quadrant around each
    /// end (on d1291's rows of holes, plain TSP, seeds 1-3, 30 s: 0.50-0.81 %
    /// off with the nearest alone, the optimum with 2 per quadrant).
    pub quadrant_neighbours: usize,
    /// Independent searches, relaxed and insertion starts in turn (the outcome
    /// depends on the start). A fixed number, not the cores: the route does
    /// not depend on the machine.
    pub searches: usize,
    /// Threads the searches run on.
    pub threads: usize,
    pub seed: u64,
    /// A feasible route every search starts from instead of a construction
    /// (the thermal planner's last route, searched again under new penalties).
    pub initial: Option<std::sync::Arc<Vec<Cut>>>,
}

/// Independent searches by default.
pub const SEARCHES: usize = 2;

impl SearchOptions {
    /// The default budget, no time limit, one thread.
    pub fn new() -> SearchOptions {
        SearchOptions { kicks: None, time_limit: None, max_stall: 0, restart_after: None, relaxed_share: 0.3, neighbours: 10, quadrant_neighbours: 2, searches: SEARCHES, threads: 1, seed: 1, initial: None }
    }
}

impl Default for SearchOptions {
    fn default() -> Self {
        SearchOptions::new()
    }
}

/// Kicks of one search on an instance of `elements` elements: about what a
/// quiet core made in the ten seconds the search used to be given (a kick
/// costs more on a larger instance, so the budget grows less than the size).
pub fn default_kicks(elements: usize) -> u64 {
    (KICKS_BASE + KICKS_PER_ELEMENT * elements as u64).min(MAX_KICKS)
}

const KICKS_BASE: u64 = 20_000;
const KICKS_PER_ELEMENT: u64 = 1_500;
const MAX_KICKS: u64 = 400_000;

/// What a search found.
#[derive(Debug, Clone)]
pub struct SearchResult {
    /// A route that keeps every rule.
    pub route: Vec<Cut>,
    pub cost: f64,
    /// Kicks (iterations of the outer loop), over all searches.
    pub iterations: u64,
    pub time_to_best: Duration,
    /// The start the best route came from.
    pub start: Start,
    /// Whether the budget or the user's time limit ended the searches.
    pub stopped_by: SearchStop,
}

/// One search: rounds of a start and kicks from it until the round stalls
/// (`restart_after` kicks finding nothing better), the first round from
/// `first`, later ones from fresh insertions in random orders, relaxed and
/// not in turn; the best route of all rounds.
pub fn search_from(inst: &Instance, first: Start, options: &SearchOptions, cap: &TimeCap) -> SearchResult {
    let began = Instant::now();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(options.seed);
    // The first start: the route given, else the cheaper of seed 001's two
    // constructions.
    let (mut insertion, first) = match &options.initial {
        Some(given) => (given.to_vec(), Start::Insertion),
        None => {
            // An insertion the time limit cuts short gives way to contour
            // order (fast, feasible); one done as the time is up is taken
            // as it is: the search must end in time.
            let insertion = insertion_within(inst, (options.seed > 1).then_some(options.seed), cap);
            let start = match insertion {
                Some(insertion) if cap.reached() => insertion,
                insertion => {
                    let contour_order = contour_order_construction(inst);
                    match insertion {
                        Some(insertion) if inst.cost(&contour_order) >= inst.cost(&insertion) => insertion,
                        _ => contour_order,
                    }
                }
            };
            (start, first)
        }
    };
    // Out of time already: the start as it is (the neighbour lists and a
    // descent on a large instance take a while).
    if cap.reached() {
        let cost = inst.cost(&insertion);
        return SearchResult { route: insertion, cost, iterations: 0, time_to_best: began.elapsed(), start: first, stopped_by: cap.stop() };
    }
    let near = Neighbours::with_quadrants(inst, options.neighbours, options.quadrant_neighbours);
    let mut s = Descent::new(inst, insertion.clone(), near);
    let mut best: Option<SearchResult> = None;
    let mut time_to_best = Duration::ZERO;
    let mut iterations = 0;
    let mut since_best = 0u64;
    let mut start = first;
    let restart_after = options.restart_after.unwrap_or((100 * inst.elements.len() as u64).max(10_000));
    let budget = options.kicks.unwrap_or_else(|| default_kicks(inst.elements.len()));
    let relaxed_share = options.relaxed_share.clamp(0.0, 1.0);
    for round in 0.. {
        if round > 0 {
            let Some(fresh) = insertion_within(inst, Some(rng.random()), cap) else { break };
            insertion = fresh;
            s.penalty = f64::INFINITY;
            s.reset_to(&insertion, inst.cost(&insertion));
            s.wake_all();
        }
        // (Out of time, neither the relaxed phase nor a descent begins.)
        if start == Start::Relaxed && !cap.reached() {
            let relaxed = (budget.saturating_sub(iterations) as f64 * relaxed_share) as u64;
            s.penalty = 0.0;
            // Under a time limit, a share of the time left at most, so that
            // the mending and the search with rules have theirs.
            let relaxed_cap = TimeCap::after(cap.remaining().map(|left| left.mul_f64(relaxed_share)));
            iterations += iterate(&mut s, &mut rng, restart_after, relaxed, |_| !relaxed_cap.reached() && !cap.reached());
            // Of the route and its reverse, the one breaking fewer rules.
            let forward = s.violations;
            s.reverse_route();
            if forward < s.violations {
                s.reverse_route();
            }
            // The rules brought back by a rising penalty, the search trading
            // air for them where it must; what is still broken, mended.
            let mut penalty = s.cost / inst.elements.len() as f64;
            let steps = (inst.elements.len() as u64).clamp(200, 5_000);
            for _ in 0..12 {
                if s.violations == 0 || cap.reached() || penalty <= 0.0 {
                    break;
                }
                s.penalty = penalty;
                s.recount();
                s.wake_all();
                iterations += iterate(&mut s, &mut rng, 0, steps, |_| !cap.reached());
                penalty *= 2.0;
            }
            let mended = s.repair(cap);
            s.penalty = f64::INFINITY;
            if !mended {
                s.reset_to(&insertion, inst.cost(&insertion));
            }
            s.wake_all();
        }
        let mut best_cost = best.as_ref().map_or(f64::INFINITY, |b| b.cost);
        if !cap.reached() {
            iterations += iterate(&mut s, &mut rng, restart_after, budget.saturating_sub(iterations), |found| {
                if let Some(cost) = found.filter(|&c| c < best_cost - EPS) {
                    best_cost = cost;
                    time_to_best = began.elapsed();
                    since_best = 0;
                }
                since_best += KICKS_PER_CLOCK;
                (options.max_stall == 0 || since_best < options.max_stall) && !cap.reached()
            });
        }
        if best.as_ref().is_none_or(|b| s.cost < b.cost - EPS) {
            if best.is_none() {
                time_to_best = began.elapsed();
            }
            best = Some(SearchResult { route: s.tour.cuts.clone(), cost: s.cost, iterations: 0, time_to_best, start, stopped_by: SearchStop::Budget });
        }
        let stalled = options.max_stall > 0 && since_best >= options.max_stall;
        if iterations >= budget || stalled || restart_after == 0 || inst.elements.len() < 4 || cap.reached() {
            break;
        }
        start = Start::Relaxed;
    }
    let mut best = best.expect("one round at least");
    best.cost = inst.cost(&best.route);
    best.iterations = iterations;
    best.time_to_best = time_to_best;
    best.stopped_by = cap.stop();
    best
}

/// Kicks between two looks at the clock (a kick and its descent take microseconds).
const KICKS_PER_CLOCK: u64 = 16;

/// Descent, then up to `max_kicks` kicks while `go_on` (told the new best
/// cost when the last kicks found one) and until `stall_limit` kicks in a row
/// found nothing better (0: no limit); leaves the best route in `s`. Returns
/// the kicks made.
fn iterate(s: &mut Descent, rng: &mut impl Rng, stall_limit: u64, max_kicks: u64, mut go_on: impl FnMut(Option<f64>) -> bool) -> u64 {
    s.descend();
    // The route in `s` is the best one between kicks: a worse one is undone.
    let mut best_cost = s.objective();
    let mut kicks = 0u64;
    let mut stall = 0u64;
    let mut found = Some(best_cost);
    while kicks < max_kicks && go_on(found.take()) && (stall_limit == 0 || stall < stall_limit) && s.tour.cuts.len() >= 4 {
        for _ in 0..KICKS_PER_CLOCK.min(max_kicks - kicks) {
            kicks += 1;
            stall += 1;
            s.record();
            if !s.kick(rng) {
                continue;
            }
            s.descend();
            let objective = s.objective();
            if objective < best_cost - EPS {
                found = Some(objective);
                stall = 0;
            }
            if objective <= best_cost + EPS {
                best_cost = objective;
            } else {
                s.undo();
                // Sums of cost changes drift by rounding: the best's own.
                s.cost = best_cost - (s.objective() - s.cost);
            }
        }
    }
    s.recording = false;
    s.cost = s.inst.cost(&s.tour.cuts);
    kicks
}

/// The independent searches, starts alternating between relaxed and
/// insertion, each its own seed, on the options' threads: the cheapest route
/// of all, ties to the first search.
pub fn search(inst: &Instance, options: &SearchOptions) -> SearchResult {
    let cap = TimeCap::after(options.time_limit);
    best_of(searches(inst, options, &cap), &cap)
}

/// Every one of `search`'s independent searches' results, in their order
/// (for a caller that judges routes by more than their cost).
pub fn searches(inst: &Instance, options: &SearchOptions, cap: &TimeCap) -> Vec<SearchResult> {
    crate::parallel::tasks(options.searches.max(1), options.threads, |k| {
        let options = SearchOptions { seed: options.seed.wrapping_add(k as u64), ..options.clone() };
        let start = Start::Relaxed;
        search_from(inst, start, &options, cap)
    })
}

/// The cheapest of independent searches' results (ties to the first), with
/// the kicks of all and what stopped them.
pub(super) fn best_of(runs: Vec<SearchResult>, cap: &TimeCap) -> SearchResult {
    let iterations = runs.iter().map(|r| r.iterations).sum();
    let mut best = runs.into_iter().min_by(|a, b| a.cost.total_cmp(&b.cost)).expect("at least one search ran");
    best.iterations = iterations;
    best.stopped_by = cap.stop();
    best
}

/// `inst`'s route from the nearest feasible construction searched `kicks`
/// kicks without rules, for tests on generated sheets (in `gen::tests`:
/// the generators come later in the pipeline).
#[cfg(test)]
pub(crate) fn relaxed_route(inst: &Instance, seed: u64, kicks: u64) -> Vec<Cut> {
    let mut s = Descent::new(inst, super::construct::construct(inst), Neighbours::new(inst, 10));
    s.penalty = 0.0;
    iterate(&mut s, &mut rand_chacha::ChaCha8Rng::seed_from_u64(seed), 0, kicks, |_| true);
    s.tour.cuts
}

/// `route` mended by [`Descent::repair`] under `cap`: whether it says every
/// rule holds, the route, and the cost and broken rules it kept count of.
#[cfg(test)]
pub(crate) fn repaired(inst: &Instance, route: Vec<Cut>, cap: &TimeCap) -> (bool, Vec<Cut>, f64, usize) {
    let mut s = Descent::new(inst, route, Neighbours::new(inst, 10));
    let ok = s.repair(cap);
    (ok, s.tour.cuts, s.cost, s.violations)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ecp::checker::check;

    #[test]
    fn every_move_kind_predicts_its_cost_and_rules() {
        // Or-opt, 2-opt and path-preserving 3-opt moves as the descent makes
        // them: each applied move's cost change and broken-rule count are
        // what the route says after it.
        for seed in 0..10 {
            let inst = crate::plan::ecp::random_instance(40, seed, 2..=6, 3.0);
            let start = crate::plan::ecp::construct::construct(&inst);
            let mut s = Descent::new(&inst, start, Neighbours::new(&inst, 8));
            s.penalty = 0.5;
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            for _ in 0..200 {
                s.kick(&mut rng);
                s.descend();
                assert!((s.cost - inst.cost(&s.tour.cuts)).abs() < 1e-6, "seed {seed}");
                assert_eq!(s.violations, check(&inst, &s.tour.cuts).len(), "seed {seed}");
            }
        }
    }

    #[test]
    fn an_undone_kick_leaves_the_route_its_cost_and_its_broken_rules_as_they_were() {
        for seed in 0..10 {
            let inst = crate::plan::ecp::random_instance(60, seed, 2..=6, 3.0);
            let start = crate::plan::ecp::construct::construct(&inst);
            let mut s = Descent::new(&inst, start, Neighbours::new(&inst, 8));
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            for penalty in [f64::INFINITY, 0.0, 2.0] {
                s.penalty = penalty;
                s.recount();
                s.descend();
                let mut changed = 0;
                for _ in 0..100 {
                    let (route, cost, violations) = (s.tour.cuts.clone(), s.cost, s.violations);
                    s.record();
                    if !s.kick(&mut rng) {
                        continue;
                    }
                    s.descend();
                    changed += usize::from(s.tour.cuts != route);
                    s.undo();
                    assert_eq!(s.tour.cuts, route, "seed {seed}");
                    assert!((s.cost - cost).abs() < 1e-6);
                    assert_eq!(s.violations, violations);
                    assert_eq!(s.violations, check(&inst, &s.tour.cuts).len());
                    assert!(s.tour.cuts.iter().enumerate().all(|(i, c)| s.tour.pos[c.element] == i));
                }
                assert!(changed > 20, "seed {seed}: kicks changed the route {changed} times before they were undone");
            }
        }
    }

    #[test]
    fn reaches_the_optimum_of_small_instances() {
        for (seed, inst, optimum) in crate::plan::ecp::small_instances_with_optimum() {
            for start in [Start::Insertion, Start::Relaxed] {
                let options = SearchOptions { max_stall: 5000, restart_after: Some(500), ..SearchOptions::new() };
                let found = search_from(&inst, start, &options, &TimeCap::none());
                assert!(check(&inst, &found.route).is_empty(), "seed {seed} {start:?}");
                assert!((found.cost - optimum).abs() < 1e-6, "seed {seed} {start:?}: {} vs optimum {optimum}", found.cost);
            }
        }
    }
}
