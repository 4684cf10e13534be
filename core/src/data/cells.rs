//! Reading a CSV's cells: the header's columns, a cell's number (or why it is not one), blank
//! and flagged rows, and the editor's line each record starts on.

use std::collections::HashMap;
use std::path::Path;

use super::DataError;

/// The index of the `flag` column, if the header has one.
pub(super) fn flag_column(header: &csv::StringRecord) -> Option<usize> {
    header.iter().position(|h| h == "flag")
}

/// The whole file: its lines are counted from its bytes ([`Lines`]) as the CSV reader parses
/// them.
pub(super) fn read_file(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|source| DataError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// A row whose every field is empty (a spreadsheet's trailing rows): a blank line, which the CSV
/// reader already skips when it holds no separator either.
pub(super) fn is_blank(record: &csv::StringRecord) -> bool {
    record.iter().all(|f| f.trim().is_empty())
}

pub(super) fn is_flagged(flag: Option<usize>, record: &csv::StringRecord) -> bool {
    flag.and_then(|i| record.get(i))
        .is_some_and(|f| !f.is_empty())
}

/// A header of one column holding a semicolon or a tab: a file separated by something other
/// than commas (a spreadsheet's export in a locale whose decimal mark is the comma).
pub(super) fn check_commas(path: &Path, header: &csv::StringRecord) -> Result<(), DataError> {
    let separator = match header.iter().collect::<Vec<_>>()[..] {
        [only] => [(';', "semicolons"), ('\t', "tabs")]
            .into_iter()
            .find(|&(c, _)| only.contains(c))
            .map(|(_, name)| name),
        _ => None,
    };
    separator.map_or(Ok(()), |separator| {
        Err(DataError::NotCommaSeparated {
            path: path.into(),
            separator,
        })
    })
}

/// Finds each chosen name in the header; a chosen name that appears twice is ambiguous.
pub(super) fn column_index(
    path: &Path,
    header: &csv::StringRecord,
    names: &[String],
) -> Result<Vec<usize>, DataError> {
    check_commas(path, header)?;
    let mut positions: HashMap<&str, usize> = HashMap::new();
    let mut duplicates: HashMap<&str, (usize, usize)> = HashMap::new();
    for (i, name) in header.iter().enumerate() {
        if let Some(&first) = positions.get(name) {
            duplicates.entry(name).or_insert((first, i));
        } else {
            positions.insert(name, i);
        }
    }
    names
        .iter()
        .map(|name| {
            if let Some(&(first, second)) = duplicates.get(name.as_str()) {
                return Err(DataError::DuplicateHeader {
                    path: path.into(),
                    name: name.clone(),
                    first: first + 1,
                    second: second + 1,
                });
            }
            positions
                .get(name.as_str())
                .copied()
                .ok_or_else(|| DataError::MissingColumn {
                    path: path.into(),
                    name: name.clone(),
                    available: header.iter().collect::<Vec<_>>().join(","),
                })
        })
        .collect()
}

/// What a cell that is not a number looks like, when a logger or a spreadsheet wrote it that
/// way: a clock time or date, or a decimal comma.
pub(super) fn not_numeric_hint(cell: &str) -> &'static str {
    let digits_and = |extra: &[char]| {
        cell.chars().any(|c| c.is_ascii_digit())
            && cell
                .chars()
                .all(|c| c.is_ascii_digit() || extra.contains(&c))
    };
    if digits_and(&[':', '-', '/', '.', 'T', 'Z', ' ', '+']) && cell.contains([':', '/', 'T']) {
        " (a clock time or date: give times as seconds, e.g. since the log's start)"
    } else if digits_and(&[',', '-', '+']) && cell.matches(',').count() == 1 {
        " (a decimal comma: write `.` as the decimal mark)"
    } else {
        ""
    }
}

pub(super) fn parse_cell(
    path: &Path,
    line: u64,
    column: &str,
    cell: &str,
) -> Result<f64, DataError> {
    if cell.is_empty() {
        return Err(DataError::EmptyCell {
            path: path.into(),
            line,
            column: column.into(),
        });
    }
    let value: f64 = cell.parse().map_err(|_| DataError::NotNumeric {
        path: path.into(),
        line,
        column: column.into(),
        value: cell.into(),
        hint: not_numeric_hint(cell),
    })?;
    if !value.is_finite() {
        return Err(DataError::NotFinite {
            path: path.into(),
            line,
            column: column.into(),
            value: cell.into(),
        });
    }
    Ok(value)
}

pub(super) fn csv_error(path: &Path, e: csv::Error, lines: &mut Lines) -> DataError {
    let line = lines.of(e.position());
    match e.into_kind() {
        csv::ErrorKind::Io(source) => DataError::Io {
            path: path.into(),
            source,
        },
        csv::ErrorKind::Utf8 { err, .. } => DataError::Malformed {
            path: path.into(),
            line,
            message: format!(
                "field {} is not UTF-8 text; save the file as UTF-8 (or plain ASCII) CSV",
                err.field() + 1
            ),
        },
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => DataError::Malformed {
            path: path.into(),
            line,
            message: format!(
                "{len} fields, but the header has {expected_len}; every row needs one value per column"
            ),
        },
        kind => DataError::Malformed {
            path: path.into(),
            line,
            message: format!("not a CSV row ({kind:?})"),
        },
    }
}

/// The line on which each record of a CSV file starts, counted from the file's bytes: the csv
/// crate's own count is one short after CRLF line ends (a Windows file: every row after the
/// first) and after a blank line (rust-csv issues 395 and 208). A line ends at `\n`, `\r\n`
/// or a lone `\r`, as the csv reader takes them.
pub(super) struct Lines<'a> {
    bytes: &'a [u8],
    /// Bytes counted so far, and the line of the byte at `at`.
    at: usize,
    line: u64,
}

impl<'a> Lines<'a> {
    pub(super) fn new(bytes: &'a [u8]) -> Self {
        Lines {
            bytes,
            at: 0,
            line: 1,
        }
    }

    /// The line of the record at `position` (0 when unknown): its first byte that is not a
    /// line end (the csv reader may place a record at the line end before it, or at blank
    /// lines it skipped). Records come in file order; one before the last is counted afresh.
    pub(super) fn of(&mut self, position: Option<&csv::Position>) -> u64 {
        let Some(position) = position else {
            return 0;
        };
        let n = self.bytes.len();
        let mut start = usize::try_from(position.byte()).map_or(n, |b| b.min(n));
        while start < n && matches!(self.bytes[start], b'\r' | b'\n') {
            start += 1;
        }
        if start < self.at {
            (self.at, self.line) = (0, 1);
        }
        let ends = self.bytes[self.at..start]
            .iter()
            .enumerate()
            .filter(|&(i, &b)| {
                b == b'\n' || (b == b'\r' && self.bytes.get(self.at + i + 1) != Some(&b'\n'))
            })
            .count();
        self.line += ends as u64;
        self.at = start;
        self.line
    }
}
