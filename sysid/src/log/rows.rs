//! Whole lines of a log cut into rows of fields: the reader's tokenizer.
//!
//! Between rows, line ends (`\n`, `\r`) are skipped and a `#` starts a comment that runs to
//! the end of its line. A row without a quote ends at the line's end or at a carriage return
//! and is split at its delimiters: CSV gives such a row no other reading. A row with a quote
//! goes through `csv-core`, the `csv` crate's own state machine, with the lines a quoted field
//! carries on into, so quoting, doubled quotes and line ends inside quotes read as the `csv`
//! crate reads them (a property test holds the two to each other). Each row is dated by the line
//! where it starts. The cutting needs no state from the lines before, so blocks of lines that
//! start and end between rows are cut on any core, in any order ([`cut`]); the reader finds such
//! ends with [`cut_growing`].

use memchr::{memchr, memchr3_iter, memchr_iter};
use std::ops::Range;

/// Rows cut from a block of whole lines: each row's fields as ranges of the block's text, or,
/// for fields `csv-core` unescaped, of `side` (a range past the text's end is in `side`, offset
/// by the text's length).
#[derive(Debug, Default)]
pub(super) struct Rows {
    fields: Vec<Range<u32>>,
    /// Per row, the end of its fields in `fields`.
    ends: Vec<u32>,
    /// Per row, the 1-based line where it starts.
    lines: Vec<u64>,
    side: Vec<u8>,
}

/// One row's fields, borrowed.
#[derive(Clone, Copy)]
pub(super) struct Fields<'a> {
    text: &'a [u8],
    side: &'a [u8],
    ranges: &'a [Range<u32>],
    /// The 1-based line where the row starts.
    pub line: u64,
}

impl<'a> Fields<'a> {
    /// Number of fields.
    pub fn len(&self) -> usize {
        self.ranges.len()
    }

    /// Field `i`, as in the file (unescaped when it was quoted); `None` past the last.
    pub fn get(&self, i: usize) -> Option<&'a [u8]> {
        let r = self.ranges.get(i)?;
        let (s, e) = (r.start as usize, r.end as usize);
        let n = self.text.len();
        Some(if s >= n {
            &self.side[s - n..e - n]
        } else {
            &self.text[s..e]
        })
    }
}

impl Rows {
    /// No rows (the buffers kept).
    fn clear(&mut self) {
        self.fields.clear();
        self.ends.clear();
        self.lines.clear();
        self.side.clear();
    }

    /// Drops the last row; the line where it started (`None` when there are no rows).
    pub fn pop(&mut self) -> Option<u64> {
        let line = self.lines.pop()?;
        self.ends.pop();
        self.fields
            .truncate(self.ends.last().map_or(0, |&e| e as usize));
        Some(line)
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    /// Row `k` of the block whose text is `text` (the text these rows were cut from).
    pub fn row<'a>(&'a self, text: &'a [u8], k: usize) -> Fields<'a> {
        let start = if k == 0 { 0 } else { self.ends[k - 1] as usize };
        Fields {
            text,
            side: &self.side,
            ranges: &self.fields[start..self.ends[k] as usize],
            line: self.lines[k],
        }
    }
}

/// Where the bytes of a cut come from: the text so far, and whether more lines can be had.
trait Source {
    fn text(&self) -> &[u8];
    /// Appends the next line of the input; `false` at its end.
    fn grow(&mut self) -> bool;
}

struct Fixed<'a>(&'a [u8]);

impl Source for Fixed<'_> {
    fn text(&self) -> &[u8] {
        self.0
    }
    fn grow(&mut self) -> bool {
        false
    }
}

struct Growing<'a, F> {
    text: &'a mut Vec<u8>,
    more: F,
}

impl<F: FnMut(&mut Vec<u8>) -> bool> Source for Growing<'_, F> {
    fn text(&self) -> &[u8] {
        self.text
    }
    fn grow(&mut self) -> bool {
        (self.more)(self.text)
    }
}

/// The rows of `text`, whole lines whose first is line `first_line` and which start between
/// rows; a quoted field still open at the end of `text` ends there, as at the end of a file.
/// `into`'s buffers are reused.
pub(super) fn cut(text: &[u8], first_line: u64, delimiter: u8, into: Rows) -> Rows {
    cut_from(&mut Fixed(text), first_line, delimiter, into)
}

/// [`cut`], where a quoted field open at the end of `text` (a row carried on into lines not yet
/// loaded) takes the following lines, which `more` appends to `text` (returning `false` at the
/// end of the input): `text` then ends between rows.
pub(super) fn cut_growing(
    text: &mut Vec<u8>,
    first_line: u64,
    delimiter: u8,
    into: Rows,
    more: impl FnMut(&mut Vec<u8>) -> bool,
) -> Rows {
    cut_from(&mut Growing { text, more }, first_line, delimiter, into)
}

