//! `vfp bench-loop`: the residual loop judged on random rigs of the simulated rig.
//!
//! Each rig is drawn from the seed (`host_sim::rigs`: effects at sizes from below detectability to
//! three times host-sim's presets, none on about a fifth of the rigs, up to three together; the
//! paper's protocol, irregular strokes, moves with dwells or breathing; SBA1–SBA3; noise of
//! several levels and kinds; 5,000–20,000 frames), run by the firmware's own tasks on host-sim's
//! plant, written as a log and read back as `vfp diagnose` reads it, then diagnosed as `vfp
//! diagnose LOG` diagnoses it (chamber 0, the baseline shape selected, the default test). The rigs
//! run one after another, so the process CPU time around each diagnosis is that rig's.
//!
//! # The oracle of an effect's size
//! Independent of the loop: the rig is simulated again without the effect (same trajectory, same
//! noise seed), and the difference of the sensor output before its noise (`sensed_kpa` plus the
//! thermal drift, chamber 0's truth per frame) is the effect's exact contribution `d` given the
//! others. Two figures come from it: its RMS over the held-out frames (mean removed) over σ, and
//! its **held-out gain as a known regressor**: the chamber law's polynomial shape (n = 3, m = 2:
//! host-sim's law, so the loop's own shape selection plays no part) plus
//! every planted effect's `d` as columns (and, with two effects or more, their interaction: the
//! rig's output minus the clean rig's minus every `d`, from one more run without any effect, so
//! the columns hold the whole departure from the law), fitted on the training frames, against the
//! same without this effect's `d`, 1 − RMSE(with)/RMSE(without) on the held-out frames. The gain is what
//! recall is binned by: it measures what the effect adds beyond what the polynomial absorbs (a
//! leak's pressure-proportional loss is largely a change of stiffness, an offset drift's mean an
//! offset), on the same split and by the same measure (held-out RMSE) the loop's `--min-gain` uses.
//! σ is the noise of the logged pressure: the standard deviation over the held-out frames of the
//! logged pressure minus the sensor output before noise.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use host_sim::rigs::{self, FormChoice, Planted, PlantedKind, RigOptions, RigSpec};
use host_sim::{simulate, SimRun};
use nalgebra::DMatrix;
use sysid::residual::{diagnose_log, Config, Diagnosis, PolyBasis, Timings};

use crate::loop_bench::{
    markdown, summarise, Gate, NamedResult, ParamCompare, PlantedResult, RigResult,
};
use crate::opts::DataOpts;
use crate::Error;

/// Arguments of `vfp bench-loop`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Number of rigs (rig i of a seed is the same whatever the number).
    #[arg(long, default_value_t = 20, conflicts_with = "gate")]
    pub rigs: usize,
    /// Seed of the rigs.
    #[arg(long, default_value_t = 1, conflicts_with = "gate")]
    pub seed: u64,
    /// Range of the logs' lengths, frames per chamber, as LOW,HIGH (drawn log-uniformly).
    #[arg(long, value_name = "LOW,HIGH", value_delimiter = ',',
          default_values_t = [5_000usize, 20_000], conflicts_with = "gate")]
    pub samples: Vec<usize>,
    /// Write the results (every rig and the summary) as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write the markdown report to FILE too (it is always printed on stdout).
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
    /// Run the CI gate's subset (rigs, seed, lengths and thresholds from FILE, e.g.
    /// bench/loop-gate.toml) and fail when a threshold is missed. CPU is reported, never gated.
    #[arg(long, value_name = "FILE")]
    pub gate: Option<PathBuf>,
    /// Keep each rig's log in DIR (default: a temporary file, removed after the rig).
    #[arg(long, value_name = "DIR")]
    pub keep_logs: Option<PathBuf>,
    /// The planted effects' forms: `usual` (those the loop's effects were written against),
    /// `other` (host-sim's other form of each kind that has one: polytropic air, linear
    /// hysteresis, second-order sensor lag, ripple with a second harmonic, orifice leak, ramp
    /// drift, slowing creep, overdamped delivery lag) or `mixed` (each effect either, at even
    /// odds). Parameters are compared with the truth on usual forms only.
    #[arg(long, default_value = "usual", value_parser = clap::builder::PossibleValuesParser::new(FormChoice::ALL.map(FormChoice::name)),
          conflicts_with = "gate")]
    pub forms: String,
    /// Run only these rigs of the `--rigs` drawn (indices from 0, as LIST of I,J,..): one rig or
    /// a few looked at again, each the same as in the whole run.
    #[arg(
        long,
        value_name = "LIST",
        value_delimiter = ',',
        conflicts_with = "gate"
    )]
    pub only: Vec<usize>,
    /// Diagnose with the baseline's shape chosen again with the effects (`vfp diagnose
    /// --reshape`; off by default, as in `vfp diagnose`).
    #[arg(long)]
    pub reshape: bool,
}

