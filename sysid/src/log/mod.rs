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
use std::io::{BufRead, Read, Write};

mod rows;
use rows::{Fields, Rows};
use std::path::{Path, PathBuf};

pub use crate::columns::ReadOptions;
use crate::columns::{Mapping, Quantity};

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
        metadata(&self.comments, key)
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

/// The value of the first `key=value` line among `comments` (a log's comment lines).
pub fn metadata<'a>(comments: &'a [String], key: &str) -> Option<&'a str> {
    comments.iter().find_map(|c| {
        let (k, v) = c.split_once('=')?;
        (k.trim() == key).then(|| v.trim())
    })
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
    /// A required column (or one `--columns` names) is absent from the header.
    #[error("{file}:{line}: missing column `{column}` (header has: {header}); {hint}")]
    MissingColumn {
        /// File name as given.
        file: String,
        /// Line of the header row.
        line: u64,
        /// The missing column's name.
        column: String,
        /// The header as found.
        header: String,
        /// How to map it (`--columns`).
        hint: String,
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
        /// Column name (the file's header).
        column: String,
        /// The cell as found.
        value: String,
        /// "cannot parse as a number", "not finite:", ...
        problem: &'static str,
    },
    /// `chamber` is not one of 0, 1, 2 (1, 2, 3 with `--chamber-base 1`).
    #[error("{file}:{line}: column `{column}`: {value:?} is not a chamber number {first}..={last}{}", if *first == 0 { " (for numbers from 1 use --chamber-base 1)" } else { "" })]
    BadChamber {
        /// File name as given.
        file: String,
        /// 1-based line number.
        line: u64,
        /// The chamber column's header.
        column: String,
        /// The cell as found.
        value: String,
        /// The first chamber's number in the file.
        first: u8,
        /// The last chamber's number in the file.
        last: u8,
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
    read_log_with(path, &ReadOptions::default())
}

/// Reads a log file whose columns are named or scaled differently, or whose chambers count from
/// 1 ([`ReadOptions`], `--columns` and `--chamber-base` on the command line).
pub fn read_log_with(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Log, LogError> {
    let path = path.as_ref();
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|source| LogError::Io {
        file: file.clone(),
        source,
    })?;
    parse_log_with(std::io::BufReader::new(f), &file, opts)
}

/// One known column found in the header: where, as which header, and its unit's factor.
#[derive(Clone)]
struct Col {
    index: usize,
    name: String,
    factor: f64,
}

/// The known columns found in the header.
struct Columns {
    time: Col,
    chamber: Option<Col>,
    volume: Col,
    flow: Option<Col>,
    pressure: Col,
    force: Option<Col>,
    extra: Vec<usize>,
    chamber_base: u8,
}

/// Parses a log from any reader; `file` names it in errors.
pub fn parse_log(reader: impl Read, file: &str) -> Result<Log, LogError> {
    parse_log_with(reader, file, &ReadOptions::default())
}

/// [`parse_log`] with a column map and chamber numbering.
pub fn parse_log_with(reader: impl Read, file: &str, opts: &ReadOptions) -> Result<Log, LogError> {
    let mut rows = LogReader::new(std::io::BufReader::new(reader), file, opts)?;
    let mut log = Log {
        extra_columns: rows.extra_columns().to_vec(),
        ..Log::default()
    };
    while let Some(sample) = rows.next_sample()? {
        log.samples.push(sample);
        if !log.extra_columns.is_empty() {
            log.extra.push(
                (0..log.extra_columns.len())
                    .map(|k| rows.extra_cell(k).to_string())
                    .collect(),
            );
        }
    }
    log.comments = rows.into_comments();
    Ok(log)
}

/// One column of an in-memory table (a pandas DataFrame or a dict of arrays in the Python
/// package).
#[derive(Debug, Clone, PartialEq)]
pub enum TableColumn {
    /// Numbers; NaN is an empty cell ("not recorded" in an optional column).
    Numbers(Vec<f64>),
    /// Cells kept as text (extra columns such as the firmware's `flags`).
    Text(Vec<String>),
}

impl TableColumn {
    fn len(&self) -> usize {
        match self {
            TableColumn::Numbers(x) => x.len(),
            TableColumn::Text(x) => x.len(),
        }
    }

    fn cell(&self, row: usize) -> String {
        match self {
            TableColumn::Numbers(x) if x[row].is_nan() => String::new(),
            TableColumn::Numbers(x) => x[row].to_string(),
            TableColumn::Text(x) => x[row].clone(),
        }
    }
}

