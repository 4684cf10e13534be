//! Every bad-input case of the data layer gets a one-line error naming file, line and column.

use std::path::Path;

use handcap::data::{read_columns, read_dataset, DataError};

use crate::common::{tempdir, write};

fn names(s: &str) -> Vec<String> {
    s.split(',').map(String::from).collect()
}

fn read(path: &Path) -> Result<handcap::data::Dataset, DataError> {
    read_dataset(path, &names("P1_kpa,P2_kpa"), &names("x_mm"))
}

#[test]
fn reads_chosen_columns_in_order_and_ignores_the_rest() {
    let dir = tempdir();
    let path = write(
        dir.path(),
        "d.csv",
        "x_mm,note,P2_kpa,P1_kpa\n1.5,a,20,10\n-2,b,40, 30 \n",
    );
    let d = read(&path).unwrap();
    assert_eq!(d.inputs.names, ["P1_kpa", "P2_kpa"]);
    assert_eq!(d.inputs.values, [10.0, 20.0, 30.0, 40.0]);
    assert_eq!(d.outputs.values, [1.5, -2.0]);
}

/// Reads `text` and returns the error message, checking it names the file.
fn error_of(text: &str) -> (DataError, String) {
    let dir = tempdir();
    let path = write(dir.path(), "bad.csv", text);
    let err = read(&path)
        .and_then(|d| d.check_fittable(3).map(|_| d))
        .unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("bad.csv"), "no file name in: {msg}");
    assert_eq!(msg.lines().count(), 1, "not one line: {msg}");
    (err, msg)
}

#[test]
fn missing_file() {
    let err = read(Path::new("/nonexistent/data.csv")).unwrap_err();
    assert!(matches!(err, DataError::Io { .. }));
    assert!(err.to_string().contains("/nonexistent/data.csv"));
}

#[test]
fn empty_file() {
    let (err, _) = error_of("");
    assert!(matches!(err, DataError::Empty { .. }));
    let (err, _) = error_of("\n\n");
    assert!(matches!(err, DataError::Empty { .. }));
}

#[test]
fn missing_column_lists_what_there_is() {
    let (err, msg) = error_of("P1_kpa,x_mm\n1,2\n");
    assert!(matches!(err, DataError::MissingColumn { ref name, .. } if name == "P2_kpa"));
    assert!(
        msg.contains("P1_kpa,x_mm") && msg.contains("no column `P2_kpa`"),
        "{msg}"
    );
}

#[test]
fn non_numeric_cell_names_line_and_column() {
    let (err, msg) = error_of("P1_kpa,P2_kpa,x_mm\n1,2,3\n4,five,6\n");
    assert!(
        matches!(err, DataError::NotNumeric { line: 3, .. }),
        "{msg}"
    );
    assert!(
        msg.contains("line 3") && msg.contains("P2_kpa") && msg.contains("five"),
        "{msg}"
    );
}

/// A clock time, a date or a decimal comma is named as what it looks like, with what to do.
#[test]
fn not_numbers_that_look_like_times_or_decimal_commas_say_so() {
    for (cell, says) in [
        ("12:00:01.5", "clock time"),
        ("2026-11-25T10:00:00Z", "clock time"),
        ("25/11/2026", "clock time"),
        ("\"1,5\"", "decimal comma"),
        ("\"-0,25\"", "decimal comma"),
    ] {
        let (err, msg) = error_of(&format!("P1_kpa,P2_kpa,x_mm\n1,2,3\n4,5,{cell}\n"));
        assert!(
            matches!(err, DataError::NotNumeric { line: 3, .. }),
            "{msg}"
        );
        assert!(msg.contains(says), "{cell}: {msg}");
    }
    let (_, msg) = error_of("P1_kpa,P2_kpa,x_mm\n1,2,3\n4,5,five\n");
    assert!(msg.ends_with("`five` is not a number"), "{msg}");
}

#[test]
fn nan_and_infinity_are_rejected() {
    for cell in ["NaN", "inf", "-inf"] {
        let (err, msg) = error_of(&format!("P1_kpa,P2_kpa,x_mm\n1,2,3\n4,5,{cell}\n"));
        assert!(matches!(err, DataError::NotFinite { line: 3, .. }), "{msg}");
        assert!(msg.contains("x_mm"), "{msg}");
    }
}

#[test]
fn duplicate_header_of_a_chosen_column() {
    let (err, msg) = error_of("P1_kpa,P2_kpa,P1_kpa,x_mm\n1,2,3,4\n");
    assert!(
        matches!(
            err,
            DataError::DuplicateHeader {
                first: 1,
                second: 3,
                ..
            }
        ),
        "{msg}"
    );
}

#[test]
fn too_few_rows_for_a_fit() {
    let (err, msg) = error_of("P1_kpa,P2_kpa,x_mm\n1,2,3\n2,3,4\n");
    assert!(
        matches!(
            err,
            DataError::TooFewRows {
                found: 2,
                needed: 3,
                ..
            }
        ),
        "{msg}"
    );
    let (err, _) = error_of("P1_kpa,P2_kpa,x_mm\n");
    assert!(matches!(err, DataError::TooFewRows { found: 0, .. }));
}

