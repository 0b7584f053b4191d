//! `vfp diagnose LOG.csv`: the residual loop on a log (see the module above for the method).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::opts::{effect_parser, LogInput, OutputOpts};
use crate::units::DisplayUnits;
use crate::Error;
use sysid::residual::analysis::Binned;
use sysid::residual::decide::{decide_log, Decision, Experiment};
use sysid::residual::validate::{validate_log, Validation};
use sysid::residual::{
    diagnose_log, document, Config, Diagnosis, EffectKind, EffectReport, Param, ResidualAnalysis,
    Rig, Timings,
};

/// `vfp diagnose`: trace the residual of a fitted model to physical effects it lacks.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The log, `--chamber` (default: the lowest chamber in the log) and the data options.
    #[command(flatten)]
    pub input: LogInput,
    /// Baseline polynomial as `N,M` (degree in v, degree in v̇); default: the shape `vfp identify`
    /// selects (the fewest parameters within one standard error of the best cross-validated error
    /// on the training cycles).
    #[arg(long, value_name = "N,M")]
    pub model: Option<String>,
    /// Choose the selected shape again with the effects: where a much simpler shape plus an
    /// effect is the cross-validated choice, run the loop again from it and keep the outcome the
    /// same rule prefers (JSON `reshape`; off by default: on the loop benchmark it costs more CPU
    /// than its gains pay for, see the guide). No effect with `--model`.
    #[arg(long)]
    pub reshape: bool,
    /// Level of the nested F-test.
    #[arg(long, default_value_t = 1e-3)]
    pub alpha: f64,
    /// Smallest relative held-out RMSE gain for an effect to be kept.
    #[arg(long, default_value_t = 0.01)]
    pub min_gain: f64,
    /// Restrict the candidates (repeatable; default: the whole library).
    #[arg(long = "effect", value_parser = effect_parser())]
    pub effects: Vec<EffectKind>,
    /// Another log of the same rig: the models fitted on LOG (baseline, after each kept effect,
    /// final) are evaluated on all of its rows, same chamber, nothing refitted; and each kept
    /// effect's carry-over: that log's own polynomial refitted with and without it, scored on its
    /// held-out cycles (JSON: `validation`, `validation.carry_over`).
    #[arg(long, value_name = "OTHER.csv")]
    pub validate: Option<PathBuf>,
    /// A log recorded with the experiment this diagnosis proposes for a kept effect it cannot
    /// tell from its alternatives (the report's `experiment`): the kept model and each
    /// alternative, at the parameters found on LOG, get that log's own polynomial refitted on
    /// its training cycles and are compared on its held-out cycles by the loop's paired test;
    /// the report says which one it supports, or that it still cannot tell (JSON: `decision`).
    #[arg(long, value_name = "OTHER.csv")]
    pub decide: Option<PathBuf>,
    /// The rig the log comes from, which names the effects: `syringe` (this project's pumps:
    /// lead-screw ripple, backlash, delivery lag) or `generic` (any other source: the same
    /// effects as periodic_in_volume, dead_band, input_lag). Default: `syringe` for the logs
    /// this project writes (their header says `source=vfp record` or `source=host-sim`),
    /// `generic` for any other file.
    #[arg(long, value_name = "RIG", value_parser = parse_rig)]
    pub rig: Option<Rig>,
    /// Where the loop's time went, stage by stage (wall-clock seconds): added to the text
    /// report, or written to stderr with `--json` (whose document always carries it as
    /// `timing_s`).
    #[arg(long)]
    pub timings: bool,
    /// `--json`: one document instead of the text report; `--plots DIR`: residual figures
    /// before and after (SVG).
    #[command(flatten)]
    pub out: OutputOpts,
}

fn parse_rig(s: &str) -> Result<Rig, String> {
    s.parse()
}

fn parse_shape(s: &str) -> Result<(usize, usize), Error> {
    let bad = || {
        Error::Usage(format!(
            "--model expects N,M with 1 ≤ N, M ≤ 7 (e.g. 3,2), got `{s}`"
        ))
    };
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let n: usize = a.trim().parse().map_err(|_| bad())?;
    let m: usize = b.trim().parse().map_err(|_| bad())?;
    if !(1..=7).contains(&n) || !(1..=7).contains(&m) {
        return Err(bad());
    }
    Ok((n, m))
}

