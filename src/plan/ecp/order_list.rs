//! A route under construction as a doubly linked list whose nodes carry
//! order labels (order maintenance): inserting next to a node is O(1)
//! amortised O(log n), and which of two nodes comes first is a comparison of
//! their labels, so that precedence rules can be checked without positions.
//!
//! Labels are u64 in `[0, 2^62]`, increasing along the list; a new node takes
//! the middle of the gap it goes into. When a gap runs out, the smallest
//! aligned block of labels around the node (sizes 2, 4, 8, …) that is sparse
//! enough (at most `2^i / T^i` nodes in a block of `2^i`, Bender et al.'s
//! "two simplified algorithms for maintaining order in a list") is labelled
//! again evenly: O(log n) amortised per insertion, whatever the pattern (many
//! insertions at one place included).

/// Bits of the label universe: the tail's label is `1 << BITS`.
const BITS: u32 = 62;
/// Density threshold base: a block of `2^i` labels may hold `(2 / T)^i` nodes.
const T: f64 = 1.3;

/// Nodes `0..n` (the elements), the head (before the first: `n`) and the
/// tail (after the last: `n + 1`), which are always in the list.
pub(crate) struct OrderList {
    next: Vec<u32>,
    prev: Vec<u32>,
    label: Vec<u64>,
    in_list: Vec<bool>,
    /// Times a block was labelled again, and nodes labelled again in all.
    pub(crate) relabels: usize,
    pub(crate) relabelled: usize,
}

const NONE: u32 = u32::MAX;

impl OrderList {
    /// An empty list for nodes `0..n`.
    pub(crate) fn new(n: usize) -> OrderList {
        assert!(n + 2 < NONE as usize, "too many nodes for an order list");
        let (head, tail) = (n, n + 1);
        let mut list = OrderList { next: vec![NONE; n + 2], prev: vec![NONE; n + 2], label: vec![0; n + 2], in_list: vec![false; n + 2], relabels: 0, relabelled: 0 };
        list.next[head] = tail as u32;
        list.prev[tail] = head as u32;
        list.label[tail] = 1 << BITS;
        list.in_list[head] = true;
        list.in_list[tail] = true;
        list
    }

    pub(crate) fn head(&self) -> usize {
        self.next.len() - 2
    }

    pub(crate) fn tail(&self) -> usize {
        self.next.len() - 1
    }

    /// The node after `x` (the tail has none).
    pub(crate) fn next(&self, x: usize) -> usize {
        self.next[x] as usize
    }

    /// The node before `x` (the head has none).
    pub(crate) fn prev(&self, x: usize) -> usize {
        self.prev[x] as usize
    }

    /// `x`'s label: `label(x) < label(y)` when `x` comes before `y`.
    pub(crate) fn label(&self, x: usize) -> u64 {
        self.label[x]
    }

    /// Puts node `new` (not in the list) right after `x` (not the tail).
    pub(crate) fn insert_after(&mut self, x: usize, new: usize) {
        assert!(self.in_list[x] && x != self.tail() && !self.in_list[new], "insert_after({x}, {new})");
        if self.label[self.next(x)] - self.label[x] < 2 {
            self.relabel_around(x);
        }
        let y = self.next(x);
        self.label[new] = self.label[x] + (self.label[y] - self.label[x]) / 2;
        self.next[new] = y as u32;
        self.prev[new] = x as u32;
        self.next[x] = new as u32;
        self.prev[y] = new as u32;
        self.in_list[new] = true;
    }

    /// Takes node `x` (not the head nor the tail) out of the list; the
    /// others keep their labels.
    pub(crate) fn remove(&mut self, x: usize) {
        assert!(self.in_list[x] && x != self.head() && x != self.tail(), "remove({x})");
        let (p, q) = (self.prev(x), self.next(x));
        self.next[p] = q as u32;
        self.prev[q] = p as u32;
        self.next[x] = NONE;
        self.prev[x] = NONE;
        self.in_list[x] = false;
    }