fn cut_from(src: &mut impl Source, first_line: u64, delimiter: u8, mut into: Rows) -> Rows {
    into.clear();
    let mut cx = Cutting {
        rows: into,
        side_fields: Vec::new(),
        quoted: None,
        delimiter,
        line: first_line,
    };
    let mut at = 0;
    // The first carriage return at or after `at`, when the text's first `searched` bytes have
    // one (searched again once passed, or once a quoted row has taken more lines).
    let (mut cr, mut searched) = (None, 0);
    while at < src.text().len() {
        let text = src.text();
        if cr.map_or(searched < text.len(), |c| c < at) {
            cr = memchr(b'\r', &text[at..]).map(|i| at + i);
            searched = text.len();
        }
        at = if cr.is_none() {
            cx.without_returns(src, at)
        } else {
            cx.by_lines(src, at)
        };
    }
    let Cutting {
        mut rows,
        side_fields,
        ..
    } = cx;
    let base = src.text().len() as u32;
    for k in side_fields {
        let r: &mut Range<u32> = &mut rows.fields[k];
        *r = r.start + base..r.end + base;
    }
    rows
}

/// A cut under way.
struct Cutting {
    rows: Rows,
    /// Fields in `rows.side`, numbered from 0 there until the text's final length is known.
    side_fields: Vec<usize>,
    /// Built at the first quoted row (building csv-core's tables costs as much as a block).
    quoted: Option<Quoted>,
    delimiter: u8,
    /// The line of the text's byte being looked at.
    line: u64,
}

/// Where [`Cutting::without_returns`] is: at a row's start, in a row, or in a comment.
#[derive(PartialEq)]
enum At {
    Start,
    Row,
    Comment,
}

impl Cutting {
    /// Cuts the text from `at` (a row's start), which has no carriage return, with one
    /// vectorised search for delimiters, line ends and quotes; returns where it stopped: the
    /// text's end, or the end of a quoted row (read by csv-core).
    fn without_returns(&mut self, src: &mut impl Source, at: usize) -> usize {
        let (d, text) = (self.delimiter, src.text());
        #[cfg(target_arch = "x86_64")]
        let stop = match memchr::arch::x86_64::avx2::memchr::Three::new(d, b'\n', b'"') {
            Some(three) => self.scan(text, at, three.iter(&text[at..])),
            None => self.scan(text, at, memchr3_iter(d, b'\n', b'"', &text[at..])),
        };
        #[cfg(not(target_arch = "x86_64"))]
        let stop = self.scan(text, at, memchr3_iter(d, b'\n', b'"', &text[at..]));
        match stop {
            Ok(end) => end,
            Err(row) => self.quoted_row(src, row),
        }
    }

    /// [`Cutting::without_returns`] over `hits`, the offsets from `at` of the text's delimiters,
    /// line ends and quotes, in order: `Ok` with the text's end, or `Err` with the start of a
    /// row with a quote (its fields not taken).
    fn scan(
        &mut self,
        text: &[u8],
        at: usize,
        hits: impl Iterator<Item = usize>,
    ) -> Result<usize, usize> {
        let (mut row, mut field, mut state) = (at, at, At::Start);
        for i in hits.map(|i| at + i) {
            if state == At::Start {
                if i == row && text[i] == b'\n' {
                    self.line += 1;
                    row = i + 1;
                    field = row;
                    continue;
                }
                state = if text[row] == b'#' {
                    At::Comment
                } else {
                    At::Row
                };
                if state == At::Row {
                    self.rows.lines.push(self.line);
                }
            }
            match (&state, text[i]) {
                (At::Comment, b'\n') => {
                    (self.line, row, field, state) = (self.line + 1, i + 1, i + 1, At::Start);
                }
                (At::Comment, _) => {}
                (_, b'"') => {
                    self.rows.lines.pop();
                    self.rows
                        .fields
                        .truncate(self.rows.ends.last().map_or(0, |&e| e as usize));
                    return Err(row);
                }
                (_, b'\n') => {
                    self.rows.fields.push(field as u32..i as u32);
                    self.rows.ends.push(self.rows.fields.len() as u32);
                    (self.line, row, field, state) = (self.line + 1, i + 1, i + 1, At::Start);
                }
                _ => {
                    self.rows.fields.push(field as u32..i as u32);
                    field = i + 1;
                }
            }
        }
        let end = text.len();
        if state == At::Row || (state == At::Start && row < end && text[row] != b'#') {
            if state == At::Start {
                self.rows.lines.push(self.line);
            }
            self.rows.fields.push(field as u32..end as u32);
            self.rows.ends.push(self.rows.fields.len() as u32);
        }
        Ok(end)
    }

