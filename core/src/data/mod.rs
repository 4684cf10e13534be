//! Datasets with named columns, read from and written to CSV.
//!
//! A CSV file has one header row and one row per sample. Columns are chosen by name
//! (`--inputs`/`--outputs`); other columns are ignored. Every value must parse as a finite
//! number. A column named `flag` marks doubtful rows (`triangulate` writes one): rows whose flag
//! is not empty are left out, and [`count_flagged`] says how many; a row whose every field is
//! empty (a spreadsheet's trailing rows) is a blank line, skipped. Errors name the file, the
//! line as an editor numbers it (the header is line 1; `Lines`) and the column, and say what
//! to do.

use std::path::{Path, PathBuf};

mod cells;
mod series;
mod table;
mod write;

use cells::{
    column_index, csv_error, flag_column, is_blank, is_flagged, parse_cell, read_file, Lines,
};
pub use series::{read_labels, read_through_flags, EveryRow};
pub use table::Table;
pub use write::{format_fixed, format_number, write_csv, Csv};

/// Input columns of the micro-hand datasets.
pub const HAND_INPUTS: [&str; 3] = ["P1_kpa", "P2_kpa", "P3_kpa"];
/// Output columns of the micro-hand datasets (tip position in the hand frame).
pub const HAND_OUTPUTS: [&str; 3] = ["x_mm", "y_mm", "z_mm"];

/// Owned column names, e.g. `names(&HAND_INPUTS)`.
pub fn names(columns: &[&str]) -> Vec<String> {
    columns.iter().map(|c| c.to_string()).collect()
}

/// Errors of reading or validating a dataset.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path}: file is empty; expected a header row naming the columns, then one row per sample"
    )]
    Empty { path: PathBuf },
    #[error("{path}: no rows (only a header, or every row flagged); give {what} a file with rows")]
    NoRows { path: PathBuf, what: String },
    #[error("{path}: line 1: column `{name}` appears twice (columns {first} and {second}); rename one of them")]
    DuplicateHeader {
        path: PathBuf,
        name: String,
        first: usize,
        second: usize,
    },
    #[error("{path}: line 1: the header is one column of names separated by {separator}; handcap reads comma-separated CSV: export the file with commas between columns (and `.` as the decimal mark)")]
    NotCommaSeparated {
        path: PathBuf,
        separator: &'static str,
    },
    #[error("{path}: no column `{name}` (the header has: {available})")]
    MissingColumn {
        path: PathBuf,
        name: String,
        available: String,
    },
    #[error("{path}: line {line}, column `{column}`: empty; give a number, or leave the row out with a non-empty `flag` column")]
    EmptyCell {
        path: PathBuf,
        line: u64,
        column: String,
    },
    #[error("{path}: line {line}, column `{column}`: `{value}` is not a number{hint}")]
    NotNumeric {
        path: PathBuf,
        line: u64,
        column: String,
        value: String,
        /// What the value looks like, when that says what to do ("" otherwise).
        hint: &'static str,
    },
    #[error(
        "{path}: line {line}, column `{column}`: `{value}` is not finite; remove or repair the row"
    )]
    NotFinite {
        path: PathBuf,
        line: u64,
        column: String,
        value: String,
    },
    #[error("{}{}: {message}", path.display(), if *line > 0 { format!(" line {line}") } else { String::new() })]
    Input {
        path: PathBuf,
        line: u64,
        message: String,
    },
    #[error("{path}: line {line}: {message}")]
    Malformed {
        path: PathBuf,
        line: u64,
        message: String,
    },
    #[error("{path}: {found} data rows, but at least {needed} are needed")]
    TooFewRows {
        path: PathBuf,
        found: usize,
        needed: usize,
    },
    #[error("{path}: input column `{column}` is constant ({value}) over all rows; it carries no information, leave it out of the inputs")]
    ConstantInput {
        path: PathBuf,
        column: String,
        value: f64,
    },
    #[error("{path}: column `{column}` holds {value:e}; values beyond ±1e100 cannot be scaled and fitted, express the column in other units")]
    TooLarge {
        path: PathBuf,
        column: String,
        value: f64,
    },
    #[error("column `{name}` is chosen twice; each column may appear once in the inputs and outputs together")]
    RepeatedSelection { name: String },
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// A block of named numeric columns, stored row-major (`rows × names.len()`).
#[derive(Clone, Debug, PartialEq)]
pub struct Columns {
    pub names: Vec<String>,
    pub values: Vec<f64>,
}

impl Columns {
    /// Builds a block from row-major values.
    ///
    /// # Panics
    /// If `values.len()` is not a multiple of `names.len()`.
    pub fn new(names: Vec<String>, values: Vec<f64>) -> Self {
        assert!(
            !names.is_empty() && values.len().is_multiple_of(names.len()),
            "{} values do not fill rows of {} columns",
            values.len(),
            names.len()
        );
        Columns { names, values }
    }