/// The polynomial shape of the oracle's fits: host-sim's chamber law (`host_sim::law`, the paper's
/// n = 3, m = 2 for every design).
const ORACLE_SHAPE: (usize, usize) = (3, 2);

/// The loop's name for a planted kind.
pub fn expected_name(kind: PlantedKind) -> &'static str {
    match kind {
        PlantedKind::Air => "air_compliance",
        PlantedKind::Hysteresis => "hysteresis",
        PlantedKind::SensorLag => "sensor_lag",
        PlantedKind::Inertance => "inertance",
        PlantedKind::ThermalDrift => "offset_drift",
        PlantedKind::Backlash => "backlash",
        PlantedKind::Ripple => "pump_ripple",
        PlantedKind::Leak => "leak",
        PlantedKind::TransportDelay => "transport_delay",
        PlantedKind::VolumeCreep => "volume_drift",
        PlantedKind::DeliveryLag => "delivery_lag",
    }
}

/// The plant's parameters that mean the same as one of the loop's, as (loop parameter, value in
/// its unit). `span_s`: the dataset's first and last frame times (the drift's change over the log).
/// The hysteresis's gap is 2·H_a (inflation minus deflation); the plant's transition v_h and the
/// loop's width are both the volume of 63 % of the switch; the delivery lag's time constant is
/// τ_d of the same critically damped second-order lag; the offset drift's change over the log is
/// D·(e^(−t₀/τ_D) − e^(−t₁/τ_D)). Inertance, air, backlash, delays, creep and the ripple's
/// amplitude and period are the same quantities in the same units.
///
/// The leak is compared on the water it lost over the log (`leaked_mm3`: the plant's leaked
/// volume between the log's first and last frames; the loop's `volume_lost_over_log`, λ·∫P dt),
/// not on its conductance: the plant's G acts on the positive pressure only (`G·max(P, 0)`, no
/// water drawn back in under suction), the loop's λ on the signed measured pressure in its open
/// form and on the positive one in its one-way form (`Effect::one_way`), the form the loop
/// chooses by its fit; the benchmark's logs reach −15 kPa in fast deflations, so an open path's
/// λ that fits is about G·∫max(P, 0) dt / ∫P dt (1.13–1.15 on rigs 24, 44 and 52 of seed 1):
/// two conductances of different forms, one volume.
pub fn truth_params(p: &Planted, span_s: (f64, f64), leaked_mm3: f64) -> Vec<(&'static str, f64)> {
    match p.kind {
        PlantedKind::Air => vec![("air_volume_at_atmospheric_pressure", p.size)],
        PlantedKind::Hysteresis => vec![("gap_at_mid_volume", 2.0 * p.size), ("width", p.shape)],
        PlantedKind::SensorLag => vec![("time_constant", p.size)],
        PlantedKind::Inertance => vec![("inertance", p.size)],
        PlantedKind::ThermalDrift => {
            let (a, b) = span_s;
            let change = p.size * ((-a / p.shape).exp() - (-b / p.shape).exp());
            vec![("change_over_log", change)]
        }
        PlantedKind::Backlash => vec![("play", p.size)],
        PlantedKind::Ripple => vec![("amplitude", p.size), ("period", p.shape)],
        PlantedKind::Leak => vec![("volume_lost_over_log", leaked_mm3)],
        PlantedKind::TransportDelay => vec![("delay", p.size)],
        PlantedKind::VolumeCreep => vec![("rate", p.size)],
        PlantedKind::DeliveryLag => vec![("time_constant", p.size)],
    }
}

/// CPU seconds (user + system) of this process so far, every thread.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn process_cpu_s() -> Option<f64> {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::uninit();
    // SAFETY: getrusage writes one `rusage` into the pointer it is given and reads nothing else.
    let rc = unsafe { libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr()) };
    if rc != 0 {
        return None;
    }
    // SAFETY: a return of 0 means the structure was filled.
    let u = unsafe { u.assume_init() };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Some(tv(u.ru_utime) + tv(u.ru_stime))
}

