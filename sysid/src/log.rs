//! Reading and writing the actuation log format (`docs/log-format.md`).
//!
//! A log is UTF-8 CSV with one header row; `#` lines are comments and may carry `key=value`
//! metadata. Columns are found by name in any order: `time_s`, `volume_mm3` and `pressure_kpa`
//! are required; `chamber` (default 0), `flow_mm3_s` and `force_n` are optional (an empty cell
//! in an optional column means "not recorded" for that row). Any other column is kept verbatim
//! and written back by [`write_log`].
//!
//! Every malformed input is a [`LogError`] naming the file, the 1-based line and the column;
//! nothing here panics on bad bytes (a property test feeds it random input).
//!
//! ```
//! use sysid::log::{parse_log, write_log_to};
//! let text = "# sample_rate_hz=25\ntime_s,volume_mm3,pressure_kpa\n0,0,0.5\n0.04,1.2,0.7\n";
//! let log = parse_log(text.as_bytes(), "mem.csv").unwrap();
//! assert_eq!(log.samples.len(), 2);
//! assert_eq!(log.metadata("sample_rate_hz"), Some("25"));
//! let mut out = Vec::new();
//! write_log_to(&mut out, &log).unwrap();
//! assert_eq!(parse_log(&out[..], "again.csv").unwrap().samples, log.samples);
//! ```

use std::fmt;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Number of actuation channels a log may address (`chamber` is `0..MAX_CHAMBERS`).
pub const MAX_CHAMBERS: u8 = 3;

/// One row of a log: a sample of one chamber.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Sample time, s; strictly increasing within one chamber.
    pub time_s: f64,
    /// Actuation channel, `0..=2`.
    pub chamber: u8,
    /// Displaced syringe volume, mm³.
    pub volume_mm3: f64,
    /// Volumetric flow, mm³/s, when the log carries it.
    pub flow_mm3_s: Option<f64>,
    /// Measured gauge pressure, kPa.
    pub pressure_kpa: f64,
    /// Reference external force from a load cell, N, when recorded.
    pub force_n: Option<f64>,
}

impl Sample {
    /// A sample with the required fields only.
    pub fn new(time_s: f64, chamber: u8, volume_mm3: f64, pressure_kpa: f64) -> Self {
        Self {
            time_s,
            chamber,
            volume_mm3,
            flow_mm3_s: None,
            pressure_kpa,
            force_n: None,
        }
    }
}

/// A whole log: comment lines, known columns per row, and unknown columns kept verbatim.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Log {
    /// Comment lines without the leading `#` (and one following space), in file order.
    pub comments: Vec<String>,
    /// Rows in file order.
    pub samples: Vec<Sample>,
    /// Names of the columns this crate does not interpret, in file order.
    pub extra_columns: Vec<String>,
    /// Per row, the cells of `extra_columns` (empty when there are none).
    pub extra: Vec<Vec<String>>,
}

impl Log {
    /// The value of the first `# key=value` comment with this key.
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.comments.iter().find_map(|c| {
            let (k, v) = c.split_once('=')?;
            (k.trim() == key).then(|| v.trim())
        })
    }

    /// Sets `# key=value` (replacing an existing entry with that key).
    pub fn set_metadata(&mut self, key: &str, value: &str) {
        let line = format!("{key}={value}");
        match self
            .comments
            .iter_mut()
            .find(|c| c.split_once('=').is_some_and(|(k, _)| k.trim() == key))
        {
            Some(c) => *c = line,
            None => self.comments.push(line),
        }
    }

    /// Chambers present in the log, ascending.
    pub fn chambers(&self) -> Vec<u8> {
        let mut seen = [false; MAX_CHAMBERS as usize];
        for s in &self.samples {
            seen[s.chamber as usize] = true;
        }
        (0..MAX_CHAMBERS).filter(|&c| seen[c as usize]).collect()
    }

    /// Appends a row with no extra-column cells (they are written empty).
    pub fn push(&mut self, sample: Sample) {
        self.samples.push(sample);
        if !self.extra_columns.is_empty() {
            self.extra
                .push(vec![String::new(); self.extra_columns.len()]);
        }
    }
}

