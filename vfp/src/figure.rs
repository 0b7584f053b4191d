//! Figures: every plot is an SVG drawn by `plotters`, with an embedded font (DejaVu Sans) so text
//! renders the same on any machine, fonts installed or not.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::{DrawingArea, IntoDrawingArea, SVGBackend};
use plotters::style::{register_font, FontStyle};

static FONTS: Once = Once::new();

/// Registers the embedded font under the family names the figures use (idempotent).
pub fn ensure_fonts() {
    FONTS.call_once(|| {
        let regular = dejavu::sans::regular();
        let bold = dejavu::sans::bold();
        for family in ["sans-serif", "serif", "monospace"] {
            // DejaVu is a valid TrueType font: registration cannot fail on it.
            let _ = register_font(family, FontStyle::Normal, regular);
            let _ = register_font(family, FontStyle::Bold, bold);
        }
    });
}

/// An SVG drawing area of `size` pixels at `path`, fonts ready.
pub fn svg<'a>(path: &'a Path, size: (u32, u32)) -> DrawingArea<SVGBackend<'a>, Shift> {
    ensure_fonts();
    SVGBackend::new(path, size).into_drawing_area()
}

/// Axis range covering the finite values with 5 % padding; (0, 1) when there are none.
pub fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in values.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1e-9)
    };
    (lo - pad, hi + pad)
}
