//! Figures: every plot is drawn by `plotters` on a [`Canvas`], written as SVG (vector, the
//! default) or PNG (plotters' bitmap backend) by `--plot-format`, with an embedded font
//! (DejaVu Sans) so text renders the same on any machine, fonts installed or not.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::{BitMapBackend, DrawingArea, IntoDrawingArea, SVGBackend};
use plotters::style::{register_font, FontStyle};
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingBackend, DrawingErrorKind,
};

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

/// The file format of the figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PlotFormat {
    /// Scalable vector graphics (text stays text).
    #[default]
    Svg,
    /// A bitmap (PNG), for documents and viewers without SVG.
    Png,
}

impl PlotFormat {
    /// The file extension.
    pub fn ext(self) -> &'static str {
        match self {
            PlotFormat::Svg => "svg",
            PlotFormat::Png => "png",
        }
    }

    /// `stem.<ext>`.
    pub fn file(self, stem: &str) -> String {
        format!("{stem}.{}", self.ext())
    }
}

/// The backend of a [`Canvas`]: SVG or bitmap, chosen at run time.
pub enum Backend<'a> {
    /// Vector output.
    Svg(SVGBackend<'a>),
    /// PNG output.
    Png(BitMapBackend<'a>),
}

/// A drawing area of either format.
pub type Canvas<'a> = DrawingArea<Backend<'a>, Shift>;

/// A drawing area of `size` pixels at `path` in `format`, fonts ready (not yet filled).
pub fn canvas(path: &Path, size: (u32, u32), format: PlotFormat) -> Canvas<'_> {
    ensure_fonts();
    match format {
        PlotFormat::Svg => Backend::Svg(SVGBackend::new(path, size)),
        PlotFormat::Png => Backend::Png(BitMapBackend::new(path, size)),
    }
    .into_drawing_area()
}

/// A backend error of either kind, as text.
#[derive(Debug)]
pub struct BackendError(String);

impl std::fmt::Display for BackendError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BackendError {}

fn conv<E: std::error::Error + Send + Sync>(
    e: DrawingErrorKind<E>,
) -> DrawingErrorKind<BackendError> {
    match e {
        DrawingErrorKind::DrawingError(e) => {
            DrawingErrorKind::DrawingError(BackendError(e.to_string()))
        }
        DrawingErrorKind::FontError(e) => DrawingErrorKind::FontError(e),
    }
}

/// Calls the same method on whichever backend is inside.
macro_rules! both {
    ($self:expr, $b:ident => $call:expr) => {
        match $self {
            Backend::Svg($b) => $call.map_err(conv),
            Backend::Png($b) => $call.map_err(conv),
        }
    };
}

type R<T = ()> = Result<T, DrawingErrorKind<BackendError>>;

impl DrawingBackend for Backend<'_> {
    type ErrorType = BackendError;

    fn get_size(&self) -> (u32, u32) {
        match self {
            Backend::Svg(b) => b.get_size(),
            Backend::Png(b) => b.get_size(),
        }
    }
    fn ensure_prepared(&mut self) -> R {
        both!(self, b => b.ensure_prepared())
    }
    fn present(&mut self) -> R {
        both!(self, b => b.present())
    }
    fn draw_pixel(&mut self, p: BackendCoord, c: BackendColor) -> R {
        both!(self, b => b.draw_pixel(p, c))
    }
    fn draw_line<S: BackendStyle>(&mut self, from: BackendCoord, to: BackendCoord, s: &S) -> R {
        both!(self, b => b.draw_line(from, to, s))
    }
    fn draw_rect<S: BackendStyle>(
        &mut self,
        ul: BackendCoord,
        br: BackendCoord,
        s: &S,
        fill: bool,
    ) -> R {
        both!(self, b => b.draw_rect(ul, br, s, fill))
    }
    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        s: &S,
    ) -> R {
        both!(self, b => b.draw_path(path, s))
    }
    fn draw_circle<S: BackendStyle>(&mut self, c: BackendCoord, r: u32, s: &S, fill: bool) -> R {
        both!(self, b => b.draw_circle(c, r, s, fill))
    }
    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        s: &S,
    ) -> R {
        both!(self, b => b.fill_polygon(vert, s))
    }
    fn draw_text<T: BackendTextStyle>(&mut self, text: &str, s: &T, pos: BackendCoord) -> R {
        both!(self, b => b.draw_text(text, s, pos))
    }
    fn estimate_text_size<T: BackendTextStyle>(&self, text: &str, s: &T) -> R<(u32, u32)> {
        both!(self, b => b.estimate_text_size(text, s))
    }
    fn blit_bitmap(&mut self, pos: BackendCoord, size: (u32, u32), src: &[u8]) -> R {
        both!(self, b => b.blit_bitmap(pos, size, src))
    }
}

/// A tick label, the one formatter of every figure: at most 4 significant digits, no trailing
/// zeros, no "-0"; in engineering notation (a mantissa in [1, 1000) and an exponent that is a
/// multiple of 3, "-900e3", "250e-6") outside [10⁻³, 10⁴), so a label never runs past a handful
/// of characters whatever the data's scale.
pub fn tick(x: f64) -> String {
    let a = x.abs();
    // Ticks are multiples of a round step; anything this small next to them is zero.
    if a < 1e-12 || !a.is_finite() {
        return if a.is_finite() {
            "0".into()
        } else {
            format!("{x}")
        };
    }
    let s = if (1e-3..1e4).contains(&a) {
        short(x)
    } else {
        let mut exp = (a.log10() / 3.0).floor() as i32 * 3;
        let mut m = x / 10f64.powi(exp);
        // Rounding to 4 digits can carry the mantissa to 1000: move to the next exponent.
        if short(m.abs()).parse::<f64>().is_ok_and(|r| r >= 1000.0) {
            exp += 3;
            m /= 1000.0;
        }
        format!("{}e{exp}", short(m))
    };
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        "0".into()
    } else {
        s
    }
}

/// `x` (0.001 ≤ |x| < 10⁴) with 4 significant digits, trailing zeros dropped.
fn short(x: f64) -> String {
    let decimals = (3 - x.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{x:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
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

#[cfg(test)]
mod tests {
    #[test]
    fn ticks_are_short_and_never_negative_zero() {
        use super::tick;
        assert_eq!(tick(-0.0), "0");
        assert_eq!(tick(-1e-17), "0");
        assert_eq!(tick(0.05), "0.05");
        assert_eq!(tick(0.0500), "0.05");
        assert_eq!(tick(1.25), "1.25");
        assert_eq!(tick(-12.5), "-12.5");
        assert_eq!(tick(2000.0), "2000");
        assert_eq!(tick(0.123456), "0.1235");
        // Engineering notation outside [1e-3, 1e4): exponents in steps of 3.
        assert_eq!(tick(12345.0), "12.35e3");
        assert_eq!(tick(0.00012), "120e-6");
        assert_eq!(tick(-1_000_000.0), "-1e6");
        assert_eq!(tick(-900_000.0), "-900e3");
        assert_eq!(tick(999_999.0), "1e6");
        assert_eq!(tick(2.5e-9), "2.5e-9");
    }
}
