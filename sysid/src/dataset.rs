//! Per-chamber datasets: derived flow and acceleration, inflation/deflation cycles, and the
//! training / held-out split.
//!
//! # Differentiator
//! Where the log has no `flow_mm3_s`, v̇ and v̈ come from a local quadratic least-squares fit
//! (a Savitzky–Golay filter generalised to the actual, possibly jittered, sample times): for each
//! sample i, fit v(t) ≈ a + b(t − tᵢ) + c(t − tᵢ)² to the samples i−h ..= i+h (the window is
//! shortened, not shifted, at the ends, down to three points), then v̇ᵢ = b and v̈ᵢ = 2c.
//! The default half-width h = 2 (5 samples, 0.16 s at 25 Hz) smooths the 0.04 mm³ step
//! quantisation while keeping a 100 mm³/s ramp's corners within one sample. When the log has
//! flow, v̈ is the same local fit applied to the flow column (its slope).
//!
//! # Cycles
//! A cycle is one inflation followed by one deflation. Phases are read from the flow smoothed by
//! a centred moving average over `phase_smooth_s` (default 0.2 s; real flow sensors are noisy,
//! the ventilator log's flow swings by ±200 000 mm³/s within one breath). The phase switches to
//! "inflating" when the smoothed v̇ > +deadband and to "deflating" when it is < −deadband for
//! `min_phase_s` (default 0.2 s) in a row; dwell inside the deadband keeps the current phase. A new cycle starts at each switch from
//! deflating to inflating. Samples before the first inflation belong to cycle 0. A switch is kept
//! as a cycle start only where the volume itself turns, by half its range ([`crate::cycles`]), so
//! noise on a real flow sensor does not cut one breath into several.
//! The default deadband is 5 % of the 95th percentile of |v̇| (robust to spikes).
//!
//! # Split
//! One cycle in every k is held out (default k = 5): cycle k−1 of the first block of k, then one
//! position earlier in each following block (k = 5: cycles 4, 8, 12, 16, 20, 29, 33, …), so a
//! protocol that repeats k conditions in turn (five flow rates) has every condition represented
//! in both sets. With fewer than k cycles
//! the last 20 % of samples (by time) are held out instead; [`Split`] records which rule applied.
//!
//! # Frames before the pressure zero
//! A log recorded from this project's firmware carries its status bits in a `flags` column (an
//! extra column to the log format (`docs/log-format.md`), so other logs simply lack it). At boot the firmware averages
//! the first frames at rest to take each sensor's zero, and those frames (flag `NOT_ZEROED`) read
//! the sensor's raw offset, a few tenths of a kPa on the simulated rig: they are left out of the
//! dataset ([`Dataset::not_zeroed`] counts them, and the commands report it). A `flags` cell that
//! is not an unsigned integer is an error naming the sample.

use crate::log::{Log, LogError, Sample, MAX_CHAMBERS};
use crate::metrics::order_statistic;
use model_core::flags::Flags;
use std::path::{Path, PathBuf};

/// How to build datasets from a log.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetConfig {
    /// Half-width h of the differentiator window (window = 2h + 1 samples).
    pub diff_half_width: usize,
    /// Ignore the log's flow column and derive v̇ from volume.
    pub derive_flow: bool,
    /// Hold out every k-th cycle; 0 disables the held-out set.
    pub holdout_every: usize,
    /// Phase-switch deadband on |v̇|, mm³/s; `None` = 5 % of the 95th percentile of |v̇|.
    pub deadband: Option<f64>,
    /// Moving-average window for phase detection, s.
    pub phase_smooth_s: f64,
    /// Time beyond the deadband needed to switch phase, s.
    pub min_phase_s: f64,
}

impl Default for DatasetConfig {
    fn default() -> Self {
        Self {
            diff_half_width: 2,
            derive_flow: false,
            holdout_every: 5,
            deadband: None,
            phase_smooth_s: 0.2,
            min_phase_s: 0.2,
        }
    }
}

/// Where v̇ came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FlowSource {
    /// The log's `flow_mm3_s` column.
    Logged,
    /// The local quadratic differentiator on `volume_mm3`, half-width h.
    Derived {
        /// Half-width of the window.
        half_width: usize,
    },
}