/// Reads an in-memory table of named columns as a log. The table is written as the text of a log
/// file (numbers in Rust's shortest round-trip form, so the reader gets back the very same f64;
/// text quoted) and read by [`parse_log_with`]: column names, the [`ReadOptions`] mapping and
/// units, chamber numbering, every check and every error message are the file reader's own. In
/// errors `name` stands for the file and row k (counted from 0) is line k + 2 (the header is
/// line 1).
pub fn log_from_table(
    name: &str,
    columns: &[(String, TableColumn)],
    opts: &ReadOptions,
) -> Result<Log, LogError> {
    let rows = columns.first().map_or(0, |(_, c)| c.len());
    if let Some((col, c)) = columns.iter().find(|(_, c)| c.len() != rows) {
        return Err(LogError::Malformed {
            file: name.into(),
            line: 1,
            message: format!(
                "column `{col}` has {} rows but column `{}` has {rows}",
                c.len(),
                columns[0].0
            ),
        });
    }
    let mut w = csv::WriterBuilder::new()
        .quote_style(csv::QuoteStyle::NonNumeric)
        .from_writer(Vec::new());
    let io = |source| LogError::Io {
        file: name.into(),
        source,
    };
    let header: Vec<&str> = columns.iter().map(|(n, _)| n.as_str()).collect();
    w.write_record(&header).map_err(|e| io(e.into()))?;
    let mut record = Vec::with_capacity(columns.len());
    for row in 0..rows {
        record.clear();
        record.extend(columns.iter().map(|(_, c)| c.cell(row)));
        w.write_record(&record).map_err(|e| io(e.into()))?;
    }
    let text = w.into_inner().map_err(|e| io(e.into_error()))?;
    parse_log_with(&text[..], name, opts)
}

/// A log read a block of lines at a time: the file is never held whole, only a few blocks of
/// [`BLOCK_BYTES`] (a 190 MB log is read in a few megabytes). The rules and errors are those of
/// [`parse_log`], which is this reader collecting every row; `# comment` lines anywhere in the
/// file are collected as they pass ([`LogReader::into_comments`]).
///
/// ```
/// use sysid::log::{LogReader, ReadOptions};
/// let text = "# rig=A\ntime_s,volume_mm3,pressure_kpa,note\n0,0,0.5,x\n0.04,1.2,0.7,y\n";
/// let mut rows = LogReader::new(text.as_bytes(), "mem.csv", &ReadOptions::default()).unwrap();
/// assert_eq!(rows.extra_columns(), ["note"]);
/// let (mut volume, mut notes) = (0.0, String::new());
/// while let Some(s) = rows.next_sample().unwrap() {
///     volume += s.volume_mm3;
///     notes += rows.extra_cell(0);
/// }
/// assert_eq!((volume, notes.as_str()), (1.2, "xy"));
/// assert_eq!(rows.into_comments(), ["rig=A"]);
/// ```
pub struct LogReader<R: BufRead> {
    lines: Lines<R>,
    shape: Shape,
    extra_columns: Vec<String>,
    checks: RowChecks,
    /// The block [`LogReader::next_sample`] is handing out, and the index of its next row.
    current: Option<Parsed>,
    next_row: usize,
    /// An error has been returned: no more rows.
    stopped: bool,
}

/// What turns a block's lines into samples: the columns found in the header, the number of
/// fields a row has, the delimiter and the file's name for errors.
struct Shape {
    cols: Columns,
    width: usize,
    delimiter: u8,
    file: String,
}

/// A block of lines with its rows cut and read into samples, up to the first error.
struct Parsed {
    buf: Buffers,
    /// The block's first error, after its samples: a bad row, or a line not UTF-8 after it.
    error: Option<LogError>,
}

/// The buffers a block's text, rows and samples live in. [`LogReader::for_each`] hands them
/// round (reading, parsing, handing on, reading again), so a long file is read in a few.
#[derive(Default)]
struct Buffers {
    text: Vec<u8>,
    rows: Rows,
    samples: Vec<Sample>,
}

impl Shape {
    /// The block's rows, cut here unless the reading side cut them, and their samples.
    fn parse(&self, block: Block) -> Parsed {
        let Block {
            mut buf,
            first_line,
            cut,
            pending,
        } = block;
        if !cut {
            buf.rows = rows::cut(&buf.text, first_line, self.delimiter, buf.rows);
        }
        buf.samples.clear();
        let mut error = None;
        for k in 0..buf.rows.len() {
            match self
                .cols
                .sample(buf.rows.row(&buf.text, k), self.width, &self.file)
            {
                Ok(s) => buf.samples.push(s),
                Err(e) => {
                    error = Some(e);
                    break;
                }
            }
        }
        Parsed {
            buf,
            error: error.or(pending),
        }
    }
}

/// The checks across rows: time increasing within each chamber, and at least one data row.
struct RowChecks {
    last_time: [f64; MAX_CHAMBERS as usize],
    rows: usize,
}

