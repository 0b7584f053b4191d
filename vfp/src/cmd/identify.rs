//! `vfp identify LOG.csv`: the paper's §II–III on a log, as tables in the paper's layout or one
//! JSON document.

use crate::opts::{family_parser, num, opt, LogInput, OutputOpts};
use crate::units::DisplayUnits;
use crate::Error;
use sysid::identify::{self, ChamberReport, Family, ModelRow, Options};
use sysid::metrics::CostWeights;
use sysid::select::{BlockKind, Reduction, Selection, Shape};

/// Identify volume-flow-pressure models from a log (Tables I, II and IV of the paper).
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub input: LogInput,
    /// Limit the run to this family (repeatable; default: all).
    #[arg(long = "family", value_parser = family_parser())]
    pub families: Vec<Family>,
    /// `--json` (one document instead of tables); `--plots DIR`: figures like the paper's
    /// Figs. 2-5 and V-P curves.
    #[command(flatten)]
    pub out: OutputOpts,
    /// Joint-cost weights w1,w2,w3 on RMSE, 1-R2adj and AICc (eq. 8).
    #[arg(long, value_name = "W1,W2,W3", default_value = "0,0,1")]
    pub weights: String,
    /// Highest power of v in the polynomial sweep.
    #[arg(long, default_value_t = 7)]
    pub max_n: usize,
    /// Highest power of v̇ in the polynomial sweep.
    #[arg(long, default_value_t = 7)]
    pub max_m: usize,
    /// Highest AR order of the poly-AR sweep.
    #[arg(long, default_value_t = 5)]
    pub ar_max: usize,
    /// (n, m) of the poly-AR sweep, e.g. 3,2 (default: the polynomial selection).
    #[arg(long, value_name = "N,M")]
    pub ar_shape: Option<String>,
    /// Highest number of exponential terms.
    #[arg(long, default_value_t = 10)]
    pub exp_k_max: usize,
    /// Highest AR order of the neural sweep.
    #[arg(long, default_value_t = 5)]
    pub nn_ar_max: usize,
    /// Least significant terms tried in the pruning table (0 = no pruning).
    #[arg(long, default_value_t = 3)]
    pub prune: usize,
}

fn parse_list(s: &str, what: &str, len: usize) -> Result<Vec<f64>, Error> {
    let v: Result<Vec<f64>, _> = s.split(',').map(|x| x.trim().parse::<f64>()).collect();
    match v {
        Ok(v) if v.len() == len && v.iter().all(|x| x.is_finite() && *x >= 0.0) => Ok(v),
        _ => Err(Error::Msg(format!(
            "{what} {s:?}: expected {len} comma-separated finite numbers >= 0"
        ))),
    }
}

impl Args {
    /// The identification options these arguments describe.
    pub fn options(&self) -> Result<Options, Error> {
        let w = parse_list(&self.weights, "--weights", 3)?;
        let ar_shape = match &self.ar_shape {
            None => None,
            Some(s) => {
                let v = parse_list(s, "--ar-shape", 2)?;
                Some((v[0] as usize, v[1] as usize))
            }
        };
        if !(1..=7).contains(&self.max_n) || !(1..=7).contains(&self.max_m) {
            return Err(Error::Msg(format!(
                "--max-n {} --max-m {}: degrees must be 1..=7",
                self.max_n, self.max_m
            )));
        }
        if self.ar_max > 5 || self.nn_ar_max > 5 {
            return Err(Error::Msg(
                "--ar-max and --nn-ar-max must be at most 5 (the device's limit)".into(),
            ));
        }
        Ok(Options {
            families: if self.families.is_empty() {
                Family::ALL.to_vec()
            } else {
                self.families.clone()
            },
            weights: CostWeights {
                w_rmse: w[0],
                w_r2: w[1],
                w_aicc: w[2],
            },
            max_n: self.max_n,
            max_m: self.max_m,
            ar_max: self.ar_max,
            ar_shape,
            exp_k_max: self.exp_k_max,
            nn_ar_max: self.nn_ar_max,
            prune_k: self.prune,
            progress: crate::progress::shown()
                .then_some(crate::progress::spinner as identify::ProgressFn),
            ..Options::default()
        })
    }
}