    pub fn width(&self) -> usize {
        self.names.len()
    }

    pub fn rows(&self) -> usize {
        self.values.len() / self.width()
    }

    pub fn row(&self, i: usize) -> &[f64] {
        let w = self.width();
        &self.values[i * w..(i + 1) * w]
    }

    pub fn iter_rows(&self) -> impl Iterator<Item = &[f64]> {
        self.values.chunks_exact(self.width())
    }

    /// The values of column `j`, top to bottom.
    pub fn column(&self, j: usize) -> impl Iterator<Item = f64> + '_ {
        self.iter_rows().map(move |r| r[j])
    }

    /// The listed rows, in the listed order.
    pub fn select_rows(&self, rows: &[usize]) -> Columns {
        Columns::new(
            self.names.clone(),
            rows.iter().flat_map(|&i| self.row(i).to_vec()).collect(),
        )
    }

    /// The names joined by commas, as on a command line.
    pub fn names_list(&self) -> String {
        self.names.join(",")
    }
}

/// Inputs and outputs of one file, row-aligned, and each row's weight in a fit's loss when
/// the rows are not all alike (`None`: every row weighs 1).
#[derive(Clone, Debug)]
pub struct Dataset {
    pub source: PathBuf,
    pub inputs: Columns,
    pub outputs: Columns,
    pub weights: Option<Vec<f64>>,
}

impl Dataset {
    /// The rows [`evenly_spaced`] keeps, in order.
    pub fn subsample(&self, max: usize) -> Dataset {
        self.select_rows(&evenly_spaced(self.rows(), max))
    }

    /// The listed rows, in the list's order.
    pub fn select_rows(&self, rows: &[usize]) -> Dataset {
        Dataset {
            source: self.source.clone(),
            inputs: self.inputs.select_rows(rows),
            outputs: self.outputs.select_rows(rows),
            weights: self.weights_of(rows),
        }
    }

    /// The listed rows' weights, when the rows carry weights.
    pub fn weights_of(&self, rows: &[usize]) -> Option<Vec<f64>> {
        let w = self.weights.as_ref()?;
        Some(rows.iter().map(|&i| w[i]).collect())
    }

    /// Each row's weight in a fit's loss, as the solvers take them.
    pub fn row_weights(&self) -> crate::model::msvr::RowWeights<'_> {
        crate::model::msvr::RowWeights(self.weights.as_deref())
    }

    pub fn rows(&self) -> usize {
        self.inputs.rows()
    }

    /// Checks what a fit needs beyond well-formed numbers: enough rows and no constant input.
    ///
    /// # Errors
    /// [`DataError::TooFewRows`], [`DataError::ConstantInput`].
    pub fn check_fittable(&self, min_rows: usize) -> Result<(), DataError> {
        if self.rows() < min_rows {
            return Err(DataError::TooFewRows {
                path: self.source.clone(),
                found: self.rows(),
                needed: min_rows,
            });
        }
        for block in [&self.inputs, &self.outputs] {
            for (j, name) in block.names.iter().enumerate() {
                if let Some(v) = block.column(j).find(|v| v.abs() > 1e100) {
                    return Err(DataError::TooLarge {
                        path: self.source.clone(),
                        column: name.clone(),
                        value: v,
                    });
                }
            }
        }
        for (j, name) in self.inputs.names.iter().enumerate() {
            let first = self.inputs.row(0)[j];
            if self.inputs.column(j).all(|v| v == first) {
                return Err(DataError::ConstantInput {
                    path: self.source.clone(),
                    column: name.clone(),
                    value: first,
                });
            }
        }
        Ok(())
    }
}

/// At most `max` of `n` row indices, evenly spaced (⌊k·n/max⌋ for k < max); all of them when
/// `n ≤ max`.
pub fn evenly_spaced(n: usize, max: usize) -> Vec<usize> {
    if n <= max {
        return (0..n).collect();
    }
    (0..max).map(|k| k * n / max).collect()
}

/// The column names of a CSV file's header.
///
/// # Errors
/// The file cannot be read or has no header.
pub fn header(path: &Path) -> Result<Vec<String>, DataError> {
    let table = Table::open(path, "a header row")?;
    Ok(table.header.iter().map(str::to_string).collect())
}

/// Reads the named columns of a CSV file, in the order given.
///
/// # Errors
/// Every [`DataError`] but the fit checks: unreadable or empty file, a chosen column missing or
/// duplicated in the header, a row of the wrong length, a cell that is not a finite number.
pub fn read_columns(path: &Path, names: &[String]) -> Result<Columns, DataError> {
    Ok(read_columns_with_lines(path, names)?.0)
}