impl RowChecks {
    fn new() -> Self {
        Self {
            last_time: [f64::NEG_INFINITY; MAX_CHAMBERS as usize],
            rows: 0,
        }
    }

    /// Checks `sample`'s time (of the row at `line`) against its chamber's previous row.
    fn row(&mut self, sample: &Sample, line: u64, file: &str) -> Result<(), LogError> {
        let c = sample.chamber as usize;
        if sample.time_s <= self.last_time[c] {
            return Err(LogError::TimeNotIncreasing {
                file: file.into(),
                line,
                chamber: sample.chamber,
                time: sample.time_s,
                previous: self.last_time[c],
            });
        }
        self.last_time[c] = sample.time_s;
        self.rows += 1;
        Ok(())
    }

    /// At the end of the rows: an [`LogError::Empty`] when there was none.
    fn end(&self, file: &str) -> Result<(), LogError> {
        if self.rows == 0 {
            return Err(LogError::Empty {
                file: file.into(),
                what: "no data rows",
            });
        }
        Ok(())
    }
}

impl<R: BufRead> LogReader<R> {
    /// Reads up to and including the header row (comments before it collected, delimiter
    /// detected from it, columns found by name). Errors: no header, a missing or repeated column.
    pub fn new(reader: R, file: &str, opts: &ReadOptions) -> Result<Self, LogError> {
        let mut lines = Lines::new(reader, file);
        let (names, header_line, delimiter) = header(&mut lines, file)?;
        let cols = Columns::find(&names, header_line, file, opts)?;
        Ok(Self {
            extra_columns: cols.extra.iter().map(|&i| names[i].clone()).collect(),
            shape: Shape {
                cols,
                width: names.len(),
                delimiter,
                file: file.into(),
            },
            lines,
            checks: RowChecks::new(),
            current: None,
            next_row: 0,
            stopped: false,
        })
    }

    /// Names of the columns this crate does not interpret, in file order.
    pub fn extra_columns(&self) -> &[String] {
        &self.extra_columns
    }

    /// The next row, checked (numbers, chamber, time increasing within its chamber); `None` at
    /// the end of the file, an [`LogError::Empty`] there when the file had no data row.
    pub fn next_sample(&mut self) -> Result<Option<Sample>, LogError> {
        let out = self.next_checked();
        self.stopped |= !matches!(out, Ok(Some(_)));
        out
    }

    fn next_checked(&mut self) -> Result<Option<Sample>, LogError> {
        if self.stopped {
            return Ok(None);
        }
        loop {
            if let Some(p) = &mut self.current {
                if let Some(s) = p.buf.samples.get(self.next_row) {
                    let line = p.buf.rows.row(&p.buf.text, self.next_row).line;
                    self.checks.row(s, line, &self.shape.file)?;
                    self.next_row += 1;
                    return Ok(Some(s.clone()));
                }
                if let Some(e) = p.error.take() {
                    return Err(e);
                }
            }
            let spare = self.current.take().map(|p| p.buf).unwrap_or_default();
            match self.lines.next_block(self.shape.delimiter, spare)? {
                Some(block) => {
                    self.current = Some(self.shape.parse(block));
                    self.next_row = 0;
                }
                None => {
                    self.current = None;
                    self.checks.end(&self.shape.file)?;
                    return Ok(None);
                }
            }
        }
    }

    /// The current row's cell of extra column `k` (`""` before the first row and once the rows
    /// are exhausted).
    pub fn extra_cell(&self, k: usize) -> &str {
        match &self.current {
            Some(p) if self.next_row > 0 && self.next_row <= p.buf.samples.len() => Row {
                fields: p.buf.rows.row(&p.buf.text, self.next_row - 1),
                extra: &self.shape.cols.extra,
            }
            .extra_cell(k),
            _ => "",
        }
    }

    /// The comment lines read so far (every one once the rows are exhausted), without `#` and one
    /// following space, in file order.
    pub fn into_comments(self) -> Vec<String> {
        self.lines.comments
    }
}

/// A row as [`LogReader::for_each`] hands it on, for its extra cells.
pub struct Row<'a> {
    fields: Fields<'a>,
    extra: &'a [usize],
}

impl<'a> Row<'a> {
    /// The row's cell of extra column `k` (as [`LogReader::extra_cell`]).
    pub fn extra_cell(&self, k: usize) -> &'a str {
        self.extra
            .get(k)
            .map_or("", |&i| text(cell(self.fields, i)))
    }
}

