//! `vfp demo`: the whole loop on the simulated rig, no hardware needed.
//!
//! 1. **simulate** — host-sim runs the firmware's own tasks on an SBA1 plant through the paper's
//!    protocol (0–550 mm³ at 20–100 mm³/s), with an effect the models do not know about:
//!    rate-independent wall hysteresis (host-sim preset `hysteresis`, 1 kPa half-height).
//! 2. **capture** — the telemetry lines are written as `probe-rs run` prints them.
//! 3. **record** — `vfp record`'s converter turns the capture into a log (gaps and bad lines
//!    would be reported).
//! 4. **identify** — the model families on each chamber (the paper's Table II; see the report for
//!    which families ran and their settings), the chambers side by side.
//! 5. **diagnose** — the residual loop on chamber 0: what does the model lack?
//! 6. **deploy** — each chamber's selected polynomial is exported (`vfp export`'s line generator)
//!    and sent to a fresh simulated board through its serial port; every line must be
//!    acknowledged, and the board's telemetry p̂ is compared with sysid's own prediction. Then
//!    the augmented models, through `vfp export --augmented`'s path ([`augmented_lines`]: the
//!    effect chain's lines included), go to another fresh board the same way.
//! 7. **force** — the paper's Sec. IV-C pushes on the same plant: each board's force estimate
//!    (bare polynomials, augmented models; same pushes, same noise) against the simulator's true
//!    force (mean, std, RMSE in mN).
//! 8. **report** — `report.md` with figures (the force figure shows the two boards' estimates
//!    side by side against the truth), and `report.json`, in the output directory.
//!
//! Every number in the report is computed in this run; a stage that cannot run says why.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::figure::PlotFormat;
use host_sim::{simulate, Effects, PlantConfig, Protocol, Scenario, SimRun, TimedCommand};
use indicatif::{ProgressBar, ProgressStyle};
use plotters::prelude::*;
use serde::Serialize;

use crate::Error;
use sysid::board::export;
use sysid::dataset::{Dataset, DatasetConfig, LogData};
use sysid::identify::{self, ChamberReport, Family};
use sysid::poly::{self, PolyFit, Scaling, Xy};
use sysid::residual;

/// `vfp demo`: simulate, record, identify, diagnose, deploy, estimate force, report.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// A short run (2 cycles per flow rate, 5 s of pushes, smaller sweeps), for CI.
    #[arg(long)]
    pub short: bool,
    /// Directory for the report, figures, capture and logs (created; files are overwritten).
    #[arg(long, value_name = "DIR", default_value = "vfp-demo-out")]
    pub out: PathBuf,
    /// Seed of the simulated sensor noise.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// The figures' file format.
    #[arg(long, value_name = "FORMAT", value_enum, default_value_t = PlotFormat::Svg)]
    pub plot_format: PlotFormat,
}

/// Baseline (n, m) of the residual loop: the paper's polynomial.
pub const DIAGNOSE_SHAPE: (usize, usize) = (3, 2);

/// The effect planted in the plant and not in any model.
pub const PLANTED_EFFECT: &str = "hysteresis";

/// Settings derived from `--short`.
#[derive(Debug, Clone, Serialize)]
pub struct Plan {
    /// The figures' file format.
    pub plot_format: PlotFormat,
    /// Cycles per flow rate.
    pub cycles: u16,
    /// Flow rates, mm³/s.
    pub flows: Vec<f64>,
    /// Seconds of force pushes.
    pub push_s: f64,
    /// Peak push force, N.
    pub push_peak_n: f64,
    /// Families identified.
    pub families: Vec<Family>,
    /// Highest n and m of the polynomial sweep.
    pub max_degree: usize,
    /// Highest AR order of the poly-AR sweep.
    pub ar_max: usize,
    /// Highest number of exponential terms.
    pub exp_k_max: usize,
    /// Network depths (when the neural family runs).
    pub nn_depths: Vec<usize>,
}

impl Plan {
    /// The plan for `--short` or the full demo.
    pub fn new(short: bool) -> Self {
        Self {
            plot_format: PlotFormat::Svg,
            cycles: if short { 2 } else { 20 },
            flows: Protocol::paper().flows,
            push_s: if short { 5.0 } else { 20.0 },
            push_peak_n: 0.3,
            families: if short {
                vec![Family::Exp, Family::Poly, Family::PolyAr]
            } else {
                vec![Family::Exp, Family::Nn, Family::Poly, Family::PolyAr]
            },
            max_degree: if short { 5 } else { 7 },
            ar_max: 5,
            exp_k_max: if short { 3 } else { 5 },
            nn_depths: vec![2, 4, 8],
        }
    }
}

/// The deployed model of one chamber and how the board ran it.
#[derive(Debug, Clone, Serialize)]
pub struct Deployed {
    /// Chamber.
    pub chamber: u8,
    /// Shape (n, m).
    pub shape: (usize, usize),
    /// The lines sent.
    pub lines: Vec<String>,
    /// Lines the board answered `ok`.
    pub acked: usize,
    /// Largest |p̂_board − p̂_sysid| over the force run's frames, kPa.
    pub max_p_hat_diff_kpa: f64,
    /// The same relative to |p̂|, largest.
    pub max_p_hat_rel_diff: f64,
    /// Frames compared.
    pub frames_compared: usize,
}

/// Force estimate against truth during the pushes.
#[derive(Debug, Clone, Serialize)]
pub struct ForceResult {
    /// Frames in the push window.
    pub frames: usize,
    /// Mean true force, mN.
    pub mean_true_mn: f64,
    /// Mean of (estimate − truth), mN.
    pub mean_error_mn: f64,
    /// Standard deviation of (estimate − truth), mN.
    pub std_error_mn: f64,
    /// RMS of (estimate − truth), mN.
    pub rmse_mn: f64,
    /// Bias predicted from the hysteresis the residual loop found: Σ A_c × amplitude, mN.
    pub predicted_bias_mn: Option<f64>,
}

/// One stage's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct StageReport {
    /// Name.
    pub name: &'static str,
    /// Wall time, s.
    pub seconds: f64,
    /// One line.
    pub summary: String,
}

