//! File output that never leaves a half-written file and never replaces an input.

use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes a file through `fill` into a temporary file beside `path`, then renames it over `path`.
///
/// If `fill` or the rename fails, `path` is untouched and the temporary file is removed.
///
/// # Errors
/// Any I/O error of creating, writing, syncing or renaming the file.
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> io::Result<()> {
    let mut tmp = temp_beside(path, ".tmp")?;
    {
        let mut w = BufWriter::new(tmp.as_file_mut());
        fill(&mut w)?;
        w.flush()?;
    }
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// A temporary file in `path`'s directory (so a rename replaces `path` atomically), readable by
/// all like any file the user writes (tempfile's default is owner-only), named with `suffix`.
///
/// # Errors
/// When the file cannot be created.
pub fn temp_beside(path: &Path, suffix: &str) -> io::Result<tempfile::NamedTempFile> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(".handcap-").suffix(suffix);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    builder.tempfile_in(dir)
}

/// Writes `bytes` to `path` atomically (see [`write_atomic`]).
///
/// # Errors
/// As [`write_atomic`].
pub fn write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// The file names a previous run listed under `"files"` in the JSON file `listing` (empty when
/// there is none, or it cannot be read).
pub fn listed_files(listing: &Path) -> Vec<String> {
    let Ok(text) = std::fs::read_to_string(listing) else {
        return Vec::new();
    };
    let Ok(json) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Vec::new();
    };
    json["files"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|v| v.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

/// Removes the files of a previous run (`previous`, names in `dir`, as [`listed_files`] read
/// them) that this run did not write again (`written`): a folder never mixes two runs' files.
/// The listing only narrows what may go: a name is removed only when `ours` says this command
/// writes files of that name there (a listing on disk can be edited, and must never make
/// handcap delete a file it did not write). Names with a path separator are ignored. Returns
/// what was removed.
pub fn remove_stale(
    dir: &Path,
    previous: &[String],
    written: &[std::path::PathBuf],
    ours: impl Fn(&Path) -> bool,
) -> Vec<std::path::PathBuf> {
    let kept: Vec<&std::ffi::OsStr> = written.iter().filter_map(|p| p.file_name()).collect();
    previous
        .iter()
        .filter(|name| !name.contains(['/', '\\']) && !name.is_empty() && !name.starts_with('.'))
        .filter(|name| !kept.contains(&std::ffi::OsStr::new(name.as_str())))
        .map(|name| dir.join(name))
        .filter(|path| path.is_file() && ours(path) && std::fs::remove_file(path).is_ok())
        .collect()
}

/// The file names of `paths`, for a `"files"` listing.
pub fn file_names(paths: &[std::path::PathBuf]) -> Vec<String> {
    paths
        .iter()
        .filter_map(|p| p.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .collect()
}

/// A file beside `path` named after it: its name without the extension (`fallback` when it has
/// none), then `suffix`. `dataset.csv` + `_pairs.csv` → `dataset_pairs.csv`.
pub fn beside(path: &Path, fallback: &str, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map_or_else(|| fallback.into(), |s| s.to_string_lossy().into_owned());
    path.with_file_name(format!("{stem}{suffix}"))
}
