//! Magnetometer logs: CSV files of raw readings, one per row.
//!
//! Columns by name (any case) or by 1-based index (`--columns mx,my,mz` or `--columns 4,5,6`);
//! by default the columns named `x`, `y`, `z` (with or without an `m` prefix, any case), else the
//! first three columns whose first data row is numeric. A first row with a cell that is not a
//! number is a header. Every row is read; a cell that is not a number is an error naming its line
//! and column, and so is a row with a non-finite or missing value unless the caller skips such
//! rows, counting them (`--skip-bad`). The readings are held: 32 bytes each with their line.

use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::Vec3;

use crate::output::manifest::Hashing;

/// The readings of a log and what was skipped.
#[derive(Debug, Clone)]
pub struct Log {
    /// The readings, in file order.
    pub readings: Vec<Vec3>,
    /// The 1-based line of each reading in the file.
    pub lines: Vec<usize>,
    /// Lines skipped for a non-finite or missing value (only with `skip_bad`), with the reason.
    pub skipped: Vec<(usize, String)>,
    /// The names of the three columns read (`column 4` without a header).
    pub columns: [String; 3],
    /// SHA-256 of the file's bytes as read (lower-case hex).
    pub sha256: String,
    /// The file's size in bytes as read.
    pub bytes: u64,
}

/// Reads `path`. `columns`: names or 1-based indices, comma-separated.
///
/// # Errors
/// A missing or unreadable file, no data rows, an unknown column, a cell that is not a number
/// (line and column named), a non-finite or missing value (unless `skip_bad`).
pub fn read(path: &Path, columns: Option<&str>, skip_bad: bool) -> Result<Log> {
    let shown = path.display().to_string();
    let file = std::fs::File::open(path).with_context(|| format!("{shown}: cannot read the log"))?;
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(std::io::BufReader::new(Hashing::new(file)));
    let mut records = reader.records();
    let Some(first) = records.next() else {
        bail!("{shown}: the log is empty");
    };
    let first = first.with_context(|| format!("{shown}: line 1"))?;
    let header = first.iter().any(|c| c.parse::<f64>().is_err());
    let names: Vec<String> = if header {
        first.iter().map(str::to_string).collect()
    } else {
        (1..=first.len()).map(|i| format!("column {i}")).collect()
    };
    // The first data row decides which columns are numeric.
    let mut pending = if header { None } else { Some(first.clone()) };
    if pending.is_none() {
        match records.next() {
            Some(r) => pending = Some(r.with_context(|| format!("{shown}: line 2"))?),
            None => bail!("{shown}: the log has a header but no readings"),
        }
    }
    let sample = pending.clone().expect("a first data row");
    let pick = choose(&names, &sample, columns).with_context(|| shown.clone())?;
    let mut log = Log {
        readings: Vec::new(),
        lines: Vec::new(),
        skipped: Vec::new(),
        columns: pick.map(|i| names[i].clone()),
        sha256: String::new(),
        bytes: 0,
    };
    let first_data_line = if header { 2 } else { 1 };
    let rows = pending.into_iter().map(Ok).chain(records);
    for (k, record) in rows.enumerate() {
        let record = record.with_context(|| format!("{shown}: line {}", first_data_line + k))?;
        let line = record.position().map_or(first_data_line + k, |p| p.line() as usize);
        if record.iter().all(str::is_empty) {
            continue;
        }
        let mut value = [0.0; 3];
        let mut bad = None;
        for (j, &c) in pick.iter().enumerate() {
            match record.get(c) {
                None | Some("") => bad = Some(format!("no value in column {} ({})", c + 1, names[c])),
                Some(cell) => match cell.parse::<f64>() {
                    Ok(v) if v.is_finite() => value[j] = v,
                    Ok(v) => bad = Some(format!("column {} ({}) is {v}", c + 1, names[c])),
                    Err(_) => bail!(
                        "{shown}: line {line}, column {} ({}): {cell:?} is not a number",
                        c + 1,
                        names[c]
                    ),
                },
            }
        }
        match bad {
            Some(reason) if skip_bad => log.skipped.push((line, reason)),
            Some(reason) => bail!("{shown}: line {line}: {reason} (--skip-bad drops such rows and counts them)"),
            None => {
                log.readings.push(value);
                log.lines.push(line);
            }
        }
    }
    if log.readings.is_empty() {
        bail!("{shown}: no readings ({} rows skipped)", log.skipped.len());
    }
    // Every record was read: the hash covers the whole file.
    let hashed = reader.into_inner().into_inner();
    log.sha256 = hashed.hex();
    log.bytes = hashed.bytes();
    Ok(log)
}

/// The three columns to read: asked for (names or 1-based indices), or `x, y, z` (optionally
/// `m`-prefixed, any case), or the first three numeric ones.
fn choose(names: &[String], sample: &csv::StringRecord, asked: Option<&str>) -> Result<[usize; 3]> {
    if let Some(asked) = asked {
        let parts: Vec<&str> = asked.split(',').map(str::trim).collect();
        if parts.len() != 3 {
            bail!("--columns {asked:?}: give three columns, names or 1-based indices");
        }
        let mut out = [0; 3];
        for (j, p) in parts.iter().enumerate() {
            out[j] = match p.parse::<usize>() {
                Ok(i) if (1..=names.len()).contains(&i) => i - 1,
                Ok(i) => bail!(
                    "--columns {asked:?}: column {i} is not in the log ({} columns)",
                    names.len()
                ),
                Err(_) => names.iter().position(|n| n.eq_ignore_ascii_case(p)).with_context(|| {
                    format!(
                        "--columns {asked:?}: no column named {p:?} (columns: {})",
                        names.join(", ")
                    )
                })?,
            };
        }
        return Ok(out);
    }
    for prefix in ["", "m", "mag", "mag_"] {
        let found: Vec<Option<usize>> = ["x", "y", "z"]
            .iter()
            .map(|axis| {
                names
                    .iter()
                    .position(|n| n.eq_ignore_ascii_case(&format!("{prefix}{axis}")))
            })
            .collect();
        if let [Some(a), Some(b), Some(c)] = found[..] {
            return Ok([a, b, c]);
        }
    }
    let numeric: Vec<usize> = (0..sample.len())
        .filter(|&i| sample.get(i).is_some_and(|c| c.parse::<f64>().is_ok()))
        .collect();
    match numeric[..] {
        [a, b, c, ..] => Ok([a, b, c]),
        _ => bail!(
            "no columns named x, y, z and fewer than three numeric columns (columns: {}); name them with --columns",
            names.join(", ")
        ),
    }
}
