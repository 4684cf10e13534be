//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use handcap::data::{Columns, Dataset};

/// A fresh temporary directory, removed when dropped.
pub fn tempdir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

/// Writes `text` to `dir/name` and returns the path.
pub fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write test file");
    path
}

/// Runs the `handcap` binary with `args` in `dir`.
pub fn handcap(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_handcap"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run handcap")
}

/// Runs `handcap` and asserts it succeeded; returns stdout.
pub fn handcap_ok(dir: &Path, args: &[&str]) -> String {
    let out = handcap(dir, args);
    assert!(
        out.status.success(),
        "handcap {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8 stdout")
}

/// Runs `handcap`, asserts exit code 1 and a one-line error; returns that line.
pub fn handcap_err(dir: &Path, args: &[&str]) -> String {
    let out = handcap(dir, args);
    assert_eq!(
        out.status.code(),
        Some(1),
        "handcap {args:?} should fail with 1"
    );
    let stderr = String::from_utf8(out.stderr).expect("utf-8 stderr");
    assert_eq!(stderr.lines().count(), 1, "error is not one line: {stderr}");
    assert!(stderr.starts_with("handcap: "), "{stderr}");
    stderr.trim_end().to_string()
}

/// A dataset from row-major inputs and outputs with generated names.
pub fn dataset(d: usize, x: Vec<f64>, q: usize, y: Vec<f64>) -> Dataset {
    Dataset {
        source: "generated".into(),
        inputs: Columns::new((0..d).map(|j| format!("x{j}")).collect(), x),
        outputs: Columns::new((0..q).map(|j| format!("y{j}")).collect(), y),
    }
}

/// A small deterministic pseudo-random stream in [0, 1) (no seed plumbing in tests).
pub struct Lcg(pub u64);

impl Lcg {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn vec(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.next()).collect()
    }
}
