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

/// `f(first, chunk)` on `items` cut into contiguous chunks of nearly equal length (one per core,
/// none shorter than `min` unless `items` is), `first` the chunk's first index, on the available
/// cores. Each chunk is `f`'s alone, so the result does not depend on the cutting when `f` treats
/// each item on its own.
pub(crate) fn par_chunks_mut<T: Send>(
    items: &mut [T],
    min: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let threads = std::thread::available_parallelism()
        .map_or(1, |t| t.get())
        .min(8)
        .min(items.len() / min.max(1))
        .max(1);
    if threads == 1 {
        f(0, items);
        return;
    }
    let len = items.len().div_ceil(threads);
    let f = &f;
    std::thread::scope(|s| {
        for (k, chunk) in items.chunks_mut(len).enumerate() {
            s.spawn(move || f(k * len, chunk));
        }
    });
}

/// Items per task of [`par_map_items`].
const ITEMS_PER_TASK: usize = 8192;

/// `f(0), …, f(count − 1)` in order, for many cheap items (one per sample, say): the cores take
/// runs of [`ITEMS_PER_TASK`] consecutive indices. Each value is `f`'s alone, so the result is
/// the serial loop's, bit for bit; a reduction over it stays serial where its order matters.
pub(crate) fn par_map_items<T: Send>(count: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    if count <= ITEMS_PER_TASK {
        return (0..count).map(f).collect();
    }
    let runs = par_map(count.div_ceil(ITEMS_PER_TASK), |k| {
        let start = k * ITEMS_PER_TASK;
        (start..(start + ITEMS_PER_TASK).min(count))
            .map(&f)
            .collect::<Vec<T>>()
    });
    let mut out = Vec::with_capacity(count);
    for run in runs {
        out.extend(run);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn items_come_back_in_order_whatever_the_count() {
        for count in [
            0,
            1,
            ITEMS_PER_TASK - 1,
            ITEMS_PER_TASK,
            3 * ITEMS_PER_TASK + 17,
        ] {
            let got = par_map_items(count, |i| i * i);
            let want: Vec<usize> = (0..count).map(|i| i * i).collect();
            assert_eq!(got, want, "count {count}");
        }
    }
}
