//! The galvo route: every geometry once, in scan fields processed one after
//! another, each geometry entered at a chosen vertex (closed) or end (open).
//! Its length is the idle stroke: the laser-off jumps from the first
//! geometry's entry to the last geometry's exit.
//!
//! [`Route::improve`] is the local search under both HHA and HGA: 2-opt,
//! Or-opt (runs of 1 to 3, kept or reversed) and a new entry vertex, driven by
//! neighbour lists and a queue of geometries to look at (don't-look bits), so
//! that after a small change only its surroundings are searched again. Fields
//! stay contiguous: a move may carry geometries into a neighbouring field
//! whose square holds them (a field left empty disappears), whole fields may
//! move or turn round, but a field is never split. [`Route::search`] adds
//! kicks (two adjacent runs of one field swapped) and keeps what is shorter.

use crate::job::Point;
use rand::{Rng, SeedableRng};
use rstar::primitives::GeomWithData;
use rstar::RTree;
use std::collections::VecDeque;
use crate::plan::stop::TimeCap;

/// One geometry as the route sees it.
#[derive(Debug, Clone)]
pub struct Stop {
    /// Closed: every vertex, any of them an entry (the exit is the same
    /// point). Open: its two ends, entered at either.
    pub vertices: Vec<Point>,
    pub closed: bool,
    /// The fields whose square holds this geometry entirely, ascending.
    pub fields: Vec<u32>,
    /// The vertices' mean, and the farthest vertex from it (to bound jumps
    /// to any vertex cheaply).
    centre: Point,
    radius: f64,
}

impl Stop {
    pub fn new(vertices: Vec<Point>, closed: bool, fields: Vec<u32>) -> Stop {
        let n = vertices.len().max(1) as f64;
        let centre = Point::from(vertices.iter().fold(nalgebra::Vector2::zeros(), |s, p| s + p.coords) / n);
        let radius = vertices.iter().map(|v| (v - centre).norm()).fold(0.0, f64::max);
        Stop { vertices, closed, fields, centre, radius }
    }

    fn entry(&self, choice: u32) -> Point {
        self.vertices[choice as usize]
    }

    fn exit(&self, choice: u32) -> Point {
        if self.closed {
            self.vertices[choice as usize]
        } else {
            self.vertices[1 - choice as usize]
        }
    }

    fn fits(&self, field: u32) -> bool {
        self.fields.binary_search(&field).is_ok()
    }

    /// A point that stands for the geometry (its vertices' mean).
    pub fn centre(&self) -> Point {
        self.centre
    }
}

/// Neighbour lists: for each stop, the stops nearest to it (by centre and,
/// for open ones, by either end), nearest first.
pub fn neighbours(stops: &[Stop], k: usize) -> Vec<Vec<u32>> {
    let mut points: Vec<GeomWithData<[f64; 2], u32>> = Vec::new();
    for (i, s) in stops.iter().enumerate() {
        let c = s.centre();
        points.push(GeomWithData::new([c.x, c.y], i as u32));
        if !s.closed {
            for p in &s.vertices {
                points.push(GeomWithData::new([p.x, p.y], i as u32));
            }
        }
    }
    let tree = RTree::bulk_load(points);
    stops
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let mut near: Vec<(f64, u32)> = Vec::new();
            let mut from = vec![s.centre()];
            if !s.closed {
                from.extend(s.vertices.iter().copied());
            }
            for p in from {
                let mut taken: Vec<u32> = Vec::with_capacity(k);
                for hit in tree.nearest_neighbor_iter([p.x, p.y]) {
                    if hit.data as usize == i || taken.contains(&hit.data) {
                        continue;
                    }
                    let d = (Point::new(hit.geom()[0], hit.geom()[1]) - p).norm();
                    near.push((d, hit.data));
                    taken.push(hit.data);
                    if taken.len() >= k {
                        break;
                    }
                }
            }
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut list: Vec<u32> = Vec::with_capacity(k);
            for (_, j) in near {
                if !list.contains(&j) {
                    list.push(j);
                    if list.len() == k {
                        break;
                    }
                }
            }
            list
        })
        .collect()
}

/// Puts the stops not yet waiting into the local search's queue.
fn enqueue(queue: &mut VecDeque<u32>, queued: &mut [bool], stops: impl IntoIterator<Item = u32>) {
    for s in stops {
        if !queued[s as usize] {
            queued[s as usize] = true;
            queue.push_back(s);
        }
    }
}

