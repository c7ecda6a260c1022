//! Magnetometer logs: text files of raw readings, one per row.
//!
//! Columns by name (any case) or by 1-based index (`--columns mx,my,mz` or `--columns 4,5,6`);
//! by default the columns named `x`, `y`, `z` (with or without an `m`, `mag` or `mag_` prefix, any
//! case), else the first three columns whose first data row is numeric. A first row with a cell
//! that is not a number is a header. Every row is read; a cell that is not a number is an error
//! naming its line and column, and so is a row with a non-finite or missing value unless the
//! caller skips such rows, counting them (`--skip-bad`). Rows that fail a [`RowFilter`]
//! (`--where COLUMN=VALUE`) are counted and not read further.
//!
//! # Format
//! - The separator is taken from the first line that is not blank or a comment: `;` if it has
//!   one, else a tab, else `,`, else runs of spaces. With `;`, tab or spaces a number may have a
//!   decimal comma (`0,123`); with `,` it cannot, and such a cell is refused naming the reason.
//! - Lines end in `\n`, `\r\n` or `\r` (each counts as one line, so line numbers are those an
//!   editor shows); blank lines and lines starting with `#` are skipped; a UTF-8 byte-order mark
//!   is ignored. A cell may be quoted (`"mx"`); a quote must close on its line.
//!
//! # Bounds
//! Every read is bounded, whatever the file is (a regular file, a FIFO, a device): a line longer
//! than [`MAX_LINE_BYTES`] is an error, and so is a log with more rows than half of the memory the
//! process may use can hold ([`limits::available_memory`]) at the caller's cost per reading
//! ([`HELD_BYTES_PER_READING`] for a log held whole, [`crate::source::open`]). Errors quote at most [`EXCERPT_CHARS`] characters
//! of the input.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::Vec3;

use crate::digest::Hashing;
use crate::limits;

/// Longest line read, bytes: a row of a hundred columns of 20 characters is 2 KiB.
pub const MAX_LINE_BYTES: usize = 1 << 20;
/// Memory a held reading costs the commands that hold a log, bytes: the reading and its line
/// (32 B), the fit's copies and residuals, and `next`'s scaled and calibrated copies; measured at
/// 61 B (`calibrate`), 95 B (`calibrate --reject --out`) and 126 B (`next`) at their peak, and
/// doubled for the growth of the vectors that hold them.
pub const HELD_BYTES_PER_READING: u64 = 256;
/// Memory a skipped row costs (its line and reason), bytes.
const SKIPPED_BYTES: u64 = 96;
/// Characters of the input an error quotes at most.
pub const EXCERPT_CHARS: usize = 40;
/// Column names an error lists at most.
const LISTED_COLUMNS: usize = 12;

/// What [`stream`] read.
#[derive(Debug, Clone)]
pub struct Streamed {
    /// Readings passed on.
    pub readings: usize,
    /// Lines skipped for a non-finite or missing value (only with `skip_bad`), with the reason.
    pub skipped: Vec<(usize, String)>,
    /// Data rows that failed a [`RowFilter`] (not read further).
    pub filtered: usize,
    /// The names of the three columns read (`column 4` without a header).
    pub columns: [String; 3],
    /// SHA-256 of the file's bytes as read (lower-case hex).
    pub sha256: String,
    /// The file's size in bytes as read.
    pub bytes: u64,
}

/// Reads `path` row by row, calling `each(line, reading)` for every reading in file order, and
/// returns the columns read and the rows skipped. `held_bytes_per_reading` is what the caller
/// keeps of each reading (0 when it keeps nothing): the log may hold as many readings as half of
/// the memory the process may use allows at that cost.
///
/// # Errors
/// A missing or unreadable file, a directory, a line longer than [`MAX_LINE_BYTES`], more rows
/// than memory allows, no data rows, an unknown, ambiguous or repeated column, a cell that is not
/// a number (line and column named), a non-finite or missing value (unless `skip_bad`), a quote
/// not closed on its line, or an error of `each`.
pub fn stream<F>(
    path: &Path,
    columns: Option<&str>,
    skip_bad: bool,
    held_bytes_per_reading: u64,
    mut each: F,
) -> Result<Streamed>
where
    F: FnMut(usize, Vec3) -> Result<()>,
{
    stream_with(
        path,
        columns,
        &[],
        &[],
        skip_bad,
        held_bytes_per_reading,
        |line, reading, _| each(line, reading),
    )
}

