//! The one error type of the crate.

use core::fmt;

/// Why a model-core operation refused its input. Every public function that takes numbers from the
/// world returns this instead of panicking or producing a silent NaN.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelError {
    /// An input or a result was NaN or infinite.
    NonFinite,
    /// An input lies outside the range the model or parameter accepts.
    OutOfRange,
    /// A model shape is outside the supported limits (degree, AR order, number of terms).
    BadShape,
    /// A slice does not have the length the shape calls for.
    BadLength,
    /// A linear-algebra step met a (numerically) singular quantity.
    Singular,
    /// The autoregressive history holds fewer samples than the model's AR order.
    ShortHistory,
    /// A configuration parameter (scaling, forgetting factor, dead band, area) is invalid.
    BadParameter,
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ModelError::NonFinite => "input or result is not finite (NaN or infinity)",
            ModelError::OutOfRange => "input is outside the model's working range",
            ModelError::BadShape => "model shape is outside the supported limits",
            ModelError::BadLength => "slice length does not match the model shape",
            ModelError::Singular => "numerically singular quantity",
            ModelError::ShortHistory => "autoregressive history is shorter than the AR order",
            ModelError::BadParameter => "invalid configuration parameter",
        })
    }
}

impl core::error::Error for ModelError {}

/// `Ok(x)` when `x` is finite, `Err(NonFinite)` otherwise.
#[inline]
pub(crate) fn finite(x: f32) -> Result<f32, ModelError> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(ModelError::NonFinite)
    }
}