/// What went wrong reading or writing a log, with the place.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// The file could not be opened, read or written.
    #[error("{file}: {source}")]
    Io {
        /// File name as given.
        file: String,
        /// Operating-system error.
        source: std::io::Error,
    },
    /// The CSV structure is broken (e.g. a row with the wrong number of fields, invalid UTF-8).
    #[error("{file}:{line}: {message}")]
    Malformed {
        /// File name as given.
        file: String,
        /// 1-based line number.
        line: u64,
        /// What the CSV reader found.
        message: String,
    },
    /// The file has no header row or no data rows.
    #[error(
        "{file}: {what}; a log needs a header row and at least one sample (see docs/log-format.md)"
    )]
    Empty {
        /// File name as given.
        file: String,
        /// "no header row" or "no data rows".
        what: &'static str,
    },
    /// A required column is absent from the header.
    #[error("{file}:{line}: missing required column `{column}` (header has: {header})")]
    MissingColumn {
        /// File name as given.
        file: String,
        /// Line of the header row.
        line: u64,
        /// The missing column's name.
        column: &'static str,
        /// The header as found.
        header: String,
    },
    /// A column name appears twice in the header.
    #[error("{file}:{line}: column `{column}` appears twice in the header")]
    DuplicateColumn {
        /// File name as given.
        file: String,
        /// Line of the header row.
        line: u64,
        /// The repeated name.
        column: String,
    },
    /// A cell is not a finite number (or an empty required cell).
    #[error("{file}:{line}: column `{column}`: {problem} {value:?}")]
    BadValue {
        /// File name as given.
        file: String,
        /// 1-based line number.
        line: u64,
        /// Column name.
        column: &'static str,
        /// The cell as found.
        value: String,
        /// "cannot parse as a number", "not finite:", ...
        problem: &'static str,
    },
    /// `chamber` is not one of 0, 1, 2.
    #[error("{file}:{line}: column `chamber`: {value:?} is not a chamber index 0..=2")]
    BadChamber {
        /// File name as given.
        file: String,
        /// 1-based line number.
        line: u64,
        /// The cell as found.
        value: String,
    },
    /// `time_s` does not increase within a chamber.
    #[error(
        "{file}:{line}: column `time_s`: {time} s is not after the previous sample of chamber {chamber} ({previous} s); time must increase strictly within a chamber"
    )]
    TimeNotIncreasing {
        /// File name as given.
        file: String,
        /// 1-based line number.
        line: u64,
        /// Chamber of the row.
        chamber: u8,
        /// The row's time.
        time: f64,
        /// The previous time of that chamber.
        previous: f64,
    },
}

/// Reads a log file. See the module docs for the rules.
pub fn read_log(path: impl AsRef<Path>) -> Result<Log, LogError> {
    let path = path.as_ref();
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|source| LogError::Io {
        file: file.clone(),
        source,
    })?;
    parse_log(std::io::BufReader::new(f), &file)
}

/// Index of each known column in the header.
struct Columns {
    time: usize,
    chamber: Option<usize>,
    volume: usize,
    flow: Option<usize>,
    pressure: usize,
    force: Option<usize>,
    extra: Vec<usize>,
}

const KNOWN: [&str; 6] = [
    "time_s",
    "chamber",
    "volume_mm3",
    "flow_mm3_s",
    "pressure_kpa",
    "force_n",
];

/// Parses a log from any reader; `file` names it in errors.
pub fn parse_log(mut reader: impl Read, file: &str) -> Result<Log, LogError> {
    let mut bytes = Vec::new();
    reader
        .read_to_end(&mut bytes)
        .map_err(|source| LogError::Io {
            file: file.into(),
            source,
        })?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count() as u64;
        LogError::Malformed {
            file: file.into(),
            line,
            message: "invalid UTF-8".into(),
        }
    })?;
    let mut log = Log::default();
    for l in text.lines() {
        if let Some(c) = l.trim_start().strip_prefix('#') {
            log.comments.push(
                c.strip_prefix(' ')
                    .unwrap_or(c)
                    .trim_end_matches('\r')
                    .to_string(),
            );
        }
    }

    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(false)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .flexible(false)
        .from_reader(text.as_bytes());
    let malformed = |e: csv::Error| {
        let line = e.position().map_or(0, |p| p.line());
        let message = match e.kind() {
            csv::ErrorKind::UnequalLengths {
                expected_len, len, ..
            } => {
                format!("row has {len} fields but the header has {expected_len}")
            }
            _ => e.to_string(),
        };
        LogError::Malformed {
            file: file.into(),
            line,
            message,
        }
    };

    let mut records = rdr.records();
    let header = loop {
        match records.next() {
            None => {
                return Err(LogError::Empty {
                    file: file.into(),
                    what: "no header row",
                })
            }
            Some(r) => {
                let r = r.map_err(malformed)?;
                // Blank lines are skipped by the reader; a header of one empty field is not a header.
                if r.iter().any(|f| !f.is_empty()) {
                    break r;
                }
            }
        }
    };
    let header_line = header.position().map_or(1, |p| p.line());
    let names: Vec<String> = header.iter().map(str::to_string).collect();
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(LogError::DuplicateColumn {
                file: file.into(),
                line: header_line,
                column: n.clone(),
            });
        }
    }
    let find = |name: &str| names.iter().position(|n| n == name);
    let required = |name: &'static str| {
        find(name).ok_or_else(|| LogError::MissingColumn {
            file: file.into(),
            line: header_line,
            column: name,
            header: names.join(","),
        })
    };
    let cols = Columns {
        time: required("time_s")?,
        chamber: find("chamber"),
        volume: required("volume_mm3")?,
        flow: find("flow_mm3_s"),
        pressure: required("pressure_kpa")?,
        force: find("force_n"),
        extra: (0..names.len())
            .filter(|&i| !KNOWN.contains(&names[i].as_str()))
            .collect(),
    };
    log.extra_columns = cols.extra.iter().map(|&i| names[i].clone()).collect();

    let mut last_time = [f64::NEG_INFINITY; MAX_CHAMBERS as usize];
    for rec in records {
        let rec = rec.map_err(malformed)?;
        let line = rec.position().map_or(0, |p| p.line());
        let cell = |i: usize| rec.get(i).unwrap_or("");
        let number = |i: usize, column: &'static str| -> Result<Option<f64>, LogError> {
            let s = cell(i);
            if s.is_empty() {
                return Ok(None);
            }
            let bad = |problem| LogError::BadValue {
                file: file.into(),
                line,
                column,
                value: s.into(),
                problem,
            };
            let x: f64 = s.parse().map_err(|_| bad("cannot parse as a number:"))?;
            if x.is_finite() {
                Ok(Some(x))
            } else {
                Err(bad("not a finite number:"))
            }
        };
        let need = |i: usize, column: &'static str| -> Result<f64, LogError> {
            number(i, column)?.ok_or_else(|| LogError::BadValue {
                file: file.into(),
                line,
                column,
                value: String::new(),
                problem: "required value is empty:",
            })
        };
        let chamber = match cols.chamber {
            None => 0,
            Some(i) => {
                let s = cell(i);
                match s.parse::<u8>() {
                    Ok(c) if c < MAX_CHAMBERS => c,
                    _ => {
                        return Err(LogError::BadChamber {
                            file: file.into(),
                            line,
                            value: s.into(),
                        })
                    }
                }
            }
        };
        let time_s = need(cols.time, "time_s")?;
        let previous = last_time[chamber as usize];
        if time_s <= previous {
            return Err(LogError::TimeNotIncreasing {
                file: file.into(),
                line,
                chamber,
                time: time_s,
                previous,
            });
        }
        last_time[chamber as usize] = time_s;
        log.samples.push(Sample {
            time_s,
            chamber,
            volume_mm3: need(cols.volume, "volume_mm3")?,
            flow_mm3_s: cols
                .flow
                .map(|i| number(i, "flow_mm3_s"))
                .transpose()?
                .flatten(),
            pressure_kpa: need(cols.pressure, "pressure_kpa")?,
            force_n: cols
                .force
                .map(|i| number(i, "force_n"))
                .transpose()?
                .flatten(),
        });
        if !cols.extra.is_empty() {
            log.extra
                .push(cols.extra.iter().map(|&i| cell(i).to_string()).collect());
        }
    }
    if log.samples.is_empty() {
        return Err(LogError::Empty {
            file: file.into(),
            what: "no data rows",
        });
    }
    Ok(log)
}