/// Runs `vfp identify`.
pub fn run(args: &Args) -> Result<(), Error> {
    let options = args.options()?;
    let units = args.out.display_units(&args.input.data);
    let data = args.input.load()?;
    let datasets = &data.datasets;
    let wrap = |ch: u8, e: identify::IdentifyError| {
        Error::Msg(format!("{}, chamber {ch}: {e}", data.path.display()))
    };
    for ds in datasets {
        identify::check_split(ds).map_err(|e| wrap(ds.chamber, e))?;
    }
    let reports: Vec<ChamberReport> = datasets
        .iter()
        .map(|ds| identify::identify(ds, &options))
        .collect();
    for r in &reports {
        identify::check_fitted(r).map_err(|e| wrap(r.chamber, e))?;
    }
    if let Some(dir) = &args.out.plots {
        for (ds, rep) in datasets.iter().zip(&reports) {
            crate::plots::identify::write_all(dir, args.out.plot_format, ds, rep, &units)?;
        }
    }
    if args.out.json {
        let doc =
            identify::Document::new(data.path.display().to_string(), options.weights, &reports);
        let text = serde_json::to_string_pretty(&doc)
            .map_err(|e| Error::Msg(format!("cannot encode JSON: {e}")))?;
        println!("{text}");
    } else {
        for r in &reports {
            print!(
                "{}",
                render(r, &data.path.display().to_string(), &options, &units)
            );
        }
        if let Some(dir) = &args.out.plots {
            println!("figures written to {}", dir.display());
        }
    }
    Ok(())
}

/// The human report of one chamber, in the paper's table layout, its numbers in `u`.
pub fn render(r: &ChamberReport, file: &str, options: &Options, u: &DisplayUnits) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let w = &options.weights;
    let _ = writeln!(s, "== {file}, chamber {} ==", r.chamber);
    let _ = writeln!(
        s,
        "{} samples, {} cycles; training {} / held-out {} ({}); flow {}",
        r.samples, r.cycles, r.train_samples, r.heldout_samples, r.split, r.flow
    );
    let _ = writeln!(
        s,
        "selection: polynomial shape by the one-standard-error rule on cycle-blocked cross-validation \
         of the training cycles; other families and the overall choice by J = {}·RMSE + {}·(1 - R2adj) + {}·AICc \
         on training data (eq. 8)\n",
        w.w_rmse, w.w_r2, w.w_aicc
    );

    s.push_str(&render_table1(&r.table1));
    s.push_str(&render_table2(r, u));
    if let Some(f) = &r.poly_fit {
        s.push_str(&render_coefficients(r, f, u));
    }
    if let Some(sel) = &r.selected {
        let _ = writeln!(
            s,
            "Lowest joint cost J among the families' choices: {} {} (nu = {}): RMSE {} {p} \
             training, {} {p} held-out",
            sel.family.name(),
            sel.shape(),
            sel.nu,
            num(u.p(sel.rmse)),
            opt(sel.rmse_heldout.map(|x| u.p(x))),
            p = u.pressure(),
        );
    }
    s.push_str(&render_model_used(r, u));
    s
}

/// The model `vfp export` and `vfp diagnose` use by default, and why: the polynomial family's
/// selection (its reduced terms for export), whatever the joint cost ranks first.
fn render_model_used(r: &ChamberReport, u: &DisplayUnits) -> String {
    let Some(sel) = &r.poly_selection else {
        return "Model used by export and diagnose: none selected (the polynomial family did not \
                run or could not be cross-validated; give --n/--m to export and diagnose)\n\n"
            .into();
    };
    let (n, m) = (sel.selected.n, sel.selected.m);
    let terms = sel.reduced.as_ref().map_or(String::new(), |red| {
        format!(
            ", {} of its {} terms kept (held-out RMSE {} {})",
            red.nu,
            red.active.len(),
            opt(red.rmse_heldout.map(|x| u.p(x))),
            u.pressure()
        )
    });
    format!(
        "Model used by export and diagnose: poly ({n}, {m}){terms}. Why: the board evaluates the \
         polynomial (the other families are reported for comparison, not exported by default), \
         and its shape is the fewest parameters the training cycles support (see the poly \
         selection above); `export` exports the reduced terms, `diagnose` starts from the shape\n\n"
    )
}