/// A column read beside the three of the field (a time, an attitude, a current): the flag that
/// names it (for errors) and its name or 1-based index.
#[derive(Debug, Clone, Copy)]
pub struct Extra<'a> {
    pub flag: &'a str,
    pub column: &'a str,
}

/// A condition a CSV row must meet to be read (`--where COLUMN=VALUE`): the cell of `column`
/// (a name in any case, or a 1-based index) equals `value`, as numbers when `value` is one
/// (`1` matches `1.0`; an empty cell does not match, a cell that is not a number is an error),
/// else as text (the cell unquoted and trimmed, case kept).
#[derive(Debug, Clone, PartialEq)]
pub struct RowFilter {
    pub column: String,
    pub value: String,
}

impl RowFilter {
    /// `COLUMN=VALUE` (split at the first `=`; both non-empty once trimmed): clap's parser.
    ///
    /// # Errors
    /// Text without `=`, or with nothing before or after it.
    pub fn parse(text: &str) -> Result<Self, String> {
        match text.split_once('=') {
            Some((c, v)) if !c.trim().is_empty() && !v.trim().is_empty() => Ok(Self {
                column: c.trim().to_string(),
                value: v.trim().to_string(),
            }),
            _ => Err(format!(
                "{}: give COLUMN=VALUE, such as movement=1",
                excerpt(text.as_bytes())
            )),
        }
    }

    /// The filter as the user wrote it, cut to an excerpt.
    pub fn shown(&self) -> String {
        let text = format!("{}={}", self.column, self.value);
        let cut: String = text.chars().take(EXCERPT_CHARS).collect();
        if cut.len() < text.len() {
            format!("{cut}...")
        } else {
            cut
        }
    }

    /// The value as a number, when it is one.
    fn number(&self) -> Option<f64> {
        self.value.parse::<f64>().ok()
    }
}

/// [`stream`], also reading the columns `extras` and keeping only the rows that meet every one
/// of `filters`: `each(line, reading, values)` gets one value per extra, `None` where its cell
/// is empty or not finite (an attitude the capture lost); a cell that is not a number is an
/// error naming its line and column.
///
/// # Errors
/// As [`stream`]; an extra or filter column that is not in the log, an extra column that is one
/// of the field's, a filter's cell that is not a number where its value is one, no row meeting
/// the filters.
pub fn stream_with<F>(
    path: &Path,
    columns: Option<&str>,
    extras: &[Extra],
    filters: &[RowFilter],
    skip_bad: bool,
    held_bytes_per_reading: u64,
    mut each: F,
) -> Result<Streamed>
where
    F: FnMut(usize, Vec3, &[Option<f64>]) -> Result<()>,
{
    let shown = path.display().to_string();
    let file = crate::limits::Bounded::open_log(path, &shown)?;
    let budget = Budget::new(held_bytes_per_reading);
    let mut hashing = Hashing::new(file);
    let mut s = read_from(
        BufReader::with_capacity(1 << 16, &mut hashing),
        &shown,
        Wanted {
            columns,
            extras,
            filters,
            skip_bad,
        },
        &budget,
        &mut each,
    )?;
    // Every line was read: the hash covers the whole file, the bytes the reader parsed.
    s.sha256 = hashing.hex();
    s.bytes = Hashing::bytes(&hashing);
    Ok(s)
}

/// What [`read_from`] calls with each reading: its line, the field and the extras' values.
type RowFn<'a> = dyn FnMut(usize, Vec3, &[Option<f64>]) -> Result<()> + 'a;

/// What [`read_from`] reads of each row.
#[derive(Clone, Copy)]
struct Wanted<'a> {
    columns: Option<&'a str>,
    extras: &'a [Extra<'a>],
    filters: &'a [RowFilter],
    skip_bad: bool,
}

/// The memory a log may take: half of what the process may use.
struct Budget {
    held: u64,
    limit: Option<(u64, u64, &'static str)>,
}

impl Budget {
    fn new(held: u64) -> Self {
        Self {
            held,
            limit: limits::available_memory().map(|(a, what)| (a / 2, a, what)),
        }
    }