/// Everything the demo measured (`report.json`).
#[derive(Debug, Clone, Serialize)]
pub struct DemoReport {
    /// The plan.
    pub plan: Plan,
    /// The planted effect and its settings.
    pub planted: String,
    /// Stage outcomes.
    pub stages: Vec<StageReport>,
    /// Recorded frames, missing frames, corrupted lines.
    pub record: (usize, u64, usize),
    /// Identification per chamber.
    pub identify: Vec<ChamberReport>,
    /// The residual loop on chamber 0.
    pub diagnosis: Option<residual::Diagnosis>,
    /// Why the residual loop did not run, if it did not.
    pub diagnosis_error: Option<String>,
    /// Deployed models.
    pub deployed: Vec<Deployed>,
    /// Force estimate of the board running the bare polynomials.
    pub force: Option<ForceResult>,
    /// The augmented models deployed (`vfp export --augmented`'s path): per chamber the effects
    /// its chain carries.
    pub augmented: Vec<ChamberEffects>,
    /// Force estimate of the board running the augmented models (same pushes, same noise).
    pub force_augmented: Option<ForceResult>,
    /// Total wall time, s.
    pub total_seconds: f64,
}

/// One progress line per stage: a spinner on a terminal, a plain line otherwise.
struct Stage {
    bar: ProgressBar,
    name: &'static str,
    index: usize,
    t0: Instant,
}

const STAGES: usize = 8;

impl Stage {
    fn start(index: usize, name: &'static str, what: &str) -> Self {
        let bar = crate::progress::new_bar(0, "{prefix:.bold} {spinner} {msg} ({elapsed})");
        bar.set_prefix(format!("[{index}/{STAGES}] {name:<9}"));
        bar.set_message(what.to_string());
        Self {
            bar,
            name,
            index,
            t0: Instant::now(),
        }
    }