    /// Labels the smallest sparse enough block around `x` again, evenly,
    /// leaving a gap of at least 2 after every node in it (and after `x`).
    fn relabel_around(&mut self, x: usize) {
        let (head, tail) = (self.head(), self.tail());
        let (mut lo, mut hi, mut count) = (x, x, 1usize);
        for i in 1..=BITS {
            let size = 1u64 << i;
            let base = self.label[x] & !(size - 1);
            let top = base + (size - 1);
            while lo != head && self.label[self.prev(lo)] >= base {
                lo = self.prev(lo);
                count += 1;
            }
            while self.next(hi) != tail && self.label[self.next(hi)] <= top {
                hi = self.next(hi);
                count += 1;
            }
            let sparse = (count as f64) <= (size as f64) / T.powi(i as i32) && 2 * count as u64 <= size;
            if sparse {
                let step = size / count as u64;
                let mut node = lo;
                for k in 0..count as u64 {
                    self.label[node] = base + k * step;
                    node = self.next(node);
                }
                self.relabels += 1;
                self.relabelled += count;
                return;
            }
        }
        unreachable!("an order list holds fewer than 2^31 nodes, so the whole universe is sparse enough");
    }

    /// The nodes from the first after the head to the last before the tail.
    pub(crate) fn to_vec(&self) -> Vec<usize> {
        let mut out = Vec::new();
        let mut x = self.next(self.head());
        while x != self.tail() {
            out.push(x);
            x = self.next(x);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Labels strictly increase along the list, and links agree both ways.
    fn assert_ordered(list: &OrderList) {
        let mut x = list.head();
        assert_eq!(list.label(x), 0);
        while x != list.tail() {
            let y = list.next(x);
            assert_eq!(list.prev(y), x);
            assert!(list.label(x) < list.label(y), "labels {} then {}", list.label(x), list.label(y));
            x = y;
        }
        assert_eq!(list.label(list.tail()), 1 << BITS);
    }

    #[test]
    fn many_insertions_at_one_place_keep_the_order() {
        // Always right after the head, always right after the same node, and
        // always before the tail: the gaps there halve each time, so blocks
        // are labelled again many times.
        let n = 20_000;
        for pattern in 0..3 {
            let mut list = OrderList::new(n);
            let mut expected: Vec<usize> = Vec::new();
            list.insert_after(list.head(), 0);
            expected.push(0);
            for new in 1..n {
                match pattern {
                    0 => {
                        list.insert_after(list.head(), new);
                        expected.insert(0, new);
                    }
                    1 => {
                        list.insert_after(0, new);
                        expected.insert(1, new);
                    }
                    _ => {
                        list.insert_after(list.prev(list.tail()), new);
                        expected.push(new);
                    }
                }
            }
            assert_ordered(&list);
            assert_eq!(list.to_vec(), expected, "pattern {pattern}");
            assert!(list.relabels > 0, "pattern {pattern}: the gaps ran out and blocks were labelled again");
            // Amortised O(log n): nodes labelled again, per insertion, stay a
            // small multiple of log2(n) (a whole-list relabelling every time
            // the gap ran out would be thousands per insertion).
            let per = list.relabelled as f64 / n as f64;
            assert!(per < 40.0 * (n as f64).log2(), "pattern {pattern}: {per} nodes labelled again per insertion");
        }
    }

    #[test]
    fn random_insertions_keep_the_order_of_a_vec() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 5_000;
        let mut list = OrderList::new(n);
        let mut expected: Vec<usize> = Vec::new();
        for new in 0..n {
            // Mostly next to recent nodes (clusters), sometimes anywhere.
            let at = if expected.is_empty() || rng.random_ratio(1, 4) { rng.random_range(0..=expected.len()) } else { expected.iter().position(|&x| x == new - 1).unwrap() + 1 };
            let after = if at == 0 { list.head() } else { expected[at - 1] };
            list.insert_after(after, new);
            expected.insert(at, new);
        }
        // Some taken out and put back elsewhere.
        for _ in 0..500 {
            let x = expected.remove(rng.random_range(0..expected.len()));
            list.remove(x);
            let at = rng.random_range(0..=expected.len());
            list.insert_after(if at == 0 { list.head() } else { expected[at - 1] }, x);
            expected.insert(at, x);
        }
        assert_ordered(&list);
        assert_eq!(list.to_vec(), expected);
        // Labels compare as positions do.
        for _ in 0..1000 {
            let (i, j) = (rng.random_range(0..n), rng.random_range(0..n));
            assert_eq!(list.label(expected[i]) < list.label(expected[j]), i < j);
        }
    }
}