/// Runs `vfp diagnose`.
pub fn run(args: &Args) -> Result<(), Error> {
    if !(args.alpha > 0.0 && args.alpha < 1.0) {
        return Err(Error::Usage(format!(
            "--alpha must lie in (0, 1), got {}",
            args.alpha
        )));
    }
    if !(0.0..1.0).contains(&args.min_gain) {
        return Err(Error::Usage(format!(
            "--min-gain must lie in [0, 1), got {}",
            args.min_gain
        )));
    }
    if args.input.data.holdout_every < 2 {
        return Err(Error::Usage("--holdout-every must be at least 2".into()));
    }
    let units = args.out.display_units(&args.input.data);
    let mut data = args.input.load()?;
    // The loop runs on the first requested chamber only; the others' data would only take room.
    data.datasets.truncate(1);
    let shape = args.model.as_deref().map(parse_shape).transpose()?;
    let (n, m) = shape.unwrap_or((3, 2));
    let mut cfg = Config {
        n,
        m,
        alpha: args.alpha,
        min_gain: args.min_gain,
        progress: crate::progress::shown()
            .then_some(crate::progress::stages as sysid::progress::ProgressFn),
        rig: args.rig,
        reshape: args.reshape,
        ..Config::default()
    };
    if !args.effects.is_empty() {
        cfg.candidates = args.effects.clone();
    }
    let d = diagnose_log(&data, &cfg, shape.is_some()).map_err(|e| Error::Msg(e.to_string()))?;
    let validation = match &args.validate {
        Some(other) => {
            let other = args.input.data.load(other, Some(data.first().chamber))?;
            Some(validate_log(&d, &other).map_err(|e| Error::Msg(e.to_string()))?)
        }
        None => None,
    };
    let decision = match &args.decide {
        Some(other) => {
            let other = args.input.data.load(other, Some(data.first().chamber))?;
            Some(decide_log(&d, &other).map_err(|e| Error::Msg(e.to_string()))?)
        }
        None => None,
    };
    if let Some(dir) = &args.out.plots {
        write_plots(dir, args.out.plot_format, &d, &units)?;
    }
    if args.out.json {
        let mut doc = document(&data, &d);
        if let (Some(v), Some(obj)) = (&validation, doc.as_object_mut()) {
            let v = serde_json::to_value(v).map_err(|e| Error::Msg(e.to_string()))?;
            obj.insert("validation".into(), v);
        }
        if let (Some(v), Some(obj)) = (&decision, doc.as_object_mut()) {
            let v = serde_json::to_value(v).map_err(|e| Error::Msg(e.to_string()))?;
            obj.insert("decision".into(), v);
        }
        crate::opts::print_json(&doc)?;
        if args.timings {
            eprint!("{}", timings_report(&d.timing));
        }
    } else {
        print!(
            "{}",
            report(
                &data.path,
                data.first().chamber,
                &data.first().split_description(),
                &d,
                &units
            )
        );
        if let Some(v) = &validation {
            print!("{}", validation_report(v, &units));
        }
        if let Some(v) = &decision {
            print!("{}", decision_report(v, &units));
        }
        if args.timings {
            print!("{}", timings_report(&d.timing));
        }
    }
    Ok(())
}

/// The `--timings` block: each stage's wall-clock seconds and share of the loop, then each
/// round's searches (the three costliest candidates) and re-tune.
pub fn timings_report(t: &Timings) -> String {
    let mut s = String::new();
    let share = |x: f64| {
        if t.total > 0.0 {
            100.0 * x / t.total
        } else {
            0.0
        }
    };
    let _ = writeln!(s, "\ntimings (wall-clock s): total {:.2}", t.total);
    for (what, x) in t.stages() {
        let _ = writeln!(s, "  {what:<20} {x:8.2}  ({:4.1} %)", share(x));
    }
    for (i, r) in t.rounds.iter().enumerate() {
        let mut c: Vec<(&str, f64)> = r.candidates.iter().map(|(k, v)| (*k, *v)).collect();
        c.sort_by(|a, b| b.1.total_cmp(&a.1));
        let top: Vec<String> = c
            .iter()
            .take(3)
            .map(|(k, v)| format!("{k} {v:.2}"))
            .collect();
        let _ = writeln!(
            s,
            "  round {} (from {} effects): searches {:.2} ({} candidates, {:.2} s on the workers; costliest {}), re-tune {:.2}",
            i + 1,
            r.effects_before,
            r.searches,
            c.len(),
            c.iter().map(|x| x.1).sum::<f64>(),
            top.join(", "),
            r.retune
        );
    }
    s
}

