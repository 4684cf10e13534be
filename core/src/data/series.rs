//! The columns of a time series: labels of its runs, and rows read through their flags (what
//! was in force at every row, seen or not).

use std::path::Path;

use super::cells::column_index;
use super::{each_row, parse_row, Columns, DataError, Flagged};

/// A column of labels (runs, trials, groups) as numbers, one per row [`read_columns`](super::read_columns) reads,
/// with the rows' file lines: the labels themselves when every one is a number, else each
/// distinct label's rank of first appearance (`T0`, `T1`, `T0` → 0, 1, 0). Labels are names,
/// not quantities: `T0`, `run-3` and `12:00` are labels like any other.
///
/// # Errors
/// As [`read_columns`](super::read_columns), but for a cell that is not a number.
pub fn read_labels(path: &Path, name: &str) -> Result<(Vec<f64>, Vec<u64>), DataError> {
    let (mut cells, mut lines) = (Vec::new(), Vec::new());
    let names = [name.to_string()];
    each_row(
        path,
        Flagged::Skip,
        |header| column_index(path, header, &names),
        |index, line, record, _| {
            cells.push(record[index[0]].to_string());
            lines.push(line);
            Ok(())
        },
    )?;
    Ok((label_values(&cells), lines))
}

/// Labels as numbers: themselves when every one is a number, else each distinct label's rank
/// of first appearance.
fn label_values(cells: &[String]) -> Vec<f64> {
    let numbers: Option<Vec<f64>> = cells
        .iter()
        .map(|c| c.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect();
    numbers.unwrap_or_else(|| {
        let mut seen: std::collections::HashMap<&str, f64> = std::collections::HashMap::new();
        cells
            .iter()
            .map(|c| {
                let next = seen.len() as f64;
                *seen.entry(c.as_str()).or_insert(next)
            })
            .collect()
    })
}

/// What [`read_through_flags`] reads.
pub struct EveryRow {
    pub columns: Columns,
    /// The label column's values, as [`read_labels`] gives them.
    pub labels: Option<Vec<f64>>,
    pub lines: Vec<u64>,
}

/// The named columns and, with `label`, a column of labels of every row, flagged rows
/// included, with each row's file line: what was in force at every
/// row of a time series, for filters that must run through the rows whose outputs were not
/// seen (a camera frame without its tip still had its pressures). A flagged row whose cells
/// are not all numbers is passed over; any other row is read as [`read_columns`](super::read_columns) reads it.
///
/// # Errors
/// As [`read_columns`](super::read_columns).
pub fn read_through_flags(
    path: &Path,
    names: &[String],
    label: Option<&str>,
) -> Result<EveryRow, DataError> {
    let all: Vec<String> = names
        .iter()
        .cloned()
        .chain(label.map(str::to_string))
        .collect();
    let (mut values, mut cells, mut lines) = (Vec::new(), Vec::new(), Vec::new());
    let mut row = vec![0.0; names.len()];
    each_row(
        path,
        Flagged::Give,
        |header| column_index(path, header, &all),
        |index, line, record, flagged| {
            match parse_row(path, line, names, index, record, &mut row) {
                Ok(()) => {}
                Err(_) if flagged => return Ok(()),
                Err(e) => return Err(e),
            }
            values.extend_from_slice(&row);
            if label.is_some() {
                cells.push(record[index[names.len()]].to_string());
            }
            lines.push(line);
            Ok(())
        },
    )?;
    Ok(EveryRow {
        columns: Columns::new(names.to_vec(), values),
        labels: label.map(|_| label_values(&cells)),
        lines,
    })
}
