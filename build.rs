//! The build's identity: `HANDCAP_BUILD_ID`, a hash of the sources both binaries are built
//! from, so that `handcap` can refuse a `handcap-cameras` beside it built from other sources
//! (`cargo run -- synth` rebuilds one binary and would otherwise run a stale other).

use std::path::{Path, PathBuf};

/// What the binaries are built from, relative to the package's root.
const SOURCES: [&str; 8] = [
    "src",
    "core/src",
    "model/src",
    "build.rs",
    "Cargo.toml",
    "core/Cargo.toml",
    "model/Cargo.toml",
    "Cargo.lock",
];

fn main() {
    let mut files = Vec::new();
    for source in SOURCES {
        println!("cargo:rerun-if-changed={source}");
        collect(Path::new(source), &mut files);
    }
    files.sort();
    // FNV-1a, 64 bits, over each file's path and bytes: stable across machines and runs.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for file in &files {
        eat(file.to_string_lossy().as_bytes());
        eat(&std::fs::read(file).unwrap_or_default());
    }
    println!(
        "cargo:rustc-env=HANDCAP_BUILD_ID={}-{hash:016x}",
        env!("CARGO_PKG_VERSION")
    );
}

/// Every file under `path` (or `path` itself).
fn collect(path: &Path, files: &mut Vec<PathBuf>) {
    match std::fs::read_dir(path) {
        Ok(entries) => {
            for entry in entries.flatten() {
                collect(&entry.path(), files);
            }
        }
        Err(_) if path.is_file() => files.push(path.to_path_buf()),
        Err(_) => {}
    }
}
