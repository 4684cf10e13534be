//! What made a file: handcap version, command line, seed and the hashes of the input files.
//!
//! Recorded in every model file, manifest and report so a result can be traced and repeated.
//! There is no timestamp: the same command on the same inputs writes the same bytes.

use std::io::Read;
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// One input file and the SHA-256 of its bytes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputFile {
    pub path: String,
    pub sha256: String,
}

/// The provenance block written into handcap's outputs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    pub handcap_version: String,
    /// The command line, argument by argument.
    pub command: Vec<String>,
    /// The seed of every random choice, when the command makes any.
    pub seed: Option<u64>,
    pub inputs: Vec<InputFile>,
}

impl Provenance {
    /// Provenance for `command` with no inputs yet.
    pub fn new(command: Vec<String>, seed: Option<u64>) -> Self {
        Provenance {
            handcap_version: env!("CARGO_PKG_VERSION").to_string(),
            command,
            seed,
            inputs: Vec::new(),
        }
    }

    /// Adds an input file with its hash.
    ///
    /// # Errors
    /// When the file cannot be read.
    pub fn with_input(mut self, path: &Path) -> std::io::Result<Self> {
        self.inputs.push(InputFile {
            path: path.display().to_string(),
            sha256: sha256_file(path)?,
        });
        Ok(self)
    }
}

/// The SHA-256 of a file's bytes, in lowercase hex.
///
/// # Errors
/// When the file cannot be read.
pub fn sha256_file(path: &Path) -> std::io::Result<String> {
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Sha256::new();
    let mut buf = [0u8; 1 << 16];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}