/// The `--validate` block of the text report.
fn validation_report(v: &Validation, u: &DisplayUnits) -> String {
    let p = u.pressure();
    let mut s = format!(
        "\nvalidation on {} ({} samples, every row, nothing refitted):\n  baseline RMSE {:.4} {p}\n",
        v.log,
        v.samples,
        u.p(v.baseline_rmse)
    );
    for st in &v.steps {
        let _ = writeln!(s, "  + {:<18} RMSE {:.4} {p}", st.effect, u.p(st.rmse));
    }
    let verdict = if v.final_rmse.is_nan() {
        "the final model could not be evaluated there".to_string()
    } else if v.final_rmse > v.baseline_rmse {
        format!(
            "the final model is WORSE there than the baseline ({:.4} against {:.4} {p}): what the loop added on this log does not hold on that one",
            u.p(v.final_rmse), u.p(v.baseline_rmse)
        )
    } else {
        format!(
            "the final model lowers the error there from {:.4} to {:.4} {p} ({:.1} %)",
            u.p(v.baseline_rmse),
            u.p(v.final_rmse),
            100.0 * (1.0 - v.final_rmse / v.baseline_rmse)
        )
    };
    let _ = writeln!(s, "  {verdict}");
    if !v.clock_bound.is_empty() {
        let _ = writeln!(
            s,
            "  {} follow the log's own clock: evaluated from the other log's start, they claim the same drift or phase there",
            v.clock_bound.join(", ")
        );
    }
    if let Some(note) = &v.carry_over_note {
        let _ = writeln!(s, "{}", u.sentence(note));
    }
    if let Some(first) = v.carry_over.first() {
        let _ = writeln!(
            s,
            "carry-over: each effect at this log's parameters, on that log's own polynomial and the other effects that hold\n  there, refitted with and without it on its training cycles; held-out RMSE over its held-out cycles, paired z\n  over {} pieces of them; carries: gain > 0 and z >= {}; `all`: every effect against the polynomial alone:",
            first.units,
            sysid::residual::validate::CARRY_Z
        );
        for c in &v.carry_over {
            let _ = writeln!(
                s,
                "  {:<18} {:.4} -> {:.4} {p}  gain {:>6.2} %  z {:>6.2}  {}",
                c.effect,
                u.p(c.without_rmse),
                u.p(c.with_rmse),
                100.0 * c.gain,
                c.z,
                if c.carries {
                    "carries"
                } else {
                    "does not carry"
                }
            );
        }
    }
    s
}

/// The `--decide` block of the text report.
fn decision_report(v: &Decision, u: &DisplayUnits) -> String {
    let p = u.pressure();
    let mut s = format!(
        "\ndecision on {}: each explanation at this log's parameters, that log's polynomial refitted on its training\n  cycles; held-out RMSE over its held-out cycles, paired z of the kept model against each over {} pieces of them\n  (positive: the kept model's errors are the smaller); decided where the best is ahead of every other by z >= {}:\n",
        v.log,
        v.units,
        sysid::residual::alternatives::ALT_Z
    );
    for e in &v.effects {
        let _ = writeln!(s, "  {}:", e.effect);
        for c in &e.scores {
            let _ = writeln!(
                s,
                "    {:<30} held-out {:.4} {p}{}",
                c.explanation,
                u.p(c.rmse_heldout),
                if c.kept {
                    "  (kept)".to_string()
                } else {
                    format!("  z {:+.2}", c.z_kept_vs_this)
                }
            );
        }
        let _ = match &e.supports {
            Some(w) => writeln!(s, "    supports {w} (z = {:.2} against the next best)", e.z),
            None => writeln!(
                s,
                "    still cannot tell: {} is best, ahead of the next by only z = {:.2}",
                e.best, e.z
            ),
        };
    }
    s
}