#[test]
fn constant_input_column() {
    let (err, msg) = error_of("P1_kpa,P2_kpa,x_mm\n0,1,3\n0,2,4\n0,3,5\n");
    assert!(
        matches!(err, DataError::ConstantInput { ref column, .. } if column == "P1_kpa"),
        "{msg}"
    );
}

/// A Windows file (CRLF), an old Mac one (CR), blank lines and a quoted field over two lines:
/// the error names the line the bad row starts on, as an editor numbers it.
#[test]
fn every_line_end_names_the_right_line() {
    let rows = ["P1_kpa,P2_kpa,x_mm", "1,2,3", "4,5,6", "7,x,9"];
    for end in ["\n", "\r\n", "\r"] {
        let (err, msg) = error_of(&(rows.join(end) + end));
        assert!(
            matches!(err, DataError::NotNumeric { line: 4, .. }),
            "{end:?}: {msg}"
        );
        // A ragged row is found by the CSV reader itself.
        let (err, msg) = error_of(&(rows[..3].join(end) + end + "1,2" + end));
        assert!(
            matches!(err, DataError::Malformed { line: 4, .. }),
            "{end:?}: {msg}"
        );
        // Two blank lines before the bad row.
        let text = rows[..3].join(end) + end + end + end + rows[3] + end;
        let (err, msg) = error_of(&text);
        assert!(
            matches!(err, DataError::NotNumeric { line: 6, .. }),
            "{end:?}: {msg}"
        );
    }
    let (err, msg) = error_of("P1_kpa,P2_kpa,x_mm,note\r\n1,2,3,\"two\r\nlines\"\r\n4,5,x,\r\n");
    assert!(
        matches!(err, DataError::NotNumeric { line: 4, .. }),
        "{msg}"
    );
    // The text tables (frame index, pressure log) count the same way.
    let dir = tempdir();
    let path = write(dir.path(), "t.csv", "a,b\r\n1,2\r\n\r\n3,4\r\n");
    let table = handcap::data::Table::open(&path, "a,b").unwrap();
    let lines: Vec<u64> = table.records().unwrap().iter().map(|r| r.0).collect();
    assert_eq!(lines, [2, 4]);
}

/// A spreadsheet's export with semicolons or tabs between columns is named as such, not as a
/// missing column.
#[test]
fn a_file_separated_by_semicolons_or_tabs_says_so() {
    for (text, separator) in [
        ("P1_kpa;P2_kpa;x_mm\n1,5;2;3\n", "semicolons"),
        ("P1_kpa\tP2_kpa\tx_mm\n1\t2\t3\n", "tabs"),
    ] {
        let (err, msg) = error_of(text);
        assert!(
            matches!(err, DataError::NotCommaSeparated { separator: s, .. } if s == separator),
            "{msg}"
        );
        assert!(
            msg.contains("line 1") && msg.contains("export the file with commas"),
            "{msg}"
        );
    }
    // A one-column file of other names is a missing column, as before.
    let (err, _) = error_of("P1_kpa\n1\n");
    assert!(matches!(err, DataError::MissingColumn { .. }));
}

/// A spreadsheet's empty rows (separators only) are blank lines; an empty cell in a row of
/// values is named as empty.
#[test]
fn empty_rows_are_blank_and_empty_cells_are_named() {
    let dir = tempdir();
    let path = write(
        dir.path(),
        "d.csv",
        "P1_kpa,P2_kpa,x_mm\n1,2,3\n, ,\n4,5,6\n,,\n,,\n",
    );
    let d = read(&path).unwrap();
    assert_eq!(d.inputs.values, [1.0, 2.0, 4.0, 5.0]);
    let (err, msg) = error_of("P1_kpa,P2_kpa,x_mm\n1,2,3\n4,,6\n");
    assert!(
        matches!(err, DataError::EmptyCell { line: 3, ref column, .. } if column == "P2_kpa"),
        "{msg}"
    );
    assert!(msg.contains("empty") && msg.contains("flag"), "{msg}");
}

#[test]
fn ragged_row() {
    let (err, msg) = error_of("P1_kpa,P2_kpa,x_mm\n1,2,3\n4,5\n");
    assert!(matches!(err, DataError::Malformed { line: 3, .. }), "{msg}");
}

#[test]
fn a_column_chosen_twice() {
    let dir = tempdir();
    let path = write(dir.path(), "d.csv", "a,b\n1,2\n");
    let err = read_dataset(&path, &names("a"), &names("a")).unwrap_err();
    assert!(matches!(err, DataError::RepeatedSelection { .. }));
    assert_eq!(
        read_columns(&path, &names("b,a")).unwrap().values,
        [2.0, 1.0]
    );
}
