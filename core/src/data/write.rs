//! Writing CSV: every CSV file handcap writes is made by [`Csv`].

use std::path::Path;

use super::{Columns, DataError};
use crate::fsio;

/// A CSV file built row by row, through the `csv` crate: a field is quoted only when it holds
/// a comma, a quote or a line end, and lines end in `\n`. Every CSV file handcap writes is made
/// here, then written atomically ([`Csv::write`]) or kept as text.
pub struct Csv(csv::Writer<Vec<u8>>);

impl Csv {
    /// A file of this header.
    pub fn new<I, S>(header: I) -> Csv
    where
        I: IntoIterator<Item = S>,
        S: AsRef<[u8]>,
    {
        let mut csv = Csv(csv::Writer::from_writer(Vec::new()));
        csv.row(header);
        csv
    }

    /// Adds one row of fields, written as given.
    pub fn row<I, S>(&mut self, fields: I)
    where
        I: IntoIterator<Item = S>,
        S: AsRef<[u8]>,
    {
        self.0.write_record(fields).expect("a CSV in memory");
    }

    /// The file's bytes so far (it may grow after).
    pub fn as_bytes(&mut self) -> &[u8] {
        self.0.flush().expect("a CSV in memory");
        self.0.get_ref()
    }

    /// The file's bytes.
    pub fn into_bytes(self) -> Vec<u8> {
        self.0.into_inner().expect("a CSV in memory")
    }

    /// The file's text (every field handed in was text).
    pub fn into_string(self) -> String {
        String::from_utf8(self.into_bytes()).expect("fields given as text")
    }

    /// Writes the file atomically (a temporary file beside it, then renamed).
    ///
    /// # Errors
    /// [`DataError::Write`] naming the file.
    pub fn write(mut self, path: &Path) -> Result<(), DataError> {
        self.save(path)
    }

    /// Writes the file as it is so far, atomically; it may grow and be saved again.
    ///
    /// # Errors
    /// [`DataError::Write`] naming the file.
    pub fn save(&mut self, path: &Path) -> Result<(), DataError> {
        fsio::write_bytes(path, self.as_bytes()).map_err(|source| DataError::Write {
            path: path.into(),
            source,
        })
    }
}

/// An optional number with `digits` decimals, empty when absent.
pub fn format_fixed(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(String::new, |v| format!("{v:.digits$}"))
}

/// Writes blocks of columns side by side as one CSV file, atomically.
///
/// Numbers are written in the shortest form that reads back to the same `f64`.
///
/// # Errors
/// [`DataError::Write`] when the file cannot be written.
///
/// # Panics
/// If the blocks have different row counts.
pub fn write_csv(path: &Path, blocks: &[&Columns]) -> Result<(), DataError> {
    let rows = blocks.first().map_or(0, |b| b.rows());
    assert!(
        blocks.iter().all(|b| b.rows() == rows),
        "blocks differ in rows"
    );
    let mut csv = Csv::new(blocks.iter().flat_map(|b| b.names.iter()));
    for i in 0..rows {
        csv.row(
            blocks
                .iter()
                .flat_map(|b| b.row(i).iter().map(|&v| format_number(v))),
        );
    }
    csv.write(path)
}

/// Formats a number in the shortest form that reads back to the same `f64` (Rust's `Display`),
/// with negative zero written as `0`.
pub fn format_number(v: f64) -> String {
    if v == 0.0 {
        "0".to_string()
    } else {
        v.to_string()
    }
}