impl<R: BufRead + Send> LogReader<R> {
    /// Every remaining row, checked as [`LogReader::next_sample`] checks it, handed in file order
    /// to `f` with the row (for its extra cells, [`Row::extra_cell`]); then returns the comment
    /// lines (as [`LogReader::into_comments`]). One thread reads the blocks, one per core cuts
    /// and parses them, and this one checks the rows across blocks and calls `f`, in file order;
    /// a few blocks' buffers go round, so memory stays a few blocks whatever the file's length.
    /// The first error in file order is returned, with the same message as `next_sample`'s.
    pub fn for_each(self, mut f: impl FnMut(&Sample, Row<'_>)) -> Result<Vec<String>, LogError> {
        let LogReader {
            mut lines,
            shape,
            mut checks,
            current,
            next_row,
            stopped,
            ..
        } = self;
        if stopped {
            return Err(LogError::Malformed {
                file: shape.file.clone(),
                line: 0,
                message: "the reader stopped at an earlier error".into(),
            });
        }
        if let Some(p) = current {
            hand_on(&shape, &mut checks, p, next_row, &mut f)?;
        }
        let workers = std::thread::available_parallelism().map_or(1, |n| n.get().min(8));
        // Blocks in flight: one being read, one waiting per worker, one being parsed per worker,
        // one parsed per worker waiting to be handed on (a few hundred kilobytes each). The
        // buffers are the tickets: the reading thread takes one before it reads a block and the
        // block's buffers come back once it is handed on, so no more than `in_flight` blocks
        // are ever held. (Without the bound a worker held up on the next block in order let the
        // other run ahead, and the parsed blocks waiting for it grew with the file.)
        let in_flight = 1 + 3 * workers;
        let (work_tx, work_rx) = std::sync::mpsc::sync_channel::<Loaded>(workers);
        let work_rx = std::sync::Arc::new(std::sync::Mutex::new(work_rx));
        let (done_tx, done_rx) = std::sync::mpsc::sync_channel::<Handed>(workers);
        let (spare_tx, spare_rx) = std::sync::mpsc::channel::<Buffers>();
        for _ in 0..in_flight {
            let _ = spare_tx.send(Buffers::default());
        }
        let shape = &shape;
        std::thread::scope(|s| {
            let reading = s.spawn(move || {
                for k in 0.. {
                    // No ticket: the consumer stopped (it drops its sender when it returns).
                    let Ok(spare) = spare_rx.recv() else { break };
                    let item = match lines.next_block(shape.delimiter, spare) {
                        Ok(Some(b)) => Ok(b),
                        Ok(None) => break,
                        Err(e) => Err(e),
                    };
                    let failed = item.is_err();
                    if work_tx.send((k, item)).is_err() || failed {
                        break;
                    }
                }
                lines.comments
            });
            for _ in 0..workers {
                let (work_rx, done_tx) = (work_rx.clone(), done_tx.clone());
                s.spawn(move || loop {
                    let next = work_rx
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner)
                        .recv();
                    let Ok((k, item)) = next else { break };
                    if done_tx.send((k, item.map(|b| shape.parse(b)))).is_err() {
                        break;
                    }
                });
            }
            drop((done_tx, work_rx));
            // Returning drops the receiver and the tickets' sender: the workers stop at their
            // next block, then the reader.
            let outcome = (move || {
                let mut waiting = std::collections::BTreeMap::new();
                let mut next = 0;
                for (k, item) in done_rx {
                    waiting.insert(k, item);
                    while let Some(item) = waiting.remove(&next) {
                        let buf = hand_on(shape, &mut checks, item?, 0, &mut f)?;
                        let _ = spare_tx.send(buf);
                        next += 1;
                    }
                }
                checks.end(&shape.file)
            })();
            let comments = reading.join().expect("the reading thread panicked");
            outcome.map(|()| comments)
        })
    }
}

/// A block as the reading thread sends it to the workers: its place in the file, and the block
/// or the error that ended the reading.
type Loaded = (usize, Result<Block, LogError>);

/// A block as a worker sends it on: its place, and its rows parsed (or the reading's error).
type Handed = (usize, Result<Parsed, LogError>);