/// CPU seconds of this process: not measured on this platform.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn process_cpu_s() -> Option<f64> {
    None
}

/// The sensor output before its noise (what the sensor element saw plus the offset's thermal
/// drift), chamber 0, one value per frame.
fn sensor_output(run: &SimRun) -> Vec<f64> {
    let drift = run.scenario.plant.effects.thermal_drift;
    run.truth
        .iter()
        .map(|f| {
            let t = f.t_us as f64 * 1e-6;
            let d = drift.map_or(0.0, |d| {
                d.offset_change_kpa * (1.0 - (-t / d.time_constant_s).exp())
            });
            f.chambers[0].sensed_kpa + d
        })
        .collect()
}

/// Mean-removed RMS of `x` over `rows`.
fn rms_about_mean(x: &[f64], rows: &[usize]) -> f64 {
    let n = rows.len().max(1) as f64;
    let mean = rows.iter().map(|&k| x[k]).sum::<f64>() / n;
    (rows.iter().map(|&k| (x[k] - mean).powi(2)).sum::<f64>() / n).sqrt()
}

/// Held-out RMSE of `cols` fitted to `y` on the training rows.
fn heldout_rmse(cols: &[&[f64]], y: &[f64], train: &[usize], test: &[usize]) -> Option<f64> {
    let x = DMatrix::from_fn(train.len(), cols.len(), |i, j| cols[j][train[i]]);
    let yt: Vec<f64> = train.iter().map(|&k| y[k]).collect();
    let names: Vec<String> = (0..cols.len()).map(|j| format!("column {j}")).collect();
    let fit = sysid::linreg::lstsq(x, &yt, &names).ok()?;
    let sse: f64 = test
        .iter()
        .map(|&k| {
            let pred: f64 = cols.iter().zip(&fit.coef).map(|(c, b)| c[k] * b).sum();
            (y[k] - pred).powi(2)
        })
        .sum();
    Some((sse / test.len().max(1) as f64).sqrt())
}

/// The columns of a dataset the oracle fits.
struct Rows<'a> {
    v: &'a [f64],
    vdot: &'a [f64],
    p: &'a [f64],
    heldout: &'a [bool],
}

/// The oracle's figures for each planted effect: (RMS over σ, held-out gain), from the
/// differences `diffs` (one per planted effect, per dataset row).
/// The held-out RMSE of the complete oracle model (`extra`: the interaction column, never scored)
/// comes first, then each effect's (RMS/σ, gain).
fn oracle(
    ds: &Rows<'_>,
    shape: (usize, usize),
    diffs: &[Vec<f64>],
    extra: Option<&[f64]>,
    sigma: f64,
) -> Result<(f64, Vec<(f64, f64)>), String> {
    let train: Vec<usize> = (0..ds.p.len()).filter(|&k| !ds.heldout[k]).collect();
    let test: Vec<usize> = (0..ds.p.len()).filter(|&k| ds.heldout[k]).collect();
    let basis = PolyBasis::for_data(ds.v, ds.vdot, shape.0, shape.1)
        .map_err(|e| format!("oracle basis: {e}"))?;
    let poly = basis.columns(ds.v, ds.vdot);
    let with_all: Vec<&[f64]> = poly
        .iter()
        .chain(diffs)
        .map(Vec::as_slice)
        .chain(extra)
        .collect();
    let all = heldout_rmse(&with_all, ds.p, &train, &test);
    let sizes = diffs
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let cols: Vec<&[f64]> = poly
                .iter()
                .chain(
                    diffs
                        .iter()
                        .enumerate()
                        .filter(|(j, _)| *j != i)
                        .map(|x| x.1),
                )
                .map(Vec::as_slice)
                .chain(extra)
                .collect();
            let without = heldout_rmse(&cols, ds.p, &train, &test);
            let gain = match (all, without) {
                (Some(a), Some(w)) if w > 0.0 => 1.0 - a / w,
                _ => f64::NAN,
            };
            (rms_about_mean(d, &test) / sigma, gain)
        })
        .collect();
    Ok((all.unwrap_or(f64::NAN), sizes))
}

fn stages(t: &Timings) -> BTreeMap<String, f64> {
    t.stages()
        .into_iter()
        .chain([("total", t.total)])
        .map(|(k, v)| (k.to_string(), v))
        .collect()
}