/// Which samples are held out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Every k-th cycle is held out.
    EveryKthCycle {
        /// k.
        k: usize,
    },
    /// Too few cycles for k: the last 20 % of samples by time are held out.
    LastFifth,
    /// No held-out set.
    None,
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Split::EveryKthCycle { k } => {
                write!(
                    f,
                    "one cycle in every {k} held out, rotating (cycles {}, {}, {}, …)",
                    k - 1,
                    2 * k - 2,
                    3 * k - 3
                )
            }
            Split::LastFifth => write!(f, "too few cycles: last 20 % of samples held out"),
            Split::None => write!(f, "no held-out set"),
        }
    }
}

/// What is wrong with a chamber's data for identification.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DataError {
    /// The log has no rows for this chamber.
    #[error("chamber {0}: no samples in the log")]
    NoSamples(u8),
    /// Too few samples to differentiate or fit.
    #[error("chamber {chamber}: only {n} samples; at least {needed} are needed")]
    TooFewSamples {
        /// Chamber.
        chamber: u8,
        /// Samples found.
        n: usize,
        /// Samples needed.
        needed: usize,
    },
    /// A cell of the firmware's `flags` column is not an unsigned integer.
    #[error("chamber {chamber}, sample at t = {time_s} s: flags column holds {cell:?}, not an unsigned integer (the firmware's status bits)")]
    BadFlags {
        /// Chamber.
        chamber: u8,
        /// The sample's time, s.
        time_s: f64,
        /// The cell as written.
        cell: String,
    },
}

/// One chamber's samples, ready for identification. All vectors have the same length.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Chamber index.
    pub chamber: u8,
    /// Time, s.
    pub t: Vec<f64>,
    /// Volume v, mm³.
    pub v: Vec<f64>,
    /// Flow v̇, mm³/s.
    pub vdot: Vec<f64>,
    /// Volumetric acceleration v̈, mm³/s².
    pub vddot: Vec<f64>,
    /// Pressure P, kPa.
    pub p: Vec<f64>,
    /// Reference force, N, when every sample of the chamber has one.
    pub force: Option<Vec<f64>>,
    /// Cycle index of each sample.
    pub cycle: Vec<usize>,
    /// `true` for held-out samples.
    pub heldout: Vec<bool>,
    /// Where v̇ came from.
    pub flow_source: FlowSource,
    /// Which held-out rule applied.
    pub split: Split,
    /// Number of cycles found.
    pub n_cycles: usize,
    /// Deadband used for the cycle split, mm³/s.
    pub deadband: f64,
    /// Rows left out because the firmware's `flags` column marks their pressure as not yet
    /// zeroed (`NOT_ZEROED`: the boot frames that take the sensor's zero read the raw offset).
    pub not_zeroed: usize,
    /// Whether the rows carry the firmware's `flags` column: each is one of its frames, the mean
    /// of its conversions of the pressure, the step count and the commanded flow over the frame
    /// (not an instant's sample).
    pub firmware_frames: bool,
}

/// Owned columns of a subset of a dataset (training or held-out), in time order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Columns {
    /// Time, s.
    pub t: Vec<f64>,
    /// Volume, mm³.
    pub v: Vec<f64>,
    /// Flow, mm³/s.
    pub vdot: Vec<f64>,
    /// Acceleration, mm³/s².
    pub vddot: Vec<f64>,
    /// Pressure, kPa.
    pub p: Vec<f64>,
    /// Index of each row in the full dataset.
    pub index: Vec<usize>,
}

impl Columns {
    /// Number of rows.
    pub fn len(&self) -> usize {
        self.p.len()
    }
    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.p.is_empty()
    }
}

impl Dataset {
    /// Builds the datasets of every chamber present in the log.
    pub fn all_from_log(log: &Log, cfg: &DatasetConfig) -> Result<Vec<Dataset>, DataError> {
        log.chambers()
            .into_iter()
            .map(|c| Self::from_log(log, c, cfg))
            .collect()
    }

