//! Work shared out over the machine's cores: motion and program planning
//! split into many independent pieces (one mark's corners, one span's blocks),
//! and the planners' independent searches.
//!
//! What is computed never depends on how many threads there are: the work is
//! cut into a fixed number of pieces (or tasks), each computed the same way on
//! whichever thread takes it, and the results come back in their order.

use std::sync::atomic::{AtomicUsize, Ordering};

use crate::error::{Error, Result};

/// Pieces `chunks` cuts its items into (at most).
const PIECES: usize = 8;

/// Most threads used; `LASERD_THREADS` may not ask for more.
const MAX_THREADS: usize = 256;

/// The threads the work runs on: `LASERD_THREADS` when set (1 to 256), else
/// the machine's cores (at most 8). Results never depend on it, only the
/// wall-clock time does.
pub fn threads() -> Result<usize> {
    match std::env::var("LASERD_THREADS") {
        Ok(text) => match text.trim().parse::<usize>() {
            Ok(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
            _ => Err(Error::Config(format!("LASERD_THREADS: {text:?} is not a number of threads from 1 to {MAX_THREADS}"))),
        },
        Err(_) => Ok(std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, 8)),
    }
}

/// `task(0..tasks)` on up to `threads` threads, the results in task order.
/// Each task is computed alone, so which thread runs it does not matter.
pub fn tasks<R: Send>(tasks: usize, threads: usize, task: impl Fn(usize) -> R + Sync) -> Vec<R> {
    let workers = threads.clamp(1, tasks.max(1));
    if workers == 1 {
        return (0..tasks).map(task).collect();
    }
    let next = AtomicUsize::new(0);
    let (task, next) = (&task, &next);
    let mut done: Vec<(usize, R)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(move || {
                    let mut done = Vec::new();
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        if k >= tasks {
                            return done;
                        }
                        done.push((k, task(k)));
                    }
                })
            })
            .collect();
        // A panic in a worker is a bug; pass it on as the same panic.
        handles.into_iter().flat_map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    });
    done.sort_by_key(|(k, _)| *k);
    done.into_iter().map(|(_, r)| r).collect()
}

/// `work` applied to consecutive chunks of `items` (a fixed number of them,
/// whatever the cores), on all cores, in order. Fewer than `min_items`: one
/// chunk on this thread.
pub fn chunks<T: Sync, R: Send>(items: &[T], min_items: usize, work: impl Fn(&[T]) -> R + Sync) -> Vec<R> {
    if items.len() < min_items.max(2) {
        return vec![work(items)];
    }
    let parts: Vec<&[T]> = items.chunks(items.len().div_ceil(PIECES)).collect();
    // An unreadable LASERD_THREADS is refused where planning starts; here it
    // could only change the speed.
    tasks(parts.len(), threads().unwrap_or(1), |k| work(parts[k]))
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

    #[test]
    fn the_pieces_do_not_depend_on_the_threads() {
        let items: Vec<u64> = (0..1001).collect();
        let pieces = super::chunks(&items, 1, |part| (part[0], part.len()));
        assert_eq!(pieces.len(), super::PIECES);
        for threads in [1, 2, 3, 8, 20] {
            let done = super::tasks(11, threads, |k| k * k);
            assert_eq!(done, (0..11).map(|k| k * k).collect::<Vec<_>>(), "{threads} threads");
        }
        assert!(super::tasks(0, 4, |k| k).is_empty());
    }
}