    fn done(self, summary: String, out: &mut Vec<StageReport>) {
        let seconds = self.t0.elapsed().as_secs_f64();
        let line = format!("{summary} ({seconds:.1} s)");
        if self.bar.is_hidden() {
            if !crate::progress::quiet() {
                eprintln!("[{}/{STAGES}] {:<9} {line}", self.index, self.name);
            }
        } else {
            self.bar.set_style(
                ProgressStyle::with_template("{prefix:.bold} ✓ {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            self.bar.finish_with_message(line);
        }
        out.push(StageReport {
            name: self.name,
            seconds,
            summary,
        });
    }
}

fn fail(e: impl std::fmt::Display) -> Error {
    Error::Msg(e.to_string())
}

/// The plant of both runs: SBA1 with the planted effect.
pub fn plant() -> PlantConfig {
    PlantConfig {
        effects: Effects::preset(PLANTED_EFFECT).unwrap_or_default(),
        ..PlantConfig::default()
    }
}

/// The identification run's scenario.
pub fn identification_scenario(plan: &Plan, seed: u64) -> Scenario {
    let protocol = Protocol {
        cycles: plan.cycles,
        flows: plan.flows.clone(),
        ..Protocol::paper()
    };
    let mut s = Scenario::protocol("demo-identification", plant(), &protocol);
    s.seed = seed;
    s
}

/// Text as `probe-rs run` prints the firmware's defmt lines: timestamp, message, location line.
pub fn probe_rs_capture(run: &SimRun, mut out: impl std::io::Write) -> std::io::Result<()> {
    writeln!(
        out,
        "      Finished `release` profile [optimized + debuginfo] target(s)"
    )?;
    writeln!(out, "     Running `probe-rs run --chip STM32F446RETx target/thumbv7em-none-eabihf/release/vfp-fw`")?;
    for (t, line) in &run.telemetry {
        writeln!(out, "{:.6} {line}", *t as f64 * 1e-6)?;
        writeln!(
            out,
            "└─ vfp_fw::__sampler_task::{{async_fn#0}} @ firmware/src/bin/vfp-fw.rs:56"
        )?;
    }
    Ok(())
}

/// The selected polynomial (n, m) of a chamber's identification, else the paper's (3, 2).
pub fn chosen_shape(rep: &ChamberReport) -> (usize, usize) {
    rep.best
        .iter()
        .find(|r| r.family == Family::Poly)
        .and_then(|r| Some((r.n?, r.m?)))
        .unwrap_or((3, 2))
}

/// Fits the deployed polynomial exactly as `vfp export` does: training cycles, scaling from all.
pub fn deploy_fit(ds: &Dataset, n: usize, m: usize) -> Result<PolyFit, Error> {
    let all = ds.all();
    let sc = Scaling::from_data(&all.v, &all.vdot).map_err(fail)?;
    poly::fit(Xy::from(&ds.train()), n, m, Some(sc)).map_err(fail)
}

/// The model lines as serial commands for a fresh simulated board: 10 ms apart from 50 ms, well
/// before the firmware's 1 s boot zero ends.
pub fn upload_commands(lines: &[String]) -> Vec<TimedCommand> {
    lines
        .iter()
        .enumerate()
        .map(|(i, l)| TimedCommand::new(0.05 + 0.01 * i as f64, l))
        .collect()
}

/// The force-push scenario with `lines` sent to the board's serial port first (10 ms apart).
pub fn force_scenario(plan: &Plan, seed: u64, lines: &[String]) -> Scenario {
    let mut s = Scenario::force_pushes(plan.push_peak_n, plan.push_s);
    s.plant = plant();
    s.seed = seed.wrapping_add(1);
    let mut cmds = upload_commands(lines);
    cmds.append(&mut s.commands);
    s.commands = cmds;
    s
}

// The neural family's settings are still growing fields; set the one the demo chooses.
#[allow(clippy::field_reassign_with_default)]
fn nn_config(plan: &Plan) -> sysid::nn::SweepConfig {
    let mut c = sysid::nn::SweepConfig::default();
    c.depths = plan.nn_depths.clone();
    c
}

/// Runs `vfp demo`.
pub fn run(args: &Args) -> Result<(), Error> {
    let plan = Plan {
        plot_format: args.plot_format,
        ..Plan::new(args.short)
    };
    let report = run_plan(plan, args.seed, &args.out)?;
    println!(
        "demo finished in {:.1} s; report: {}",
        report.total_seconds,
        args.out.join("report.md").display()
    );
    Ok(())
}

/// The whole chain for a given plan, writing into `out`; returns what it measured.
pub fn run_plan(plan: Plan, seed: u64, out: &Path) -> Result<DemoReport, Error> {
    let total = Instant::now();
    std::fs::create_dir_all(out.join("figures"))
        .map_err(|e| Error::Msg(format!("{}: {e}", out.display())))?;
    let mut stages = Vec::new();
    let ident_run = stage_simulate(&plan, seed, &mut stages)?;
    let capture = stage_capture(&ident_run, out, &mut stages)?;
    let (rec, log_path) = stage_record(&capture, out, &mut stages)?;
    let (datasets, reports) = stage_identify(&plan, &log_path, &mut stages)?;
    let (diagnosis, diagnosis_error) = stage_diagnose(&datasets, &mut stages);
    let dep = stage_deploy(
        &plan,
        seed,
        &datasets,
        &reports,
        diagnosis.as_ref(),
        &mut stages,
    )?;
    let forces = stage_force(&plan, &dep, diagnosis.as_ref(), &mut stages);

    // 8. report
    let st = Stage::start(8, "report", "figures, report.md, report.json");
    let figures = write_figures(
        &plan,
        out,
        &datasets,
        &reports,
        diagnosis.as_ref(),
        &dep,
        &forces,
    )?;
    let mut report = DemoReport {
        plan,
        planted: match plant().effects.hysteresis {
            Some(h) => format!(
                "{PLANTED_EFFECT} (half-height {} kPa, so a {} kPa gap between inflation and deflation; \
                 transition {} mm³)",
                h.amplitude_kpa,
                2.0 * h.amplitude_kpa,
                h.transition_mm3
            ),
            None => format!("{PLANTED_EFFECT} (preset missing in host-sim)"),
        },
        stages,
        record: (rec.frames, rec.missing_frames(), rec.corrupted.len()),
        identify: reports,
        diagnosis,
        diagnosis_error,
        deployed: dep.deployed,
        force: forces.bare,
        augmented: dep.augmented,
        force_augmented: forces.augmented,
        total_seconds: 0.0,
    };
    st.done(format!("{} figures", figures.len()), &mut report.stages);
    report.total_seconds = total.elapsed().as_secs_f64();
    let md = markdown(&report, &figures);
    std::fs::write(out.join("report.md"), md)
        .map_err(|e| Error::Msg(format!("{}: {e}", out.join("report.md").display())))?;
    let json = serde_json::to_string_pretty(&report).map_err(fail)?;
    std::fs::write(out.join("report.json"), json)
        .map_err(|e| Error::Msg(format!("{}: {e}", out.join("report.json").display())))?;
    Ok(report)
}

/// Stage 1: the firmware's tasks run the identification protocol on the simulated rig.
fn stage_simulate(plan: &Plan, seed: u64, stages: &mut Vec<StageReport>) -> Result<SimRun, Error> {
    let st = Stage::start(
        1,
        "simulate",
        "firmware tasks on the simulated rig, paper protocol",
    );
    let scenario = identification_scenario(plan, seed);
    let ident_run = simulate(&scenario).map_err(fail)?;
    st.done(
        format!(
            "{:.0} s of rig time, {} frames, {} steps ({} cycles at {:?} mm³/s, planted: {PLANTED_EFFECT})",
            ident_run.stats.end_us as f64 * 1e-6,
            ident_run.frames.len(),
            ident_run.stats.steps,
            plan.cycles,
            plan.flows
        ),
        stages,
    );
    Ok(ident_run)
}

/// Stage 2: the run's telemetry as `probe-rs run` prints it, into `out/telemetry.txt`.
fn stage_capture(
    ident_run: &SimRun,
    out: &Path,
    stages: &mut Vec<StageReport>,
) -> Result<std::path::PathBuf, Error> {
    let st = Stage::start(2, "capture", "telemetry as printed by probe-rs");
    let capture = out.join("telemetry.txt");
    {
        let f = std::fs::File::create(&capture)
            .map_err(|e| Error::Msg(format!("{}: {e}", capture.display())))?;
        let mut w = std::io::BufWriter::new(f);
        probe_rs_capture(ident_run, &mut w)
            .and_then(|_| w.flush())
            .map_err(|e| Error::Msg(format!("{}: {e}", capture.display())))?;
    }
    st.done(
        format!(
            "{} telemetry lines → {}",
            ident_run.telemetry.len(),
            capture.display()
        ),
        stages,
    );
    Ok(capture)
}

/// Stage 3: the capture converted to a log, `out/identification.csv`.
fn stage_record(
    capture: &Path,
    out: &Path,
    stages: &mut Vec<StageReport>,
) -> Result<(sysid::board::record::Recording, std::path::PathBuf), Error> {
    let st = Stage::start(3, "record", "capture → log");
    let rec = sysid::board::record::convert_file(capture).map_err(fail)?;
    let log_path = out.join("identification.csv");
    sysid::log::write_log(&log_path, &rec.log).map_err(fail)?;
    st.done(
        format!(
            "{} frames → {} ({} missing, {} corrupted lines)",
            rec.frames,
            log_path.display(),
            rec.missing_frames(),
            rec.corrupted.len()
        ),
        stages,
    );
    Ok((rec, log_path))
}

/// Stage 4: the plan's model families identified on every chamber of the log.
fn stage_identify(
    plan: &Plan,
    log_path: &Path,
    stages: &mut Vec<StageReport>,
) -> Result<(Vec<Dataset>, Vec<ChamberReport>), Error> {
    let st = Stage::start(4, "identify", "model families per chamber");
    let datasets = LogData::read(log_path, None, &DatasetConfig::default())
        .map_err(fail)?
        .datasets;
    let opts = identify::Options {
        families: plan.families.clone(),
        max_n: plan.max_degree,
        max_m: plan.max_degree,
        ar_max: plan.ar_max,
        exp_k_max: plan.exp_k_max,
        nn: nn_config(plan),
        nn_ar_max: 0,
        progress: None,
        ..identify::Options::default()
    };
    // The chambers are independent: side by side, reported in the chambers' order.
    st.bar
        .set_message(format!("{} chambers side by side", datasets.len()));
    let reports: Vec<_> = std::thread::scope(|s| {
        let handles: Vec<_> = datasets
            .iter()
            .map(|ds| s.spawn(|| identify::identify(ds, &opts)))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .map_err(|_| Error::Msg("a chamber's identification panicked".into()))
            })
            .collect::<Result<_, _>>()
    })?;
    let sel: Vec<String> = reports
        .iter()
        .map(|r| {
            let (n, m) = chosen_shape(r);
            let rmse = r
                .best
                .iter()
                .find(|b| b.family == Family::Poly)
                .map_or(f64::NAN, |b| b.rmse);
            format!("ch{} poly ({n}, {m}) RMSE {rmse:.3} kPa", r.chamber)
        })
        .collect();
    st.done(sel.join("; "), stages);
    Ok((datasets, reports))
}