/// The report's lines on the experiment proposed for an effect.
fn experiment_lines(x: &Experiment) -> String {
    let seps: Vec<String> = x
        .separations
        .iter()
        .map(|s| {
            format!(
                "from {} by z ≈ {:.1} (against |z| = {:.2} on this log)",
                s.alternative,
                s.expected_z,
                s.z_on_this_log.abs()
            )
        })
        .collect();
    let mut s = format!(
        "   experiment that decides: {} ({:.0} s of {}), expected to separate it {}; record its log (vfp record) and run\n   vfp diagnose LOG --decide THAT.csv",
        x.commands
            .iter()
            .map(|c| format!("`{c}`"))
            .collect::<Vec<_>>()
            .join(", "),
        x.duration_s,
        x.family,
        seps.join(", ")
    );
    if x.expected_z < sysid::residual::alternatives::ALT_Z {
        let _ = write!(
            s,
            "\n   (even {:.0} s is not expected to reach z = {}: the rig may not be able to tell them apart)",
            x.duration_s,
            sysid::residual::alternatives::ALT_Z
        );
    }
    s.push('\n');
    s
}

/// A parameter in `u`: its value, standard error and interval by the factor of its unit.
fn fmt_param(p: &Param, u: &DisplayUnits) -> String {
    let (f, unit) = u.convert(1.0, p.unit);
    let name = u.param_name(&p.name);
    // A factor of exactly 1 (the format's units, or s, Hz, 1) leaves the numbers as they are.
    let c = |x: f64| if f == 1.0 { x } else { u.convert(x, p.unit).0 };
    let mut s = match p.std_err {
        Some(se) => format!("{} = {:.4e} ± {:.2e} {}", name, c(p.value), c(se), unit),
        None => format!("{} = {:.4e} {}", name, c(p.value), unit),
    };
    if let Some([lo, hi]) = p.ci95.map(|b| b.map(c)) {
        let bound = if p.ci95_clipped { ", clipped at 0" } else { "" };
        s.push_str(&format!(" (95 % {lo:.3e} to {hi:.3e}{bound})"));
    }
    s
}

/// The text report for a person, its numbers in `u`.
pub fn report(path: &Path, chamber: u8, split: &str, d: &Diagnosis, u: &DisplayUnits) -> String {
    let p = u.pressure();
    let mut s = String::new();
    let _ = writeln!(s, "vfp diagnose {} — chamber {chamber}", path.display());
    let _ = writeln!(
        s,
        "split: {split}; {} training, {} held-out samples",
        d.samples.0, d.samples.1
    );
    let _ = writeln!(s, "significance: {}", d.significance);
    let _ = writeln!(
        s,
        "intervals: 95 % from the data's scatter over cycle blocks, and on a motor step count the volume's resolution; they leave out the error of an effect's form, so on the loop benchmark they held the planted value for about three named parameters in four (the user guide: intervals on the parameters)"
    );
    let _ = writeln!(
        s,
        "rig: {} ({})",
        d.rig.name(),
        match d.rig {
            Rig::Syringe => "effects named for a syringe pump's mechanisms",
            Rig::Generic =>
                "not a syringe rig of this project: effects named for the signal, not a pump's mechanism; --rig syringe to name them so",
        }
    );
    let _ = writeln!(
        s,
        "\nbaseline polynomial n = {}, m = {} ({} parameters): RMSE train {:.4} {p}, held-out {:.4} {p}",
        d.baseline.n,
        d.baseline.m,
        d.baseline.nu,
        u.p(d.baseline.rmse_train),
        u.p(d.baseline.rmse_heldout)
    );
    if let Some(r) = &d.reshape {
        reshape_lines(&mut s, r, u);
    }
    let _ = writeln!(
        s,
        "  residual: Ljung–Box p = {:.2e}, lag-1 autocorrelation {:.2}, strongest input {} (lag {}, r = {:.2}), spectral peak {:.3} Hz, inflation − deflation {:+.4} {p}",
        d.before.ljung_box_p,
        d.before.acf_lag1,
        d.before.strongest_input.0,
        d.before.strongest_input.1,
        d.before.strongest_input.2,
        d.before.spectral_peak_hz,
        u.p(d.before.direction_gap)
    );
    if d.effects.is_empty() {
        let _ = writeln!(s, "\nno effect passed the test");
    }
    for (i, e) in d.effects.iter().enumerate() {
        report_effect(&mut s, i + 1, e, u);
    }
    let _ = writeln!(
        s,
        "\nfinal model ({} parameters): RMSE train {:.4} {p}, held-out {:.4} {p}{}",
        d.final_model.nu,
        u.p(d.final_model.rmse_train),
        u.p(d.final_model.rmse_heldout),
        if d.final_model.uses_measured_pressure {
            " (uses measured pressure as a scheduling input)"
        } else {
            ""
        }
    );
    if d.remaining.is_empty() {
        let _ = writeln!(
            s,
            "remaining structure: none (held-out residual passes Ljung–Box, p = {:.3})",
            d.after.ljung_box_p
        );
    } else {
        let _ = writeln!(s, "remaining structure that no candidate explains:");
        for r in &d.remaining {
            let _ = writeln!(s, "  - {}: {}", r.kind, u.sentence(&r.description));
        }
    }
    s
}