    /// Refuses one more row when `readings` held and `skipped` rows already take the budget.
    fn check(&self, shown: &str, line: usize, readings: usize, skipped: usize) -> Result<()> {
        let Some((limit, available, what)) = self.limit else {
            return Ok(());
        };
        let used = self.held.saturating_mul(readings as u64 + 1) + SKIPPED_BYTES * skipped as u64;
        if used > limit {
            bail!(
                "{shown}: line {line}: the log holds more rows than fit in memory ({readings} readings of about {} B and {skipped} skipped rows; the limit is {}, half of {} {what})",
                self.held,
                limits::bytes(limit),
                limits::bytes(available)
            );
        }
        Ok(())
    }
}

/// The field separator of a log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Separator {
    /// One byte: `,`, `;` or a tab.
    Byte(u8),
    /// Runs of spaces or tabs.
    Whitespace,
}

impl Separator {
    /// From the first line that is not blank or a comment (see the module docs).
    fn sniff(line: &[u8]) -> Self {
        let mut quoted = false;
        let (mut semicolons, mut tabs, mut commas) = (0, 0, 0);
        for &b in line {
            match b {
                b'"' => quoted = !quoted,
                b';' if !quoted => semicolons += 1,
                b'\t' if !quoted => tabs += 1,
                b',' if !quoted => commas += 1,
                _ => {}
            }
        }
        if semicolons > 0 {
            Self::Byte(b';')
        } else if tabs > 0 {
            Self::Byte(b'\t')
        } else if commas > 0 {
            Self::Byte(b',')
        } else if line.trim_ascii().contains(&b' ') {
            Self::Whitespace
        } else {
            Self::Byte(b',')
        }
    }

    fn name(self) -> &'static str {
        match self {
            Self::Byte(b',') => "comma-separated",
            Self::Byte(b';') => "semicolon-separated",
            Self::Byte(b'\t') => "tab-separated",
            Self::Byte(_) => "separated",
            Self::Whitespace => "space-separated",
        }
    }

    /// A decimal comma is read only when the comma does not separate cells.
    fn decimal_comma(self) -> bool {
        self != Self::Byte(b',')
    }
}

/// Splits one line into cells: at its separator byte where it has no quote, else unquoting them
/// (csv-core); or at runs of whitespace.
struct Splitter {
    separator: Separator,
    reader: csv_core::Reader,
    out: Vec<u8>,
    ends: Vec<usize>,
    count: usize,
}

impl Splitter {
    fn new(separator: Separator) -> Self {
        let mut builder = csv_core::ReaderBuilder::new();
        if let Separator::Byte(b) = separator {
            builder.delimiter(b);
        }
        Self {
            separator,
            reader: builder.build(),
            out: Vec::new(),
            ends: Vec::new(),
            count: 0,
        }
    }

    /// Splits `line` (which ends in the `\n` the caller appended). `Err(())`: a quote not closed.
    fn split(&mut self, line: &[u8]) -> Result<(), ()> {
        self.out.clear();
        self.ends.clear();
        match self.separator {
            Separator::Whitespace => {
                for token in line.split(|b| b.is_ascii_whitespace()).filter(|t| !t.is_empty()) {
                    self.out.extend_from_slice(token);
                    self.ends.push(self.out.len());
                }
                self.count = self.ends.len();
                Ok(())
            }
            // Without a quote, csv-core's cells are the bytes between separators (the line has
            // no other terminator than its last byte): split there, without csv-core's state machine.
            Separator::Byte(d) if !line.contains(&b'"') => {
                let body = line.strip_suffix(b"\n").unwrap_or(line);
                for cell in body.split(|&b| b == d) {
                    self.out.extend_from_slice(cell);
                    self.ends.push(self.out.len());
                }
                self.count = self.ends.len();
                Ok(())
            }
            Separator::Byte(_) => {
                // Unquoted cells are never longer than the line, and there are at most as many
                // cells as bytes plus one.
                self.out.resize(line.len(), 0);
                self.ends.resize(line.len() + 1, 0);
                self.reader.reset();
                let (result, _, _, count) = self.reader.read_record(line, &mut self.out, &mut self.ends);
                self.count = count;
                match result {
                    csv_core::ReadRecordResult::Record => Ok(()),
                    _ => Err(()),
                }
            }
        }
    }

    fn len(&self) -> usize {
        self.count
    }

    /// Cell `i`, trimmed of spaces; `None` past the end.
    fn get(&self, i: usize) -> Option<&[u8]> {
        if i >= self.count {
            return None;
        }
        let start = if i == 0 { 0 } else { self.ends[i - 1] };
        Some(self.out[start..self.ends[i]].trim_ascii())
    }
}

