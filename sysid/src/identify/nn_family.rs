//! The neural family in [`super::identify`]: as in the paper (Table III), depths d = 1..=15
//! without AR inputs, then AR orders p = 1..=`nn_ar_max` at depth `nn_ar_depth` ([`crate::nn`]).

use super::{Family, ModelFamily, ModelRow, Progress, Sweep};
use crate::{metrics, nn};

/// The neural family.
pub struct NnFamily;

impl ModelFamily for NnFamily {
    fn family(&self) -> Family {
        Family::Nn
    }

    fn sweep(&self, cx: &mut Sweep<'_>) {
        let family = self.family();
        let opt = cx.opt;
        let mut plain = opt.nn.clone();
        plain.ar_orders = vec![0];
        let mut ar = opt.nn.clone();
        ar.depths = vec![opt.nn_ar_depth];
        ar.ar_orders = (1..=opt.nn_ar_max).collect();
        let mut runs = vec![(plain, "depths 1..=15")];
        if opt.nn_ar_max > 0 {
            runs.push((ar, "AR orders"));
        }
        for (cfg, what) in runs {
            cx.tell(Progress::Working {
                family,
                what: &format!("training {what}"),
            });
            let it = inputs(&cx.train);
            for r in nn::sweep(&it, &cx.train.p, &cfg).results {
                match r {
                    Ok(f) => add(cx, &f),
                    Err(e) => cx.fail(family, "(p, d)".into(), &e),
                }
            }
        }
        cx.tell(Progress::Done { family });
    }
}

/// The network's inputs over `c` (the AR lags are the network's own).
fn inputs(c: &crate::dataset::Columns) -> nn::Inputs<'_> {
    nn::Inputs {
        v: &c.v,
        vdot: &c.vdot,
        ar_order: 0,
    }
}

/// Scores one trained network, on the samples after its first `p` (which have no lagged
/// inputs), and adds its row.
fn add(cx: &mut Sweep<'_>, f: &nn::NnFit) {
    let p = f.ar_order;
    let (train, held) = (&cx.train, &cx.held);
    let yt = f.predict(&inputs(train));
    let yh = f.predict(&inputs(held));
    let r = metrics::compute(
        &train.p[p.min(train.len())..],
        &yt[p.min(yt.len())..],
        f.n_params,
    )
    .map(|t| {
        let h = (held.len() > p + f.n_params + 1)
            .then(|| metrics::compute(&held.p[p..], &yh[p.min(yh.len())..], f.n_params).ok())
            .flatten();
        ModelRow::new(Family::Nn, &t, h.as_ref(), &cx.opt.weights)
    });
    match r {
        Ok(mut row) => {
            row.p = Some(f.ar_order);
            row.d = Some(f.depth);
            cx.rep.models.push(row);
        }
        Err(e) => cx.fail(
            Family::Nn,
            format!("(p, d) = ({}, {})", f.ar_order, f.depth),
            &e,
        ),
    }
}