/// `p`'s samples from row `from` checked and handed to `f`, then its error if any; else its
/// buffers, for another block.
fn hand_on(
    shape: &Shape,
    checks: &mut RowChecks,
    p: Parsed,
    from: usize,
    f: &mut impl FnMut(&Sample, Row<'_>),
) -> Result<Buffers, LogError> {
    let Parsed { buf, error } = p;
    for (k, s) in buf.samples.iter().enumerate().skip(from) {
        let fields = buf.rows.row(&buf.text, k);
        checks.row(s, fields.line, &shape.file)?;
        let extra = &shape.cols.extra;
        f(s, Row { fields, extra });
    }
    match error {
        Some(e) => Err(e),
        None => Ok(buf),
    }
}

/// Bytes of whole lines [`Lines`] loads at a time once the header is found.
const BLOCK_BYTES: usize = 64 * 1024;

/// The longest line a log may have, and the most a quoted field may carry on over lines: far
/// above a log's lines (a few hundred bytes), low enough that a file that is no log (megabytes
/// without a line end, a quote left open) stops at an error instead of being read whole. It
/// also keeps a block's offsets within the 32 bits [`rows`] stores them in.
const MAX_LINE_BYTES: usize = 1 << 20;

/// A block of whole lines as [`Lines`] loads it.
struct Block {
    /// Its text; its rows when `cut`; buffers for its samples.
    buf: Buffers,
    first_line: u64,
    /// Whether the reading side cut its rows already (to find the block's end: a quote in it).
    cut: bool,
    /// An error met right after the block (its lines come first).
    pending: Option<LogError>,
}

/// The file's lines: checked for UTF-8 (an error names the line), a leading byte-order mark
/// dropped, and each `#` comment line's text kept as it passes. Up to the header a line at a
/// time; after it, blocks of whole lines of about [`BLOCK_BYTES`], each checked at once, so that
/// a long file costs a few passes over its bytes rather than a few calls per line. A block ends
/// between rows: one with a quote in it is cut into rows as it is loaded, taking the lines a
/// quoted field carries on into; any other ends at a line's end ([`rows`]).
struct Lines<R> {
    inner: R,
    file: String,
    /// Lines loaded so far.
    number: u64,
    comments: Vec<String>,
    /// An error met after the lines loaded (handed on after them), and whether it was.
    pending: Option<LogError>,
    stopped: bool,
}

impl<R: BufRead> Lines<R> {
    fn new(inner: R, file: &str) -> Self {
        Self {
            inner,
            file: file.into(),
            number: 0,
            comments: Vec::new(),
            pending: None,
            stopped: false,
        }
    }

    fn io_error(&self, source: std::io::Error) -> LogError {
        LogError::Io {
            file: self.file.clone(),
            source,
        }
    }

    fn malformed(&self, line: u64, message: String) -> LogError {
        LogError::Malformed {
            file: self.file.clone(),
            line,
            message,
        }
    }

    fn bad_utf8(&self, line: u64) -> LogError {
        self.malformed(line, "invalid UTF-8".into())
    }

    fn overlong_line(&self, line: u64) -> LogError {
        let mib = MAX_LINE_BYTES >> 20;
        self.malformed(
            line,
            format!("no line end within {mib} MiB: not a log line"),
        )
    }

    /// Drops from `text` (a block whose first line is `first_line`) the line holding byte `at`
    /// and all after it, and makes `error` at that line `pending`: the lines before it come first.
    fn stop_at(
        &mut self,
        text: &mut Vec<u8>,
        at: usize,
        first_line: u64,
        error: fn(&Self, u64) -> LogError,
    ) {
        let start = memchr::memrchr(b'\n', &text[..at]).map_or(0, |i| i + 1);
        text.truncate(start);
        self.pending = Some(error(self, first_line + newlines(text)));
    }

    /// Appends to `text` the rest of a line, at most [`MAX_LINE_BYTES`] of it: the bytes read,
    /// and whether the line was longer (it did not end within them).
    fn read_line(&mut self, text: &mut Vec<u8>) -> std::io::Result<(usize, bool)> {
        let n = (&mut self.inner)
            .take(MAX_LINE_BYTES as u64)
            .read_until(b'\n', text)?;
        let over = n == MAX_LINE_BYTES
            && text.last() != Some(&b'\n')
            && !self.inner.fill_buf()?.is_empty();
        Ok((n, over))
    }

    /// Appends the next line to `text` (checked, its comment kept); `false` at the end of the
    /// input, or at an error, which is then `pending`.
    fn append_line(&mut self, text: &mut Vec<u8>) -> bool {
        let start = text.len();
        match self.read_line(text) {
            Ok((0, _)) => return false,
            Ok((_, false)) => {}
            Ok((_, true)) => {
                text.truncate(start);
                self.pending = Some(self.overlong_line(self.number + 1));
                return false;
            }
            Err(e) => {
                self.pending = Some(self.io_error(e));
                return false;
            }
        }
        self.number += 1;
        if self.number == 1 && text[start..].starts_with("\u{feff}".as_bytes()) {
            text.drain(start..start + 3);
        }
        match std::str::from_utf8(&text[start..]) {
            Ok(line) => keep_comments(line, &mut self.comments),
            Err(_) => {
                text.truncate(start);
                self.pending = Some(self.bad_utf8(self.number));
                return false;
            }
        }
        true
    }

    /// `text`'s rows (whole lines from `first_line`), a quoted field open at its end taking the
    /// next lines ([`rows::cut_growing`]) for at most [`MAX_LINE_BYTES`] more; past that the
    /// row is dropped and an error naming the line where it starts is `pending`.
    fn cut_rows(&mut self, text: &mut Vec<u8>, first_line: u64, delimiter: u8, into: Rows) -> Rows {
        let limit = text.len() + MAX_LINE_BYTES;
        let mut overlong = false;
        let mut rows = rows::cut_growing(text, first_line, delimiter, into, |t| {
            overlong = t.len() >= limit;
            !overlong && self.append_line(t)
        });
        if overlong {
            let line = rows.pop().unwrap_or(self.number);
            let mib = MAX_LINE_BYTES >> 20;
            let message = format!(
                "a quoted field runs on over more than {mib} MiB of lines: a quote left open?"
            );
            self.pending = Some(self.malformed(line, message));
        }
        rows
    }

    /// The next block of whole lines (`None` at the end of the input, or after an error). A line
    /// that is not UTF-8 ends the block before it, and its error is the block's `pending`.
    fn next_block(&mut self, delimiter: u8, spare: Buffers) -> Result<Option<Block>, LogError> {
        if self.stopped {
            return Ok(None);
        }
        let first_line = self.number + 1;
        let Buffers {
            mut text,
            rows,
            samples,
        } = spare;
        // Read straight into the block (a buffered reader passes a read this large through).
        text.clear();
        text.resize(BLOCK_BYTES, 0);
        let mut filled = 0;
        while filled < BLOCK_BYTES {
            match self.inner.read(&mut text[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    self.stopped = true;
                    return Err(self.io_error(e));
                }
            }
        }
        text.truncate(filled);
        if text.last().is_some_and(|&b| b != b'\n') {
            match self.read_line(&mut text) {
                Ok((_, false)) => {}
                Ok((_, true)) => {
                    let end = text.len();
                    self.stop_at(&mut text, end, first_line, Self::overlong_line);
                }
                Err(e) => {
                    self.stopped = true;
                    return Err(self.io_error(e));
                }
            }
        }
        if text.is_empty() && self.pending.is_none() {
            self.stopped = true;
            return Ok(None);
        }
        match std::str::from_utf8(&text) {
            Ok(t) => keep_comments(t, &mut self.comments),
            Err(e) => {
                // The lines before the bad one come first (rare: checked twice).
                self.stop_at(&mut text, e.valid_up_to(), first_line, Self::bad_utf8);
                if let Ok(t) = std::str::from_utf8(&text) {
                    keep_comments(t, &mut self.comments);
                }
            }
        }
        let unterminated = text.last().is_some_and(|&b| b != b'\n');
        self.number += newlines(&text) + u64::from(unterminated);
        let cut = self.pending.is_none() && memchr::memchr(b'"', &text).is_some();
        let rows = if cut {
            self.cut_rows(&mut text, first_line, delimiter, rows)
        } else {
            rows
        };
        let pending = self.pending.take();
        self.stopped = pending.is_some();
        if text.is_empty() && pending.is_none() {
            return Ok(None);
        }
        Ok(Some(Block {
            buf: Buffers {
                text,
                rows,
                samples,
            },
            first_line,
            cut,
            pending,
        }))
    }

    /// Reads lines until the header row (the first neither blank nor a comment) and returns it,
    /// with its line number and the delimiter detected from it. `None` at the end of the input.
    fn header_line(&mut self) -> Result<Option<(Vec<u8>, u64, u8)>, LogError> {
        loop {
            let mut line = Vec::new();
            if !self.append_line(&mut line) {
                return match self.pending.take() {
                    Some(e) => Err(e),
                    None => Ok(None),
                };
            }
            let text = String::from_utf8_lossy(&line);
            let t = text.trim();
            if !t.is_empty() && !t.starts_with('#') {
                let delimiter = detect_delimiter(&text);
                return Ok(Some((line, self.number, delimiter)));
            }
        }
    }
}

/// Number of `\n` in `text`.
fn newlines(text: &[u8]) -> u64 {
    memchr::memchr_iter(b'\n', text).count() as u64
}

/// Keeps the text of each comment line of `text` (the lines whose first non-blank character is
/// `#`) in `comments`, without `#` and one following space.
fn keep_comments(text: &str, comments: &mut Vec<String>) {
    let mut next = 0;
    for hash in memchr::memchr_iter(b'#', text.as_bytes()) {
        if hash < next {
            continue;
        }
        let start = memchr::memrchr(b'\n', &text.as_bytes()[..hash]).map_or(0, |i| i + 1);
        let end = memchr::memchr(b'\n', &text.as_bytes()[hash..]).map_or(text.len(), |i| hash + i);
        next = end;
        if text[start..hash].trim_start().is_empty() {
            // Passed on as it is: the CSV reader skips (and counts) a line starting with `#`.
            let c = text[hash + 1..end].trim_end_matches('\r');
            comments.push(c.strip_prefix(' ').unwrap_or(c).to_string());
        }
    }
}

/// The field delimiter: whichever of `,` `;` and tab occurs most often (outside quotes) in the
/// header row, the first line that is neither blank nor a comment; `,` when none does.
pub fn detect_delimiter(text: &str) -> u8 {
    let Some(header) = text
        .lines()
        .find(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
    else {
        return b',';
    };
    let mut counts = [0usize; 3];
    let mut quoted = false;
    for b in header.bytes() {
        match b {
            b'"' => quoted = !quoted,
            b',' if !quoted => counts[0] += 1,
            b';' if !quoted => counts[1] += 1,
            b'\t' if !quoted => counts[2] += 1,
            _ => {}
        }
    }
    let best = (0..3).max_by_key(|&i| (counts[i], std::cmp::Reverse(i)));
    match best {
        Some(1) if counts[1] > 0 => b';',
        Some(2) if counts[2] > 0 => b'\t',
        _ => b',',
    }
}

/// Field `i` of a row without its surrounding whitespace (empty when the row has no such field).
/// The bytes are UTF-8: [`Lines`] checked every line before it was cut.
fn cell(row: Fields<'_>, i: usize) -> &[u8] {
    let b = row.get(i).unwrap_or_default().trim_ascii();
    // Whitespace beyond ASCII (a no-break space, say) is rare: trimmed as text.
    if b.first().is_some_and(|c| !c.is_ascii()) || b.last().is_some_and(|c| !c.is_ascii()) {
        return std::str::from_utf8(b).map_or(b, |s| s.trim().as_bytes());
    }
    b
}

/// A cell's text. Cells are UTF-8 ([`cell`]); the empty string stands in for what cannot occur.
fn text(b: &[u8]) -> &str {
    std::str::from_utf8(b).unwrap_or_default()
}

/// The header row's names, line and delimiter; an error when there is none or a name repeats.
/// A row whose fields are all blank is not a header.
fn header<R: BufRead>(
    lines: &mut Lines<R>,
    file: &str,
) -> Result<(Vec<String>, u64, u8), LogError> {
    let (names, line, delimiter) = loop {
        let Some((mut row_text, line, delimiter)) = lines.header_line()? else {
            return Err(LogError::Empty {
                file: file.into(),
                what: "no header row",
            });
        };
        let rows = lines.cut_rows(&mut row_text, line, delimiter, Rows::default());
        if let Some(e) = lines.pending.take() {
            return Err(e);
        }
        if rows.len() == 0 {
            continue;
        }
        let fields = rows.row(&row_text, 0);
        let names: Vec<String> = (0..fields.len())
            .map(|i| text(fields.get(i).unwrap_or_default()).trim().to_string())
            .collect();
        if names.iter().any(|n| !n.is_empty()) {
            break (names, line, delimiter);
        }
    };
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(LogError::DuplicateColumn {
                file: file.into(),
                line,
                column: n.clone(),
            });
        }
    }
    Ok((names, line, delimiter))
}