/// Table I: the correlations and the PCA of the normalised [v, v̇, v̈, P].
fn render_table1(t: &identify::Table1) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Table I. Correlations and PCA of the normalised [v, vdot, vddot, P]"
    );
    let _ = writeln!(
        s,
        "  corr(P, v) = {}   corr(P, vdot) = {}   corr(P, vddot) = {}",
        opt_f(t.corr_v),
        opt_f(t.corr_vdot),
        opt_f(t.corr_vddot)
    );
    if let (Some(v), Some(l)) = (t.vectors, t.lambda_norm) {
        let _ = writeln!(
            s,
            "  {:>12} {:>7} {:>7} {:>7} {:>7}",
            "", "PC1", "PC2", "PC3", "PC4"
        );
        for (name, row) in ["v(t)", "vdot(t)", "vddot(t)", "P(t)"].iter().zip(v) {
            let _ = writeln!(
                s,
                "  V {:>10} {:>7.2} {:>7.2} {:>7.2} {:>7.2}",
                name, row[0], row[1], row[2], row[3]
            );
        }
        let _ = writeln!(
            s,
            "  {:>12} {:>7.2} {:>7.2} {:>7.2} {:>7.2}",
            "lambda_norm", l[0], l[1], l[2], l[3]
        );
    } else {
        let _ = writeln!(s, "  PCA not defined: a column is constant");
    }
    let _ = writeln!(s);

    s
}

/// Table II: every family's sweep (training | held-out), failures, notes and the polynomial
/// selection.
fn render_table2(r: &ChamberReport, u: &DisplayUnits) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Table II. Regression performances (training | held-out); * = the family's choice (poly: see below; others: lowest cost)"
    );
    if !u.is_canonical() {
        let _ = writeln!(
            s,
            "  RMSE in {}; AICc and BIC from the residuals in kPa, as in --json (a change of unit \
             shifts every model's by the same constant)",
            u.pressure()
        );
    }
    for fam in Family::ALL {
        let rows: Vec<&ModelRow> = r.models.iter().filter(|m| m.family == fam).collect();
        if rows.is_empty() && !r.failed.iter().any(|f| f.family == fam) {
            continue;
        }
        let best = r.best.iter().find(|b| b.family == fam);
        let head = match fam {
            Family::Exp => "k",
            Family::Nn => "(p, d)",
            Family::Poly => "(n, m)",
            Family::PolyAr => "(p, n, m)",
        };
        let _ = writeln!(s, "  -- {} --", fam.name());
        let _ = writeln!(
            s,
            "  {:>11} {:>4} {:>9} {:>8} {:>11} {:>11} | {:>9} {:>8}",
            head, "nu", "RMSE", "R2adj", "AICc", "BIC", "RMSE", "R2adj"
        );
        for m in rows {
            let star = if Some(m) == best { "*" } else { " " };
            let _ = writeln!(
                s,
                "  {:>10}{} {:>4} {:>9} {:>8.4} {:>11} {:>11} | {:>9} {:>8}",
                m.shape(),
                star,
                m.nu,
                num(u.p(m.rmse)),
                m.r2_adj,
                format!("{:.4e}", m.aicc),
                format!("{:.4e}", m.bic),
                opt(m.rmse_heldout.map(|x| u.p(x))),
                m.r2_adj_heldout.map_or("-".into(), |x| format!("{x:.4}"))
            );
        }
        for f in r.failed.iter().filter(|f| f.family == fam) {
            let _ = writeln!(s, "  {:>11} not fitted: {}", f.shape, f.error);
        }
        if let Some(t) = r.timing_s.get(fam.name()) {
            let _ = writeln!(s, "  sweep time {:.3} s", t);
        }
    }
    for n in &r.notes {
        let _ = writeln!(s, "  note: {}", u.sentence(n));
    }
    if let Some(sel) = &r.poly_selection {
        s.push_str(&render_selection(sel, u));
    }
    let _ = writeln!(s);

    s
}

