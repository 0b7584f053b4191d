//! The polynomial family in [`super::identify`]: the sweep of `Σ αᵢⱼ vⁱ v̇ʲ` over n ≤ `max_n`,
//! m ≤ `max_m` ([`crate::poly`]), the selection of its shape by cross-validation
//! ([`crate::select`]), and the selected shape's coefficient statistics and pruning table.

use super::{Coefficient, Family, ModelFamily, ModelRow, Sweep};
use crate::poly::{self, Xy};
use crate::select::{self, CvScore, Shape};

/// The polynomial family.
pub struct PolyFamily;

impl ModelFamily for PolyFamily {
    fn family(&self) -> Family {
        Family::Poly
    }

    fn sweep(&self, cx: &mut Sweep<'_>) {
        let family = self.family();
        let (max_n, max_m) = (cx.opt.max_n, cx.opt.max_m);
        let sc = match cx.scaling.clone() {
            Ok(sc) => sc,
            Err(e) => return cx.fail(family, "all".into(), &e),
        };
        let moments = match poly::SweepMoments::gather(Xy::from(&cx.train), cx.held_xy(), &sc) {
            Ok(moments) => moments,
            Err(e) => return cx.fail(family, "all".into(), &e),
        };
        let entries = match moments.sweep(max_n, max_m) {
            Ok(entries) => entries,
            Err(e) => return cx.fail(family, "all".into(), &e),
        };
        cx.poly_moments = Some(moments);
        let shapes = (1..=max_n).flat_map(|n| (1..=max_m).map(move |m| (n, m)));
        for ((n, m), entry) in shapes.zip(&entries) {
            match entry {
                Ok(e) => {
                    let mut row =
                        ModelRow::new(family, &e.train, e.heldout.as_ref(), &cx.opt.weights);
                    row.n = Some(n);
                    row.m = Some(m);
                    cx.rep.models.push(row);
                }
                Err(e) => cx.fail(family, format!("({n}, {m})"), e),
            }
        }
        cx.poly_choice = choose_poly(cx, &sc);
    }
}

/// Cross-validates the polynomial sweep on the training cycles, notes each row's cross-validated
/// RMSE, records the [`Selection`] and returns the chosen shape. When the cross-validation cannot
/// run (fewer than two blocks), the lowest joint cost chooses, and a note says so.
fn choose_poly(cx: &mut Sweep<'_>, sc: &poly::Scaling) -> Option<(usize, usize)> {
    let (rep, ds, opt) = (&mut cx.rep, cx.ds, cx.opt);
    let rows = || rep.models.iter().filter(|r| r.family == Family::Poly);
    let shape_of = |r: &ModelRow| Some(Shape::new(r.n?, r.m?));
    let aicc = rows()
        .min_by(|a, b| a.aicc.total_cmp(&b.aicc))
        .and_then(shape_of);
    let cost = rows()
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
        .and_then(shape_of);
    let fallback = cost.map(|s| (s.n, s.m));
    let (blocks, bm) = match select::block_moments(ds, sc) {
        Ok(x) => x,
        Err(e) => {
            rep.notes.push(format!(
                "poly: no cross-validation ({e}); the lowest joint cost chose the shape"
            ));
            return fallback;
        }
    };
    let ok: Vec<CvScore> = bm
        .sweep(opt.max_n, opt.max_m)
        .into_iter()
        .flatten()
        .collect();
    for r in rep.models.iter_mut().filter(|r| r.family == Family::Poly) {
        if let Some(s) = ok.iter().find(|s| Some(s.n) == r.n && Some(s.m) == r.m) {
            r.cv_rmse = Some(s.rmse());
            r.cv_rmse_se = Some(s.se / (2.0 * s.rmse()).max(f64::MIN_POSITIVE));
        }
    }
    match select::selection(&blocks, &ok, aicc, cost, opt.weights) {
        Some(mut sel) => {
            let pick = (sel.selected.n, sel.selected.m);
            match bm.reduce_terms(pick.0, pick.1, &ok) {
                Ok(mut red) => {
                    red.rmse_heldout = bm.heldout_rmse(&red, Xy::from(&cx.held));
                    sel.reduced = Some(red);
                }
                Err(e) => rep.notes.push(format!("poly: terms not reduced ({e})")),
            }
            rep.poly_selection = Some(sel);
            Some(pick)
        }
        None => {
            rep.notes.push(
                "poly: no shape could be cross-validated; the lowest joint cost chose the shape"
                    .into(),
            );
            fallback
        }
    }
}

/// Statistics and pruning of the selected polynomial (a QR refit, residuals computed directly),
/// when the poly family ran and selected a shape.
pub(super) fn statistics(cx: &mut Sweep<'_>) {
    let Some((n, m)) = cx.poly_choice else {
        return;
    };
    let scaling = cx.scaling.as_ref().ok().copied();
    let (train, held, k) = (Xy::from(&cx.train), cx.held_xy(), cx.opt.prune_k);
    // The fit and the pruning table side by side (each also splits its passes over the cores).
    let (fitted, pruned) = std::thread::scope(|s| {
        let pruning = (k > 0).then(|| s.spawn(move || poly::prune(train, held, n, m, k)));
        // The sweep's training moments are this fit's (same rows, scaling and centre).
        let fitted = match (scaling, &cx.poly_moments) {
            (Some(sc), Some(sm)) => poly::fit_from(train, n, m, sc, &sm.train),
            _ => poly::fit(train, n, m, scaling),
        };
        let pruned = pruning.map(|h| h.join().expect("the pruning thread panicked"));
        (fitted, pruned)
    });
    match fitted {
        Ok(f) => {
            cx.rep.poly_coefficients = f
                .term_names()
                .into_iter()
                .zip(&f.raw)
                .map(|(term, stat)| Coefficient { term, stat: *stat })
                .collect();
            cx.rep.poly_fit = Some(f);
        }
        Err(e) => cx.fail(Family::Poly, format!("({n}, {m}) refit"), &e),
    }
    match pruned {
        Some(Ok(rows)) => cx.rep.pruning = rows,
        Some(Err(e)) => cx.fail(Family::Poly, format!("({n}, {m}) pruning"), &e),
        None => {}
    }
}
