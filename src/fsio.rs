//! File output that never leaves a half-written file and never replaces an input.

use std::io::{self, BufWriter, Write};
use std::path::Path;

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