/// Table IV: the selected polynomial's coefficients with their statistics, and the pruning table.
fn render_coefficients(r: &ChamberReport, f: &sysid::poly::PolyFit, u: &DisplayUnits) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let units = if u.is_canonical() {
        "paper units (kPa, mm3, mm3/s)".to_string()
    } else {
        format!(
            "units {}, {}, {} (P = sum of coeff. v^i vdot^j with P, v and vdot in them)",
            u.pressure(),
            u.volume(),
            u.flow()
        )
    };
    let _ = writeln!(
        s,
        "Table IV. Coefficients of the polynomial model (n = {}, m = {}), {units}",
        f.n, f.m
    );
    let _ = writeln!(
        s,
        "  {:>14} {:>13} {:>11} {:>9} {:>10}",
        "term", "coeff.", "SE", "t", "p"
    );
    for (k, c) in r.poly_coefficients.iter().enumerate() {
        // Terms in the order of `PolyFit::term_names`: index i·(m + 1) + j for vⁱ v̇ʲ.
        let (i, j) = (k / (f.m + 1), k % (f.m + 1));
        let _ = writeln!(
            s,
            "  {:>14} {:>13.4e} {:>11.3e} {:>9.2} {:>10.2e}",
            c.term,
            u.coefficient(c.stat.estimate, i, j),
            u.coefficient(c.stat.se, i, j),
            c.stat.t,
            c.stat.p
        );
    }
    if !r.pruning.is_empty() {
        let _ = writeln!(
            s,
            "  Reduced models (least significant terms excluded, refitted)"
        );
        let _ = writeln!(
            s,
            "  {:>26} {:>4} {:>9} {:>8} {:>11} | {:>9}",
            "excluded term(s)", "nu", "RMSE", "R2adj", "AICc", "RMSE ho"
        );
        let _ = writeln!(
            s,
            "  {:>26} {:>4} {:>9} {:>8.4} {:>11} |",
            "(none)",
            f.nu,
            num(u.p(f.train.rmse)),
            f.train.r2_adj,
            format!("{:.4e}", f.train.aicc)
        );
        for p in &r.pruning {
            let _ = writeln!(
                s,
                "  {:>26} {:>4} {:>9} {:>8.4} {:>11} | {:>9}",
                p.excluded.join(", "),
                p.nu,
                num(u.p(p.train.rmse)),
                p.train.r2_adj,
                format!("{:.4e}", p.train.aicc),
                opt(p.heldout.map(|h| u.p(h.rmse)))
            );
        }
    }
    let _ = writeln!(s);
    s
}

/// The polynomial selection in words, with the AICc and joint-cost picks beside it.
fn render_selection(sel: &Selection, u: &DisplayUnits) -> String {
    let shape = |s: &Shape| format!("({}, {}) (nu = {})", s.n, s.m, s.nu);
    let pick = |s: &Option<Shape>| s.as_ref().map_or("-".into(), shape);
    // The excess compares log ratios (no unit) over cycles, squared pressures over stretches.
    let (blocks, compared, sq) = match sel.blocks {
        BlockKind::Cycles => (
            "training cycles",
            "(mean log ratio of block errors)".to_string(),
            1.0,
        ),
        BlockKind::TimeStretches => (
            "stretches of the training samples (too few cycles)",
            format!("{} (pooled difference)", u.convert(1.0, "kPa2").1),
            u.convert(1.0, "kPa2").0,
        ),
    };
    let p = u.pressure();
    format!(
        "  poly selection: {} — typical cross-validated RMSE {} {p} (pooled {} {p}); lowest {} {p} \
         at {}; excess {:.3e} {compared} within one paired SE {:.3e}, typical RMSE at most {} x \
         the lowest; {} blocks ({blocks}), {} folds\n  \
         beside it: lowest pooled cross-validated RMSE {} {p} at {} (textbook one-SE limit {} {p}); \
         lowest training AICc {}; lowest joint cost J {}\n",
        shape(&sel.selected),
        num(u.p(sel.typical_rmse)),
        num(u.p(sel.cv_rmse)),
        num(u.p(sel.typical_best_rmse)),
        shape(&sel.cv_best),
        sel.excess * sq,
        sel.excess_se * sq,
        sysid::select::MAX_RMSE_RATIO,
        sel.n_blocks,
        sel.folds,
        num(u.p(sel.pooled_best.0)),
        shape(&sel.pooled_best.1),
        num(u.p(sel.cv_limit_rmse)),
        pick(&sel.aicc_pick),
        pick(&sel.joint_cost_pick),
    ) + &sel
        .reduced
        .as_ref()
        .map_or(String::new(), |r| render_reduction(r, u))
}

/// The selected shape's terms reduced by the selection's rule: what `vfp export` exports.
fn render_reduction(r: &Reduction, u: &DisplayUnits) -> String {
    let dropped = if r.dropped.is_empty() {
        "none".to_string()
    } else {
        r.dropped.join(", ")
    };
    let why = if r.limited {
        format!(
            "the fewest within the band had more than {}; the best of at most {} instead",
            sysid::select::MAX_PARAMS,
            sysid::select::MAX_PARAMS
        )
    } else {
        "fewest within the band".to_string()
    };
    format!(
        "  terms: {} of {} kept ({why}; lowest typical cross-validated RMSE {} {p}): typical \
         cross-validated RMSE {} {p}, held-out {} {p}; dropped {dropped}\n",
        r.nu,
        r.active.len(),
        num(u.p(r.typical_lowest_rmse)),
        num(u.p(r.typical_rmse)),
        opt(r.rmse_heldout.map(|x| u.p(x))),
        p = u.pressure(),
    )
}

fn opt_f(x: Option<f64>) -> String {
    x.map_or_else(
        || "undefined (constant column)".into(),
        |x| format!("{x:.4}"),
    )
}
