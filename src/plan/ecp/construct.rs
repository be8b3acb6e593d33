//! Feasible starting routes (seed 001's constructions) and dir-opt.

use rand::SeedableRng;
use rstar::primitives::{GeomWithData, Line};
use rstar::RTree;

use super::moves::{link, Rules};
use super::order_list::OrderList;
use super::{Cut, Instance};
use crate::job::Point;
use crate::plan::stop::TimeCap;

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

/// End points of elements in an R-tree, each with its datum (the element,
/// or the element and a contour): the constructions' nearest-first choices
/// in O(log n) each instead of a scan of everything left.
struct Ends<T: Copy + PartialEq + Ord> {
    tree: RTree<GeomWithData<[f64; 2], T>>,
}

/// Distinct accepted data a nearest-first choice looks at past the nearest
/// by straight distance, and among which it takes the nearest by the
/// instance's metric (the same one unless the metric prices machine time).
const PROBE: usize = 4;

impl<T: Copy + PartialEq + Ord> Ends<T> {
    fn new(inst: &Instance, items: impl Iterator<Item = (usize, T)>) -> Ends<T> {
        let ends = items.flat_map(|(e, t)| end_points(inst, e).map(|p| GeomWithData::new(p, t))).collect();
        Ends { tree: RTree::bulk_load(ends) }
    }

    fn remove(&mut self, inst: &Instance, e: usize, t: T) {
        for p in end_points(inst, e) {
            self.tree.remove(&GeomWithData::new(p, t));
        }
    }

    /// The datum `accept`ed whose element is nearest to `here` by the
    /// instance's metric (an element's distance: to its nearer end), among
    /// the [`PROBE`] nearest by straight distance and all those tied with the
    /// nearest; ties to the lowest datum.
    fn nearest(&self, inst: &Instance, here: Point, element: impl Fn(T) -> usize, mut accept: impl FnMut(T) -> bool) -> Option<T> {
        let mut seen: Vec<(T, bool)> = Vec::new();
        let mut found: Vec<T> = Vec::new();
        let mut first = None;
        for (hit, d2) in self.tree.nearest_neighbor_iter_with_distance_2([here.x, here.y]) {
            if first.is_some_and(|f| d2 > f) && found.len() >= PROBE {
                break;
            }
            let t = hit.data;
            if seen.iter().any(|s| s.0 == t) {
                continue;
            }
            let ok = accept(t);
            seen.push((t, ok));
            if ok {
                first.get_or_insert(d2);
                found.push(t);
            }
        }
        let distance = |t: T| {
            let el = &inst.elements[element(t)];
            inst.distance(here, el.a).min(inst.distance(here, el.b))
        };
        found.into_iter().map(|t| (distance(t), t)).min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1))).map(|(_, t)| t)
    }
}

fn end_points(inst: &Instance, e: usize) -> [[f64; 2]; 2] {
    let el = &inst.elements[e];
    [[el.a.x, el.a.y], [el.b.x, el.b.y]]
}

/// A feasible order: nearest neighbour among the elements that may come next.
/// An element may not close a contour before the contour's inner contours are
/// cut, nor be the last element cut of the rest of a common cut's two contours
/// while that common cut waits (it could never be cut then). Falls back to
/// cutting contour by contour, innermost first, should it ever get stuck.
/// The elements left are in an R-tree of their ends, so that the next is
/// found near where the last ended (few elements are ever not allowed: a
/// contour's last, the last but one next to a waiting common cut).
pub fn construct(inst: &Instance) -> Vec<Cut> {
    let n = inst.elements.len();
    let rules = Rules::new(inst);
    let mut left: Vec<usize> = inst.contours.iter().map(Vec::len).collect();
    let mut done = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut here = inst.depot;
    let mut ends = Ends::new(inst, (0..n).map(|e| (e, e)));
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
        let Some(f) = ends.nearest(inst, here, |e| e, allowed) else { return dir_opt(inst, &contour_order(inst)) };
        done[f] = true;
        ends.remove(inst, f, f);
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
///
/// The positions looked at are the route's air moves nearest to either end
/// of the element ([`INSERTION_NEAREST`] each, from an R-tree of the moves
/// as segments, among those that keep the rules), the route's start, its end
/// (which keeps every rule) and right after what the element must follow to
/// close its contours: the cheapest place is all but always among them
/// (against trying every position, as seed 001 did: 4 to 9 % cheaper on
/// random instances of 200 and 1000 elements, the same within 1 % on those
/// of 40 and on generated sheets, single sheets -4 to +1 %; 1 to 2 % dearer
/// on `bench sheet`'s 11k and 34k elements, built in 0.2 and 0.6 s instead
/// of 3.7 and 27 s, topology included, on a loaded machine). The route is an
/// order-maintenance list ([`OrderList`]), so inserting costs O(log n)
/// amortised and the rules compare labels: O(n log n) in all.
pub fn insertion(inst: &Instance) -> Vec<Cut> {
    insertion_in_order(inst, None)
}

/// Air moves of the route, nearest to each end of the element coming in,
/// into which it may go.
pub const INSERTION_NEAREST: usize = 12;

/// [`insertion`] with the elements of each depth taken in a random order
/// (`seed`), or in index order (`None`): different starts for parallel searches.
pub fn insertion_in_order(inst: &Instance, seed: Option<u64>) -> Vec<Cut> {
    insertion_within(inst, seed, &TimeCap::none()).expect("no time cap")
}

/// [`insertion_in_order`], or `None` once `cap` is reached before it is done.
pub fn insertion_within(inst: &Instance, seed: Option<u64>, cap: &TimeCap) -> Option<Vec<Cut>> {
    insert_all(inst, seed, cap).map(|(route, _)| route)
}

/// How an insertion went where the rules left an element no place.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Insertion {
    /// Elements moved after a common cut that would have closed both its contours.
    pub(crate) moved: usize,
    /// Whether it gave up for the nearest-neighbour construction.
    pub(crate) fell_back: bool,
}

