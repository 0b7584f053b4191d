//! The exponential family in [`super::identify`]: `Σ αᵢ exp(βᵢ v) + γ v̇ + δ`, k = 1..=`exp_k_max`
//! terms ([`crate::exp`]).

use super::{Family, ModelFamily, Progress, Sweep};
use crate::exp;

/// The exponential family.
pub struct ExpFamily;

impl ModelFamily for ExpFamily {
    fn family(&self) -> Family {
        Family::Exp
    }

    fn sweep(&self, cx: &mut Sweep<'_>) {
        let family = self.family();
        cx.tell(Progress::Working {
            family,
            what: "fitting",
        });
        let fits = exp::sweep(&cx.train.v, &cx.train.vdot, &cx.train.p, cx.opt.exp_k_max);
        cx.tell(Progress::Done { family });
        for (i, r) in fits.into_iter().enumerate() {
            let f = match r {
                Ok(f) => f,
                Err(e) => {
                    cx.fail(family, format!("k = {}", i + 1), &e);
                    continue;
                }
            };
            let predict = |v: &[f64], q: &[f64]| -> Vec<f64> {
                v.iter().zip(q).map(|(&v, &q)| f.predict(v, q)).collect()
            };
            let yt = predict(&cx.train.v, &cx.train.vdot);
            let yh = predict(&cx.held.v, &cx.held.vdot);
            match cx.score(family, &yt, Some(&yh), 2 * f.k + 2) {
                Ok(mut row) => {
                    row.k = Some(f.k);
                    cx.rep.models.push(row);
                }
                Err(e) => cx.fail(family, format!("k = {}", f.k), &e),
            }
        }
    }
}