/// The lines of a reader, each without its terminator (`\n`, `\r\n` or `\r`), numbered from 1,
/// at most [`MAX_LINE_BYTES`] long.
struct Lines<R> {
    inner: R,
    line: usize,
    after_cr: bool,
}

impl<R: BufRead> Lines<R> {
    fn new(inner: R) -> Self {
        Self {
            inner,
            line: 0,
            after_cr: false,
        }
    }

    /// The next line into `buf`, and its number; `None` at the end.
    fn next(&mut self, buf: &mut Vec<u8>, shown: &str) -> Result<Option<usize>> {
        buf.clear();
        let mut started = false;
        loop {
            let chunk = match self.inner.fill_buf() {
                Ok(c) => c,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                // A stream's bound names the file in its own words.
                Err(e) if e.get_ref().is_some_and(|r| r.is::<crate::limits::StreamBound>()) => {
                    bail!("{e} (at line {})", self.line + 1)
                }
                Err(e) => bail!("{shown}: line {}: cannot read: {e}", self.line + 1),
            };
            if chunk.is_empty() {
                if started {
                    self.line += 1;
                    return Ok(Some(self.line));
                }
                return Ok(None);
            }
            // The `\n` of a `\r\n` split across two reads.
            let skip = usize::from(std::mem::take(&mut self.after_cr) && chunk[0] == b'\n');
            let rest = &chunk[skip..];
            let end = rest.iter().position(|&b| b == b'\n' || b == b'\r');
            let take = end.unwrap_or(rest.len());
            if buf.len() + take > MAX_LINE_BYTES {
                buf.extend_from_slice(&rest[..take.min(4 * EXCERPT_CHARS)]);
                bail!(
                    "{shown}: line {} is longer than {} (it starts {}); is this a log?",
                    self.line + 1,
                    limits::bytes(MAX_LINE_BYTES as u64),
                    excerpt(buf)
                );
            }
            buf.extend_from_slice(&rest[..take]);
            started |= take > 0;
            match end {
                Some(i) => {
                    self.after_cr = rest[i] == b'\r';
                    self.inner.consume(skip + i + 1);
                    self.line += 1;
                    return Ok(Some(self.line));
                }
                None => {
                    let n = chunk.len();
                    self.inner.consume(n);
                }
            }
        }
    }
}

/// At most [`EXCERPT_CHARS`] characters of `bytes`, quoted, with `...` when cut.
pub fn excerpt(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(&bytes[..bytes.len().min(4 * EXCERPT_CHARS)]);
    let cut: String = text.chars().take(EXCERPT_CHARS).collect();
    if cut.len() < bytes.len() {
        format!("{cut:?}...")
    } else {
        format!("{cut:?}")
    }
}

/// A cell as a number: plain, or with a decimal comma where the separator allows one.
fn number(cell: &[u8], separator: Separator) -> Option<f64> {
    let text = std::str::from_utf8(cell).ok()?;
    if let Ok(v) = text.parse::<f64>() {
        return Some(v);
    }
    if separator.decimal_comma() && decimal_comma(cell) {
        return text.replacen(',', ".", 1).parse::<f64>().ok();
    }
    None
}

/// `-1,5`, `0,123e3`: digits, one comma, digits.
fn decimal_comma(cell: &[u8]) -> bool {
    let body = cell
        .strip_prefix(b"-")
        .or_else(|| cell.strip_prefix(b"+"))
        .unwrap_or(cell);
    let Some(comma) = body.iter().position(|&b| b == b',') else {
        return false;
    };
    let (int, frac) = (&body[..comma], &body[comma + 1..]);
    !int.is_empty()
        && int.iter().all(u8::is_ascii_digit)
        && frac.first().is_some_and(u8::is_ascii_digit)
        && frac
            .iter()
            .all(|b| b.is_ascii_digit() || matches!(b, b'e' | b'E' | b'-' | b'+'))
}

/// Names for an error: at most [`LISTED_COLUMNS`], each cut to a few characters.
fn list(names: &[String]) -> String {
    let mut shown: Vec<String> = names
        .iter()
        .take(LISTED_COLUMNS)
        .map(|n| {
            let cut: String = n.chars().take(24).collect();
            if cut.len() < n.len() { format!("{cut}...") } else { cut }
        })
        .collect();
    if names.len() > LISTED_COLUMNS {
        shown.push(format!("... ({} columns)", names.len()));
    }
    shown.join(", ")
}