pub(crate) fn insert_all(inst: &Instance, seed: Option<u64>, cap: &TimeCap) -> Option<(Vec<Cut>, Insertion)> {
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
    let mut list = OrderList::new(n);
    let (head, tail) = (list.head(), list.tail());
    let mut reversed = vec![false; n];
    // Per contour: its elements not in the route yet, and once it is
    // complete, the element that closes it (inserting others never changes
    // which one that is).
    let mut missing: Vec<usize> = inst.contours.iter().map(Vec::len).collect();
    let mut last = vec![usize::MAX; inst.contours.len()];
    // The route's air moves (from the end of node x to the start of the
    // next: the depot for the head and the tail) as segments, in pieces of
    // a few elements' spacing at most: the tree's boxes stay small even
    // while the moves are long (elements taken in a random order), or a
    // look-up would open most of them.
    let piece = piece_length(inst);
    let mut links: RTree<GeomWithData<Line<[f64; 2]>, usize>> = RTree::new();
    let pieces_of = |x: usize, y: usize, reversed: &[bool]| {
        let p = if x == head { inst.depot } else { inst.ends(Cut { element: x, reversed: reversed[x] }).1 };
        let q = if y == tail { inst.depot } else { inst.ends(Cut { element: y, reversed: reversed[y] }).0 };
        let k = ((q - p).norm() / piece).ceil().clamp(1.0, 4096.0) as usize;
        let at = move |i: usize| p + (q - p) * (i as f64 / k as f64);
        (0..k).map(move |i| {
            let (a, b) = (at(i), at(i + 1));
            GeomWithData::new(Line::new([a.x, a.y], [b.x, b.y]), x)
        })
    };
    for l in pieces_of(head, tail, &reversed) {
        links.insert(l);
    }
    let mut candidates: Vec<usize> = Vec::new();
    let mut moved = 0;
    for (i, &f) in order.iter().enumerate() {
        if i % 64 == 0 && cap.reached() {
            return None;
        }
        for &k in &rules.contours_of[f] {
            missing[k] -= 1;
        }
        // The contours f completes, each with its last element but f.
        let completes: Vec<(usize, Option<usize>)> = rules.contours_of[f]
            .iter()
            .filter(|&&k| missing[k] == 0)
            .map(|&k| (k, inst.contours[k].iter().copied().filter(|&e| e != f).max_by_key(|&e| list.label(e))))
            .collect();
        // Positions as labels doubled, f's (right after node x) odd between them.
        let key = |e: usize| 2 * list.label(e);
        let closes = |k: usize, fk: u64| match completes.iter().find(|c| c.0 == k) {
            Some(&(_, other)) => other.map_or(fk, |o| key(o).max(fk)),
            None => key(last[k]),
        };
        let keeps = |x: usize| -> bool {
            let fk = 2 * list.label(x) + 1;
            let at = |e: usize| if e == f { fk } else { key(e) };
            completes.iter().all(|&(k, _)| {
                let ck = closes(k, fk);
                !(rules.outers[k].iter().any(|&o| missing[o] == 0 && ck >= closes(o, fk))
                    || rules.inners[k].iter().any(|&i| missing[i] == 0 && closes(i, fk) >= ck)
                    || rules.shared[k].iter().any(|&(c, other)| missing[other] == 0 && at(c) == ck && at(c) == closes(other, fk)))
            })
        };
        // The start, the end, right after what f must follow to close its
        // contours, and the air moves nearest to either end of f that keep
        // the rules (looking a little further for those where f closes one).
        candidates.clear();
        candidates.extend([head, list.prev(tail)]);
        for &(k, other) in &completes {
            let inner_last = rules.inners[k].iter().filter(|&&i| missing[i] == 0).map(|&i| last[i]);
            if let Some(x) = other.into_iter().chain(inner_last).max_by_key(|&e| list.label(e)) {
                candidates.push(x);
            }
        }
        let el = &inst.elements[f];
        for end in [el.a, el.b] {
            let (mut taken, mut looked) = (0, 0);
            for hit in links.nearest_neighbor_iter([end.x, end.y]) {
                if taken == INSERTION_NEAREST || looked == 16 * INSERTION_NEAREST {
                    break;
                }
                looked += 1;
                if !candidates.contains(&hit.data) && (completes.is_empty() || keeps(hit.data)) {
                    candidates.push(hit.data);
                    taken += 1;
                }
            }
        }
        let cut = |x: usize| (x < n).then(|| Cut { element: x, reversed: reversed[x] });
        let mut best: Option<(f64, usize, Cut)> = None;
        for &x in &candidates {
            let (a, b) = (cut(x), cut(list.next(x)));
            for r in [false, true] {
                let c = Cut { element: f, reversed: r };
                let d = link(inst, a, Some(c)) + link(inst, Some(c), b) - link(inst, a, b);
                if best.as_ref().is_none_or(|(bd, _, _)| d < *bd) && (completes.is_empty() || keeps(x)) {
                    best = Some((d, x, c));
                }
            }
        }
        let Some((_, x, c)) = best else {
            // Only where f is a common cut that would close both its
            // contours wherever it went after their inner contours (their
            // other elements came before those, as common cuts of deeper
            // contours): f at the end, then one of their other elements
            // whose other contour is not complete yet (no rule of which is
            // decided) moved after it, so that f closes one and it the other.
            let completed = |c: usize| completes.iter().any(|cc| cc.0 == c);
            let movable = |g: usize| g != f && rules.contours_of[g].iter().filter(|&&c| completed(c)).count() == 1 && rules.contours_of[g].iter().all(|&c| completed(c) || missing[c] > 0);
            let fits = completes.len() == 2 && completes.iter().all(|&(k, _)| rules.outers[k].iter().all(|&o| missing[o] > 0));
            let Some(g) = completes.iter().flat_map(|&(k, _)| inst.contours[k].iter().copied()).find(|&g| fits && movable(g)) else { return Some((construct(inst), Insertion { moved, fell_back: true })) };
            moved += 1;
            let (gp, gn) = (list.prev(g), list.next(g));
            for l in pieces_of(gp, g, &reversed).chain(pieces_of(g, gn, &reversed)) {
                links.remove(&l);
            }
            list.remove(g);
            for l in pieces_of(gp, gn, &reversed) {
                links.insert(l);
            }
            let end = list.prev(tail);
            for l in pieces_of(end, tail, &reversed) {
                links.remove(&l);
            }
            let cost = |r: bool| link(inst, cut(end), Some(Cut { element: f, reversed: r }));
            reversed[f] = cost(true) < cost(false);
            list.insert_after(end, f);
            list.insert_after(f, g);
            for l in pieces_of(end, f, &reversed).chain(pieces_of(f, g, &reversed)).chain(pieces_of(g, tail, &reversed)) {
                links.insert(l);
            }
            for &(k, _) in &completes {
                last[k] = if inst.contours[k].contains(&g) { g } else { f };
            }
            continue;
        };
        let y = list.next(x);
        for l in pieces_of(x, y, &reversed) {
            let split = links.remove(&l);
            debug_assert!(split.is_some(), "the air move f goes into is in the tree");
        }
        list.insert_after(x, f);
        reversed[f] = c.reversed;
        for l in pieces_of(x, f, &reversed).chain(pieces_of(f, y, &reversed)) {
            links.insert(l);
        }
        for &(k, other) in &completes {
            last[k] = match other {
                Some(o) if list.label(o) > list.label(f) => o,
                _ => f,
            };
        }
    }
    Some((dir_opt(inst, &list.to_vec()), Insertion { moved, fell_back: false }))
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
///
/// Nearest first from R-trees of element ends: of the groups left, of the
/// contours left of the same depth and rank in a group, and of a long
/// contour's elements left; O(n log n) in all.
pub fn contour_order_construction(inst: &Instance) -> Vec<Cut> {
    let k = inst.contours.len();
    let n = inst.elements.len();
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
    // Each group's contours, deepest first, then highest rank, then by index.
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); k];
    for c in 0..k {
        members[group[c]].push(c);
    }
    for m in &mut members {
        m.sort_by_key(|&c| (std::cmp::Reverse(depth[c]), std::cmp::Reverse(rank[c]), c));
    }
    // Every element is in one group (its contours are linked).
    let group_of_element = |e: usize| group[rules.contours_of[e][0]];
    let mut groups = Ends::new(inst, (0..n).filter(|&e| !rules.contours_of[e].is_empty()).map(|e| (e, e)));
    let mut done = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut here = inst.depot;
    while let Some(nearest) = groups.nearest(inst, here, |e| e, |_| true) {
        let g = group_of_element(nearest);
        for &c in &members[g] {
            for &e in &inst.contours[c] {
                groups.remove(inst, e, e);
            }
        }
        // Contours of one depth and rank at a time, nearest first.
        let mut class_start = 0;
        let list = &members[g];
        while class_start < list.len() {
            let key = |c: usize| (depth[c], rank[c]);
            let class_end = class_start + list[class_start..].iter().take_while(|&&c| key(c) == key(list[class_start])).count();
            let class = &list[class_start..class_end];
            class_start = class_end;
            let mut contours = Ends::new(inst, class.iter().flat_map(|&c| inst.contours[c].iter().filter(|&&e| !done[e]).map(move |&e| (e, (e, c)))));
            let mut contour_left = class.len();
            while contour_left > 0 {
                // A contour whose elements were all cut already (by its
                // neighbours' common cuts) is in no tree: done as it comes.
                let next = contours.nearest(inst, here, |(e, _)| e, |_| true).map(|(_, c)| c);
                let c = match next {
                    Some(c) => c,
                    None => {
                        contour_left = 0;
                        continue;
                    }
                };
                contour_left -= 1;
                let left: Vec<usize> = inst.contours[c].iter().copied().filter(|&e| !done[e]).collect();
                for &e in &left {
                    done[e] = true;
                    for &o in &rules.contours_of[e] {
                        contours.remove(inst, e, (e, o));
                    }
                }
                here = cut_nearest_first(inst, here, left, &mut order);
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

/// Longest piece of an air move in the insertion's R-tree: twice the
/// spacing elements would have spread evenly over the box of the instance.
fn piece_length(inst: &Instance) -> f64 {
    let points = inst.elements.iter().flat_map(|e| [e.a, e.b]).chain([inst.depot]);
    let (lo, hi) = crate::job::bounds_of(points.collect::<Vec<_>>().iter());
    let (w, h, n) = (hi.x - lo.x, hi.y - lo.y, inst.elements.len().max(1) as f64);
    let spacing = if w * h > 0.0 { (w * h / n).sqrt() } else { (w + h) / n };
    if spacing.is_finite() && spacing > 0.0 {
        2.0 * spacing
    } else {
        f64::INFINITY
    }
}

/// Appends `elements` to `order` nearest first from `here`, each ending at
/// its end farther from where it starts; returns where the last ends. A
/// long list goes through an R-tree of its ends.
fn cut_nearest_first(inst: &Instance, mut here: Point, mut elements: Vec<usize>, order: &mut Vec<usize>) -> Point {
    let mut cut = |here: Point, e: usize| {
        let el = &inst.elements[e];
        order.push(e);
        if inst.distance(here, el.a) <= inst.distance(here, el.b) {
            el.b
        } else {
            el.a
        }
    };
    if elements.len() <= 16 {
        while !elements.is_empty() {
            let distance_to = |e: usize| {
                let el = &inst.elements[e];
                inst.distance(here, el.a).min(inst.distance(here, el.b))
            };
            let (i, _) = elements.iter().enumerate().map(|(i, &e)| (i, distance_to(e))).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
            here = cut(here, elements.remove(i));
        }
    } else {
        let mut tree = Ends::new(inst, elements.iter().map(|&e| (e, e)));
        for _ in 0..elements.len() {
            let e = tree.nearest(inst, here, |e| e, |_| true).expect("the tree holds the elements left");
            tree.remove(inst, e, e);
            here = cut(here, e);
        }
    }
    here
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
    let mut contours_of = vec![0usize; inst.elements.len()];
    for &e in inst.contours.iter().flatten() {
        contours_of[e] += 1;
    }
    let mut done = vec![false; inst.elements.len()];
    let mut order = Vec::new();
    for c in contours {
        // Common cuts first, so that they never close this contour.
        let mut elements = inst.contours[c].clone();
        elements.sort_by_key(|&e| contours_of[e] == 1);
        for e in elements {
            if !std::mem::replace(&mut done[e], true) {
                order.push(e);
            }
        }
    }
    order
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::plan::ecp::{checker::check, exact};

    fn random_instance(n: usize, seed: u64) -> Instance {
        crate::plan::ecp::random_instance(n, seed, 2..=4, 3.0)
    }

    /// Seed 001's insertion as it was first written: every position of the
    /// route tried (O(n) each, O(n²) in all), the reference the insertion's
    /// cost is held to.
    pub(crate) fn insertion_everywhere(inst: &Instance) -> Vec<Cut> {
        let n = inst.elements.len();
        let rules = Rules::new(inst);
        let depth = contour_depths(inst);
        let mut order: Vec<usize> = (0..n).collect();
        let element_depth = |e: usize| rules.contours_of[e].iter().map(|&k| depth[k]).max().unwrap_or(0);
        order.sort_by_key(|&e| (std::cmp::Reverse(element_depth(e)), rules.contours_of[e].len() == 1));
        let mut present = vec![false; n];
        let mut route: Vec<Cut> = Vec::with_capacity(n);
        let mut pos = vec![usize::MAX; n];
        let complete = |k: usize, present: &[bool]| inst.contours[k].iter().all(|&e| present[e]);
        for &f in &order {
            present[f] = true;
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
            let (_, p, c) = best.expect("the route's end keeps every rule");
            route.insert(p, c);
            for (i, cut) in route.iter().enumerate().skip(p) {
                pos[cut.element] = i;
            }
        }
        let elements: Vec<usize> = route.iter().map(|c| c.element).collect();
        dir_opt(inst, &elements)
    }

    /// Instances the insertion is measured on: random ones of a few sizes
    /// (elements scattered at random, contours of 2 to 6, pierce cost 3);
    /// generated sheets in `gen::tests` (the generators come later).
    fn insertion_cases() -> Vec<(String, Instance)> {
        let mut cases = Vec::new();
        for (n, seeds) in [(40, 0..20u64), (200, 0..10), (1000, 0..4)] {
            for seed in seeds {
                cases.push((format!("random {n} #{seed}"), crate::plan::ecp::random_instance(n, seed, 2..=6, 3.0)));
            }
        }
        cases
    }

    #[test]
    fn insertion_near_the_nearest_is_feasible_and_as_cheap_as_everywhere() {
        // Greedy insertion is chaotic: one element placed elsewhere early
        // changes the rest, a few % either way on a small instance. So the
        // totals of each kind of instance are held to the reference.
        let mut totals: std::collections::BTreeMap<String, (f64, f64, usize)> = Default::default();
        for (name, inst) in insertion_cases() {
            let reference = insertion_everywhere(&inst);
            if !check(&inst, &reference).is_empty() {
                // A random instance whose rules no route keeps (nesting in a cycle).
                continue;
            }
            let ours = insertion(&inst);
            assert_eq!(check(&inst, &ours), vec![], "{name}");
            let (a, b) = (inst.cost(&ours), inst.cost(&reference));
            eprintln!("{name}: {a:.1} against {b:.1} ({:+.2} %)", 100.0 * (a / b - 1.0));
            assert!(a <= 1.15 * b, "{name}: {a} against {b} trying every position");
            let kind = name.split(" #").next().unwrap().to_string();
            let t = totals.entry(kind).or_default();
            *t = (t.0 + a, t.1 + b, t.2 + 1);
            // Shuffled orders (the searches' later starts) are feasible too.
            assert_eq!(check(&inst, &insertion_in_order(&inst, Some(7))), vec![], "{name}, shuffled");
        }
        for (kind, (a, b, count)) in totals {
            eprintln!("{kind}: {a:.1} against {b:.1} ({:+.2} %) over {count}", 100.0 * (a / b - 1.0));
            assert!(count >= 2, "{kind}: {count} instances compared");
            assert!(a <= 1.03 * b, "{kind}: {a} against {b} trying every position");
        }
    }

    #[test]
    fn an_insertion_past_its_time_cap_gives_up() {
        let inst = random_instance(300, 1);
        assert!(insertion_within(&inst, None, &TimeCap::after(Some(std::time::Duration::ZERO))).is_none());
        assert_eq!(insertion_within(&inst, None, &TimeCap::none()), Some(insertion(&inst)));
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
