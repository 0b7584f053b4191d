//! Options shared by the subcommands, declared once and flattened into each command's arguments,
//! and the small helpers every command's rendering uses.

use crate::figure::PlotFormat;
use crate::units::DisplayUnits;
use crate::Error;
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use std::path::{Path, PathBuf};
use sysid::columns::{ColumnMap, ReadOptions};
use sysid::dataset::{DatasetConfig, LogData};

/// How a log becomes datasets (every command that reads logs flattens this).
#[derive(Debug, Clone, clap::Args)]
pub struct DataOpts {
    /// Hold out one cycle in every K (rotating; 0 = no held-out set).
    #[arg(long, value_name = "K", default_value_t = 5)]
    pub holdout_every: usize,
    /// Derive v̇ from volume even when the log has a flow column.
    #[arg(long)]
    pub derive_flow: bool,
    /// Half-width h of the flow differentiator (window 2h+1 samples).
    #[arg(long, value_name = "H", default_value_t = 2)]
    pub diff_half_width: usize,
    /// Phase deadband on |v̇|, mm³/s: flow above it is inflation, below its negative deflation, in
    /// between rest (default: 5 % of the 95th percentile of |v̇|, per chamber).
    #[arg(long, value_name = "MM3_S")]
    pub deadband: Option<f64>,
    /// The file's own column names and units, e.g.
    /// `time=t,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O` (quantities time, chamber,
    /// volume, flow, pressure, force; units in docs/log-format.md). Comma, semicolon and tab
    /// delimiters are detected.
    #[arg(long, value_name = "SPEC", value_parser = parse_columns)]
    pub columns: Option<ColumnMap>,
    /// The number the file gives its first chamber: 1 for files that count chambers 1..=3
    /// (read as 0..=2; --chamber and the reports count from 0).
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=1))]
    pub chamber_base: u8,
}

fn parse_columns(s: &str) -> Result<ColumnMap, String> {
    s.parse::<ColumnMap>().map_err(|e| e.to_string())
}

impl Default for DataOpts {
    fn default() -> Self {
        let d = DatasetConfig::default();
        Self {
            holdout_every: d.holdout_every,
            derive_flow: d.derive_flow,
            diff_half_width: d.diff_half_width,
            deadband: d.deadband,
            columns: None,
            chamber_base: 0,
        }
    }
}

impl DataOpts {
    /// The dataset configuration these options describe.
    pub fn config(&self) -> DatasetConfig {
        DatasetConfig {
            diff_half_width: self.diff_half_width.max(1),
            derive_flow: self.derive_flow,
            holdout_every: self.holdout_every,
            deadband: self.deadband,
            ..DatasetConfig::default()
        }
    }

    /// Reads `path` and builds the datasets of `chamber` (every chamber when `None`): the one
    /// library path from a log file to datasets ([`LogData::read`]).
    pub fn load(&self, path: &Path, chamber: Option<u8>) -> Result<LogData, Error> {
        Ok(LogData::read_with(
            path,
            chamber,
            &self.config(),
            &self.read_options(),
        )?)
    }

    /// How the reader maps the file's columns and chambers.
    pub fn read_options(&self) -> ReadOptions {
        ReadOptions {
            columns: self.columns.clone().unwrap_or_default(),
            chamber_base: self.chamber_base,
        }
    }
}

/// Which chamber to analyse.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct ChamberOpt {
    /// Analyse only this chamber (0..=2); default: every chamber in the log (commands that
    /// analyse one chamber take the lowest).
    #[arg(long)]
    pub chamber: Option<u8>,
}

/// One log and how to read it: the positional log path, `--chamber` and the data options.
#[derive(Debug, Clone, clap::Args)]
pub struct LogInput {
    /// The actuation log (CSV, docs/log-format.md).
    pub log: PathBuf,
    #[command(flatten)]
    pub chamber: ChamberOpt,
    #[command(flatten)]
    pub data: DataOpts,
}

impl LogInput {
    /// An input with the default options.
    pub fn new(log: impl Into<PathBuf>) -> Self {
        Self {
            log: log.into(),
            chamber: ChamberOpt::default(),
            data: DataOpts::default(),
        }
    }

    /// Reads the log into the requested chambers' datasets.
    pub fn load(&self) -> Result<LogData, Error> {
        self.data.load(&self.log, self.chamber.chamber)
    }
}