/// Stage 5: the residual loop on chamber 0 with the paper's (3, 2) baseline; the diagnosis, or
/// why it did not run.
fn stage_diagnose(
    datasets: &[Dataset],
    stages: &mut Vec<StageReport>,
) -> (Option<residual::Diagnosis>, Option<String>) {
    let st = Stage::start(5, "diagnose", "residual loop on chamber 0, (3, 2) baseline");
    let (diagnosis, diagnosis_error) = match datasets.first() {
        None => (None, Some("no chamber in the log".to_string())),
        Some(ds) => {
            // The paper's (3, 2) baseline: its 12 columns keep the loop's candidate searches
            // (≈ N × columns² each) inside the time budget; a (7, 7) baseline costs ~30× more.
            let cfg = residual::Config {
                n: DIAGNOSE_SHAPE.0,
                m: DIAGNOSE_SHAPE.1,
                ..residual::Config::default()
            };
            match residual::series_from_dataset(ds).and_then(|s| residual::diagnose(s, &cfg)) {
                Ok(d) => (Some(d), None),
                Err(e) => (None, Some(e.to_string())),
            }
        }
    };
    let found = match (&diagnosis, &diagnosis_error) {
        (Some(d), _) => format!(
            "found: {}; held-out RMSE {:.3} → {:.3} kPa (loop: {})",
            if d.effects.is_empty() {
                "nothing".to_string()
            } else {
                d.effects
                    .iter()
                    .map(|e| e.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            },
            d.baseline.rmse_heldout,
            d.final_model.rmse_heldout,
            loop_time(&d.timing)
        ),
        (None, Some(e)) => format!("not run: {e}"),
        (None, None) => "not run".into(),
    };
    st.done(found, stages);
    (diagnosis, diagnosis_error)
}

/// Where the residual loop's time went, in one line (`vfp diagnose --timings` has the rounds).
fn loop_time(t: &residual::Timings) -> String {
    format!(
        "searches {:.1} s, re-tunes {:.1} s, single swaps {:.1} s, pair trials {:.1} s, analysis {:.1} s",
        t.searches, t.retune, t.single_swaps + t.apply_swaps, t.pair_trials, t.residual_analysis
    )
}

/// What stage 6 deployed and the force runs of the boards that ran it.
struct Deployment {
    /// The bare polynomials, board against sysid.
    deployed: Vec<Deployed>,
    /// The pushes on the board running the bare polynomials.
    force_run: SimRun,
    /// Per chamber the effects the augmented chain carries.
    augmented: Vec<ChamberEffects>,
    /// The pushes on the board running the augmented models, with the lines it acknowledged.
    aug_run: Option<(SimRun, usize)>,
}

/// Stage 6: each chamber's polynomial exported and sent to a fresh board (and the augmented
/// models to another), both then pushed on.
fn stage_deploy(
    plan: &Plan,
    seed: u64,
    datasets: &[Dataset],
    reports: &[ChamberReport],
    diagnosis: Option<&residual::Diagnosis>,
    stages: &mut Vec<StageReport>,
) -> Result<Deployment, Error> {
    let st = Stage::start(
        6,
        "deploy",
        "export each chamber's polynomial, send to a fresh board",
    );
    let mut fits = Vec::new();
    let mut lines = Vec::new();
    for (ds, rep) in datasets.iter().zip(reports) {
        let (n, m) = chosen_shape(rep);
        let fit = deploy_fit(ds, n, m)?;
        let model = fit.to_model_core().map_err(fail)?;
        let l = export::command_lines(ds.chamber, &model);
        lines.push(l);
        fits.push(fit);
    }
    let all_lines: Vec<String> = lines.iter().flatten().cloned().collect();
    // The bare board's run does not depend on the augmented models (the residual loop on the
    // other chambers, then their board's run): the two go side by side, each as it would alone.
    let (bare, aug) = std::thread::scope(|s| {
        let bare = s.spawn(|| run_deployed(plan, seed, &all_lines));
        let aug = (|| -> Result<_, Error> {
            let (aug_lines, augmented) = match diagnosis {
                Some(d) => augmented_lines(datasets, d)?,
                None => (Vec::new(), Vec::new()),
            };
            let aug_run = if aug_lines.is_empty() {
                None
            } else {
                Some(run_deployed(plan, seed, &aug_lines)?)
            };
            Ok((augmented, aug_run))
        })();
        (bare.join(), aug)
    });
    let (force_run, acked) =
        bare.map_err(|_| Error::Msg("the bare board's simulation panicked".into()))??;
    let (augmented, aug_run) = aug?;
    let deployed = compare_p_hat(datasets, &fits, &lines, &force_run);
    let worst = deployed
        .iter()
        .map(|d| d.max_p_hat_rel_diff)
        .fold(0.0, f64::max);
    st.done(
        format!(
            "{} lines acknowledged on {} channels; board p̂ = sysid p̂ within {:.1e} (relative) over {} frames; augmented: {} lines acknowledged ({})",
            acked,
            lines.len(),
            worst,
            deployed.first().map_or(0, |d| d.frames_compared),
            aug_run.as_ref().map_or(0, |r| r.1),
            effects_summary(&augmented)
        ),
        stages,
    );
    Ok(Deployment {
        deployed,
        force_run,
        augmented,
        aug_run,
    })
}

/// The force estimates of stage 7 with their traces.
struct Forces {
    bare: Option<ForceResult>,
    bare_trace: Trace,
    augmented: Option<ForceResult>,
    augmented_trace: Trace,
}

/// Stage 7: the boards' force estimates during the pushes against the truth.
fn stage_force(
    plan: &Plan,
    dep: &Deployment,
    diagnosis: Option<&residual::Diagnosis>,
    stages: &mut Vec<StageReport>,
) -> Forces {
    let st = Stage::start(7, "force", "pushes on the tip: estimate vs truth");
    let predicted_bias = diagnosis
        .and_then(hysteresis_amplitude)
        .map(|a| 3.0 * f64::from(model_core::force::DEFAULT_AREA_MM2) * a);
    let (bare, bare_trace) = force_stats(plan, &dep.force_run, predicted_bias);
    let (augmented, augmented_trace) = match dep.aug_run.as_ref() {
        Some((run, _)) => force_stats(plan, run, None),
        None => (None, Trace::new()),
    };
    let line = |f: &Option<ForceResult>| match f {
        Some(f) => format!(
            "error mean {:+.1} mN, std {:.1} mN, RMSE {:.1} mN over {} frames (true mean {:.0} mN)",
            f.mean_error_mn, f.std_error_mn, f.rmse_mn, f.frames, f.mean_true_mn
        ),
        None => "no frames in the push window".into(),
    };
    st.done(
        format!("bare: {}; augmented: {}", line(&bare), line(&augmented)),
        stages,
    );
    Forces {
        bare,
        bare_trace,
        augmented,
        augmented_trace,
    }
}

/// The report's figures (identification and diagnosis of chamber 0, the force panels), each
/// with its path relative to `out` and its caption: every file written is linked from the report.
fn write_figures(
    plan: &Plan,
    out: &Path,
    datasets: &[Dataset],
    reports: &[ChamberReport],
    diagnosis: Option<&residual::Diagnosis>,
    dep: &Deployment,
    forces: &Forces,
) -> Result<Vec<(String, String)>, Error> {
    let fig = out.join("figures");
    let mut written = Vec::new();
    let format = plan.plot_format;
    if let (Some(ds), Some(rep)) = (datasets.first(), reports.first()) {
        written.extend(crate::plots::identify::write_all(
            &fig,
            format,
            ds,
            rep,
            &crate::units::DisplayUnits::default(),
        )?);
    }
    if let Some(d) = diagnosis {
        written.extend(super::diagnose::write_plots(
            &fig,
            format,
            d,
            &crate::units::DisplayUnits::default(),
        )?);
    }
    let force_path = fig.join(format.file("force"));
    let mut panels = vec![ForcePanel::new(
        "bare polynomials",
        &forces.bare,
        &forces.bare_trace,
    )];
    if !forces.augmented_trace.is_empty() {
        let title = format!("augmented ({})", carried_union(&dep.augmented));
        panels.push(ForcePanel::new(
            &title,
            &forces.augmented,
            &forces.augmented_trace,
        ));
    }
    force_figure(&force_path, format, &panels)
        .map_err(|e| Error::Msg(format!("{}: {e}", force_path.display())))?;
    written.push(force_path);
    Ok(written
        .iter()
        .map(|p| {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let stem = p
                .file_stem()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            (format!("figures/{name}"), caption(&stem))
        })
        .collect())
}

/// A chamber and the effects its deployed chain carries.
pub type ChamberEffects = (u8, Vec<String>);

/// The simulated board's force run with `lines` sent first; every line must be acknowledged.
/// Returns the run and the number of lines acknowledged.
fn run_deployed(plan: &Plan, seed: u64, lines: &[String]) -> Result<(SimRun, usize), Error> {
    let run = simulate(&force_scenario(plan, seed, lines)).map_err(fail)?;
    let acked = run
        .replies
        .iter()
        .take(lines.len())
        .take_while(|(_, r)| r == "ok")
        .count();
    if acked != lines.len() {
        let (sent, reply) = (
            &lines[acked.min(lines.len() - 1)],
            run.replies.get(acked).map_or("no reply", |r| r.1.as_str()),
        );
        return Err(Error::Msg(format!(
            "the simulated board refused `{sent}` with `{reply}`"
        )));
    }
    Ok((run, acked))
}

/// Every chamber's augmented model through `vfp export --augmented`'s own path
/// ([`sysid::board::augmented`], [`export::command_lines`]): chamber 0's is the export of the
/// residual loop the demo ran on it, the others' the loop run on them over the effects it kept
/// on chamber 0 (the same plant). Returns the lines and, per chamber, the effects its chain
/// carries.
pub fn augmented_lines(
    datasets: &[Dataset],
    diagnosis: &residual::Diagnosis,
) -> Result<(Vec<String>, Vec<ChamberEffects>), Error> {
    use sysid::board::augmented::{augmented_export, from_diagnosis};
    let kept: Vec<residual::EffectKind> = diagnosis.effects.iter().map(|e| e.kind).collect();
    let export_one = |i: usize, ds: &Dataset| -> Result<_, Error> {
        let wrap = |e: &dyn std::fmt::Display| Error::Msg(format!("chamber {}: {e}", ds.chamber));
        let series = residual::series_from_dataset(ds).map_err(|e| wrap(&e))?;
        if i == 0 {
            from_diagnosis(diagnosis.clone(), &series)
        } else {
            let cfg = residual::Config {
                n: DIAGNOSE_SHAPE.0,
                m: DIAGNOSE_SHAPE.1,
                candidates: kept.clone(),
                ..residual::Config::default()
            };
            augmented_export(series, &cfg)
        }
        .map_err(|e| wrap(&e))
    };
    // The chambers' loops are independent: side by side, in the chambers' order after.
    let exports: Vec<Result<_, Error>> = std::thread::scope(|s| {
        let handles: Vec<_> = datasets
            .iter()
            .enumerate()
            .map(|(i, ds)| s.spawn(move || export_one(i, ds)))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(Error::Msg("a chamber's loop panicked".into())))
            })
            .collect()
    });
    let mut lines = Vec::new();
    let mut carried = Vec::new();
    for (ds, x) in datasets.iter().zip(exports) {
        let x = x?;
        carried.push((
            ds.chamber,
            x.carried.iter().map(|c| c.name.to_string()).collect(),
        ));
        lines.extend(export::board_lines(ds.chamber, &x.device.board_model()));
    }
    Ok((lines, carried))
}