/// The report's paragraph on the `k`-th effect kept.
fn report_effect(s: &mut String, k: usize, e: &EffectReport, u: &DisplayUnits) {
    let p = u.pressure();
    let _ = writeln!(
        s,
        "\n{}. {} — held-out RMSE {:.4} → {:.4} {p} ({:+.1} %), F = {:.1} on ({:.0}, {:.0}) df, N_eff = {:.0}, p = {:.2e}",
        k,
        e.name,
        u.p(e.rmse_heldout_before),
        u.p(e.rmse_heldout_after),
        100.0 * (e.rmse_heldout_after / e.rmse_heldout_before - 1.0),
        e.test.f_statistic,
        e.test.df1,
        e.test.df2,
        e.test.n_eff,
        e.p_value
    );
    let _ = writeln!(s, "   {}", e.story);
    for par in &e.params {
        let _ = writeln!(s, "   {}", fmt_param(par, u));
    }
    let _ = writeln!(
        s,
        "   on the device: {} ({})",
        if e.device.runs_on_device { "yes" } else { "no" },
        e.device.reason
    );
    if let Some(r) = &e.runner_up {
        let _ = writeln!(
            s,
            "   runner-up: {}, held-out {:.4} {p} ({:+.1} % against {:.4} {p} with this one), p = {:.2e}, {}",
            r.name,
            u.p(r.rmse_heldout),
            100.0 * (r.rmse_heldout / e.rmse_heldout_after - 1.0),
            u.p(e.rmse_heldout_after),
            r.p_value,
            u.sentence(&r.reason)
        );
    }
    if !e.alternatives.is_empty() {
        let _ = writeln!(s, "   {}", alternatives_line(e, u));
    }
    if let Some(x) = &e.experiment {
        s.push_str(&experiment_lines(x));
    }
}

/// The one line on the explanations the held-out data cannot tell from effect `e`, its numbers
/// in `u`.
fn alternatives_line(e: &EffectReport, u: &DisplayUnits) -> String {
    let alts: Vec<String> = e
        .alternatives
        .iter()
        .map(|a| {
            let place = if a.replaces.len() > 1 {
                format!(" in place of {}", a.replaces.join(" + "))
            } else {
                String::new()
            };
            let params: Vec<String> = a
                .params
                .iter()
                .map(|p| {
                    let (value, unit) = u.convert(p.value, p.unit);
                    format!("{} = {:.4e} {}", u.param_name(&p.name), value, unit)
                })
                .collect();
            let plural = |k: i64| if k == 1 { "" } else { "s" };
            let simpler = match a.extra_params {
                0 => String::new(),
                k if k < 0 => format!(", {} parameter{} fewer", -k, plural(-k)),
                k => format!(", {k} parameter{} more", plural(k)),
            };
            format!(
                "{}{place} ({}; held-out {:.4} {}, z = {:+.2}{simpler})",
                a.effect,
                params.join(", "),
                u.p(a.rmse_heldout),
                u.pressure(),
                a.z
            )
        })
        .collect();
    let simpler = e
        .alternatives
        .iter()
        .filter(|a| a.extra_params < 0)
        .map(|a| a.effect.as_str())
        .collect::<Vec<_>>();
    let choice = if simpler.is_empty() {
        format!("{} kept, as simple as any of them", e.name)
    } else {
        format!(
            "{} kept (the loop's choice on the training rows), though {} is simpler",
            e.name,
            simpler.join(", ")
        )
    };
    format!(
        "cannot tell apart on held-out data (paired z over held-out cycles, |z| < {}) from: {}; {choice}",
        sysid::residual::alternatives::ALT_Z,
        alts.join("; ")
    )
}