/// A route over `stops`: the order, each stop's entry choice and field.
#[derive(Debug, Clone)]
pub struct Route<'a> {
    stops: &'a [Stop],
    order: Vec<u32>,
    pos: Vec<u32>,
    choice: Vec<u32>,
    field: Vec<u32>,
    /// Stops per field.
    count: Vec<u32>,
    /// The positions changed since this was last cleared (the search copies
    /// only those between its current and its best route).
    dirty: Option<(usize, usize)>,
}

/// Positions a kick may span: it stays local, so the repair does too.
const KICK_WINDOW: usize = 30;

/// Every this many kicks, one rebuilds a whole field.
const REBUILD_EVERY: usize = 64;

/// Slack on "shorter": lengths are sums of floating-point distances.
const EPS: f64 = 1e-7;

fn dist(a: Point, b: Point) -> f64 {
    (b - a).norm()
}

/// A move found by the local search.
#[derive(Debug, Clone, Copy)]
enum Move {
    /// Reverse positions i..=j.
    TwoOpt { i: usize, j: usize },
    /// Move the run s..s+len between positions t-1 and t, reversed or not,
    /// into `field`; `entry` is the new choice of a single closed stop.
    OrOpt { s: usize, len: usize, t: usize, reverse: bool, field: u32, entry: Option<u32> },
    /// A new entry for the stop at position p.
    Entry { p: usize, choice: u32 },
}