/// The reading loop of [`stream`] over any reader.
fn read_from<R: Read>(
    input: BufReader<R>,
    shown: &str,
    wanted: Wanted,
    budget: &Budget,
    each: &mut RowFn,
) -> Result<Streamed> {
    let Wanted {
        columns,
        extras,
        filters,
        skip_bad,
    } = wanted;
    let mut lines = Lines::new(input);
    let mut buf = Vec::new();
    let mut splitter: Option<Splitter> = None;
    let mut names: Vec<String> = Vec::new();
    let mut pick: Option<[usize; 3]> = None;
    let mut extra_pick: Vec<usize> = Vec::new();
    let mut extra_values: Vec<Option<f64>> = Vec::new();
    let mut filter_pick: Vec<usize> = Vec::new();
    let mut filtered = 0usize;
    let mut first_row = true;
    let mut readings = 0usize;
    let mut skipped: Vec<(usize, String)> = Vec::new();
    while let Some(line) = lines.next(&mut buf, shown)? {
        text_line(&mut buf, line, shown)?;
        let content = buf.trim_ascii_start();
        if content.is_empty() || content[0] == b'#' {
            continue;
        }
        let s = splitter.get_or_insert_with(|| Splitter::new(Separator::sniff(content)));
        let separator = s.separator;
        buf.push(b'\n');
        if s.split(&buf).is_err() {
            bail!(
                "{shown}: line {line}: a quote (\") is not closed on its line: {}",
                excerpt(buf.trim_ascii())
            );
        }
        if (0..s.len()).all(|i| s.get(i).is_some_and(<[u8]>::is_empty)) {
            continue;
        }
        if first_row {
            first_row = false;
            let header = (0..s.len()).any(|i| {
                let cell = s.get(i).unwrap_or_default();
                !cell.is_empty() && number(cell, separator).is_none()
            });
            if header {
                names = header_names(s);
                continue;
            }
            names = (1..=s.len()).map(|i| format!("column {i}")).collect();
        }
        let pick = match pick {
            Some(p) => p,
            None => {
                let (p, e, f) = pick_columns(s, &names, columns, (extras, filters), shown)?;
                (extra_pick, filter_pick) = (e, f);
                *pick.insert(p)
            }
        };
        if !passes(s, filters, &filter_pick, &names, shown, line)? {
            filtered += 1;
            continue;
        }
        let (value, bad) = row_value(s, pick, &names, shown, line)?;
        extra_values.clear();
        for &c in &extra_pick {
            extra_values.push(extra_value(s, c, &names, shown, line)?);
        }
        budget.check(shown, line, readings, skipped.len())?;
        match bad {
            Some(reason) if skip_bad => skipped.push((line, reason)),
            Some(reason) => bail!("{shown}: line {line}: {reason} (--skip-bad drops such rows and counts them)"),
            None => {
                each(line, value, &extra_values)?;
                readings += 1;
            }
        }
    }
    if splitter.is_none() {
        bail!("{shown}: the log is empty");
    }
    let Some(pick) = pick else {
        bail!("{shown}: the log has a header but no readings");
    };
    if readings == 0 {
        bail!("{shown}: {}", no_readings(filters, filtered, skipped.len()));
    }
    Ok(Streamed {
        readings,
        skipped,
        filtered,
        columns: pick.map(|i| column_name(&names, i)),
        sha256: String::new(),
        bytes: 0,
    })
}

/// Why a log gave no readings: every row left out by `filters`, or skipped.
fn no_readings(filters: &[RowFilter], filtered: usize, skipped: usize) -> String {
    if skipped == 0 && filtered > 0 {
        let shown: Vec<String> = filters.iter().map(|f| format!("--where {}", f.shown())).collect();
        format!("no row meets {} ({filtered} rows)", shown.join(" and "))
    } else {
        format!("no readings ({skipped} rows skipped)")
    }
}