/// Writes `resid-before.<ext>` and `resid-after.<ext>` into `dir`.
pub fn write_plots(
    dir: &Path,
    format: crate::figure::PlotFormat,
    d: &Diagnosis,
    u: &DisplayUnits,
) -> Result<Vec<PathBuf>, Error> {
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    let mut out = Vec::new();
    for (name, a, title) in [
        ("resid-before", &d.analysis_before, "baseline"),
        ("resid-after", &d.analysis_after, "after the residual loop"),
    ] {
        let path = dir.join(format.file(name));
        figure(&path, format, a, title, u).map_err(|msg| Error::output(&path, msg))?;
        out.push(path);
    }
    Ok(out)
}

type Area<'a> = crate::figure::Canvas<'a>;

/// One curve of a panel: label, points, colour, drawn as points (true) or a line.
type Curve<'a> = (&'a str, Vec<(f64, f64)>, RGBColor, bool);

fn bounds(pts: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let (lo, hi) = pts.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        if x.is_finite() {
            (a.min(x), b.max(x))
        } else {
            (a, b)
        }
    });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = if hi > lo { 0.05 * (hi - lo) } else { 1.0 };
    (lo - pad, hi + pad)
}

fn panel(
    area: &Area<'_>,
    caption: &str,
    xl: &str,
    yl: &str,
    series: &[Curve<'_>],
    hlines: &[f64],
) -> Result<(), String> {
    let xs = series.iter().flat_map(|s| s.1.iter().map(|p| p.0));
    let ys = series
        .iter()
        .flat_map(|s| s.1.iter().map(|p| p.1))
        .chain(hlines.iter().copied());
    let (x0, x1) = bounds(xs.collect::<Vec<_>>().into_iter());
    let (y0, y1) = bounds(ys.collect::<Vec<_>>().into_iter());
    // A legend (several curves) sits in headroom above the data, never on it: 12 % of the data's
    // range per entry, about 40 px per entry on a 400 px panel for an entry's 20 px.
    let legend = series.len() > 1;
    let y1 = if legend {
        y1 + (y1 - y0) * 0.12 * series.len() as f64
    } else {
        y1
    };
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| e.to_string())?;
    // Six labels per axis at most: a panel is a third of the figure's width, and an engineering
    // label ("-900e3") is up to seven characters.
    chart
        .configure_mesh()
        .x_desc(xl)
        .y_desc(yl)
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&|x| crate::figure::tick(*x))
        .y_label_formatter(&|y| crate::figure::tick(*y))
        .light_line_style(WHITE)
        .draw()
        .map_err(|e| e.to_string())?;
    for &h in hlines {
        chart
            .draw_series(LineSeries::new(
                vec![(x0, h), (x1, h)],
                BLACK.mix(0.4).stroke_width(1),
            ))
            .map_err(|e| e.to_string())?;
    }
    for (label, pts, color, points) in series {
        let c = *color;
        if *points {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 1, c.mix(0.5).filled())))
                .map_err(|e| e.to_string())?
                .label(*label)
                .legend(move |(x, y)| Circle::new((x + 8, y), 3, c.filled()));
        } else {
            chart
                .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
                .map_err(|e| e.to_string())?
                .label(*label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2))
                });
        }
    }
    if legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK.mix(0.3))
            .draw()
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn figure(
    path: &Path,
    format: crate::figure::PlotFormat,
    a: &ResidualAnalysis,
    title: &str,
    u: &DisplayUnits,
) -> Result<(), String> {
    let root = crate::figure::canvas(path, (1500, 900), format);
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let root = root
        .titled(
            &format!(
                "held-out residual, {title}: RMSE {:.4} {}, Ljung–Box p = {:.2e}",
                u.p(a.rmse),
                u.pressure(),
                a.whiteness.lb_p_value
            ),
            ("sans-serif", 22),
        )
        .map_err(|e| e.to_string())?;
    let panels = root.split_evenly((2, 3));
    time_panels(&panels[..3], a, u)?;
    shape_panels(&panels[3..], a, u)?;
    root.present().map_err(|e| e.to_string())
}

const BLUE: RGBColor = RGBColor(31, 119, 180);
const RED: RGBColor = RGBColor(214, 39, 40);
const GREEN: RGBColor = RGBColor(44, 160, 44);
const GREY: RGBColor = RGBColor(90, 90, 90);