    /// Builds one chamber's dataset.
    pub fn from_log(log: &Log, chamber: u8, cfg: &DatasetConfig) -> Result<Dataset, DataError> {
        assert!(
            chamber < MAX_CHAMBERS,
            "chamber index {chamber} out of range"
        );
        let flags_col = log.extra_columns.iter().position(|c| c == "flags");
        let mut rows = ChamberRows::new(chamber);
        for (i, s) in log.samples.iter().enumerate() {
            if s.chamber == chamber {
                let flags = flags_col.and_then(|c| log.extra.get(i).and_then(|e| e.get(c)));
                rows.push(s, flags.map(String::as_str));
            }
        }
        rows.into_dataset(cfg)
    }

    /// Builds a dataset from columns directly (flow given), e.g. for simulated data in tests.
    pub fn from_columns(
        t: Vec<f64>,
        v: Vec<f64>,
        vdot: Vec<f64>,
        p: Vec<f64>,
        cfg: &DatasetConfig,
    ) -> Dataset {
        assert!(
            t.len() == v.len() && v.len() == vdot.len() && vdot.len() == p.len(),
            "column lengths differ"
        );
        let h = cfg.diff_half_width.max(1);
        let (vddot, _) = local_quadratic_derivatives(&t, &vdot, h);
        let (cycle, deadband) = cycles(&t, &v, &vdot, cfg);
        let n_cycles = cycle.last().map_or(0, |c| c + 1);
        let (heldout, split) = holdout_mask(&cycle, n_cycles, cfg.holdout_every);
        Dataset {
            chamber: 0,
            t,
            v,
            vdot,
            vddot,
            p,
            force: None,
            cycle,
            heldout,
            flow_source: FlowSource::Logged,
            split,
            n_cycles,
            deadband,
            not_zeroed: 0,
            firmware_frames: false,
        }
    }

    /// The held-out rule in words, and the frames left out before the pressure zero if any.
    pub fn split_description(&self) -> String {
        match self.not_zeroed {
            0 => self.split.to_string(),
            n => format!(
                "{}; {n} frames before the pressure zero (flag NOT_ZEROED) left out",
                self.split
            ),
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.p.len()
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.p.is_empty()
    }

    /// Rows selected by `keep(i)`.
    pub fn select(&self, keep: impl Fn(usize) -> bool) -> Columns {
        let rows = (0..self.len()).filter(|&i| keep(i)).count();
        let mut c = Columns {
            t: Vec::with_capacity(rows),
            v: Vec::with_capacity(rows),
            vdot: Vec::with_capacity(rows),
            vddot: Vec::with_capacity(rows),
            p: Vec::with_capacity(rows),
            index: Vec::with_capacity(rows),
        };
        for i in (0..self.len()).filter(|&i| keep(i)) {
            c.t.push(self.t[i]);
            c.v.push(self.v[i]);
            c.vdot.push(self.vdot[i]);
            c.vddot.push(self.vddot[i]);
            c.p.push(self.p[i]);
            c.index.push(i);
        }
        c
    }

    /// Training rows (not held out).
    pub fn train(&self) -> Columns {
        self.select(|i| !self.heldout[i])
    }

    /// Held-out rows.
    pub fn heldout(&self) -> Columns {
        self.select(|i| self.heldout[i])
    }

    /// All rows.
    pub fn all(&self) -> Columns {
        self.select(|_| true)
    }
}

/// One chamber's rows as they are read, as columns (no per-row records are kept): what
/// [`Dataset::from_log`] and the streaming [`LogData::read_with`] collect before building the
/// dataset, the rows the firmware flagged `NOT_ZEROED` left out (module docs).
#[derive(Debug, Clone)]
struct ChamberRows {
    chamber: u8,
    t: Vec<f64>,
    v: Vec<f64>,
    p: Vec<f64>,
    /// Logged flow, `None` once a row lacks it.
    flow: Option<Vec<f64>>,
    /// Reference force, `None` once a row lacks it.
    force: Option<Vec<f64>>,
    not_zeroed: usize,
    /// Whether a row had a `flags` cell (the firmware's frames).
    flagged: bool,
    /// The first bad `flags` cell, reported when the dataset is built (after the whole log has
    /// been read, so a malformed row anywhere is reported first, as for a log read whole).
    bad: Option<DataError>,
}

impl ChamberRows {
    fn new(chamber: u8) -> Self {
        Self {
            chamber,
            t: Vec::new(),
            v: Vec::new(),
            p: Vec::new(),
            flow: Some(Vec::new()),
            force: Some(Vec::new()),
            not_zeroed: 0,
            flagged: false,
            bad: None,
        }
    }