/// Simulates, diagnoses and scores one rig; an `Err` is the reason the rig cannot be scored.
fn run_rig(
    spec: &RigSpec,
    keep: Option<&Path>,
    reshape: bool,
    result: &mut RigResult,
) -> Result<(), String> {
    let sim = simulate(&spec.scenario()).map_err(|e| format!("simulation: {e}"))?;
    if let Some(f) = sim.first_event("fault") {
        return Err(format!("the firmware latched a fault: {f:?}"));
    }
    let name = format!("bench-loop-{}-{}.csv", spec.seed, spec.index);
    let path = match keep {
        Some(dir) => dir.join(&name),
        None => std::env::temp_dir().join(format!("{}-{name}", std::process::id())),
    };
    let write = || -> std::io::Result<()> {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&path)?);
        sim.write_log(&mut w)?;
        std::io::Write::flush(&mut w)
    };
    write().map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let data = DataOpts::default().load(&path, Some(0));
    if keep.is_none() {
        let _ = std::fs::remove_file(&path);
    }
    let mut data = data.map_err(|e| format!("reading the log back: {e}"))?;
    data.datasets.truncate(1);
    // `vfp diagnose LOG`'s configuration: its defaults, the shape selected.
    let cfg = Config {
        reshape,
        ..Config::default()
    };
    let cpu0 = process_cpu_s();
    let d: Diagnosis = diagnose_log(&data, &cfg, false).map_err(|e| format!("diagnosis: {e}"))?;
    let cpu1 = process_cpu_s();
    result.cpu_s = cpu0.zip(cpu1).map(|(a, b)| b - a);
    result.stages_s = stages(&d.timing);
    result.baseline_rmse_kpa = d.baseline.rmse_heldout;
    result.baseline_shape = (d.baseline.n, d.baseline.m);
    result.final_rmse_kpa = d.final_model.rmse_heldout;
    result.named = d
        .effects
        .iter()
        .map(|e| NamedResult {
            name: e.name.to_string(),
            params: e.params.iter().map(|p| (p.name.clone(), p.value)).collect(),
            reaches_absent: e.kind.presence().is_some_and(|name| {
                e.params
                    .iter()
                    .find(|p| p.name == name)
                    .and_then(|p| p.ci95)
                    .is_some_and(|[lo, hi]| lo <= 0.0 && 0.0 <= hi)
            }),
            alternatives: e
                .alternatives
                .iter()
                .map(|a| a.effect.split(" + ").map(str::to_string).collect())
                .collect(),
        })
        .collect();

    let ds = data.first();
    result.samples = ds.t.len();
    let skip = ds.not_zeroed;
    if ds.t.len() + skip != sim.truth.len() {
        return Err(format!(
            "the log's {} rows and {} zeroing frames do not line up with the simulator's {} frames",
            ds.t.len(),
            skip,
            sim.truth.len()
        ));
    }
    let out_all = sensor_output(&sim);
    let test: Vec<usize> = (0..ds.t.len()).filter(|&k| ds.heldout[k]).collect();
    let noise: Vec<f64> = (0..ds.t.len())
        .map(|k| ds.p[k] - out_all[k + skip])
        .collect();
    let sigma = rms_about_mean(&noise, &test);
    result.sigma_kpa = sigma;

    let mut diffs = Vec::with_capacity(spec.planted.len());
    for p in &spec.planted {
        let without = simulate(&spec.scenario_without(Some(p.kind)))
            .map_err(|e| format!("simulation without {}: {e}", p.kind.name()))?;
        let out = sensor_output(&without);
        if out.len() != out_all.len() {
            return Err(format!(
                "the run without {} has {} frames, the rig {}",
                p.kind.name(),
                out.len(),
                out_all.len()
            ));
        }
        diffs.push(
            (0..ds.t.len())
                .map(|k| out_all[k + skip] - out[k + skip])
                .collect::<Vec<f64>>(),
        );
    }
    // Two effects or more: what they do together beyond the sum of each one's part.
    let interaction = if spec.planted.len() >= 2 {
        let clean = simulate(&spec.scenario_with(|_| false))
            .map_err(|e| format!("simulation without any effect: {e}"))?;
        let out = sensor_output(&clean);
        if out.len() != out_all.len() {
            return Err(format!(
                "the run without any effect has {} frames, the rig {}",
                out.len(),
                out_all.len()
            ));
        }
        Some(
            (0..ds.t.len())
                .map(|k| {
                    out_all[k + skip] - out[k + skip] - diffs.iter().map(|d| d[k]).sum::<f64>()
                })
                .collect::<Vec<f64>>(),
        )
    } else {
        None
    };
    let rows = Rows {
        v: &ds.v,
        vdot: &ds.vdot,
        p: &ds.p,
        heldout: &ds.heldout,
    };
    let (complete, sizes) = oracle(&rows, ORACLE_SHAPE, &diffs, interaction.as_deref(), sigma)?;
    result.oracle_rmse_kpa = complete;
    let span = (ds.t[0], ds.t[ds.t.len() - 1]);
    let leaked_at = |k: usize| sim.truth[k + skip].chambers[0].leaked_mm3;
    let leaked = leaked_at(ds.t.len() - 1) - leaked_at(0);
    result.planted = spec
        .planted
        .iter()
        .zip(sizes)
        .map(|(p, (rms, gain))| {
            let expects = expected_name(p.kind);
            let named = d.effects.iter().find(|e| e.name == expects);
            PlantedResult {
                kind: p.kind.name().into(),
                expects: expects.into(),
                size: p.size,
                relative_size: p.relative_size(),
                oracle_rms_sigma: rms,
                oracle_gain: gain,
                found: named.is_some(),
                other_form: p.other_form,
                // The other forms' parameters do not all mean the loop's.
                params: (if p.other_form {
                    Vec::new()
                } else {
                    truth_params(p, span, leaked)
                })
                .into_iter()
                .map(|(name, truth)| ParamCompare {
                    name: name.into(),
                    truth,
                    named: named
                        .and_then(|e| e.params.iter().find(|q| q.name == name).map(|q| q.value)),
                    ci95: named.and_then(|e| {
                        e.params
                            .iter()
                            .find(|q| q.name == name)
                            .and_then(|q| q.ci95)
                    }),
                })
                .collect(),
            }
        })
        .collect();
    Ok(())
}