    /// Cuts the line at `at` (a row's start), and the lines a quoted field carries on into;
    /// returns where it stopped.
    fn by_lines(&mut self, src: &mut impl Source, at: usize) -> usize {
        let text = src.text();
        match text[at] {
            b'\n' => {
                self.line += 1;
                at + 1
            }
            b'\r' => at + 1,
            b'#' => memchr(b'\n', &text[at..]).map_or(text.len(), |i| at + i),
            _ => {
                let first = self.rows.fields.len();
                match plain_row(text, at, self.delimiter, &mut self.rows.fields) {
                    Some(end) => {
                        self.rows.lines.push(self.line);
                        self.rows.ends.push(self.rows.fields.len() as u32);
                        end
                    }
                    None => {
                        self.rows.fields.truncate(first);
                        self.quoted_row(src, at)
                    }
                }
            }
        }
    }

    /// The row at `at` read by csv-core; returns where it ended.
    fn quoted_row(&mut self, src: &mut impl Source, at: usize) -> usize {
        self.rows.lines.push(self.line);
        let q = self
            .quoted
            .get_or_insert_with(|| Quoted::new(self.delimiter));
        let stop = q.record(src, at, &mut self.rows, &mut self.side_fields);
        self.line += memchr_iter(b'\n', &src.text()[at..stop]).count() as u64;
        stop
    }
}

/// The fields of the row starting at `at` pushed onto `fields`, when it has no quote: it ends at
/// the next line end (`\n` or `\r`, not taken) or the end of the text, which is returned. `None`
/// at a quote (some fields may have been pushed).
fn plain_row(text: &[u8], at: usize, delimiter: u8, fields: &mut Vec<Range<u32>>) -> Option<usize> {
    let mut start = at;
    for (i, &b) in text.iter().enumerate().skip(at) {
        if b == delimiter {
            fields.push(start as u32..i as u32);
            start = i + 1;
        } else if b == b'\n' || b == b'\r' {
            fields.push(start as u32..i as u32);
            return Some(i);
        } else if b == b'"' {
            return None;
        }
    }
    fields.push(start as u32..text.len() as u32);
    Some(text.len())
}

/// `csv-core` and its buffers, for the rows the plain split does not read.
struct Quoted {
    core: csv_core::Reader,
    out: Vec<u8>,
    ends: Vec<usize>,
}

impl Quoted {
    fn new(delimiter: u8) -> Self {
        Self {
            core: csv_core::ReaderBuilder::new().delimiter(delimiter).build(),
            out: vec![0; 256],
            ends: vec![0; 16],
        }
    }