    /// Adds one sample of this chamber with its `flags` cell, if the log has that column.
    fn push(&mut self, s: &Sample, flags: Option<&str>) {
        if self.bad.is_some() {
            return;
        }
        if let Some(cell) = flags.map(str::trim).filter(|c| !c.is_empty()) {
            self.flagged = true;
            let Ok(bits) = cell.parse::<u32>() else {
                self.bad = Some(DataError::BadFlags {
                    chamber: self.chamber,
                    time_s: s.time_s,
                    cell: cell.to_string(),
                });
                return;
            };
            if Flags(bits).has(Flags::NOT_ZEROED) {
                self.not_zeroed += 1;
                return;
            }
        }
        self.t.push(s.time_s);
        self.v.push(s.volume_mm3);
        self.p.push(s.pressure_kpa);
        for (col, x) in [(&mut self.flow, s.flow_mm3_s), (&mut self.force, s.force_n)] {
            match (col.as_mut(), x) {
                (Some(c), Some(x)) => c.push(x),
                (Some(_), None) => *col = None,
                (None, _) => {}
            }
        }
    }

    /// The dataset: flow logged or derived, v̈, cycles and the split (module docs).
    fn into_dataset(self, cfg: &DatasetConfig) -> Result<Dataset, DataError> {
        let chamber = self.chamber;
        if let Some(e) = self.bad {
            return Err(e);
        }
        if self.t.is_empty() {
            return Err(DataError::NoSamples(chamber));
        }
        if self.t.len() < 3 {
            return Err(DataError::TooFewSamples {
                chamber,
                n: self.t.len(),
                needed: 3,
            });
        }
        let (mut t, mut v, mut p) = (self.t, self.v, self.p);
        // Grown by doubling while the file was read: give back the unused half.
        for c in [&mut t, &mut v, &mut p] {
            c.shrink_to_fit();
        }
        let logged_flow = self.flow.filter(|_| !cfg.derive_flow);
        let h = cfg.diff_half_width.max(1);
        let (vdot, vddot, flow_source) = match logged_flow {
            Some(f) => {
                let (fd, _) = local_quadratic_derivatives(&t, &f, h);
                (f, fd, FlowSource::Logged)
            }
            None => {
                let (d1, d2) = local_quadratic_derivatives(&t, &v, h);
                (d1, d2, FlowSource::Derived { half_width: h })
            }
        };
        let (cycle, deadband) = cycles(&t, &v, &vdot, cfg);
        let n_cycles = cycle.last().map_or(0, |c| c + 1);
        let (heldout, split) = holdout_mask(&cycle, n_cycles, cfg.holdout_every);
        Ok(Dataset {
            chamber,
            t,
            v,
            vdot,
            vddot,
            p,
            force: self.force.map(|mut f| {
                f.shrink_to_fit();
                f
            }),
            cycle,
            heldout,
            flow_source,
            split,
            n_cycles,
            deadband,
            not_zeroed: self.not_zeroed,
            firmware_frames: self.flagged,
        })
    }
}

/// The rows of the requested chambers as a log passes (the one per-row step of both ways into
/// [`LogData`]), and the chambers present.
struct Collect {
    path: PathBuf,
    want: Option<u8>,
    present: [bool; MAX_CHAMBERS as usize],
    rows: [Option<ChamberRows>; MAX_CHAMBERS as usize],
}

impl Collect {
    fn new(path: &Path, want: Option<u8>, cfg: &DatasetConfig) -> Result<Self, LoadError> {
        if let Some(d) = cfg.deadband {
            if !(d.is_finite() && d >= 0.0) {
                return Err(LoadError::BadDeadband(d));
            }
        }
        if let Some(c) = want.filter(|&c| c >= MAX_CHAMBERS) {
            return Err(LoadError::BadChamber { chamber: c });
        }
        Ok(Self {
            path: path.to_path_buf(),
            want,
            present: [false; MAX_CHAMBERS as usize],
            rows: [None, None, None],
        })
    }