fn write_file(path: &Path, text: &str) -> Result<(), Error> {
    std::fs::write(path, text).map_err(|e| Error::output(path, e))
}

/// Writes `--json` and `--markdown` for `results`; returns the summary and the markdown.
fn write_outputs(
    args: &Args,
    command: &str,
    seed: u64,
    samples: (usize, usize),
    results: &[RigResult],
) -> Result<(crate::loop_bench::Summary, String), Error> {
    let summary = summarise(results);
    let md = markdown(command, &summary, results);
    if let Some(p) = &args.markdown {
        write_file(p, &md)?;
    }
    if let Some(p) = &args.json {
        let doc = serde_json::json!({
            "command": command,
            "seed": seed,
            "samples": [samples.0, samples.1],
            "summary": summary,
            "rigs": results,
        });
        let text = serde_json::to_string_pretty(&doc).map_err(|e| Error::Msg(e.to_string()))?;
        write_file(p, &text)?;
    }
    Ok((summary, md))
}

/// Runs `vfp bench-loop`.
pub fn run(args: &Args) -> Result<(), Error> {
    let gate: Option<Gate> = match &args.gate {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| Error::Msg(format!("cannot read {}: {e}", path.display())))?;
            Some(
                toml::from_str(&text)
                    .map_err(|e| Error::Msg(format!("gate file {}: {e}", path.display())))?,
            )
        }
        None => None,
    };
    let (n, seed, samples) = match (&gate, &args.samples[..]) {
        (Some(g), _) => (g.rigs, g.seed, (g.samples[0], g.samples[1])),
        (None, &[lo, hi]) => (args.rigs, args.seed, (lo, hi)),
        (None, other) => {
            return Err(Error::Usage(format!(
                "--samples expects LOW,HIGH (two numbers of frames), got {} numbers",
                other.len()
            )))
        }
    };
    if n == 0 {
        return Err(Error::Usage("--rigs must be at least 1".into()));
    }
    let forms = FormChoice::ALL
        .into_iter()
        .find(|f| f.name() == args.forms)
        .unwrap_or_default();
    let opts = RigOptions { samples, forms };
    if let Some(dir) = &args.keep_logs {
        std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    }
    let command = match &args.gate {
        Some(g) => format!("vfp bench-loop --gate {}", g.display()),
        None => format!(
            "vfp bench-loop --rigs {n} --seed {seed} --samples {},{}{}{}{}",
            samples.0,
            samples.1,
            if args.reshape { " --reshape" } else { "" },
            if forms == FormChoice::Usual {
                String::new()
            } else {
                format!(" --forms {}", forms.name())
            },
            if args.only.is_empty() {
                String::new()
            } else {
                let list: Vec<String> = args.only.iter().map(|i| i.to_string()).collect();
                format!(" --only {}", list.join(","))
            }
        ),
    };
    let mut results = Vec::with_capacity(n);
    let indices: Vec<usize> = (0..n)
        .filter(|i| args.only.is_empty() || args.only.contains(i))
        .collect();
    for (at, &i) in indices.iter().enumerate() {
        let spec = rigs::draw(seed, i, &opts).map_err(|e| Error::Usage(format!("--{e}")))?;
        let mut r = RigResult {
            index: i,
            label: spec.label(),
            ..RigResult::default()
        };
        if let Err(e) = run_rig(&spec, args.keep_logs.as_deref(), args.reshape, &mut r) {
            r.error = Some(e);
        }
        // One line per rig even into a file (a long run's log); `--quiet` silences it.
        if !crate::progress::quiet() {
            eprintln!("{}", progress_line(&r, n));
        }
        results.push(r);
        // The files hold the rigs so far after each one: a long run stopped early keeps them.
        if at + 1 < indices.len() {
            write_outputs(args, &command, seed, samples, &results)?;
        }
    }
    let (summary, md) = write_outputs(args, &command, seed, samples, &results)?;
    print!("{md}");
    if let Some(g) = &gate {
        let missed = g.check(&summary);
        if !missed.is_empty() {
            return Err(Error::Msg(format!(
                "loop benchmark gate failed: {}",
                missed.join("; ")
            )));
        }
        eprintln!("loop benchmark gate passed");
    }
    Ok(())
}