/// Output options: `--json` and `--plots DIR`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct OutputOpts {
    /// Print one JSON document instead of the human report.
    #[arg(long)]
    pub json: bool,
    /// Write the figures into this directory (created if needed).
    #[arg(long, value_name = "DIR")]
    pub plots: Option<PathBuf>,
    /// The figures' file format.
    #[arg(long, value_name = "FORMAT", value_enum, default_value_t = PlotFormat::Svg)]
    pub plot_format: PlotFormat,
    /// Units of the text report and the figures, `VOLUME,PRESSURE` (e.g. `mL,cmH2O`; the unit
    /// names of --columns); flow is the volume unit per second. Default: the units --columns
    /// gave, else mm3 and kPa. JSON stays in mm3, mm3/s and kPa.
    #[arg(long, value_name = "VOLUME,PRESSURE", value_parser = parse_units)]
    pub units: Option<DisplayUnits>,
}

fn parse_units(s: &str) -> Result<DisplayUnits, String> {
    s.parse()
}

impl OutputOpts {
    /// The units to show: `--units`, else those `--columns` read the file in, else mm³ and kPa.
    pub fn display_units(&self, data: &DataOpts) -> DisplayUnits {
        self.units.unwrap_or_else(|| {
            data.columns
                .as_ref()
                .map_or_else(DisplayUnits::default, DisplayUnits::of_columns)
        })
    }

    /// Writes the figure when `--plots DIR` asks for it (`plot` gets the directory and the format
    /// and returns the file it wrote), then the report: pretty JSON with `--json`, else
    /// `human(report)`.
    pub fn emit<T: serde::Serialize>(
        &self,
        report: &T,
        human: impl Fn(&T) -> String,
        plot: impl FnOnce(&Path, PlotFormat) -> Result<PathBuf, Error>,
    ) -> Result<(), Error> {
        if let Some(dir) = &self.plots {
            let path = plot(dir, self.plot_format)?;
            if !self.json {
                println!("figure: {}", path.display());
            }
        }
        if self.json {
            print_json(report)?;
        } else {
            print!("{}", human(report));
        }
        Ok(())
    }
}

/// Prints a serialisable report as pretty JSON on stdout (non-finite numbers become null).
pub fn print_json<T: serde::Serialize>(value: &T) -> Result<(), Error> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::Msg(format!("cannot encode JSON: {e}")))?;
    println!("{text}");
    Ok(())
}

/// A value parser over a library enum: the possible values are `names` (shown by `--help`),
/// each parsed to the variant with that name.
fn enum_parser<T: Copy + Send + Sync + 'static>(
    all: &'static [T],
    name: fn(T) -> String,
) -> impl TypedValueParser<Value = T> {
    let names: Vec<PossibleValue> = all
        .iter()
        .map(|&v| PossibleValue::new(&*Box::leak(name(v).into_boxed_str())))
        .collect();
    PossibleValuesParser::new(names).try_map(move |s: String| {
        all.iter()
            .copied()
            .find(|&v| name(v) == s)
            .ok_or_else(|| format!("unknown value `{s}`"))
    })
}

/// `--family` values: [`sysid::identify::Family`] by its name.
pub fn family_parser() -> impl TypedValueParser<Value = sysid::identify::Family> {
    enum_parser(&sysid::identify::Family::ALL, |f| f.name().to_string())
}

/// `--effect` values: the effects of [`sysid::residual::REGISTRY`] by name with `-` for `_`.
pub fn effect_parser() -> impl TypedValueParser<Value = sysid::residual::EffectKind> {
    enum_parser(sysid::residual::REGISTRY, |e| e.name().replace('_', "-"))
}

/// `--method` values: [`sysid::diag::chow::Method`] by its name.
pub fn method_parser() -> impl TypedValueParser<Value = sysid::diag::chow::Method> {
    enum_parser(&sysid::diag::chow::Method::ALL, |m| m.name().to_string())
}

/// Formats a number for tables: 4 significant digits, scientific outside [1e-3, 1e5).
pub fn num(x: f64) -> String {
    if !x.is_finite() {
        return "-".into();
    }
    let a = x.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{x:.4e}")
    } else {
        format!("{x:.4}")
    }
}

/// Formats an optional number.
pub fn opt(x: Option<f64>) -> String {
    x.map_or_else(|| "-".into(), num)
}
