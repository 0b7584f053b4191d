//! `vfp._native`: the extension module under the `vfp` Python package (python/vfp/). Each
//! function reads its log through the `sysid` library's one path from a log to datasets
//! ([`LogData::from_log`]), runs the same library call as the `vfp` command, and returns the
//! command's `--json` document as JSON text (the Python layer parses it with `json.loads`, so the
//! numbers are the very f64 the command prints). The interpreter is released (`Python::detach`)
//! while the library works. Every library error becomes a `ValueError` carrying the command's
//! message (file, line, column).

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sysid::columns::{ColumnMap, ReadOptions};
use sysid::dataset::{DatasetConfig, LogData};
use sysid::identify::{Document, Family, Options};
use sysid::log::{self, Log, TableColumn};
use sysid::metrics::CostWeights;
use sysid::residual::{self, EffectKind};

/// A library error as the `ValueError` the Python caller sees (the command's message).
fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The JSON text of a report (non-finite numbers become `null`, as in the command's output).
fn json(value: &impl serde::Serialize) -> PyResult<String> {
    serde_json::to_string(value).map_err(value_error)
}

/// A log as the Python layer hands it over: a path, or a table of named columns (float64 bytes
/// in native order, or text cells) with the name that stands for the file in messages.
#[derive(FromPyObject)]
enum Source {
    Path(std::path::PathBuf),
    Table(String, Vec<(String, Column)>),
}

#[derive(FromPyObject)]
enum Column {
    Numbers(Vec<u8>),
    Text(Vec<String>),
}

/// How a log becomes datasets (the command's data options).
#[derive(FromPyObject)]
struct DataOptions {
    columns: Option<String>,
    chamber_base: u8,
    holdout_every: usize,
    derive_flow: bool,
    diff_half_width: usize,
    deadband: Option<f64>,
}

impl DataOptions {
    fn read_options(&self) -> PyResult<ReadOptions> {
        let columns = match &self.columns {
            Some(spec) => spec.parse::<ColumnMap>().map_err(value_error)?,
            None => ColumnMap::default(),
        };
        if self.chamber_base > 1 {
            return Err(value_error(format!(
                "chamber_base {}: 0 or 1",
                self.chamber_base
            )));
        }
        Ok(ReadOptions {
            columns,
            chamber_base: self.chamber_base,
        })
    }

    fn config(&self) -> DatasetConfig {
        DatasetConfig {
            diff_half_width: self.diff_half_width.max(1),
            derive_flow: self.derive_flow,
            holdout_every: self.holdout_every,
            deadband: self.deadband,
            ..DatasetConfig::default()
        }
    }
}

/// Reads the log of `source` (the file reader, or [`log::log_from_table`] for a table).
fn read(source: Source, opts: &ReadOptions) -> Result<(std::path::PathBuf, Log), log::LogError> {
    match source {
        Source::Path(path) => {
            let log = log::read_log_with(&path, opts)?;
            Ok((path, log))
        }
        Source::Table(name, columns) => {
            let columns: Vec<(String, TableColumn)> = columns
                .into_iter()
                .map(|(n, c)| {
                    let c = match c {
                        Column::Numbers(bytes) => TableColumn::Numbers(
                            bytes
                                .chunks_exact(8)
                                .map(|b| f64::from_ne_bytes(b.try_into().unwrap_or([0; 8])))
                                .collect(),
                        ),
                        Column::Text(cells) => TableColumn::Text(cells),
                    };
                    (n, c)
                })
                .collect();
            let log = log::log_from_table(&name, &columns, opts)?;
            Ok((name.into(), log))
        }
    }
}

/// The datasets of `chamber` (every chamber when `None`) of a log: [`LogData::from_log`].
fn load(source: Source, data: &DataOptions, chamber: Option<u8>) -> PyResult<LogData> {
    let opts = data.read_options()?;
    let (path, log) = read(source, &opts).map_err(value_error)?;
    LogData::from_log(&path, log, chamber, &data.config()).map_err(value_error)
}

/// One column of a log for the Python layer: float64 bytes or text cells.
type OutColumn = (String, Option<Vec<u8>>, Option<Vec<String>>);

fn numbers(name: &str, x: impl Iterator<Item = f64>) -> OutColumn {
    let bytes = x.flat_map(f64::to_ne_bytes).collect();
    (name.to_string(), Some(bytes), None)
}

/// A log's columns in the format's names and units (absent optional values NaN), extra columns
/// as text; the comment lines.
fn columns_of(log: &Log) -> (Vec<OutColumn>, Vec<String>) {
    let s = &log.samples;
    let mut out = vec![
        numbers("time_s", s.iter().map(|r| r.time_s)),
        numbers("chamber", s.iter().map(|r| f64::from(r.chamber))),
        numbers("volume_mm3", s.iter().map(|r| r.volume_mm3)),
    ];
    if s.iter().any(|r| r.flow_mm3_s.is_some()) {
        out.push(numbers(
            "flow_mm3_s",
            s.iter().map(|r| r.flow_mm3_s.unwrap_or(f64::NAN)),
        ));
    }
    out.push(numbers("pressure_kpa", s.iter().map(|r| r.pressure_kpa)));
    if s.iter().any(|r| r.force_n.is_some()) {
        out.push(numbers(
            "force_n",
            s.iter().map(|r| r.force_n.unwrap_or(f64::NAN)),
        ));
    }
    for (k, name) in log.extra_columns.iter().enumerate() {
        let cells = log.extra.iter().map(|row| row[k].clone()).collect();
        out.push((name.clone(), None, Some(cells)));
    }
    (out, log.comments.clone())
}

/// `read_log`: the log's columns and comments.
#[pyfunction]
fn read_log(
    py: Python<'_>,
    source: Source,
    data: DataOptions,
) -> PyResult<(Vec<OutColumn>, Vec<String>)> {
    let opts = data.read_options()?;
    let log = py
        .detach(|| read(source, &opts).map(|(_, log)| log))
        .map_err(value_error)?;
    Ok(columns_of(&log))
}

/// `identify`: the `vfp identify --json` document.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn identify(
    py: Python<'_>,
    source: Source,
    data: DataOptions,
    chamber: Option<u8>,
    families: Option<Vec<String>>,
    weights: (f64, f64, f64),
    max_n: usize,
    max_m: usize,
    prune: usize,
) -> PyResult<String> {
    let families = match families {
        None => Family::ALL.to_vec(),
        Some(names) => names
            .iter()
            .map(|n| {
                Family::ALL
                    .into_iter()
                    .find(|f| f.name() == n)
                    .ok_or_else(|| {
                        let all: Vec<&str> = Family::ALL.iter().map(|f| f.name()).collect();
                        value_error(format!("family `{n}`: one of {}", all.join(", ")))
                    })
            })
            .collect::<PyResult<_>>()?,
    };
    let options = Options {
        families,
        weights: CostWeights {
            w_rmse: weights.0,
            w_r2: weights.1,
            w_aicc: weights.2,
        },
        max_n,
        max_m,
        prune_k: prune,
        progress: None,
        ..Options::default()
    };
    py.detach(|| {
        let data = load(source, &data, chamber)?;
        let reports: Vec<_> = data
            .datasets
            .iter()
            .map(|ds| sysid::identify::identify(ds, &options))
            .collect();
        json(&Document::new(data.name(), options.weights, &reports))
    })
}