/// [`read_columns`], with the file line of each row kept (the header is line 1; flagged rows
/// are left out, so lines may skip), for errors found later that must name the line.
///
/// # Errors
/// As [`read_columns`].
pub fn read_columns_with_lines(
    path: &Path,
    names: &[String],
) -> Result<(Columns, Vec<u64>), DataError> {
    let (mut values, mut lines) = (Vec::new(), Vec::new());
    read_selected(path, names, |line, row| {
        lines.push(line);
        values.extend_from_slice(row);
    })?;
    Ok((Columns::new(names.to_vec(), values), lines))
}

/// A column of row weights (`--weight`): finite and above 0 on every row the model reads.
///
/// # Errors
/// As [`read_columns`]; [`DataError::Input`] naming the line of a weight of 0 or below.
pub fn read_weights(path: &Path, column: &str) -> Result<Vec<f64>, DataError> {
    let (weights, lines) = read_columns_with_lines(path, &[column.to_string()])?;
    let weights = weights.values;
    match refused_weight(&weights) {
        Some(i) => Err(DataError::Input {
            path: path.to_path_buf(),
            line: lines[i],
            message: format!(
                "weight {} in column `{column}`: give every row a weight above 0 (a row of weight 0 is one to leave out of the file)",
                weights[i]
            ),
        }),
        None => Ok(weights),
    }
}

/// The first row whose weight a fit refuses: not a finite number above 0.
pub fn refused_weight(weights: &[f64]) -> Option<usize> {
    weights.iter().position(|w| !(w.is_finite() && *w > 0.0))
}

/// Every column of a CSV file but those in `skip` (and `flag`) that holds a finite number on
/// every row [`read_columns`] reads, by name, in the header's order; one pass over the file
/// however many columns it has (the candidates for the folds' groups).
///
/// # Errors
/// As [`read_columns`]: unreadable or empty file, a row of the wrong length.
pub fn numeric_columns(path: &Path, skip: &[String]) -> Result<Vec<(String, Vec<f64>)>, DataError> {
    let columns = each_row(
        path,
        Flagged::Skip,
        |header| {
            let flag = flag_column(header);
            Ok(header
                .iter()
                .enumerate()
                .filter(|&(j, name)| Some(j) != flag && !skip.iter().any(|s| s == name))
                .map(|(j, name)| (j, name.to_string(), Some(Vec::new())))
                .collect::<Vec<(usize, String, Option<Vec<f64>>)>>())
        },
        |columns, _, record, _| {
            for (j, _, values) in columns.iter_mut() {
                let number = record[*j].parse::<f64>().ok().filter(|v| v.is_finite());
                match (values.as_mut(), number) {
                    (Some(values), Some(v)) => values.push(v),
                    _ => *values = None,
                }
            }
            columns.retain(|c| c.2.is_some());
            Ok(())
        },
    )?;
    Ok(columns
        .into_iter()
        .filter_map(|(_, name, values)| Some((name, values?)))
        .collect())
}

/// Reads a dataset: `inputs` and `outputs` columns of one CSV file.
///
/// # Errors
/// As [`read_columns`], and [`DataError::RepeatedSelection`] when a name is chosen twice.
pub fn read_dataset(
    path: &Path,
    inputs: &[String],
    outputs: &[String],
) -> Result<Dataset, DataError> {
    let all: Vec<String> = inputs.iter().chain(outputs).cloned().collect();
    for (i, name) in all.iter().enumerate() {
        if all[..i].contains(name) {
            return Err(DataError::RepeatedSelection { name: name.clone() });
        }
    }
    let (mut x, mut y) = (Vec::new(), Vec::new());
    read_selected(path, &all, |_, row| {
        x.extend_from_slice(&row[..inputs.len()]);
        y.extend_from_slice(&row[inputs.len()..]);
    })?;
    Ok(Dataset {
        source: path.to_path_buf(),
        inputs: Columns::new(inputs.to_vec(), x),
        outputs: Columns::new(outputs.to_vec(), y),
        weights: None,
    })
}

/// Streams the file line and the chosen columns of every data row to `sink`, validated.
fn read_selected(
    path: &Path,
    names: &[String],
    mut sink: impl FnMut(u64, &[f64]),
) -> Result<(), DataError> {
    let mut row = vec![0.0; names.len()];
    each_row(
        path,
        Flagged::Skip,
        |header| column_index(path, header, names),
        |index, line, record, _| {
            parse_row(path, line, names, index, record, &mut row)?;
            sink(line, &row);
            Ok(())
        },
    )
    .map(drop)
}

