//! Cycles that survive noisy flow: the flow's phase switches, kept only where the volume itself
//! turns.
//!
//! The phase machine of [`crate::dataset`] reads the sign of the smoothed flow, and on a real
//! flow sensor every wiggle that outlasts its debounce is a new "inflation": a ventilator's
//! pressure overshoot that pushes a little air back into the lung, or the ringing after each
//! exhalation, each starts a cycle, and a log of 8 breaths comes out as 25 cycles.
//!
//! A cycle is one inflation and one deflation *of the stroke*. So the volume decides which phase
//! switches are cycle starts: its turning points are found with hysteresis (a trough counts once
//! the volume has risen [`TURN_FRACTION`] of the log's volume range above it, a peak once it has
//! fallen as far below it; range = 5th to 95th percentile, robust to spikes and to a drifting
//! zero), and each confirmed trough keeps the one flow boundary nearest to it between its two
//! neighbouring peaks (the trough itself where there is none). On clean data with full strokes
//! every flow boundary sits at a trough and nothing changes; the spurious ones are dropped.

/// Fraction of the volume range (5th to 95th percentile) the volume must move back from an
/// extreme for it to count as a turning point: half a stroke.
pub const TURN_FRACTION: f64 = 0.5;

/// Confirmed turning points of `v`: alternating troughs and peaks, as (index, is_trough), with
/// hysteresis `h` (see the module docs). The trough's index is the last sample at its minimum.
pub fn turning_points(v: &[f64], h: f64) -> Vec<(usize, bool)> {
    let mut out = Vec::new();
    if v.is_empty() || h.is_nan() || h <= 0.0 {
        return out;
    }
    // Until the first turn is confirmed, track both extremes.
    let (mut lo, mut hi) = (0usize, 0usize);
    let mut seeking_peak: Option<bool> = None;
    for (i, &x) in v.iter().enumerate() {
        match seeking_peak {
            None => {
                if x <= v[lo] {
                    lo = i;
                }
                if x >= v[hi] {
                    hi = i;
                }
                if x - v[lo] >= h {
                    out.push((lo, true));
                    seeking_peak = Some(true);
                    hi = i;
                } else if v[hi] - x >= h {
                    out.push((hi, false));
                    seeking_peak = Some(false);
                    lo = i;
                }
            }
            Some(true) => {
                if x >= v[hi] {
                    hi = i;
                } else if v[hi] - x >= h {
                    out.push((hi, false));
                    seeking_peak = Some(false);
                    lo = i;
                }
            }
            Some(false) => {
                if x <= v[lo] {
                    lo = i;
                } else if x - v[lo] >= h {
                    out.push((lo, true));
                    seeking_peak = Some(true);
                    hi = i;
                }
            }
        }
    }
    out
}

/// The hysteresis for `v`: [`TURN_FRACTION`] of its 5th-to-95th-percentile range (0 when the
/// data are empty or the volume is flat).
pub fn hysteresis(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.len() < 2 {
        return 0.0;
    }
    let mut q = |p: f64| {
        let k = ((s.len() - 1) as f64 * p).round() as usize;
        crate::metrics::order_statistic(&mut s, k).expect("k < len")
    };
    TURN_FRACTION * (q(0.95) - q(0.05))
}

/// Cycle labels (as [`crate::dataset::segment_cycles`] gives them, one per sample, starting at 0
/// and rising by one at each cycle start) relabelled so that only the boundaries at the volume's
/// troughs remain (see the module docs). Returns the labels and the number of cycles.
pub fn keep_volume_cycles(v: &[f64], flow_labels: &[usize]) -> (Vec<usize>, usize) {
    let n = flow_labels.len().min(v.len());
    let bounds: Vec<usize> = (1..n)
        .filter(|&i| flow_labels[i] != flow_labels[i - 1])
        .collect();
    let turns = turning_points(&v[..n], hysteresis(&v[..n]));
    if turns.iter().filter(|t| t.1).count() == 0 {
        // The volume never makes a full stroke: the flow's boundaries are all there is.
        let count = flow_labels.last().map_or(0, |c| c + 1);
        return (flow_labels[..n].to_vec(), count);
    }
    let mut starts = Vec::new();
    for (k, &(t, trough)) in turns.iter().enumerate() {
        if !trough {
            continue;
        }
        let lo = if k > 0 { turns[k - 1].0 } else { 0 };
        let hi = turns.get(k + 1).map_or(n, |p| p.0);
        let near = bounds
            .iter()
            .copied()
            .filter(|&b| b > lo && b <= hi)
            .min_by_key(|&b| b.abs_diff(t));
        starts.push(near.unwrap_or(t));
    }
    // As in the flow's phase machine, the first inflation does not start a new cycle: samples
    // before it belong to cycle 0 with it.
    starts.dedup();
    if !starts.is_empty() {
        starts.remove(0);
    }
    let mut labels = vec![0usize; n];
    let mut c = 0usize;
    let mut next = starts.iter().peekable();
    for (i, l) in labels.iter_mut().enumerate() {
        while next.peek().is_some_and(|&&s| s <= i) {
            next.next();
            c += 1;
        }
        *l = c;
    }
    (labels, c + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turning_points_of_a_triangle_wave() {
        // 0 → 10 → 0 → 10 → 0, one sample per unit.
        let v: Vec<f64> = (0..=40)
            .map(|i| {
                let k = i % 20;
                if k <= 10 {
                    k as f64
                } else {
                    (20 - k) as f64
                }
            })
            .collect();
        let t = turning_points(&v, 5.0);
        assert_eq!(t, vec![(0, true), (10, false), (20, true), (30, false)]);
    }

    #[test]
    fn small_wiggles_are_not_turns() {
        let v = [0.0, 10.0, 8.0, 9.0, 0.0, 1.0, 0.5, 10.0];
        let t = turning_points(&v, 5.0);
        assert_eq!(t, vec![(0, true), (1, false), (4, true)]);
    }
}
