//! The poly-AR family in [`super::identify`]: the polynomial of the poly family's selected shape
//! (or `ar_shape`, else (3, 2)) plus linear AR input terms, p = 0..=`ar_max` ([`crate::polyar`]).

use super::{Family, ModelFamily, ModelRow, Sweep};
use crate::polyar;

/// The poly-AR family.
pub struct PolyArFamily;

impl ModelFamily for PolyArFamily {
    fn family(&self) -> Family {
        Family::PolyAr
    }

    fn sweep(&self, cx: &mut Sweep<'_>) {
        let family = self.family();
        let opt = cx.opt;
        let (n, m) = opt.ar_shape.or(cx.poly_choice).unwrap_or((3, 2));
        let results = match cx
            .scaling
            .clone()
            .and_then(|sc| polyar::sweep(cx.ds, n, m, opt.ar_max, &sc))
        {
            Ok(results) => results,
            Err(e) => return cx.fail(family, format!("({n}, {m})"), &e),
        };
        let mut fits = Vec::new();
        for (p, r) in results.into_iter().enumerate() {
            match r {
                Ok(f) => fits.push(f),
                Err(e) => cx.fail(family, format!("({p}, {n}, {m})"), &e),
            }
        }
        for f in &fits {
            let mut row = ModelRow::new(family, &f.train, f.heldout.as_ref(), &opt.weights);
            row.n = Some(n);
            row.m = Some(m);
            row.p = Some(f.p);
            cx.rep.models.push(row);
        }
        let w = &opt.weights;
        let best = fits
            .iter()
            .min_by(|a, b| w.cost(&a.train).total_cmp(&w.cost(&b.train)));
        cx.rep.poly_ar_fit = best.cloned();
        cx.rep.notes.push(format!(
            "poly-ar: the AR terms are past inputs v(t-k), v̇(t-k), never past pressure, so one-step-ahead and \
             free-run (simulation) errors are identical; all orders use the same {} training rows \
             (samples with {} predecessors)",
            fits.first().map_or(0, |f| f.train.n),
            opt.ar_max
        ));
    }
}
