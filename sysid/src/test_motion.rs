//! Motion shared by the unit tests (compiled for tests only).

/// `len` frames at 25 Hz of two incommensurate strokes: times (s), volume (mm³) and flow (mm³/s).
/// One tone traces an ellipse in (v, v̇), on which the tensor basis is rank-deficient; two fill an
/// area.
pub(crate) fn two_tones(len: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let t: Vec<f64> = (0..len).map(|k| 0.04 * k as f64).collect();
    let v: Vec<f64> = t
        .iter()
        .map(|&t| 275.0 + 150.0 * (0.3 * t).sin() + 80.0 * (0.71 * t).sin())
        .collect();
    let f: Vec<f64> = t
        .iter()
        .map(|&t| 45.0 * (0.3 * t).cos() + 56.8 * (0.71 * t).cos())
        .collect();
    (t, v, f)
}