fn progress_line(r: &RigResult, n: usize) -> String {
    if let Some(e) = &r.error {
        return format!("[{}/{n}] {}: failed: {e}", r.index + 1, r.label);
    }
    let planted: Vec<String> = r
        .planted
        .iter()
        .map(|p| format!("{}{}", if p.found { "" } else { "✗" }, p.kind))
        .collect();
    let named: Vec<String> = r.named.iter().map(NamedResult::label).collect();
    format!(
        "[{}/{n}] {}: planted [{}], named [{}], {:.3} σ, {} CPU s",
        r.index + 1,
        r.label,
        planted.join(", "),
        named.join(", "),
        r.final_over_sigma(),
        r.cpu_s.map_or("–".into(), |c| format!("{c:.2}"))
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_planted_kind_maps_to_a_loop_effect_with_its_parameters() {
        let names: Vec<&str> = sysid::residual::REGISTRY.iter().map(|k| k.name()).collect();
        for kind in PlantedKind::ALL {
            let e = expected_name(kind);
            assert!(
                names.contains(&e),
                "{e} is not in the loop's registry {names:?}"
            );
            let p = Planted {
                kind,
                size: kind.preset_size(),
                shape: 20.0,
                other_form: false,
            };
            assert!(!truth_params(&p, (0.0, 600.0), 5.0).is_empty());
        }
    }

    #[test]
    fn the_oracle_gain_of_a_known_column_by_hand() {
        // p = 1 + v + d + noise-free: with d as a column the fit is exact (gain 1); d orthogonal
        // to the polynomial, so without it the residual is d itself.
        let n = 200;
        let v: Vec<f64> = (0..n).map(|k| (k % 20) as f64).collect();
        let vdot: Vec<f64> = (0..n)
            .map(|k| if k % 40 < 20 { 1.0 } else { -1.0 })
            .collect();
        let d: Vec<f64> = (0..n).map(|k| (0.7 * k as f64).sin()).collect();
        let p: Vec<f64> = (0..n).map(|k| 1.0 + v[k] + d[k]).collect();
        let heldout: Vec<bool> = (0..n).map(|k| k % 5 == 0).collect();
        let rows = Rows {
            v: &v,
            vdot: &vdot,
            p: &p,
            heldout: &heldout,
        };
        let (complete, r) = oracle(&rows, (1, 1), &[d], None, 0.5).unwrap();
        assert!(
            complete < 1e-9,
            "the complete model is exact, RMSE {complete}"
        );
        assert!((r[0].1 - 1.0).abs() < 1e-6, "gain {}", r[0].1);
        // RMS of sin over the held-out rows ≈ 1/√2, over σ = 0.5.
        assert!(
            (r[0].0 - 2.0 / 2f64.sqrt()).abs() < 0.15,
            "rms/σ {}",
            r[0].0
        );
    }
}
