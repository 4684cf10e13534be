//! A text table of named columns, each row with its line (the frame index, the pressure log).

use std::path::{Path, PathBuf};

use super::cells::{check_commas, csv_error, is_blank, Lines};
use super::DataError;

/// A CSV input read as text (a frame index, a pressure log): its records with their line
/// numbers, and its columns by name; every error names the file and the line.
pub struct Table {
    path: PathBuf,
    pub header: csv::StringRecord,
    bytes: Vec<u8>,
    /// What the header must hold, for messages (e.g. "frame,camera,time_s").
    needs: &'static str,
}

impl Table {
    pub fn open(path: &Path, needs: &'static str) -> Result<Self, DataError> {
        let bad = |line, message| Table::error(path, line, message);
        let bytes = std::fs::read(path)
            .map_err(|e| bad(0, format!("{e}; it must be a CSV file with {needs}")))?;
        let header = Table::reader(&bytes)
            .headers()
            .map_err(|e| csv_error(path, e, &mut Lines::new(&bytes)))?
            .clone();
        check_commas(path, &header)?;
        Ok(Table {
            path: path.to_path_buf(),
            header,
            bytes,
            needs,
        })
    }

    fn reader(bytes: &[u8]) -> csv::Reader<&[u8]> {
        csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_reader(bytes)
    }

    fn error(path: &Path, line: u64, message: String) -> DataError {
        DataError::Input {
            path: path.to_path_buf(),
            line,
            message,
        }
    }

    /// [`Table::bad`] as the `Err` of any result whose error takes a [`DataError`].
    pub fn fail<T, E: From<DataError>>(&self, line: u64, message: String) -> Result<T, E> {
        Err(self.bad(line, message).into())
    }

    /// An error at `line` of this file.
    pub fn bad(&self, line: u64, message: String) -> DataError {
        Table::error(&self.path, line, message)
    }

    /// The position of a required column.
    pub fn column(&self, name: &str) -> Result<usize, DataError> {
        self.header.iter().position(|h| h == name).ok_or_else(|| {
            self.bad(
                1,
                format!("no {name} column; the header must have {}", self.needs),
            )
        })
    }

    /// Every record with its line number, blank ones (every field empty) left out.
    pub fn records(&self) -> Result<Vec<(u64, csv::StringRecord)>, DataError> {
        let mut lines = Lines::new(&self.bytes);
        Table::reader(&self.bytes)
            .records()
            .map(|r| {
                let r = r.map_err(|e| csv_error(&self.path, e, &mut lines))?;
                Ok((lines.of(r.position()), r))
            })
            .filter(|r| !r.as_ref().is_ok_and(|(_, r)| is_blank(r)))
            .collect()
    }
}