impl Columns {
    fn find(
        names: &[String],
        line: u64,
        file: &str,
        opts: &ReadOptions,
    ) -> Result<Columns, LogError> {
        let find = |q: Quantity| {
            let m = opts.columns.get(q);
            let index = names.iter().position(|n| *n == m.header)?;
            Some(Col {
                index,
                name: m.header,
                factor: m.factor,
            })
        };
        let required = |q: Quantity| {
            find(q).ok_or_else(|| {
                let m = opts.columns.get(q);
                LogError::MissingColumn {
                    file: file.into(),
                    line,
                    column: m.header.clone(),
                    header: names.join(","),
                    hint: missing_hint(q, &m),
                }
            })
        };
        // An optional column is optional only under its own name: one `--columns` names must be there.
        let optional = |q: Quantity| match find(q) {
            None if opts.columns.get(q).given => required(q).map(Some),
            found => Ok(found),
        };
        let known: Vec<Option<Col>> = Quantity::ALL.iter().map(|&q| find(q)).collect();
        let extra = (0..names.len())
            .filter(|&i| !known.iter().flatten().any(|c| c.index == i))
            .collect();
        Ok(Columns {
            time: required(Quantity::Time)?,
            chamber: optional(Quantity::Chamber)?,
            volume: required(Quantity::Volume)?,
            flow: optional(Quantity::Flow)?,
            pressure: required(Quantity::Pressure)?,
            force: optional(Quantity::Force)?,
            extra,
            chamber_base: opts.chamber_base,
        })
    }