/// The held-out points of a residual analysis (time s, volume mm³, flow mm³/s, residual kPa per
/// row) as float64 bytes, row-major.
fn points(a: &residual::ResidualAnalysis) -> Vec<u8> {
    a.points
        .iter()
        .flatten()
        .flat_map(|x| x.to_ne_bytes())
        .collect()
}

/// `diagnose`: the `vfp diagnose --json` document and the residual points before and after.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn diagnose(
    py: Python<'_>,
    source: Source,
    data: DataOptions,
    chamber: Option<u8>,
    model: Option<(usize, usize)>,
    alpha: f64,
    min_gain: f64,
    effects: Option<Vec<String>>,
    validate: Option<Source>,
) -> PyResult<(String, Vec<u8>, Vec<u8>)> {
    let mut cfg = residual::Config {
        alpha,
        min_gain,
        ..residual::Config::default()
    };
    if let Some((n, m)) = model {
        (cfg.n, cfg.m) = (n, m);
    }
    if let Some(names) = effects {
        cfg.candidates = names
            .iter()
            .map(|n| {
                EffectKind::named(&n.replace('-', "_")).ok_or_else(|| {
                    let all: Vec<String> = residual::REGISTRY
                        .iter()
                        .map(|e| e.name().replace('_', "-"))
                        .collect();
                    value_error(format!("effect `{n}`: one of {}", all.join(", ")))
                })
            })
            .collect::<PyResult<_>>()?;
    }
    py.detach(|| {
        let log = load(source, &data, chamber)?;
        let d = residual::diagnose_log(&log, &cfg, model.is_some()).map_err(value_error)?;
        let mut doc = residual::document(&log, &d);
        if let Some(other) = validate {
            let other = load(other, &data, Some(log.first().chamber))?;
            let v = residual::validate::validate_log(&d, &other).map_err(value_error)?;
            if let Some(obj) = doc.as_object_mut() {
                obj.insert(
                    "validation".into(),
                    serde_json::to_value(&v).map_err(value_error)?,
                );
            }
        }
        let doc = json(&doc)?;
        Ok((doc, points(&d.analysis_before), points(&d.analysis_after)))
    })
}

