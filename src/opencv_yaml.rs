//! OpenCV FileStorage YAML (`%YAML:1.0`), written so that `cv2.FileStorage(path,
//! cv2.FILE_STORAGE_READ)` and C++ `cv::FileStorage` read it: matrices as `!!opencv-matrix`
//! with `rows`, `cols`, `dt: d` and row-major `data`, reals always with a decimal point and 17
//! significant digits (they read back exactly), strings quoted.

use std::fmt::Write as _;

/// A FileStorage document under construction: one top-level map.
#[derive(Clone, Debug)]
pub struct FileStorage {
    text: String,
}

impl Default for FileStorage {
    fn default() -> Self {
        FileStorage {
            text: String::from("%YAML:1.0\n---\n"),
        }
    }
}

/// A real number as OpenCV writes one: a mantissa with a point and an exponent.
pub fn real(v: f64) -> String {
    if v.is_nan() {
        ".Nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { ".Inf" } else { "-.Inf" }.into()
    } else {
        format!("{v:.16e}")
    }
}

/// A double-quoted YAML string.
fn quote(v: &str) -> String {
    format!("\"{}\"", v.replace('\\', "\\\\").replace('"', "\\\""))
}

impl FileStorage {
    pub fn new() -> Self {
        FileStorage::default()
    }

    pub fn int(&mut self, key: &str, v: i64) -> &mut Self {
        let _ = writeln!(self.text, "{key}: {v}");
        self
    }

    pub fn real(&mut self, key: &str, v: f64) -> &mut Self {
        let _ = writeln!(self.text, "{key}: {}", real(v));
        self
    }

    pub fn string(&mut self, key: &str, v: &str) -> &mut Self {
        let _ = writeln!(self.text, "{key}: {}", quote(v));
        self
    }

    /// A flow sequence of integers, e.g. `image_size: [ 1280, 720 ]`.
    pub fn ints(&mut self, key: &str, v: &[i64]) -> &mut Self {
        let items: Vec<String> = v.iter().map(i64::to_string).collect();
        let _ = writeln!(self.text, "{key}: [ {} ]", items.join(", "));
        self
    }

    /// A flow sequence of strings.
    pub fn strings(&mut self, key: &str, v: &[String]) -> &mut Self {
        let items: Vec<String> = v.iter().map(|x| quote(x)).collect();
        let _ = writeln!(self.text, "{key}: [ {} ]", items.join(", "));
        self
    }

    /// A flow sequence of reals.
    pub fn reals(&mut self, key: &str, v: &[f64]) -> &mut Self {
        let items: Vec<String> = v.iter().map(|&x| real(x)).collect();
        let _ = writeln!(self.text, "{key}: [ {} ]", items.join(", "));
        self
    }

    /// A `rows × cols` matrix of doubles, `data` row-major.
    ///
    /// # Panics
    /// If `data.len() != rows * cols`.
    pub fn matrix(&mut self, key: &str, rows: usize, cols: usize, data: &[f64]) -> &mut Self {
        assert_eq!(data.len(), rows * cols, "matrix {key}: wrong element count");
        let items: Vec<String> = data.iter().map(|&x| real(x)).collect();
        let _ = write!(
            self.text,
            "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
            items.join(", ")
        );
        self
    }

    /// The document's text.
    pub fn text(&self) -> &str {
        &self.text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_the_opencv_layout() {
        let mut fs = FileStorage::new();
        fs.ints("image_size", &[1280, 720])
            .matrix("T", 3, 1, &[-60.0, 0.5, 1e-3])
            .real("rms_px", 0.25)
            .int("views", 20)
            .string("command", "handcap \"synth\"");
        let text = fs.text();
        assert!(text.starts_with("%YAML:1.0\n---\n"));
        assert!(text.contains("image_size: [ 1280, 720 ]\n"));
        assert!(text.contains(
            "T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ -6.0000000000000000e1, 5.0000000000000000e-1, 1.0000000000000000e-3 ]\n"
        ));
        assert!(text.contains("rms_px: 2.5000000000000000e-1\n"));
        assert!(text.contains("command: \"handcap \\\"synth\\\"\"\n"));
        // Reals read back exactly.
        for v in [0.1, 1.0 / 3.0, 906.78912345, -1e-300] {
            assert_eq!(real(v).parse::<f64>().unwrap(), v);
        }
    }
}
