//! Independent filter passes on the cores: the σ1 candidates, the anomaly-process profiles
//! and the jackknife's refits each re-filter the whole flight with inputs that do not depend
//! on one another. Each item is computed exactly as a serial loop would, and the results
//! come back in the items' order, so nothing depends on the thread count.

/// `f` over `items`, in their order, on up to `available_parallelism` threads.
pub(super) fn map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(items.len())
        .max(1);
    if threads == 1 {
        return items.iter().map(f).collect();
    }
    // Interleaved (item i on thread i mod n): the passes cost about the same.
    let f = &f;
    let mut slots: Vec<(usize, R)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                s.spawn(move || {
                    (t..items.len())
                        .step_by(threads)
                        .map(|i| (i, f(&items[i])))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("a filter pass panicked"))
            .collect()
    });
    slots.sort_by_key(|(i, _)| *i);
    slots.into_iter().map(|(_, r)| r).collect()
}
