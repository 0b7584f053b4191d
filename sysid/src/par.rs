//! Work shared among the available cores, results in order (std's scoped threads).

/// `f(0), …, f(count − 1)` in order, computed on the available cores (indices dealt out in turn,
/// so that work growing with the index is shared evenly).
pub(crate) fn par_map<T: Send>(count: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |t| t.get())
        .min(8)
        .min(count);
    if threads <= 1 {
        return (0..count).map(f).collect();
    }
    let f = &f;
    let parts: Vec<Vec<T>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|first| s.spawn(move || (first..count).step_by(threads).map(f).collect()))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a par_map worker panicked"))
            .collect()
    });
    let mut parts: Vec<_> = parts.into_iter().map(Vec::into_iter).collect();
    (0..count)
        .map(|k| parts[k % threads].next().expect("one result per index"))
        .collect()
}