/// The residual over time, its autocorrelation and its cross-correlation with the inputs.
fn time_panels(panels: &[Area<'_>], a: &ResidualAnalysis, u: &DisplayUnits) -> Result<(), String> {
    // Subsample the scatter so figures stay small.
    let step = (a.points.len() / 4000).max(1);
    let pts: Vec<&[f64; 4]> = a.points.iter().step_by(step).collect();
    panel(
        &panels[0],
        "residual over time",
        "time (s)",
        &format!("residual ({})", u.pressure()),
        &[(
            "residual",
            pts.iter().map(|p| (p[0], u.p(p[3]))).collect(),
            GREY,
            true,
        )],
        &[0.0],
    )?;
    let w = &a.whiteness;
    panel(
        &panels[1],
        "autocorrelation (95 % white band)",
        "lag (s)",
        "acf",
        &[(
            "acf",
            w.acf
                .iter()
                .enumerate()
                .map(|(k, &r)| (k as f64 * w.lag_s, r))
                .collect(),
            BLUE,
            false,
        )],
        &[w.band, -w.band, 0.0],
    )?;
    let colors = [BLUE, RED, GREEN, GREY];
    let cross: Vec<Curve<'_>> = a
        .cross
        .iter()
        .zip(colors)
        .map(|(c, col)| {
            (
                c.input,
                c.lags
                    .iter()
                    .zip(&c.values)
                    .map(|(&l, &v)| (l as f64 * w.lag_s, v))
                    .collect(),
                col,
                false,
            )
        })
        .collect();
    panel(
        &panels[2],
        "cross-correlation (input leads at +lag)",
        "lag (s)",
        "correlation",
        &cross,
        &[w.band, -w.band],
    )?;
    Ok(())
}

/// The residual against volume and speed by direction, and its spectrum.
fn shape_panels(panels: &[Area<'_>], a: &ResidualAnalysis, u: &DisplayUnits) -> Result<(), String> {
    let dir = &a.direction;
    // Bins of volume (mm³) or speed (mm³/s): the same factor.
    let line = |b: &Binned| {
        b.centre
            .iter()
            .map(|&x| u.v(x))
            .zip(b.mean.iter().map(|&r| u.p(r)))
            .collect::<Vec<_>>()
    };
    let (vol, pres) = (DisplayUnits::pretty(u.volume()), u.pressure());
    let mean = format!("mean residual ({pres})");
    panel(
        &panels[0],
        "residual vs volume by direction",
        &format!("volume ({vol})"),
        &mean,
        &[
            ("inflation", line(&dir.inflation_vs_v), RED, false),
            ("deflation", line(&dir.deflation_vs_v), BLUE, false),
        ],
        &[0.0],
    )?;
    panel(
        &panels[1],
        "residual vs |flow| by direction",
        &format!("|flow| ({vol}/s)"),
        &mean,
        &[
            ("inflation", line(&dir.inflation_vs_speed), RED, false),
            ("deflation", line(&dir.deflation_vs_speed), BLUE, false),
        ],
        &[0.0],
    )?;
    let sp = &a.spectrum;
    panel(
        &panels[2],
        "Welch spectrum",
        "frequency (Hz)",
        &format!("log10 PSD ({pres}²/Hz)"),
        &[(
            "psd",
            sp.freq_hz
                .iter()
                .zip(&sp.psd)
                .skip(1)
                .map(|(&f, &p)| (f, u.p(u.p(p)).max(1e-30).log10()))
                .collect(),
            BLUE,
            false,
        )],
        &[],
    )?;
    Ok(())
}

/// The shape chosen again with the effects: which was selected, which is used, and the
/// cross-validated numbers that decided.
fn reshape_lines(s: &mut String, r: &sysid::residual::ReshapeReport, u: &DisplayUnits) {
    let p = u.pressure();
    let _ = writeln!(
        s,
        "  shape: selected ({}, {}) without effects, used ({}, {}); {}",
        r.selected.0, r.selected.1, r.used.0, r.used.1, r.verdict
    );
    let rows = if r.outcomes.is_empty() {
        &r.probe
    } else {
        &r.outcomes
    };
    for m in rows {
        let with = if m.effects.is_empty() {
            "alone".to_string()
        } else {
            format!("+ {}", m.effects.join(" + "))
        };
        let _ = writeln!(
            s,
            "    ({}, {}) {with}: {} parameters, cross-validated typical RMSE {:.4} {p} (excess {:.4} ± {:.4})",
            m.n,
            m.m,
            m.nu,
            u.p(m.typical_rmse),
            m.excess.0,
            m.excess.1
        );
    }
}