/// The field's three columns, the extras' columns and the filters' columns, from the first data
/// row (which decides which columns are numeric).
fn pick_columns(
    s: &Splitter,
    names: &[String],
    columns: Option<&str>,
    (extras, filters): (&[Extra], &[RowFilter]),
    shown: &str,
) -> Result<([usize; 3], Vec<usize>, Vec<usize>)> {
    let separator = s.separator;
    let numeric: Vec<bool> = (0..names.len())
        .map(|i| s.get(i).is_some_and(|c| number(c, separator).is_some()))
        .collect();
    let p = choose(names, &numeric, columns).with_context(|| format!("{shown} (read as {})", separator.name()))?;
    let e: Vec<usize> = extras
        .iter()
        .map(|e| choose_extra(names, e, &p))
        .collect::<Result<_>>()
        .with_context(|| shown.to_string())?;
    // One column, one meaning: the same column as two Euler angles, or as the time and an angle,
    // is a slip, not a log.
    for (i, a) in e.iter().enumerate() {
        if let Some((j, _)) = e.iter().enumerate().take(i).find(|(_, b)| *b == a) {
            let name = names.get(*a).map_or(String::new(), |n| format!(" ({n:?})"));
            let (first, second) = (extras[j].flag, extras[i].flag);
            let how = if first == second {
                format!("{first} names column {}{name} twice", a + 1)
            } else {
                format!("{first} and {second} both name column {}{name}", a + 1)
            };
            bail!("{shown}: {how}: each column is one quantity; name another");
        }
    }
    let f = filters
        .iter()
        .map(|f| find_column(names, "--where", &f.column))
        .collect::<Result<_>>()
        .with_context(|| shown.to_string())?;
    Ok((p, e, f))
}

/// Line `line` of the log in `buf` as text: a UTF-8 byte order mark on line 1 removed; UTF-16 text
/// and binary files (a NUL byte) named as such, not as a log without numeric columns quoting
/// bytes a terminal cannot show.
fn text_line(buf: &mut Vec<u8>, line: usize, shown: &str) -> Result<()> {
    if line == 1 && buf.starts_with(b"\xef\xbb\xbf") {
        buf.drain(..3);
    }
    // UTF-16: a spreadsheet's "Unicode text".
    if line == 1 && (buf.starts_with(b"\xff\xfe") || buf.starts_with(b"\xfe\xff")) {
        bail!("{shown}: line 1: the log is UTF-16 text (it starts with a UTF-16 byte order mark); save it as UTF-8");
    }
    // `contains` looks for the byte a word at a time; where it is found, `position` says where.
    if buf.contains(&0)
        && let Some(at) = buf.iter().position(|&b| b == 0)
    {
        bail!(
            "{shown}: line {line}: byte {} is NUL: not a text log (UTF-16 text or a binary file? a flight log through a pipe: give --format)",
            at + 1
        );
    }
    Ok(())
}

/// The column names of a header row, control characters escaped (a name is quoted in errors, and
/// a header must never move the terminal's cursor); an empty name is `column N`.
fn header_names(s: &Splitter) -> Vec<String> {
    (0..s.len())
        .map(|i| {
            // Control characters escaped: a name is quoted in errors, and a header
            // must never move the terminal's cursor.
            let name: String = String::from_utf8_lossy(s.get(i).unwrap_or_default())
                .chars()
                .map(|c| {
                    if c.is_control() {
                        c.escape_debug().to_string()
                    } else {
                        c.to_string()
                    }
                })
                .collect();
            if name.is_empty() {
                format!("column {}", i + 1)
            } else {
                name
            }
        })
        .collect()
}

/// The reading of a data row from the columns `pick`, or why the row is bad (a missing or
/// non-finite value: the caller skips it or stops); a cell that is not a number is an error.
fn row_value(
    s: &Splitter,
    pick: [usize; 3],
    names: &[String],
    shown: &str,
    line: usize,
) -> Result<(Vec3, Option<String>)> {
    let separator = s.separator;
    let mut value = [0.0; 3];
    let mut bad = None;
    for (j, &c) in pick.iter().enumerate() {
        match s.get(c) {
            None | Some(b"") => bad = Some(format!("no value in column {} ({})", c + 1, names[c])),
            Some(cell) => match number(cell, separator) {
                Some(v) if v.is_finite() => value[j] = v,
                // A number written as such but beyond the range of f64 reads as infinite: say
                // which, rather than call 1e400 "inf".
                Some(v) if v.is_nan() || cell_says_non_finite(cell) => {
                    bad = Some(format!("column {} ({}) is {v}", c + 1, names[c]));
                }
                Some(_) => {
                    bad = Some(format!(
                        "column {} ({}) is {}, beyond the largest number (1.8e308)",
                        c + 1,
                        names[c],
                        excerpt(cell)
                    ));
                }
                None => {
                    let why = if decimal_comma(cell) {
                        " (a decimal comma cannot be read where the comma separates cells; use decimal points, or ';' between cells)"
                    } else {
                        ""
                    };
                    bail!(
                        "{shown}: line {line}, column {} ({}): {} is not a number{why}",
                        c + 1,
                        names[c],
                        excerpt(cell)
                    )
                }
            },
        }
    }
    Ok((value, bad))
}