/// Writes a log file (comments, then header, then rows). `flow_mm3_s` and `force_n` columns are
/// written when any row has them; extra columns follow, verbatim.
pub fn write_log(path: impl AsRef<Path>, log: &Log) -> Result<(), LogError> {
    let path: PathBuf = path.as_ref().into();
    let file = path.display().to_string();
    let io = |source| LogError::Io {
        file: file.clone(),
        source,
    };
    let f = std::fs::File::create(&path).map_err(io)?;
    let mut w = std::io::BufWriter::new(f);
    write_log_to(&mut w, log).map_err(io)?;
    w.flush().map_err(io)
}

/// Writes a log to any writer. Numbers use Rust's shortest round-trip formatting, so reading the
/// output back gives bit-identical values.
pub fn write_log_to(w: &mut impl Write, log: &Log) -> std::io::Result<()> {
    for c in &log.comments {
        writeln!(w, "# {c}")?;
    }
    let has_flow = log.samples.iter().any(|s| s.flow_mm3_s.is_some());
    let has_force = log.samples.iter().any(|s| s.force_n.is_some());
    let mut csvw = csv::WriterBuilder::new().has_headers(false).from_writer(w);
    let mut header = vec!["time_s", "chamber", "volume_mm3"];
    if has_flow {
        header.push("flow_mm3_s");
    }
    header.push("pressure_kpa");
    if has_force {
        header.push("force_n");
    }
    header.extend(log.extra_columns.iter().map(String::as_str));
    csvw.write_record(&header)?;
    let opt = |x: Option<f64>| x.map(|x| x.to_string()).unwrap_or_default();
    let mut row: Vec<String> = Vec::with_capacity(header.len());
    for (i, s) in log.samples.iter().enumerate() {
        row.clear();
        row.push(s.time_s.to_string());
        row.push(s.chamber.to_string());
        row.push(s.volume_mm3.to_string());
        if has_flow {
            row.push(opt(s.flow_mm3_s));
        }
        row.push(s.pressure_kpa.to_string());
        if has_force {
            row.push(opt(s.force_n));
        }
        if let Some(extra) = log.extra.get(i) {
            row.extend(extra.iter().cloned());
        } else {
            row.extend(std::iter::repeat_n(String::new(), log.extra_columns.len()));
        }
        csvw.write_record(&row)?;
    }
    csvw.flush()?;
    Ok(())
}

impl fmt::Display for Sample {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "t={} s chamber={} v={} mm³ P={} kPa",
            self.time_s, self.chamber, self.volume_mm3, self.pressure_kpa
        )
    }
}