/// The cells of `names` (at `index` in the header) of one record as numbers, into `row`.
fn parse_row(
    path: &Path,
    line: u64,
    names: &[String],
    index: &[usize],
    record: &csv::StringRecord,
    row: &mut [f64],
) -> Result<(), DataError> {
    for (slot, (&col, name)) in row.iter_mut().zip(index.iter().zip(names)) {
        *slot = parse_cell(path, line, name, &record[col])?;
    }
    Ok(())
}

/// Whether a reader gives the rows a `flag` column marks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Flagged {
    Skip,
    /// Given, with their flag, to a reader that takes what they hold.
    Give,
}

/// Reads a file's header, gives it to `setup`, then gives each data row (blank rows skipped,
/// flagged rows as `flagged` says, a row of the wrong length refused) with its file line and
/// whether it is flagged to `row`, with what `setup` made of the header (the chosen columns'
/// positions, or a state the rows build); returns that.
fn each_row<C>(
    path: &Path,
    flagged: Flagged,
    setup: impl FnOnce(&csv::StringRecord) -> Result<C, DataError>,
    mut row: impl FnMut(&mut C, u64, &csv::StringRecord, bool) -> Result<(), DataError>,
) -> Result<C, DataError> {
    let bytes = read_file(path)?;
    let mut lines = Lines::new(&bytes);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .trim(csv::Trim::All)
        .from_reader(bytes.as_slice());
    let mut records = reader.records();
    let header = match records.next() {
        None => return Err(DataError::Empty { path: path.into() }),
        Some(r) => r.map_err(|e| csv_error(path, e, &mut lines))?,
    };
    if header.iter().all(str::is_empty) {
        return Err(DataError::Empty { path: path.into() });
    }
    let mut made = setup(&header)?;
    let flag = flag_column(&header);
    for record in records {
        let record = record.map_err(|e| csv_error(path, e, &mut lines))?;
        let is_flagged = is_flagged(flag, &record);
        if is_blank(&record) || (is_flagged && flagged == Flagged::Skip) {
            continue;
        }
        let line = lines.of(record.position());
        if record.len() != header.len() {
            return Err(DataError::Malformed {
                path: path.into(),
                line,
                message: format!(
                    "{} fields, but the header has {}; every row needs one value per column",
                    record.len(),
                    header.len()
                ),
            });
        }
        row(&mut made, line, &record, is_flagged)?;
    }
    Ok(made)
}

/// Copies the header and the rows of `from` whose `columns` satisfy `keep` into `to`
/// (atomically), every field as it was; returns the rows kept.
///
/// # Errors
/// As [`read_columns`] for `from`; [`DataError::Write`] for `to`.
pub fn copy_rows(
    from: &Path,
    to: &Path,
    columns: &[String],
    keep: impl Fn(&[f64]) -> bool,
) -> Result<usize, DataError> {
    let bytes = read_file(from)?;
    let mut lines = Lines::new(&bytes);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(bytes.as_slice());
    let mut records = reader.records();
    let header = match records.next() {
        None => return Err(DataError::Empty { path: from.into() }),
        Some(r) => r.map_err(|e| csv_error(from, e, &mut lines))?,
    };
    let trimmed: csv::StringRecord = header.iter().map(str::trim).collect();
    let index = column_index(from, &trimmed, columns)?;
    let mut kept = vec![header];
    let mut values = vec![0.0; columns.len()];
    for record in records {
        let record = record.map_err(|e| csv_error(from, e, &mut lines))?;
        if is_blank(&record) {
            continue;
        }
        let line = lines.of(record.position());
        for (slot, (&col, name)) in values.iter_mut().zip(index.iter().zip(columns)) {
            *slot = parse_cell(from, line, name, record.get(col).unwrap_or("").trim())?;
        }
        if keep(&values) {
            kept.push(record);
        }
    }
    let mut csv = Csv::new(&kept[0]);
    for record in &kept[1..] {
        csv.row(record);
    }
    csv.write(to)?;
    Ok(kept.len() - 1)
}

/// The rows of `path` that a `flag` column leaves out.
///
/// # Errors
/// [`DataError::Io`] or a malformed CSV file.
pub fn count_flagged(path: &Path) -> Result<usize, DataError> {
    let bytes = read_file(path)?;
    let mut lines = Lines::new(&bytes);
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(bytes.as_slice());
    let header = reader
        .headers()
        .map_err(|e| csv_error(path, e, &mut lines))?;
    let flag = flag_column(header);
    let mut n = 0;
    for record in reader.records() {
        let record = record.map_err(|e| csv_error(path, e, &mut lines))?;
        n += usize::from(is_flagged(flag, &record));
    }
    Ok(n)
}