/// Whether a cell names a value that is not finite (`inf`, `-Infinity`, `NaN`) rather than a
/// number too large to hold.
fn cell_says_non_finite(cell: &[u8]) -> bool {
    let t = String::from_utf8_lossy(cell).trim().to_ascii_lowercase();
    let t = t.trim_start_matches(['+', '-']);
    t.starts_with("inf") || t.starts_with("nan")
}

/// The value of an extra column in a data row: `None` where the cell is empty or not finite; a
/// cell that is not a number is an error.
fn extra_value(s: &Splitter, c: usize, names: &[String], shown: &str, line: usize) -> Result<Option<f64>> {
    match s.get(c) {
        None | Some(b"") => Ok(None),
        Some(cell) => match number(cell, s.separator) {
            Some(v) => Ok(Some(v).filter(|v| v.is_finite())),
            None => bail!(
                "{shown}: line {line}, column {} ({}): {} is not a number",
                c + 1,
                names[c],
                excerpt(cell)
            ),
        },
    }
}

/// Whether a data row meets every filter (`at` their columns); a cell that is not a number where
/// the filter's value is one is an error naming its line and column.
fn passes(
    s: &Splitter,
    filters: &[RowFilter],
    at: &[usize],
    names: &[String],
    shown: &str,
    line: usize,
) -> Result<bool> {
    for (f, &c) in filters.iter().zip(at) {
        let cell = s.get(c).unwrap_or_default();
        let meets = match f.number() {
            None => cell == f.value.as_bytes(),
            Some(_) if cell.is_empty() => false,
            Some(want) => match number(cell, s.separator) {
                Some(v) => v == want,
                None => bail!(
                    "{shown}: line {line}, column {} ({}): {} is not a number, and --where {} compares numbers",
                    c + 1,
                    names[c],
                    excerpt(cell),
                    f.shown()
                ),
            },
        };
        if !meets {
            return Ok(false);
        }
    }
    Ok(true)
}

/// The column `column` names for `flag`: by name (any case) or 1-based index.
fn find_column(names: &[String], flag: &str, column: &str) -> Result<usize> {
    let shown = excerpt(column.as_bytes());
    Ok(match column.trim().parse::<usize>() {
        Ok(i) if (1..=names.len()).contains(&i) => i - 1,
        Ok(i) => bail!("{flag} {shown}: column {i} is not in the log ({} columns)", names.len()),
        Err(_) => {
            let found: Vec<usize> = (0..names.len())
                .filter(|&i| names[i].eq_ignore_ascii_case(column.trim()))
                .collect();
            match found[..] {
                [i] => i,
                [] => bail!("{flag} {shown}: no column of that name (columns: {})", list(names)),
                [a, b, ..] => bail!(
                    "{flag} {shown}: columns {} and {} both have that name; give an index",
                    a + 1,
                    b + 1
                ),
            }
        }
    })
}

/// The column of an extra: by name (any case) or 1-based index; not one of the field's.
fn choose_extra(names: &[String], extra: &Extra, field: &[usize; 3]) -> Result<usize> {
    let shown = excerpt(extra.column.as_bytes());
    let flag = extra.flag;
    let i = find_column(names, flag, extra.column)?;
    if field.contains(&i) {
        bail!(
            "{flag} {shown}: column {} ({}) is one of the field's columns",
            i + 1,
            names[i]
        );
    }
    Ok(i)
}

/// The name column `i` is recorded by: its header name, or `column N` (1-based) when other
/// columns carry the same name, so that the record finds this column again.
fn column_name(names: &[String], i: usize) -> String {
    if names.iter().filter(|n| n.eq_ignore_ascii_case(&names[i])).count() > 1 {
        format!("column {}", i + 1)
    } else {
        names[i].clone()
    }
}