    fn push(&mut self, s: &Sample, flags: Option<&str>) {
        let c = s.chamber;
        self.present[c as usize] = true;
        if self.want.is_none_or(|w| w == c) {
            self.rows[c as usize]
                .get_or_insert_with(|| ChamberRows::new(c))
                .push(s, flags);
        }
    }

    fn finish(self, comments: Vec<String>, cfg: &DatasetConfig) -> Result<LogData, LoadError> {
        let present: Vec<u8> = (0..MAX_CHAMBERS)
            .filter(|&c| self.present[c as usize])
            .collect();
        let path = self.path;
        if let Some(c) = self.want.filter(|c| !present.contains(c)) {
            return Err(LoadError::NoChamber {
                path,
                chamber: c,
                present,
            });
        }
        let datasets = self
            .rows
            .into_iter()
            .flatten()
            .map(|r| r.into_dataset(cfg))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|source| LoadError::Data {
                path: path.clone(),
                source,
            })?;
        if datasets.is_empty() {
            return Err(LoadError::Empty { path });
        }
        Ok(LogData {
            path,
            comments,
            datasets,
        })
    }
}

/// A log file read and turned into the datasets of the requested chambers: the one way from a log
/// to datasets that every analysis and every `vfp` command takes (flags handling, the `NOT_ZEROED`
/// count, flow source, deadband and training / held-out split all come from one per-chamber
/// collection of rows, as [`Dataset::from_log`] does, with one [`DatasetConfig`]). A file is
/// read row by row ([`crate::log::LogReader`]) straight into the requested chambers' columns: the
/// rows themselves and the other chambers are not kept.
#[derive(Clone, Debug)]
pub struct LogData {
    /// Where the log came from (as given; reports name it so).
    pub path: PathBuf,
    /// The log's comment lines, with its `key=value` metadata ([`LogData::meta`]).
    pub comments: Vec<String>,
    /// The requested chambers' datasets, in chamber order; never empty.
    pub datasets: Vec<Dataset>,
}

/// Why a log could not be turned into datasets.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The file could not be read or does not follow `docs/log-format.md` (file, line, column).
    #[error(transparent)]
    Log(#[from] LogError),
    /// A chamber's dataset could not be built.
    #[error("{path}: {source}")]
    Data {
        /// The log.
        path: PathBuf,
        /// Why.
        source: DataError,
    },
    /// The requested chamber is not one the format knows.
    #[error("--chamber {chamber}: chambers are 0, 1 and 2")]
    BadChamber {
        /// The request.
        chamber: u8,
    },
    /// The requested chamber has no samples in the log.
    #[error("{path}, column `chamber`: no samples for chamber {chamber} (present: {present:?}); choose one with --chamber")]
    NoChamber {
        /// The log.
        path: PathBuf,
        /// The request.
        chamber: u8,
        /// The chambers the log has.
        present: Vec<u8>,
    },
    /// The log holds no samples at all.
    #[error("{path}: the log holds no samples")]
    Empty {
        /// The log.
        path: PathBuf,
    },
    /// The deadband is not a flow.
    #[error("--deadband {0}: must be a finite flow >= 0 mm3/s")]
    BadDeadband(f64),
}

impl LogData {
    /// Reads `path` and builds the dataset of `chamber`, or of every chamber in the log when
    /// `None`.
    pub fn read(
        path: &Path,
        chamber: Option<u8>,
        cfg: &DatasetConfig,
    ) -> Result<LogData, LoadError> {
        Self::read_with(path, chamber, cfg, &crate::log::ReadOptions::default())
    }

    /// [`read`](Self::read) for a file with its own column names, units or chamber numbering
    /// ([`crate::columns`]): the mapping happens in the reader, so what follows is the same path.
    pub fn read_with(
        path: &Path,
        chamber: Option<u8>,
        cfg: &DatasetConfig,
        opts: &crate::log::ReadOptions,
    ) -> Result<LogData, LoadError> {
        let mut collect = Collect::new(path, chamber, cfg)?;
        let file = path.display().to_string();
        let f = std::fs::File::open(path).map_err(|source| LogError::Io {
            file: file.clone(),
            source,
        })?;
        let rows = crate::log::LogReader::new(std::io::BufReader::new(f), &file, opts)?;
        let flags_col = rows.extra_columns().iter().position(|c| c == "flags");
        let comments =
            rows.for_each(|s, row| collect.push(s, flags_col.map(|k| row.extra_cell(k))))?;
        collect.finish(comments, cfg)
    }