    /// One row as a sample (units converted, chamber renumbered), time order not yet checked.
    /// `rec` as a sample (units converted, chamber renumbered) when it has the header's `width`
    /// fields, time order not yet checked.
    fn sample(&self, rec: Fields<'_>, width: usize, file: &str) -> Result<Sample, LogError> {
        let line = rec.line;
        if rec.len() != width {
            return Err(LogError::Malformed {
                file: file.into(),
                line,
                message: format!("row has {} fields but the header has {width}", rec.len()),
            });
        }
        let number = |c: &Col| -> Result<Option<f64>, LogError> {
            let s = cell(rec, c.index);
            if s.is_empty() {
                return Ok(None);
            }
            let bad = |problem| LogError::BadValue {
                file: file.into(),
                line,
                column: c.name.clone(),
                value: text(s).into(),
                problem,
            };
            // The syntax of `str::parse::<f64>` (a property test holds the two to each other),
            // from bytes and in about half the time.
            let x: f64 = fast_float2::parse(s).map_err(|_| bad("cannot parse as a number:"))?;
            if x.is_finite() {
                Ok(Some(x * c.factor))
            } else {
                Err(bad("not a finite number:"))
            }
        };
        let need = |c: &Col| -> Result<f64, LogError> {
            number(c)?.ok_or_else(|| LogError::BadValue {
                file: file.into(),
                line,
                column: c.name.clone(),
                value: String::new(),
                problem: "required value is empty:",
            })
        };
        let opt = |c: &Option<Col>| c.as_ref().map(number).transpose().map(Option::flatten);
        Ok(Sample {
            time_s: need(&self.time)?,
            chamber: self.chamber(rec, file)?,
            volume_mm3: need(&self.volume)?,
            flow_mm3_s: opt(&self.flow)?,
            pressure_kpa: need(&self.pressure)?,
            force_n: opt(&self.force)?,
        })
    }

