//! File output that never leaves a half-written file and never replaces an input.

use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes a file through `fill` into a temporary file beside `path`, then renames it over `path`.
///
/// If `fill` or the rename fails, `path` is untouched and the temporary file is removed. A path
/// that is not a regular file is never replaced (see [`Target`]): a device, a FIFO or
/// `/dev/stdout` is written into as it is, and a symbolic link to a file keeps its link (the
/// file it names is replaced).
///
/// # Errors
/// Any I/O error of creating, writing, syncing or renaming the file; a folder at `path`.
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> io::Result<()> {
    let path = match Target::of(path)? {
        Target::File(path) => path,
        Target::Stream(path) => {
            let mut w = BufWriter::new(std::fs::OpenOptions::new().write(true).open(path)?);
            fill(&mut w)?;
            return w.flush();
        }
    };
    let path = path.as_path();
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

/// Where an output named `path` is written.
#[derive(Debug, PartialEq)]
pub enum Target {
    /// A regular file (or none yet), replaced atomically: `path`, or the file a symbolic link
    /// names (the link kept).
    File(PathBuf),
    /// Anything else that exists and is not a folder (a device such as `/dev/null`, a FIFO, a
    /// socket, a terminal, `/dev/stdout` and the files under `/proc` it links to): written into
    /// in place, never replaced.
    Stream(PathBuf),
}

impl Target {
    /// What `path` is, following symbolic links.
    ///
    /// # Errors
    /// A folder at `path`, or a link that cannot be followed.
    pub fn of(path: &Path) -> io::Result<Self> {
        let link = match std::fs::symlink_metadata(path) {
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Self::File(path.into())),
            Err(e) => return Err(e),
            Ok(m) if m.file_type().is_file() => return Ok(Self::File(path.into())),
            Ok(m) => m.file_type().is_symlink(),
        };
        let target = match std::fs::metadata(path) {
            // A dangling link: the file it names is created.
            Err(e) if link && e.kind() == io::ErrorKind::NotFound => {
                return Ok(Self::File(link_target(path)?));
            }
            Err(e) => return Err(e),
            Ok(m) => m,
        };
        if target.is_dir() {
            return Err(io::Error::new(
                io::ErrorKind::IsADirectory,
                "a folder is there: name a file",
            ));
        }
        // A link into the system's special trees (`/dev/stdout` → `/proc/self/fd/1` → a file the
        // shell redirected to, or a pipe) is the descriptor, not the file: replacing the file
        // would lose it.
        let special = |p: &Path| {
            [Path::new("/dev"), Path::new("/proc")]
                .iter()
                .any(|r| p.starts_with(r))
        };
        Ok(match std::fs::canonicalize(path) {
            Ok(resolved) if target.is_file() && !special(path) && !special(&resolved) => {
                Self::File(resolved)
            }
            _ => Self::Stream(path.into()),
        })
    }
}

/// The path a dangling symbolic link names (relative to the link's folder when relative).
fn link_target(path: &Path) -> io::Result<PathBuf> {
    let named = std::fs::read_link(path)?;
    Ok(match (named.is_absolute(), path.parent()) {
        (false, Some(dir)) => dir.join(named),
        _ => named,
    })
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

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    /// Hostile probe 1 (issue 61): every writer renamed a temporary file over its output, so a
    /// FIFO (or a device, or `/dev/stdout`) named as the output was replaced by a regular file
    /// and its reader waited forever.
    #[test]
    fn hostile_outputs_never_replace_special_files() {
        use std::os::unix::fs::FileTypeExt;
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo");
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        write_bytes(&fifo, b"x,y\n1,2\n").unwrap();
        assert_eq!(reader.join().unwrap(), b"x,y\n1,2\n");
        let kind = std::fs::symlink_metadata(&fifo).unwrap().file_type();
        assert!(kind.is_fifo(), "the FIFO was replaced: {kind:?}");
        // /dev/null is written into (a test as root must never risk replacing it: it is only
        // classified here, and written through the FIFO above).
        assert_eq!(
            Target::of(Path::new("/dev/null")).unwrap(),
            Target::Stream("/dev/null".into())
        );
        assert!(matches!(
            Target::of(Path::new("/dev/stdout")).unwrap(),
            Target::Stream(_)
        ));
    }

    #[test]
    fn a_link_to_a_file_keeps_its_link_and_a_folder_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (file, link) = (dir.path().join("real.csv"), dir.path().join("link.csv"));
        std::fs::write(&file, "old").unwrap();
        std::os::unix::fs::symlink(&file, &link).unwrap();
        write_bytes(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&file).unwrap(), b"new");
        let dangling = dir.path().join("dangling.csv");
        std::os::unix::fs::symlink("made.csv", &dangling).unwrap();
        write_bytes(&dangling, b"made").unwrap();
        assert_eq!(std::fs::read(dir.path().join("made.csv")).unwrap(), b"made");
        let err = write_bytes(dir.path(), b"x").unwrap_err();
        assert!(err.to_string().contains("folder"), "{err}");
    }
}