/// `force`: the `vfp force --json` report (`augmented`: `vfp force --augmented --json`).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn force(
    py: Python<'_>,
    ident: Source,
    test: Source,
    data: DataOptions,
    shape: (usize, usize),
    area: Vec<f64>,
    smooth: usize,
    augmented: bool,
) -> PyResult<String> {
    let o = sysid::diag::force::ForceOptions {
        shape: sysid::diag::Shape {
            n: shape.0,
            m: shape.1,
        },
        area,
        smooth,
    };
    o.shape.validate().map_err(value_error)?;
    py.detach(|| {
        let ident = load(ident, &data, None)?;
        let test = load(test, &data, None)?;
        if augmented {
            // The residual loop as `vfp force --augmented` runs it: `vfp diagnose`'s settings,
            // baseline (n, m).
            let cfg = sysid::residual::Config {
                n: o.shape.n,
                m: o.shape.m,
                ..sysid::residual::Config::default()
            };
            let (report, _) = sysid::board::force::estimate_augmented(&ident, &test, &o, &cfg)
                .map_err(value_error)?;
            return json(&report);
        }
        let (report, _) = sysid::diag::force::estimate(&ident, &test, &o).map_err(value_error)?;
        json(&report)
    })
}

/// `export`: per chamber the f32 warning, the command lines and the Rust constants.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn export(
    py: Python<'_>,
    source: Source,
    data: DataOptions,
    chamber: Option<u8>,
    shape: (Option<usize>, Option<usize>),
    p: usize,
    all_samples: bool,
) -> PyResult<Vec<(u8, Option<String>, Vec<String>, String)>> {
    py.detach(|| {
        let data = load(source, &data, chamber)?;
        let out = sysid::board::export::export_log(&data, shape.0, shape.1, p, all_samples)
            .map_err(value_error)?;
        Ok(out
            .into_iter()
            .map(|e| (e.chamber, e.warning, e.lines, e.rust))
            .collect())
    })
}

/// `replay`: `vfp replay MODEL LOG --json`'s summary and every frame as columns (the columns of
/// `vfp replay -o`: `time_s`, per chamber `p_i`, `p_hat_i`, `residual_i`, `load_i`, `k_i`,
/// `c_i`, then `force_n` and `force_ref_n`; the board's f32 values widened to f64).
#[pyfunction]
fn replay(
    py: Python<'_>,
    model: String,
    model_name: String,
    source: Source,
    data: DataOptions,
) -> PyResult<(String, Vec<OutColumn>)> {
    py.detach(|| {
        let uploads =
            sysid::board::deploy::parse_lines(&model, &model_name).map_err(value_error)?;
        let models = sysid::board::deploy::board_models(&uploads)
            .map_err(|e| value_error(format!("{model_name}: {e}")))?;
        let data = load(source, &data, None)?;
        let (summary, frames) =
            sysid::board::replay::replay(&models, &data).map_err(value_error)?;
        let mut cols = vec![numbers("time_s", frames.iter().map(|f| f.t))];
        for ch in 0..sysid::board::replay::CHAMBERS {
            let c = |f: &sysid::board::replay::ReplayFrame| f.frame.chambers[ch];
            let col = |name: &str, get: &dyn Fn(&sysid::board::replay::ReplayFrame) -> f32| {
                numbers(
                    &format!("{name}_{ch}"),
                    frames.iter().map(|f| f64::from(get(f))),
                )
            };
            cols.push(col("p", &|f| c(f).p));
            cols.push(col("p_hat", &|f| c(f).p_hat));
            cols.push(col("residual", &|f| c(f).residual));
            cols.push(col("load", &|f| f.load_kpa[ch]));
            cols.push(col("k", &|f| c(f).k));
            cols.push(col("c", &|f| c(f).c));
        }
        cols.push(numbers(
            "force_n",
            frames.iter().map(|f| f64::from(f.frame.force_n)),
        ));
        cols.push(numbers(
            "force_ref_n",
            frames.iter().map(|f| f.force_ref.unwrap_or(f64::NAN)),
        ));
        Ok((json(&summary)?, cols))
    })
}

/// `simulate`: the log `vfp simulate` writes, as columns and comments.
#[pyfunction]
fn simulate(
    py: Python<'_>,
    preset: String,
    cycles: Option<u16>,
    flows: Option<Vec<f64>>,
    seed: Option<u64>,
) -> PyResult<(Vec<OutColumn>, Vec<String>)> {
    let opts = host_sim::PresetOptions {
        cycles,
        flows,
        ..host_sim::PresetOptions::default()
    };
    let log = py.detach(|| -> PyResult<Log> {
        let mut sc = host_sim::Scenario::preset(&preset, &opts).map_err(value_error)?;
        if let Some(seed) = seed {
            sc.seed = seed;
        }
        sc.validate().map_err(value_error)?;
        let sim =
            host_sim::simulate(&sc).map_err(|e| value_error(format!("simulation failed: {e}")))?;
        let mut text = Vec::new();
        sim.write_log(&mut text).map_err(value_error)?;
        log::parse_log(&text[..], &format!("simulate {preset}")).map_err(value_error)
    })?;
    Ok(columns_of(&log))
}

/// The `vfp` package's compiled half.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_log, m)?)?;
    m.add_function(wrap_pyfunction!(identify, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(force, m)?)?;
    m.add_function(wrap_pyfunction!(export, m)?)?;
    m.add_function(wrap_pyfunction!(replay, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add(
        "__doc__",
        "The compiled half of the vfp package (see vfp/__init__.py).",
    )?;
    Ok(())
}