/// Whether the first row of the log at `path` is a header (a cell that is not a number) and its
/// cells' names (`column N` for an empty one), read as [`stream`] reads them: the same separator,
/// quotes, byte-order mark, comments and blank lines. `None` when the file cannot be read, holds
/// no row, or its first row cannot be split ([`stream`] then says why).
pub fn first_row(path: &Path) -> Option<(bool, Vec<String>)> {
    // A stream is read once, by the reader: its first row is not taken from it here.
    if !std::fs::metadata(path).ok()?.is_file() {
        return None;
    }
    let file = std::fs::File::open(path).ok()?;
    let mut lines = Lines::new(BufReader::with_capacity(1 << 16, file));
    let mut buf = Vec::new();
    let mut splitter: Option<Splitter> = None;
    while let Some(line) = lines.next(&mut buf, "").ok()? {
        if line == 1 && buf.starts_with(b"\xef\xbb\xbf") {
            buf.drain(..3);
        }
        // Not a text log: no first row here; the reader names the fault.
        if (line == 1 && (buf.starts_with(b"\xff\xfe") || buf.starts_with(b"\xfe\xff"))) || buf.contains(&0) {
            return None;
        }
        let content = buf.trim_ascii_start();
        if content.is_empty() || content[0] == b'#' {
            continue;
        }
        let s = splitter.get_or_insert_with(|| Splitter::new(Separator::sniff(content)));
        buf.push(b'\n');
        s.split(&buf).ok()?;
        let cells: Vec<&[u8]> = (0..s.len()).map(|i| s.get(i).unwrap_or_default()).collect();
        if cells.iter().all(|c| c.is_empty()) {
            continue;
        }
        let header = cells.iter().any(|c| !c.is_empty() && number(c, s.separator).is_none());
        let names = cells
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if c.is_empty() {
                    format!("column {}", i + 1)
                } else {
                    String::from_utf8_lossy(c).into_owned()
                }
            })
            .collect();
        return Some((header, names));
    }
    None
}

/// The three columns to read: asked for (names or 1-based indices), or `x, y, z` (optionally
/// prefixed, any case), or the first three numeric ones. A name that several columns carry, and a
/// column chosen twice, are refused.
fn choose(names: &[String], numeric: &[bool], asked: Option<&str>) -> Result<[usize; 3]> {
    let positions = |name: &str| -> Vec<usize> {
        (0..names.len())
            .filter(|&i| names[i].eq_ignore_ascii_case(name))
            .collect()
    };
    if let Some(asked) = asked {
        let shown = excerpt(asked.as_bytes());
        let parts: Vec<&str> = asked.split(',').map(str::trim).collect();
        if parts.len() != 3 {
            bail!("--columns {shown}: give three columns, names or 1-based indices");
        }
        let mut out = [0; 3];
        for (j, p) in parts.iter().enumerate() {
            out[j] = match p.parse::<usize>() {
                Ok(i) if (1..=names.len()).contains(&i) => i - 1,
                Ok(i) => bail!(
                    "--columns {shown}: column {i} is not in the log ({} columns)",
                    names.len()
                ),
                Err(_) => match positions(p)[..] {
                    [i] => i,
                    [] => bail!(
                        "--columns {shown}: no column named {} (columns: {})",
                        excerpt(p.as_bytes()),
                        list(names)
                    ),
                    [a, b, ..] => bail!(
                        "--columns {shown}: columns {} and {} are both named {}; give indices",
                        a + 1,
                        b + 1,
                        excerpt(p.as_bytes())
                    ),
                },
            };
        }
        for (a, b) in [(0, 1), (0, 2), (1, 2)] {
            if out[a] == out[b] {
                bail!(
                    "--columns {shown}: column {} ({}) is chosen twice; give three different columns",
                    out[a] + 1,
                    names[out[a]]
                );
            }
        }
        return Ok(out);
    }
    for prefix in ["", "m", "mag", "mag_"] {
        let found: Vec<Vec<usize>> = ["x", "y", "z"]
            .iter()
            .map(|axis| positions(&format!("{prefix}{axis}")))
            .collect();
        if found.iter().all(|f| f.len() == 1) {
            return Ok([found[0][0], found[1][0], found[2][0]]);
        }
        if found.iter().all(|f| !f.is_empty()) {
            let twice = found.iter().find(|f| f.len() > 1).expect("a name found twice");
            bail!(
                "columns {} are all named {:?}; choose with --columns (columns: {})",
                twice.iter().map(|i| (i + 1).to_string()).collect::<Vec<_>>().join(", "),
                names[twice[0]],
                list(names)
            );
        }
    }
    let found: Vec<usize> = (0..numeric.len()).filter(|&i| numeric[i]).collect();
    match found[..] {
        [a, b, c, ..] => Ok([a, b, c]),
        _ => bail!(
            "no columns named x, y, z and fewer than three numeric columns in the first data row ({} columns: {}); name them with --columns",
            names.len(),
            list(names)
        ),
    }
}

#[cfg(test)]
mod tests;
