//! Work shared out over the machine's cores: motion and program planning
//! split into many independent pieces (one mark's corners, one span's blocks),
//! and a dense job has thousands of them.

/// `work` applied to consecutive chunks of `items`, one chunk per core, in
/// order. With one core, or fewer than `min_items`, one chunk on this thread.
pub fn chunks<T: Sync, R: Send>(items: &[T], min_items: usize, work: impl Fn(&[T]) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, 8);
    if threads == 1 || items.len() < min_items.max(2) {
        return vec![work(items)];
    }
    let chunk = items.len().div_ceil(threads);
    let work = &work;
    std::thread::scope(|scope| {
        let workers: Vec<_> = items.chunks(chunk).map(|part| scope.spawn(move || work(part))).collect();
        // A panic in a worker is a bug; pass it on as the same panic.
        workers.into_iter().map(|w| w.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    })
}

/// `f` of every item, computed on all cores, in order.
pub fn map<T: Sync, R: Send>(items: &[T], min_items: usize, f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    chunks(items, min_items, |part| part.iter().map(&f).collect::<Vec<_>>()).into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn results_come_back_in_order() {
        let items: Vec<u64> = (0..1000).collect();
        let squares = super::map(&items, 1, |x| x * x);
        assert_eq!(squares, items.iter().map(|x| x * x).collect::<Vec<_>>());
        let sums = super::chunks(&items, 1, |part| part.iter().sum::<u64>());
        assert_eq!(sums.iter().sum::<u64>(), 499_500);
        assert_eq!(super::chunks(&items[..3], 10, |part| part.len()), vec![3], "few items stay on one thread");
    }
}