    /// The same for a log already parsed (`path` names it in messages and reports).
    pub fn from_log(
        path: &Path,
        log: Log,
        chamber: Option<u8>,
        cfg: &DatasetConfig,
    ) -> Result<LogData, LoadError> {
        let mut collect = Collect::new(path, chamber, cfg)?;
        let flags_col = log.extra_columns.iter().position(|c| c == "flags");
        for (i, s) in log.samples.iter().enumerate() {
            let flags = flags_col.and_then(|c| log.extra.get(i).and_then(|e| e.get(c)));
            collect.push(s, flags.map(String::as_str));
        }
        collect.finish(log.comments, cfg)
    }

    /// The first requested chamber's dataset (the requested one, else the lowest in the log).
    pub fn first(&self) -> &Dataset {
        &self.datasets[0]
    }

    /// The dataset of `chamber`, when it was requested and is in the log.
    pub fn dataset(&self, chamber: u8) -> Option<&Dataset> {
        self.datasets.iter().find(|d| d.chamber == chamber)
    }

    /// Whether v̇ was derived from volume and time in any dataset (no `flow_mm3_s` column, or
    /// `derive_flow`).
    pub fn flow_derived(&self) -> bool {
        self.datasets
            .iter()
            .any(|d| matches!(d.flow_source, FlowSource::Derived { .. }))
    }

    /// `# key=value` metadata of the log.
    pub fn meta(&self, key: &str) -> Option<&str> {
        crate::log::metadata(&self.comments, key)
    }

    /// A short label: the file stem.
    pub fn label(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    }

    /// The path as reports print it.
    pub fn name(&self) -> String {
        self.path.display().to_string()
    }
}

/// Smooths the flow, picks the deadband and segments (see the module docs), keeping only the
/// boundaries where the volume turns ([`crate::cycles`]).
fn cycles(t: &[f64], v: &[f64], vdot: &[f64], cfg: &DatasetConfig) -> (Vec<usize>, f64) {
    let mut dts: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let middle = dts.len() / 2;
    let dt = order_statistic(&mut dts, middle).unwrap_or(1.0);
    let samples = |secs: f64| ((secs / dt).round() as usize).max(1);
    let smooth = moving_average(vdot, samples(cfg.phase_smooth_s) / 2);
    let deadband = cfg.deadband.unwrap_or_else(|| default_deadband(&smooth));
    let flow_labels = segment_cycles(&smooth, deadband, samples(cfg.min_phase_s));
    (
        crate::cycles::keep_volume_cycles(v, &flow_labels).0,
        deadband,
    )
}

/// Centred moving average over i−h ..= i+h (clipped at the ends).
fn moving_average(x: &[f64], h: usize) -> Vec<f64> {
    let mut pre = Vec::with_capacity(x.len() + 1);
    pre.push(0.0);
    for v in x {
        pre.push(pre.last().copied().unwrap_or(0.0) + v);
    }
    (0..x.len())
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(h), (i + h + 1).min(x.len()));
            (pre[hi] - pre[lo]) / (hi - lo) as f64
        })
        .collect()
}

/// 5 % of the 95th percentile of |v̇|; zero when the flow is zero everywhere.
fn default_deadband(vdot: &[f64]) -> f64 {
    let mut a: Vec<f64> = vdot.iter().map(|x| x.abs()).collect();
    let k = ((a.len() - 1) as f64 * 0.95).round() as usize;
    0.05 * order_statistic(&mut a, k).unwrap_or(0.0)
}

/// Median sample interval (s) of the times `t` (NaN with fewer than two): a board's frame
/// interval, as its log recorded it.
pub fn median_dt(t: &[f64]) -> f64 {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(f64::NAN)
}

/// First and second derivatives of `y(t)` by a local quadratic least-squares fit over
/// `i−h ..= i+h` (clipped at the ends). See the module docs.
/// Each sample's pair is its own (computed on the available cores).
pub fn local_quadratic_derivatives(t: &[f64], y: &[f64], h: usize) -> (Vec<f64>, Vec<f64>) {
    let n = t.len();
    if n < 2 {
        return (vec![0.0; n], vec![0.0; n]);
    }
    crate::par::par_map_items(n, |i| local_quadratic_at(t, y, h, i))
        .into_iter()
        .unzip()
}