    fn chamber(&self, rec: Fields<'_>, file: &str) -> Result<u8, LogError> {
        let Some(c) = &self.chamber else {
            return Ok(0);
        };
        let s = text(cell(rec, c.index));
        let base = self.chamber_base;
        match s.parse::<u8>() {
            Ok(n) if n >= base && n - base < MAX_CHAMBERS => Ok(n - base),
            _ => Err(LogError::BadChamber {
                file: file.into(),
                line: rec.line,
                column: c.name.clone(),
                value: s.into(),
                first: base,
                last: base + MAX_CHAMBERS - 1,
            }),
        }
    }
}

/// What to do about a missing column: name it with `--columns` (or fix the name given there).
fn missing_hint(q: Quantity, m: &Mapping) -> String {
    if m.given {
        format!(
            "--columns maps `{}` to `{}`, which the header does not have",
            q.key(),
            m.header
        )
    } else {
        format!(
            "if the file names it differently, map it with --columns {}=NAME[:UNIT] \
             (see docs/log-format.md)",
            q.key()
        )
    }
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
    let layout = RowLayout {
        flow: log.samples.iter().any(|s| s.flow_mm3_s.is_some()),
        force: log.samples.iter().any(|s| s.force_n.is_some()),
    };
    let mut csvw = csv::WriterBuilder::new().has_headers(false).from_writer(w);
    csvw.write_record(layout.header(&log.extra_columns))?;
    let mut row: Vec<String> = Vec::new();
    let none = vec![String::new(); log.extra_columns.len()];
    for (i, s) in log.samples.iter().enumerate() {
        layout.row(s, log.extra.get(i).unwrap_or(&none), &mut row);
        csvw.write_record(&row)?;
    }
    csvw.flush()?;
    Ok(())
}

/// Which optional known columns a written log carries: the one definition of the written header
/// and rows ([`write_log_to`], and `vfp record`'s streaming writer).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowLayout {
    /// Whether `flow_mm3_s` is written.
    pub flow: bool,
    /// Whether `force_n` is written.
    pub force: bool,
}

impl RowLayout {
    /// The header fields: the known columns in the format's order, then `extra`.
    pub fn header<'a>(&self, extra: &'a [String]) -> Vec<&'a str> {
        let mut h = vec!["time_s", "chamber", "volume_mm3"];
        if self.flow {
            h.push("flow_mm3_s");
        }
        h.push("pressure_kpa");
        if self.force {
            h.push("force_n");
        }
        h.extend(extra.iter().map(String::as_str));
        h
    }

    /// One row's fields into `row` (cleared first): numbers in shortest round-trip form, an
    /// unrecorded optional value empty, then the extra cells verbatim.
    pub fn row(&self, s: &Sample, extra: &[String], row: &mut Vec<String>) {
        let opt = |x: Option<f64>| x.map(|x| x.to_string()).unwrap_or_default();
        row.clear();
        row.push(s.time_s.to_string());
        row.push(s.chamber.to_string());
        row.push(s.volume_mm3.to_string());
        if self.flow {
            row.push(opt(s.flow_mm3_s));
        }
        row.push(s.pressure_kpa.to_string());
        if self.force {
            row.push(opt(s.force_n));
        }
        row.extend(extra.iter().cloned());
    }
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