fn effects_summary(aug: &[ChamberEffects]) -> String {
    aug.iter()
        .map(|(c, e)| {
            format!(
                "ch{c} {}",
                if e.is_empty() {
                    "-".into()
                } else {
                    e.join("+")
                }
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Half the up−down pressure gap of the hysteresis the residual loop found, kPa: how far the
/// inflation branch lies above the branch-averaging polynomial.
fn hysteresis_amplitude(d: &residual::Diagnosis) -> Option<f64> {
    let e = d.effects.iter().find(|e| e.name == "hysteresis")?;
    e.params
        .iter()
        .find(|p| p.name == "gap_at_mid_volume")
        .map(|p| 0.5 * p.value.abs())
}

/// Board p̂ against sysid's f64 prediction of the deployed fit, on the force run's frames.
fn compare_p_hat(
    datasets: &[Dataset],
    fits: &[PolyFit],
    lines: &[Vec<String>],
    run: &SimRun,
) -> Vec<Deployed> {
    datasets
        .iter()
        .zip(fits)
        .zip(lines)
        .map(|((ds, fit), l)| {
            let c = ds.chamber as usize;
            let (mut max_abs, mut max_rel, mut count) = (0.0f64, 0.0f64, 0);
            // Frames after the model-loaded event: every frame once the board has zeroed.
            for f in run.frames.iter().filter(|f| f.t_us > 1_500_000) {
                let ch = &f.chambers[c];
                if !ch.p_hat.is_finite() {
                    continue;
                }
                let want = fit.predict(ch.v as f64, ch.vdot as f64);
                let d = (ch.p_hat as f64 - want).abs();
                max_abs = max_abs.max(d);
                max_rel = max_rel.max(d / want.abs().max(1.0));
                count += 1;
            }
            Deployed {
                chamber: ds.chamber,
                shape: (fit.n, fit.m),
                lines: l.clone(),
                acked: l.len(),
                max_p_hat_diff_kpa: max_abs,
                max_p_hat_rel_diff: max_rel,
                frames_compared: count,
            }
        })
        .collect()
}

/// Trace of (t s, true N, estimated N) over the force run.
type Trace = Vec<(f64, f64, f64)>;

fn force_stats(
    plan: &Plan,
    run: &SimRun,
    predicted_bias_mn: Option<f64>,
) -> (Option<ForceResult>, Trace) {
    let push = run.scenario.force.first();
    let (t0, t1) = push.map_or((0.0, 0.0), |p| (p.start_s, p.start_s + p.duration_s));
    let trace: Trace = run
        .frames
        .iter()
        .zip(&run.truth)
        .map(|(f, t)| (f.t_us as f64 * 1e-6, t.force_n, f.force_n as f64))
        .filter(|(t, _, _)| *t >= t0 - 3.0)
        .collect();
    let win: Vec<&(f64, f64, f64)> = trace
        .iter()
        .filter(|(t, _, e)| *t >= t0 && *t <= t1 && e.is_finite())
        .collect();
    if win.len() < 2 {
        return (None, trace);
    }
    let _ = plan;
    let err: Vec<f64> = win.iter().map(|(_, tr, e)| (e - tr) * 1e3).collect();
    let n = err.len() as f64;
    let mean = err.iter().sum::<f64>() / n;
    let std = (err.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let rmse = (err.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let mean_true = win.iter().map(|w| w.1).sum::<f64>() / n * 1e3;
    (
        Some(ForceResult {
            frames: win.len(),
            mean_true_mn: mean_true,
            mean_error_mn: mean,
            std_error_mn: std,
            rmse_mn: rmse,
            predicted_bias_mn,
        }),
        trace,
    )
}

/// The report's caption of a figure, by its file stem.
fn caption(stem: &str) -> String {
    let chamber = stem.strip_prefix("ch").and_then(|s| s.split_once('-'));
    let (c, what) = chamber.unwrap_or(("", stem));
    let text = match what {
        "vp" => "V–P curves: measured and the selected polynomial".to_string(),
        "residual-vs-volume" => {
            "Held-out residual of the selected polynomial against volume".into()
        }
        "error-histogram" => "Held-out error distribution of the selected polynomial".into(),
        "resid-before" => "Residual loop: held-out residual before".into(),
        "resid-after" => "Residual loop: held-out residual after".into(),
        "force" => {
            "Force pushes: the board's estimate against the true force (bare polynomials, augmented models)"
                .into()
        }
        w => match w.strip_suffix("-rmse-aicc") {
            Some(fam) => format!("Model comparison, {fam}: RMSE (bars) and AICc"),
            None => w.to_string(),
        },
    };
    if c.is_empty() {
        text
    } else {
        format!("{text} (chamber {c})")
    }
}

/// One panel of the force figure: a board's estimate against the truth.
struct ForcePanel<'a> {
    title: String,
    trace: &'a Trace,
}

impl<'a> ForcePanel<'a> {
    /// The panel of a board named `what`, its error statistics in the title.
    fn new(what: &str, stats: &Option<ForceResult>, trace: &'a Trace) -> Self {
        let title = match stats {
            Some(f) => format!(
                "{what}: error {:+.1} ± {:.1} mN",
                f.mean_error_mn, f.std_error_mn
            ),
            None => what.to_string(),
        };
        ForcePanel { title, trace }
    }
}

/// The effects any chamber's augmented chain carries, in first-seen order (`a + b`).
fn carried_union(aug: &[ChamberEffects]) -> String {
    let mut names: Vec<&str> = Vec::new();
    for n in aug.iter().flat_map(|(_, e)| e) {
        if !names.contains(&n.as_str()) {
            names.push(n);
        }
    }
    if names.is_empty() {
        "no effect carried".into()
    } else {
        names.join(" + ").replace('_', " ")
    }
}

/// The force figure: one panel per board (bare, augmented) side by side, on one force axis.
fn force_figure(path: &Path, format: PlotFormat, panels: &[ForcePanel]) -> Result<(), String> {
    let w = 700 * panels.len().max(1) as u32;
    let root = crate::figure::canvas(path, (w, 420), format);
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let hi = panels
        .iter()
        .flat_map(|p| p.trace.iter().flat_map(|q| [q.1, q.2]))
        .filter(|x| x.is_finite())
        .fold(0.0f64, f64::max)
        * 1e3
        * 1.35
        + 10.0;
    let areas = root.split_evenly((1, panels.len().max(1)));
    for (area, panel) in areas.iter().zip(panels) {
        force_panel(area, panel, hi)?;
    }
    root.present().map_err(|e| e.to_string())
}

fn force_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    panel: &ForcePanel,
    hi: f64,
) -> Result<(), String> {
    let trace = panel.trace;
    let (x0, x1) = trace
        .first()
        .zip(trace.last())
        .map_or((0.0, 1.0), |(a, b)| (a.0, b.0.max(a.0 + 1.0)));
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(x0..x1, -10.0..hi)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("force (mN)")
        .x_label_formatter(&|x| crate::figure::tick(*x))
        .y_label_formatter(&|y| crate::figure::tick(*y))
        .draw()
        .map_err(|e| e.to_string())?;
    let black = RGBColor(20, 20, 20);
    let red = RGBColor(214, 39, 40);
    chart
        .draw_series(LineSeries::new(
            trace.iter().map(|p| (p.0, p.1 * 1e3)),
            black.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("true (simulator)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], black.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            trace
                .iter()
                .filter(|p| p.2.is_finite())
                .map(|p| (p.0, p.2 * 1e3)),
            red.stroke_width(1),
        ))
        .map_err(|e| e.to_string())?
        .label("the board's estimate (|Σ residual × 22 mm²|)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], red.stroke_width(2)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK.mix(0.3))
        .draw()
        .map_err(|e| e.to_string())
}

fn markdown(r: &DemoReport, figures: &[(String, String)]) -> String {
    let mut s = String::new();
    md_header(&mut s, r);
    md_identification(&mut s, r);
    md_residual_loop(&mut s, r);
    md_deployment(&mut s, r);
    md_force(&mut s, r);
    md_figures(&mut s, figures);
    md_glossary(&mut s, r);
    s
}

/// What the report's symbols mean, and each parameter name the residual loop reported.
fn md_glossary(s: &mut String, r: &DemoReport) {
    const SYMBOLS: [(&str, &str); 6] = [
        ("ν", "the number of a model's parameters (coefficients, and an effect's searched ones)"),
        ("RMSE", "root-mean-square error of the predicted pressure, kPa; *held-out*: on the cycles left out of the fit (one in five)"),
        ("R²adj", "the coefficient of determination adjusted for ν"),
        ("AICc", "Akaike's information criterion with the small-sample correction (lower is better)"),
        ("p", "the probability of an improvement this large by chance, from the loop's F-test with the sample size corrected for residual autocorrelation; `0.0e0` is below what a double can hold"),
        ("shape", "(n, m): the highest powers of v and v̇ in the polynomial; (p, n, m) with p autoregressive input terms"),
    ];
    const PARAMS: [(&str, &str); 15] = [
        ("width", "hysteresis: the volume over which 63 % of the switch happens after a reversal"),
        ("gap_at_mid_volume", "hysteresis: pressure on inflation minus on deflation, at mid volume"),
        ("gap_change_to_range_ends", "hysteresis: how much that gap changes from mid volume to either end of the volume range"),
        ("time_constant", "a lag's time constant τ"),
        ("delay", "a pure delay"),
        ("effective_delay", "the delay the lag amounts to (2τ for the delivery lag's two stages)"),
        ("play", "backlash: the plunger's dead travel after each reversal"),
        ("inertance", "the pressure per unit volume acceleration, P = L·v̈"),
        ("conductance", "leak: flow out per kPa"),
        ("volume_lost_over_log", "leak: the volume lost over the whole log"),
        ("one_way", "leak: 1 where water leaks out only above the atmosphere's pressure (a seal that closes under suction), 0 where it comes back in below it too"),
        ("frequency", "a ripple's frequency"),
        ("amplitude", "a ripple's amplitude"),
        ("rate", "a drift's rate"),
        ("change_over_log", "a drift's total change over the log"),
    ];
    let used: Vec<&str> = r
        .diagnosis
        .iter()
        .flat_map(|d| {
            d.effects
                .iter()
                .flat_map(|e| e.params.iter().map(|p| p.name.as_str()))
        })
        .collect();
    let _ = writeln!(s, "\n## Glossary\n");
    for (term, meaning) in SYMBOLS {
        let _ = writeln!(s, "- **{term}**: {meaning}.");
    }
    for (name, meaning) in PARAMS.iter().filter(|(n, _)| used.contains(n)) {
        let _ = writeln!(s, "- `{name}`: {meaning}.");
    }
}

/// The title, the plan and the stages with their times.
fn md_header(s: &mut String, r: &DemoReport) {
    let _ = writeln!(s, "# vfp demo report\n");
    let _ = writeln!(
        s,
        "Simulated SBA1 rig (host-sim running the firmware's own tasks) with an effect no model family \
         contains: **{}**. {} cycles per flow rate at {:?} mm³/s; {} s of force pushes (peak {} N, 1 Hz). \
         Total wall time {:.1} s.\n",
        r.planted, r.plan.cycles, r.plan.flows, r.plan.push_s, r.plan.push_peak_n, r.total_seconds
    );
    let _ = writeln!(
        s,
        "## Stages\n\n| stage | time (s) | result |\n| --- | ---: | --- |"
    );
    for st in &r.stages {
        let _ = writeln!(
            s,
            "| {} | {:.1} | {} |",
            st.name,
            st.seconds,
            st.summary.replace('|', "/")
        );
    }
}

/// The best model of each family per chamber (training RMSE, held-out in brackets) and what was run.
fn md_identification(s: &mut String, r: &DemoReport) {
    let _ = writeln!(
        s,
        "\n## Identification (training cycles; held-out in brackets)\n"
    );
    let _ = writeln!(s, "| chamber | family | shape | ν | RMSE kPa | R²adj | AICc |\n| --- | --- | --- | ---: | ---: | ---: | ---: |");
    for rep in &r.identify {
        for b in &rep.best {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {:.4} ({}) | {:.4} | {:.4e} |",
                rep.chamber,
                b.family.name(),
                b.shape(),
                b.nu,
                b.rmse,
                b.rmse_heldout.map_or("-".into(), |x| format!("{x:.4}")),
                b.r2_adj,
                b.aicc
            );
        }
        for f in &rep.failed {
            let _ = writeln!(
                s,
                "| {} | {} | {} | | not fitted: {} | | |",
                rep.chamber,
                f.family.name(),
                f.shape,
                f.error
            );
        }
    }
    let ran: Vec<&str> = r.plan.families.iter().map(|f| f.name()).collect();
    let _ = writeln!(
        s,
        "\nFamilies run: {}; polynomial sweep n, m ≤ {}; poly-AR p ≤ {}; exponential k ≤ {}{}.",
        ran.join(", "),
        r.plan.max_degree,
        r.plan.ar_max,
        r.plan.exp_k_max,
        if r.plan.families.contains(&Family::Nn) {
            format!("; neural depths {:?} without AR inputs (reduced from the paper's 1..=15 to fit the time budget)", r.plan.nn_depths)
        } else {
            "; neural networks not run in the short form".into()
        }
    );
}

/// The residual loop's baseline, the effects it kept and what was planted.
fn md_residual_loop(s: &mut String, r: &DemoReport) {
    let _ = writeln!(s, "\n## Residual loop (chamber 0)\n");
    match (&r.diagnosis, &r.diagnosis_error) {
        (Some(d), _) => {
            let _ = writeln!(
                s,
                "Baseline polynomial ({}, {}): held-out RMSE {:.4} kPa. Final model: {:.4} kPa ({} parameters).\n",
                d.baseline.n, d.baseline.m, d.baseline.rmse_heldout, d.final_model.rmse_heldout, d.final_model.nu
            );
            for e in &d.effects {
                let ps: Vec<String> = e
                    .params
                    .iter()
                    .map(|p| format!("{} = {:.4} {}", p.name, p.value, p.unit))
                    .collect();
                let _ = writeln!(
                    s,
                    "- **{}** — held-out RMSE {:.4} → {:.4} kPa, p = {:.1e}; {}. On the device: {}.",
                    e.name,
                    e.rmse_heldout_before,
                    e.rmse_heldout_after,
                    e.p_value,
                    ps.join(", "),
                    if e.device.runs_on_device { "yes" } else { e.device.reason }
                );
            }
            if d.effects.is_empty() {
                let _ = writeln!(s, "- no effect passed the test");
            }
            let _ = writeln!(s, "\nPlanted in the simulator: {}.", r.planted);
        }
        (None, Some(e)) => {
            let _ = writeln!(s, "Not run: {e}.");
        }
        _ => {}
    }
}

/// Each chamber's deployment and how closely the board's p̂ follows sysid's.
fn md_deployment(s: &mut String, r: &DemoReport) {
    let _ = writeln!(s, "\n## Deployment\n");
    for d in &r.deployed {
        let _ = writeln!(
            s,
            "- chamber {}: polynomial ({}, {}), {} lines acknowledged by the simulated board; its telemetry p̂ equals \
             sysid's prediction within {:.2e} kPa ({:.1e} relative) over {} frames.",
            d.chamber, d.shape.0, d.shape.1, d.acked, d.max_p_hat_diff_kpa, d.max_p_hat_rel_diff, d.frames_compared
        );
    }
}

/// The force error of the bare and the augmented board during the pushes.
fn md_force(s: &mut String, r: &DemoReport) {
    let _ = writeln!(s, "\n## Force estimate\n");
    match &r.force {
        Some(f) => {
            let _ = writeln!(
                s,
                "During the pushes ({} frames, mean true force {:.1} mN): error mean **{:+.1} mN**, std **{:.1} mN**, \
                 RMSE **{:.1} mN** (paper, Sec. IV-C: 1.60 mN mean, 7.50 mN std).",
                f.frames, f.mean_true_mn, f.mean_error_mn, f.std_error_mn, f.rmse_mn
            );
            if let Some(b) = f.predicted_bias_mn {
                let _ = writeln!(
                    s,
                    "\nThe deployed polynomial cannot carry hysteresis (no state on the device). At rest on the \
                     inflation branch the residual loop's hysteresis amplitude predicts a bias of 3 × 22 mm² × \
                     amplitude = {b:.1} mN; the measured mean error is {:+.1} mN.",
                    f.mean_error_mn
                );
            }
        }
        None => {
            let _ = writeln!(s, "No frames in the push window.");
        }
    }
    if let Some(f) = &r.force_augmented {
        let _ = writeln!(
            s,
            "\nThe same pushes on a board running the augmented models (`vfp export --augmented`'s lines; effects carried: {}): \
             error mean **{:+.1} mN**, std **{:.1} mN**, RMSE **{:.1} mN** over {} frames{}.",
            effects_summary(&r.augmented),
            f.mean_error_mn,
            f.std_error_mn,
            f.rmse_mn,
            f.frames,
            r.force.as_ref().map_or(String::new(), |b| format!(
                " (bare polynomials: {:+.1} mN mean, {:.1} mN std)",
                b.mean_error_mn, b.std_error_mn
            ))
        );
    }
}

/// The figures with their captions, and the files beside the report.
fn md_figures(s: &mut String, figures: &[(String, String)]) {
    let _ = writeln!(s, "\n## Figures\n");
    for (f, cap) in figures {
        let _ = writeln!(s, "### {cap}\n\n![{cap}]({f})\n");
    }
    let _ = writeln!(
        s,
        "Files: `telemetry.txt` (capture as printed by probe-rs), `identification.csv` (the recorded log), \
         `report.json` (every number above)."
    );
}