/// (dy/dt, d²y/dt²) at sample `i` of [`local_quadratic_derivatives`] (`t` has two samples or
/// more).
fn local_quadratic_at(t: &[f64], y: &[f64], h: usize, i: usize) -> (f64, f64) {
    let n = t.len();
    let lo = i.saturating_sub(h);
    let hi = (i + h).min(n - 1);
    // Need three points for a quadratic; widen on the short side at the ends.
    let (lo, hi) = if hi - lo < 2 && n >= 3 {
        if lo == 0 {
            (0, 2.min(n - 1))
        } else {
            (n - 3, n - 1)
        }
    } else {
        (lo, hi)
    };
    // Normal equations in τ = (t − tᵢ)/s are 3×3 and well conditioned after scaling by s.
    let s = (t[hi] - t[lo]).max(f64::MIN_POSITIVE);
    let mut m = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for j in lo..=hi {
        let tau = (t[j] - t[i]) / s;
        let b = [1.0, tau, tau * tau];
        for a in 0..3 {
            r[a] += b[a] * y[j];
            for c in 0..3 {
                m[a][c] += b[a] * b[c];
            }
        }
    }
    let (c1, c2) = if hi - lo >= 2 {
        match solve3(m, r) {
            Some(x) => (x[1], x[2]),
            None => (0.0, 0.0),
        }
    } else {
        // Two points: a straight line.
        ((y[hi] - y[lo]) / (t[hi] - t[lo]) * s, 0.0)
    };
    (c1 / s, 2.0 * c2 / (s * s))
}

/// Solves a 3×3 system by Cramer's rule (the systems are tiny and well scaled).
fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det(m);
    if d.abs() < 1e-300 {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut mk = m;
        for row in 0..3 {
            mk[row][k] = r[row];
        }
        *xk = det(mk) / d;
    }
    Some(x)
}

/// Cycle index per sample (see the module docs).
pub fn segment_cycles(vdot: &[f64], deadband: f64, min_run: usize) -> Vec<usize> {
    #[derive(PartialEq, Clone, Copy)]
    enum Phase {
        Start,
        Inflating,
        Deflating,
    }
    let mut phase = Phase::Start;
    let mut cycle = 0usize;
    let mut seen_inflation = false;
    let mut run_sign = 0i8;
    let mut run_len = 0usize;
    let mut run_start = 0usize;
    let mut out = vec![0usize; vdot.len()];
    // Samples are labelled when their run is confirmed, so a new cycle starts at the first sample
    // of the confirming run, not min_run samples late.
    for (i, &f) in vdot.iter().enumerate() {
        let sign = if f > deadband {
            1
        } else if f < -deadband {
            -1
        } else {
            0
        };
        if sign != 0 && sign == run_sign {
            run_len += 1;
        } else {
            run_sign = sign;
            run_len = 1;
            run_start = i;
        }
        if run_sign != 0 && run_len == min_run {
            let next = if run_sign > 0 {
                Phase::Inflating
            } else {
                Phase::Deflating
            };
            if next == Phase::Inflating && phase != Phase::Inflating {
                if seen_inflation {
                    cycle += 1;
                }
                seen_inflation = true;
                for o in &mut out[run_start..i] {
                    *o = cycle;
                }
            }
            phase = next;
        }
        out[i] = cycle;
    }
    out
}

/// Held-out mask for the split rule.
fn holdout_mask(cycle: &[usize], n_cycles: usize, k: usize) -> (Vec<bool>, Split) {
    let n = cycle.len();
    if k == 0 {
        return (vec![false; n], Split::None);
    }
    if k >= 2 && n_cycles >= k {
        // Rotate the held-out position by one in each block of k cycles: a protocol that repeats k
        // conditions in turn would otherwise have only one condition held out.
        return (
            cycle.iter().map(|&c| (c + c / k) % k == k - 1).collect(),
            Split::EveryKthCycle { k },
        );
    }
    let cut = n - n / 5;
    ((0..n).map(|i| i >= cut).collect(), Split::LastFifth)
}