    /// Reads the one row starting at `at` (a row's start) into `rows` (its fields' bytes into
    /// `rows.side`, their indices into `side_fields`), taking more lines from `src` while a
    /// quoted field is open. Returns where the row ended.
    fn record(
        &mut self,
        src: &mut impl Source,
        at: usize,
        rows: &mut Rows,
        side_fields: &mut Vec<usize>,
    ) -> usize {
        use csv_core::ReadRecordResult as R;
        self.core.reset();
        let (mut pos, mut nout, mut nend) = (at, 0, 0);
        loop {
            // At the end of the text: the next line, else the end of the input (an empty input
            // tells csv-core so, and it ends the row).
            let at_end = pos == src.text().len() && !src.grow();
            let input = if at_end { &[][..] } else { &src.text()[pos..] };
            let (res, nin, o, e) =
                self.core
                    .read_record(input, &mut self.out[nout..], &mut self.ends[nend..]);
            pos += nin;
            nout += o;
            nend += e;
            match res {
                R::OutputFull => self.out.resize(self.out.len() * 2, 0),
                R::OutputEndsFull => self.ends.resize(self.ends.len() * 2, 0),
                R::InputEmpty if !at_end => {}
                R::InputEmpty | R::Record | R::End => break,
            }
        }
        let base = rows.side.len();
        rows.side.extend_from_slice(&self.out[..nout]);
        let mut start = 0;
        for &end in &self.ends[..nend] {
            side_fields.push(rows.fields.len());
            rows.fields.push((base + start) as u32..(base + end) as u32);
            start = end;
        }
        rows.ends.push(rows.fields.len() as u32);
        pos
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The `csv` crate's rows of `text` (comments `#`, any number of fields), with their lines.
    fn csv_crate(text: &[u8]) -> Vec<(u64, Vec<String>)> {
        let mut r = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .comment(Some(b'#'))
            .from_reader(text);
        let mut rec = csv::ByteRecord::new();
        let mut out = Vec::new();
        while r.read_byte_record(&mut rec).expect("in memory") {
            let line = rec.position().expect("a read record has one").line();
            let cells = rec
                .iter()
                .map(|f| String::from_utf8_lossy(f).into_owned())
                .collect();
            out.push((line, cells));
        }
        out
    }

    proptest! {
        /// Whatever the quotes, line ends and comments, the rows are the `csv` crate's, each at
        /// the line where it starts; and a text cut into blocks at any line ends, each grown to
        /// the end of its last row, gives the same rows.
        #[test]
        fn rows_are_the_csv_crates(
            lines in proptest::collection::vec("[a,\"#\r ]{0,7}", 0..14),
            cuts in proptest::collection::vec(0usize..14, 0..4),
        ) {
            // Every line ends (the csv crate reads a comment ending the file without one as a
            // row of one empty field).
            let text: String = lines.iter().map(|l| format!("{l}\n")).collect();
            let whole = strings(text.as_bytes(), &cut(text.as_bytes(), 1, b',', Rows::default()));
            let theirs = csv_crate(text.as_bytes());
            let fields = |rows: &[(u64, Vec<String>)]| -> Vec<Vec<String>> {
                rows.iter().map(|r| r.1.clone()).collect()
            };
            prop_assert_eq!(fields(&whole), fields(&theirs));
            // The csv crate dates a row from the first of the empty lines and comments before
            // it (and, after a `\r\n`, from the line before): here it is the row's own line.
            for ((ours, _), (csv_line, _)) in whole.iter().zip(&theirs) {
                prop_assert!(ours >= csv_line);
                if !text.contains('\r') {
                    for skipped in &lines[(*csv_line - 1) as usize..(*ours - 1) as usize] {
                        prop_assert!(skipped.is_empty() || skipped.starts_with('#'), "{:?}", skipped);
                    }
                }
            }
            let want = whole;

            // Blocks: whole lines up to each cut, the rest of a row taken from the lines after.
            let all: Vec<&str> = text.split_inclusive('\n').collect();
            let mut next = 0;
            let mut got = Vec::new();
            let mut line = 1;
            let mut bounds: Vec<usize> = cuts.iter().map(|&c| c.min(all.len())).collect();
            bounds.sort_unstable();
            bounds.push(all.len());
            for b in bounds {
                if b <= next {
                    continue;
                }
                let mut block: Vec<u8> = all[next..b].concat().into_bytes();
                let mut taken = b;
                let rows = cut_growing(&mut block, line, b',', Rows::default(), |t| match all.get(taken) {
                    Some(l) => {
                        t.extend_from_slice(l.as_bytes());
                        taken += 1;
                        true
                    }
                    None => false,
                });
                got.extend(strings(&block, &rows));
                line += block.iter().filter(|&&c| c == b'\n').count() as u64;
                next = taken;
            }
            prop_assert_eq!(got, want);
        }
    }

    fn strings(text: &[u8], rows: &Rows) -> Vec<(u64, Vec<String>)> {
        (0..rows.len())
            .map(|k| {
                let f = rows.row(text, k);
                let cells = (0..f.len())
                    .map(|i| String::from_utf8_lossy(f.get(i).unwrap()).into_owned())
                    .collect();
                (f.line, cells)
            })
            .collect()
    }

    #[test]
    fn plain_quoted_and_carried_rows_with_their_lines() {
        let text = b"a,b\r\n\n# note, \"odd\n\"x,\"\"y\"\"\",2\n\"multi\nline\",3\nz,4";
        let rows = cut(text, 10, b',', Rows::default());
        assert_eq!(
            strings(text, &rows),
            [
                (10, vec!["a".into(), "b".into()]),
                (13, vec!["x,\"y\"".into(), "2".into()]),
                (14, vec!["multi\nline".into(), "3".into()]),
                (16, vec!["z".into(), "4".into()]),
            ]
        );
    }

    #[test]
    fn a_comment_or_a_crlf_ending_the_text_is_no_row() {
        for text in [&b"1,2\n# end"[..], b"1,2\r\n", b"1,2\r\n\r\n"] {
            let rows = cut(text, 1, b',', Rows::default());
            assert_eq!(strings(text, &rows), [(1, vec!["1".into(), "2".into()])]);
        }
    }

    #[test]
    fn a_quoted_field_open_at_the_end_takes_the_next_lines() {
        let mut text = b"1,\"a\n".to_vec();
        let mut rest = [b"b\n".to_vec(), b"c\",2\n".to_vec(), b"3,4\n".to_vec()].into_iter();
        let rows = cut_growing(&mut text, 1, b',', Rows::default(), |t| {
            rest.next().map(|l| t.extend_from_slice(&l)).is_some()
        });
        assert_eq!(text, b"1,\"a\nb\nc\",2\n");
        assert_eq!(
            strings(&text, &rows),
            [(1, vec!["1".into(), "a\nb\nc".into(), "2".into()])]
        );
    }
}