impl<'a> Route<'a> {
    /// A route in the given order, with the given choices and fields (each
    /// field's stops contiguous; `fields` is the number of fields).
    pub fn new(stops: &'a [Stop], order: Vec<u32>, choice: Vec<u32>, field: Vec<u32>, fields: usize) -> Route<'a> {
        let mut pos = vec![0; stops.len()];
        for (p, &s) in order.iter().enumerate() {
            pos[s as usize] = p as u32;
        }
        let mut count = vec![0; fields];
        for &f in &field {
            count[f as usize] += 1;
        }
        let route = Route { stops, order, pos, choice, field, count, dirty: None };
        debug_assert!(route.contiguous());
        route
    }

    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Entry choice per stop (closed: vertex index; open: 1 when reversed).
    pub fn choices(&self) -> &[u32] {
        &self.choice
    }

    /// Field per stop.
    pub fn fields(&self) -> &[u32] {
        &self.field
    }

    /// Fields with at least one stop.
    pub fn used_fields(&self) -> usize {
        self.count.iter().filter(|&&c| c > 0).count()
    }

    fn stop_at(&self, p: usize) -> &Stop {
        &self.stops[self.order[p] as usize]
    }

    fn entry_at(&self, p: usize) -> Point {
        let s = self.order[p] as usize;
        self.stops[s].entry(self.choice[s])
    }

    fn exit_at(&self, p: usize) -> Point {
        let s = self.order[p] as usize;
        self.stops[s].exit(self.choice[s])
    }

    fn field_at(&self, p: usize) -> u32 {
        self.field[self.order[p] as usize]
    }

    /// The jump from position p to p + 1 (none past either end).
    fn link(&self, p: isize) -> f64 {
        if p < 0 || p as usize + 1 >= self.order.len() {
            0.0
        } else {
            dist(self.exit_at(p as usize), self.entry_at(p as usize + 1))
        }
    }

    /// The idle stroke: the sum of the jumps.
    pub fn length(&self) -> f64 {
        (0..self.order.len() as isize).map(|p| self.link(p)).sum()
    }

    /// Whether every field's stops follow one another and lie in its square.
    pub fn contiguous(&self) -> bool {
        let mut seen = vec![false; self.count.len()];
        for p in 0..self.order.len() {
            let f = self.field_at(p);
            if !self.stop_at(p).fits(f) {
                return false;
            }
            if p == 0 || self.field_at(p - 1) != f {
                if seen[f as usize] {
                    return false;
                }
                seen[f as usize] = true;
            }
        }
        true
    }

    fn block_starts_at(&self, p: usize) -> bool {
        p == 0 || self.field_at(p - 1) != self.field_at(p)
    }

    fn block_ends_at(&self, p: usize) -> bool {
        p + 1 == self.order.len() || self.field_at(p + 1) != self.field_at(p)
    }

    /// Change in length of reversing positions i..=j (open stops inside turn
    /// round, so the jumps inside keep their lengths).
    fn two_opt_delta(&self, i: usize, j: usize) -> f64 {
        let n = self.order.len();
        let mut delta = 0.0;
        if i > 0 {
            let before = self.exit_at(i - 1);
            delta += dist(before, self.exit_at(j)) - dist(before, self.entry_at(i));
        }
        if j + 1 < n {
            let after = self.entry_at(j + 1);
            delta += dist(self.entry_at(i), after) - dist(self.exit_at(j), after);
        }
        delta
    }

    fn two_opt_allowed(&self, i: usize, j: usize) -> bool {
        self.field_at(i) == self.field_at(j) || (self.block_starts_at(i) && self.block_ends_at(j))
    }

    /// The field a run s..s+len takes when put between t - 1 and t, if any.
    fn field_for_run(&self, s: usize, len: usize, t: usize) -> Option<u32> {
        let n = self.order.len();
        let own = self.field_at(s);
        if self.field_at(s + len - 1) != own {
            return None;
        }
        let left = (t > 0).then(|| self.field_at(t - 1));
        let right = (t < n).then(|| self.field_at(t));
        let fits = |f: u32| (s..s + len).all(|p| self.stop_at(p).fits(f));
        match (left, right) {
            (Some(l), Some(r)) if l == r => (l == own || fits(l)).then_some(l),
            _ => {
                // At a border between fields (or an end of the route): the
                // run's own field when the run is the whole of it, else one of
                // the two sides.
                if left == Some(own) || right == Some(own) || self.count[own as usize] as usize == len {
                    return Some(own);
                }
                [left, right].into_iter().flatten().find(|&f| fits(f))
            }
        }
    }

    /// What taking the run s..s+len out of the route saves.
    fn removal_gain(&self, s: usize, len: usize) -> f64 {
        let e = s + len - 1;
        let before = (s > 0).then(|| self.exit_at(s - 1));
        let after = (e + 1 < self.order.len()).then(|| self.entry_at(e + 1));
        let mut gain = before.map_or(0.0, |b| dist(b, self.entry_at(s))) + after.map_or(0.0, |a| dist(self.exit_at(e), a));
        if let (Some(b), Some(a)) = (before, after) {
            gain -= dist(b, a);
        }
        gain
    }

    /// What putting the run s..s+len between t - 1 and t costs (t outside
    /// the run); with `choose_vertex`, a single closed stop goes in at its
    /// best vertex there, which is returned.
    fn insertion_cost(&self, s: usize, len: usize, t: usize, reverse: bool, choose_vertex: bool) -> (f64, Option<u32>) {
        let e = s + len - 1;
        let left = (t > 0).then(|| self.exit_at(t - 1));
        let right = (t < self.order.len()).then(|| self.entry_at(t));
        let mut cost = match (left, right) {
            (Some(l), Some(r)) => -dist(l, r),
            _ => 0.0,
        };
        let stop = self.stop_at(s);
        if choose_vertex && len == 1 && stop.closed {
            // The vertex that makes the two new jumps shortest.
            let mut best = (f64::INFINITY, 0);
            for (v, &p) in stop.vertices.iter().enumerate() {
                let c = left.map_or(0.0, |l| dist(l, p)) + right.map_or(0.0, |r| dist(p, r));
                if c < best.0 {
                    best = (c, v as u32);
                }
            }
            return (cost + best.0, Some(best.1));
        }
        let (head, tail) = if reverse { (self.exit_at(e), self.entry_at(s)) } else { (self.entry_at(s), self.exit_at(e)) };
        cost += left.map_or(0.0, |l| dist(l, head)) + right.map_or(0.0, |r| dist(tail, r));
        (cost, None)
    }

    /// Change in length of moving the run s..s+len between t - 1 and t.
    #[cfg(test)]
    fn or_opt_delta(&self, s: usize, len: usize, t: usize, reverse: bool) -> (f64, Option<u32>) {
        let (cost, entry) = self.insertion_cost(s, len, t, reverse, true);
        (cost - self.removal_gain(s, len), entry)
    }

    /// The best entry of the stop at p between its neighbours, and the change.
    fn entry_delta(&self, p: usize) -> (f64, u32) {
        let s = self.order[p] as usize;
        let stop = &self.stops[s];
        let before = (p > 0).then(|| self.exit_at(p - 1));
        let after = (p + 1 < self.order.len()).then(|| self.entry_at(p + 1));
        let cost = |c: u32| before.map_or(0.0, |b| dist(b, stop.entry(c))) + after.map_or(0.0, |a| dist(stop.exit(c), a));
        let now = cost(self.choice[s]);
        let options = if stop.closed { stop.vertices.len() as u32 } else { 2 };
        let mut best = (0.0, self.choice[s]);
        for c in 0..options {
            let d = cost(c) - now;
            if d < best.0 {
                best = (d, c);
            }
        }
        best
    }

    fn reverse(&mut self, i: usize, j: usize) {
        self.order[i..=j].reverse();
        for p in i..=j {
            let s = self.order[p] as usize;
            self.pos[s] = p as u32;
            if !self.stops[s].closed {
                self.choice[s] ^= 1;
            }
        }
    }

    /// The positions whose jumps a move changes (to look at them again).
    fn touched(&self, m: Move) -> [u32; 6] {
        let n = self.order.len();
        let ps: [usize; 6] = match m {
            Move::TwoOpt { i, j } => [i.saturating_sub(1), i, j, (j + 1).min(n - 1), i, j],
            Move::OrOpt { s, len, t, .. } => [s.saturating_sub(1), s, s + len - 1, (s + len).min(n - 1), t.saturating_sub(1), t.min(n - 1)],
            Move::Entry { p, .. } => [p.saturating_sub(1), p, (p + 1).min(n - 1), p, p, p],
        };
        ps.map(|p| self.order[p])
    }

    /// Reorders the stops at positions a..c with `f`; returns the change in
    /// length (only the jumps from a - 1 to c can change).
    fn rearrange(&mut self, a: usize, c: usize, f: impl FnOnce(&mut [u32])) -> f64 {
        let links = |r: &Route| (a as isize - 1..c as isize).map(|p| r.link(p)).sum::<f64>();
        let before = links(self);
        f(&mut self.order[a..c]);
        for p in a..c {
            self.pos[self.order[p] as usize] = p as u32;
        }
        links(self) - before
    }

    fn mark(&mut self, lo: usize, hi: usize) {
        self.dirty = Some(self.dirty.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
    }

    /// Positions lo..=hi (and the choices and fields of the stops there) as
    /// in `other`, which differs from this route only there.
    fn copy_range(&mut self, other: &Route, lo: usize, hi: usize) {
        for p in lo..=hi {
            let s = other.order[p];
            self.order[p] = s;
            self.pos[s as usize] = p as u32;
            self.choice[s as usize] = other.choice[s as usize];
            self.field[s as usize] = other.field[s as usize];
        }
        self.count.copy_from_slice(&other.count);
    }

    fn apply(&mut self, m: Move) {
        match m {
            Move::TwoOpt { i, j } => {
                self.mark(i, j);
                self.reverse(i, j)
            }
            Move::OrOpt { s, len, t, reverse, field, entry } => {
                for p in s..s + len {
                    let st = self.order[p] as usize;
                    self.count[self.field[st] as usize] -= 1;
                    self.field[st] = field;
                    self.count[field as usize] += 1;
                }
                let (from, to) = if t < s {
                    self.order[t..s + len].rotate_right(len);
                    (t, s + len)
                } else {
                    self.order[s..t].rotate_left(len);
                    (s, t)
                };
                for p in from..to {
                    self.pos[self.order[p] as usize] = p as u32;
                }
                self.mark(from, to - 1);
                let start = if t < s { t } else { t - len };
                if reverse {
                    self.reverse(start, start + len - 1);
                }
                if let Some(v) = entry {
                    self.choice[self.order[start] as usize] = v;
                }
            }
            Move::Entry { p, choice } => {
                self.mark(p, p);
                let s = self.order[p] as usize;
                self.choice[s] = choice;
            }
        }
        debug_assert!(self.contiguous());
    }

    /// The best move around stop `a` that shortens the route, if any.
    fn best_move(&self, a: usize, near: &[u32]) -> Option<(f64, Move)> {
        let n = self.order.len();
        let p = self.pos[a] as usize;
        let mut best: Option<(f64, Move)> = None;
        let mut consider = |delta: f64, m: Move| {
            if delta < -EPS && best.is_none_or(|(d, _)| delta < d) {
                best = Some((delta, m));
            }
        };
        let (d, choice) = self.entry_delta(p);
        consider(d, Move::Entry { p, choice });
        // Gain criterion: a 2-opt move joining a to a neighbour must make a
        // jump shorter than the one of a's it removes.
        let out_link = self.link(p as isize);
        let in_link = self.link(p as isize - 1);
        // Runs of 1 to 3 with a at one end whose removal saves something.
        let mut runs = [(0usize, 0usize, 0.0f64); 5];
        let mut run_count = 0;
        for len in 1..=3usize.min(n) {
            for s in [p, (p + 1).saturating_sub(len)] {
                if s + len > n || (s != p && s + len - 1 != p) || runs[..run_count].iter().any(|r| r.0 == s && r.1 == len) {
                    continue;
                }
                let gain = self.removal_gain(s, len);
                if gain > EPS {
                    runs[run_count] = (s, len, gain);
                    run_count += 1;
                }
            }
        }
        let runs = &runs[..run_count];
        let (entry_a, exit_a) = (self.entry_at(p), self.exit_at(p));
        for &c in near {
            let q = self.pos[c as usize] as usize;
            let (lo, hi) = (p.min(q), p.max(q));
            // 2-opt joining a and c exit to exit, and entry to entry.
            if lo < hi && dist(exit_a, self.exit_at(q)) < out_link && self.two_opt_allowed(lo + 1, hi) {
                consider(self.two_opt_delta(lo + 1, hi), Move::TwoOpt { i: lo + 1, j: hi });
            }
            if lo < hi && dist(entry_a, self.entry_at(q)) < in_link && self.two_opt_allowed(lo, hi - 1) {
                consider(self.two_opt_delta(lo, hi - 1), Move::TwoOpt { i: lo, j: hi - 1 });
            }
            // Or-opt: those runs put next to c, where a jump to c is shorter
            // than what the removal saves (a closed stop alone may change
            // its vertex: always tried).
            let (c_entry, c_exit) = (self.entry_at(q), self.exit_at(q));
            for &(s, len, gain) in runs {
                let stop = self.stop_at(s);
                let free = len == 1 && stop.closed;
                let ends = [self.entry_at(s), self.exit_at(s + len - 1)];
                for t in [q, q + 1] {
                    if t >= s && t <= s + len {
                        continue;
                    }
                    let c_point = if t == q { c_entry } else { c_exit };
                    // The jump between c and the run is at least this long.
                    let nearest = if free { dist(c_point, stop.centre) - stop.radius } else { dist(c_point, ends[0]).min(dist(c_point, ends[1])) };
                    if nearest >= gain {
                        continue;
                    }
                    let Some(field) = self.field_for_run(s, len, t) else { continue };
                    for reverse in [false, true] {
                        let (cost, entry) = self.insertion_cost(s, len, t, reverse, true);
                        consider(cost - gain, Move::OrOpt { s, len, t, reverse, field, entry });
                        if entry.is_some() {
                            break;
                        }
                    }
                }
            }
        }
        best
    }

    /// Local search from the stops in `queue` until no move shortens the route.
    /// Returns the change in length.
    pub fn improve_from(&mut self, near: &[Vec<u32>], queue: &mut VecDeque<u32>, queued: &mut [bool]) -> f64 {
        let mut change = 0.0;
        while let Some(a) = queue.pop_front() {
            queued[a as usize] = false;
            if let Some((delta, m)) = self.best_move(a as usize, &near[a as usize]) {
                change += delta;
                let touched = self.touched(m);
                self.apply(m);
                enqueue(queue, queued, touched.into_iter().chain([a]));
            }
        }
        change
    }

    /// Local search over the whole route, then whole fields moved or turned
    /// round, again until neither helps.
    pub fn improve(&mut self, near: &[Vec<u32>]) {
        let mut queue: VecDeque<u32> = self.order.iter().copied().collect();
        let mut queued = vec![true; self.order.len()];
        loop {
            self.improve_from(near, &mut queue, &mut queued);
            let Some(touched) = self.move_a_field() else { break };
            enqueue(&mut queue, &mut queued, touched);
        }
    }

    /// Positions of each field's stops, in route order.
    fn blocks(&self) -> Vec<(usize, usize)> {
        let mut blocks = Vec::new();
        let mut start = 0;
        for p in 1..=self.order.len() {
            if p == self.order.len() || self.field_at(p) != self.field_at(start) {
                blocks.push((start, p));
                start = p;
            }
        }
        blocks
    }

    /// The best move of one whole field to another place between fields,
    /// turned round or not, if it shortens the route; returns the stops at the
    /// changed jumps.
    fn move_a_field(&mut self) -> Option<[u32; 6]> {
        let blocks = self.blocks();
        let mut best: Option<(f64, Move)> = None;
        for &(s, end) in &blocks {
            let len = end - s;
            for &(t, _) in blocks.iter().chain(std::iter::once(&(self.order.len(), 0))) {
                if t >= s && t <= end {
                    continue;
                }
                for reverse in [false, true] {
                    if len == 1 && reverse && self.stop_at(s).closed {
                        continue;
                    }
                    // The field keeps its entries (a field of one closed
                    // stop finds a better vertex by the entry move).
                    let delta = self.insertion_cost(s, len, t, reverse, false).0 - self.removal_gain(s, len);
                    if delta < -EPS && best.is_none_or(|(d, _)| delta < d) {
                        best = Some((delta, Move::OrOpt { s, len, t, reverse, field: self.field_at(s), entry: None }));
                    }
                }
            }
        }
        let (_, m) = best?;
        let touched = self.touched(m);
        // A whole field moves with its stops in it reversed; open stops turn.
        self.apply(m);
        Some(touched)
    }

    /// The best entries for the order as it is: a shortest path through the
    /// choices of every stop, one stop after another (exact, where the entry
    /// moves of the local search change one stop at a time).
    pub fn best_entries(&mut self) {
        let n = self.order.len();
        if n == 0 {
            return;
        }
        let options = |s: &Stop| if s.closed { s.vertices.len() } else { 2 };
        // cost[c]: the shortest route up to this stop entered with choice c.
        let mut cost: Vec<f64> = vec![0.0; options(self.stop_at(0))];
        let mut back: Vec<Vec<u32>> = Vec::with_capacity(n);
        back.push(Vec::new());
        for p in 1..n {
            let (prev, here) = (self.stop_at(p - 1), self.stop_at(p));
            let mut next = vec![f64::INFINITY; options(here)];
            let mut from = vec![0u32; options(here)];
            for (c, slot) in next.iter_mut().enumerate() {
                let entry = here.entry(c as u32);
                for (b, &base) in cost.iter().enumerate() {
                    let d = base + dist(prev.exit(b as u32), entry);
                    if d < *slot {
                        *slot = d;
                        from[c] = b as u32;
                    }
                }
            }
            cost = next;
            back.push(from);
        }
        let mut c = (0..cost.len()).min_by(|&a, &b| cost[a].total_cmp(&cost[b])).unwrap() as u32;
        for p in (0..n).rev() {
            let s = self.order[p] as usize;
            self.choice[s] = c;
            if p > 0 {
                c = back[p][c as usize];
            }
        }
    }

    /// Iterated local search: `kicks` times (or until the `cap`), two
    /// adjacent runs inside one field swap places, the local search repairs
    /// around them, and the route is kept if it is no longer. Returns the
    /// best route found.
    pub fn search(mut self, near: &[Vec<u32>], kicks: usize, cap: &TimeCap, seed: u64) -> Route<'a> {
        let n = self.order.len();
        self.improve(near);
        if n < 8 {
            return self;
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let window = KICK_WINDOW.min(n);
        let mut best = self.clone();
        let mut length = self.length();
        let mut best_length = length;
        let mut queue = VecDeque::new();
        let mut queued = vec![false; n];
        for k in 0..kicks {
            if k % 16 == 0 && cap.reached() {
                break;
            }
            self.dirty = None;
            let blocks = if k % REBUILD_EVERY == REBUILD_EVERY / 2 { self.blocks() } else { Vec::new() };
            let (a, c, b) = if blocks.len() >= 3 {
                // Now and then the fields' order: two runs of neighbouring
                // fields swap places.
                let first = rng.random_range(0..blocks.len() - 2);
                let last = (first + 3 + rng.random_range(0..3usize)).min(blocks.len());
                let middle = rng.random_range(first + 1..last);
                let (a, b, c) = (blocks[first].0, blocks[middle].0, blocks[last - 1].1);
                length += self.rearrange(a, c, |run| run.rotate_left(b - a));
                (a, c, Some(a + c - b))
            } else if k % REBUILD_EVERY == REBUILD_EVERY - 1 {
                // Now and then a whole field again, nearest neighbour first,
                // from the field before or back from the field after: the
                // way through a field can be wrong as a whole (a letter run
                // from its middle), which small kicks never turn round.
                let p = rng.random_range(0..n);
                let field = self.field_at(p);
                let a = (0..=p).rev().take_while(|&q| self.field_at(q) == field).last().unwrap();
                let c = (p..n).take_while(|&q| self.field_at(q) == field).last().unwrap() + 1;
                if c - a < 4 {
                    continue;
                }
                let backwards = rng.random_bool(0.5) && c < n;
                let mut left: Vec<u32> = self.order[a..c].to_vec();
                let mut path: Vec<u32> = Vec::with_capacity(left.len());
                let mut here = if backwards { self.entry_at(c) } else if a > 0 { self.exit_at(a - 1) } else { self.entry_at(a) };
                while !left.is_empty() {
                    let stop = |s: u32| &self.stops[s as usize];
                    let key = |s: u32| if backwards { dist(stop(s).exit(self.choice[s as usize]), here) } else { dist(here, stop(s).entry(self.choice[s as usize])) };
                    let i = (0..left.len()).min_by(|&i, &j| key(left[i]).total_cmp(&key(left[j]))).unwrap();
                    let s = left.swap_remove(i);
                    here = if backwards { stop(s).entry(self.choice[s as usize]) } else { stop(s).exit(self.choice[s as usize]) };
                    path.push(s);
                }
                if backwards {
                    path.reverse();
                }
                length += self.rearrange(a, c, |run| run.copy_from_slice(&path));
                (a, c, None)
            } else {
                // Three cut points within a short window of one field; the
                // runs a..b and b..c swap.
                let start = rng.random_range(0..=n - window);
                let field = self.field_at(start);
                let end = (start..start + window).take_while(|&p| self.field_at(p) == field).last().unwrap() + 1;
                if end - start < 3 {
                    continue;
                }
                let mut cuts = [rng.random_range(start..end), rng.random_range(start..end), rng.random_range(start..=end)];
                cuts.sort_unstable();
                let [a, b, c] = cuts;
                if a == b || b == c {
                    continue;
                }
                length += self.rearrange(a, c, |run| run.rotate_left(b - a));
                (a, c, Some(b))
            };
            self.mark(a, c - 1);
            // The stops at the changed jumps (after a rebuild, all of it).
            let stop = |p: usize| self.order[p];
            match b {
                Some(b) => enqueue(&mut queue, &mut queued, [a.saturating_sub(1), a, b - 1, b, c - 1, c.min(n - 1)].map(stop)),
                None => enqueue(&mut queue, &mut queued, (a.saturating_sub(1)..=c.min(n - 1)).map(stop)),
            }
            length += self.improve_from(near, &mut queue, &mut queued);
            let (lo, hi) = self.dirty.unwrap();
            if length > best_length + EPS {
                self.copy_range(&best, lo, hi);
                length = best_length;
            } else {
                // Shorter, or as long: kept (sideways steps help on plateaus).
                best.copy_range(&self, lo, hi);
                best_length = best_length.min(length);
            }
        }
        debug_assert!((best.length() - best_length).abs() < 1e-6 * (1.0 + best_length));
        best.improve(near);
        best.best_entries();
        best.improve(near);
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x: f64, y: f64, fields: Vec<u32>) -> Stop {
        Stop::new(vec![Point::new(x, y), Point::new(x + 1.0, y), Point::new(x + 1.0, y + 1.0), Point::new(x, y + 1.0)], true, fields)
    }

    fn random_stops(n: usize, seed: u64) -> Vec<Stop> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let (x, y) = (rng.random_range(0.0..100.0), rng.random_range(0.0..100.0));
                let field = |x: f64, y: f64| (x / 50.0) as u32 + 2 * (y / 50.0) as u32;
                if rng.random_bool(0.3) {
                    let (x2, y2) = ((x + rng.random_range(-3.0..3.0f64)).clamp(0.0, 99.9), (y + rng.random_range(-3.0..3.0f64)).clamp(0.0, 99.9));
                    let mut fields = vec![field(x, y)];
                    if field(x2, y2) != fields[0] {
                        fields = Vec::new();
                    }
                    if fields.is_empty() {
                        return square(x.min(98.0), y.min(98.0), vec![field(x.min(98.0), y.min(98.0))]);
                    }
                    Stop::new(vec![Point::new(x, y), Point::new(x2, y2)], false, fields)
                } else {
                    // A square near a field border may fit two overlapping fields.
                    let mut fields = vec![field(x, y)];
                    let other = field((x + 5.0).min(99.9), y);
                    if other != fields[0] {
                        fields.push(other);
                        fields.sort_unstable();
                    }
                    square(x, y, fields)
                }
            })
            .collect()
    }

    /// A contiguous start: stops grouped by their first field.
    fn start(stops: &[Stop]) -> Route<'_> {
        let field: Vec<u32> = stops.iter().map(|s| s.fields[0]).collect();
        let mut order: Vec<u32> = (0..stops.len() as u32).collect();
        order.sort_by_key(|&s| field[s as usize]);
        Route::new(stops, order, vec![0; stops.len()], field, 4)
    }

    #[test]
    fn every_move_changes_the_length_by_its_delta_and_keeps_fields_contiguous() {
        let stops = random_stops(60, 7);
        let near = neighbours(&stops, 8);
        let mut route = start(&stops);
        let mut moves = 0;
        for round in 0..200 {
            let a = (round * 7) % stops.len();
            let before = route.length();
            // Any move around a, improving or not: the first allowed one.
            let p = route.pos[a] as usize;
            let q = route.pos[near[a][round % 8] as usize] as usize;
            let (lo, hi) = (p.min(q), p.max(q));
            let m = if round % 2 == 0 && lo < hi && route.two_opt_allowed(lo + 1, hi) {
                let d = route.two_opt_delta(lo + 1, hi);
                (d, Move::TwoOpt { i: lo + 1, j: hi })
            } else if q != p + 1 && q != p {
                match route.field_for_run(p, 1, q) {
                    Some(field) => {
                        let (d, entry) = route.or_opt_delta(p, 1, q, round % 3 == 0);
                        (d, Move::OrOpt { s: p, len: 1, t: q, reverse: round % 3 == 0, field, entry })
                    }
                    None => continue,
                }
            } else {
                continue;
            };
            route.apply(m.1);
            moves += 1;
            assert!((route.length() - before - m.0).abs() < 1e-6, "{:?}: {} != {}", m.1, route.length() - before, m.0);
            assert!(route.contiguous());
            let mut seen: Vec<u32> = route.order.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..stops.len() as u32).collect::<Vec<_>>());
        }
        assert!(moves > 50);
    }

    #[test]
    fn the_search_shortens_a_route_and_keeps_it_valid() {
        let stops = random_stops(200, 3);
        let near = neighbours(&stops, 8);
        let route = start(&stops);
        let before = route.length();
        let improved = {
            let mut r = route.clone();
            r.improve(&near);
            r
        };
        let searched = route.clone().search(&near, 2000, &TimeCap::none(), 1);
        assert!(improved.length() < 0.5 * before, "{} vs {}", improved.length(), before);
        assert!(searched.length() <= improved.length() + 1e-9);
        assert!(searched.contiguous() && improved.contiguous());
        assert!(searched.used_fields() <= 4);
    }

    #[test]
    fn the_same_seed_gives_the_same_route() {
        let stops = random_stops(150, 9);
        let near = neighbours(&stops, 8);
        let one = start(&stops).search(&near, 800, &TimeCap::none(), 42);
        let two = start(&stops).search(&near, 800, &TimeCap::none(), 42);
        assert_eq!((one.order(), one.choices(), one.fields()), (two.order(), two.choices(), two.fields()));
        assert!(one.contiguous());
    }

    #[test]
    fn squares_in_a_row_are_entered_at_their_near_corners() {
        // Unit squares at x = 0, 4 and 8: a closed square is left where it is
        // entered, so the middle one costs its side once: 3 + 4.
        let stops: Vec<Stop> = (0..3).map(|i| square(4.0 * i as f64, 0.0, vec![0])).collect();
        let near = neighbours(&stops, 2);
        let mut route = Route::new(&stops, vec![2, 0, 1], vec![0; 3], vec![0; 3], 1);
        route.improve(&near);
        assert!((route.length() - 7.0).abs() < 1e-9, "{}", route.length());
    }
}
