//! The one check every command runs before its work: nothing it will write replaces a file it
//! reads, no two of its outputs are the same file, and every output's directory exists (or is
//! created) and can be written. A long search or triangulation is never lost to an output
//! problem found at the end.

use std::collections::{HashMap, HashSet};
use std::ffi::OsStr;
use std::path::{Component, Path, PathBuf};

use super::PipelineError;

/// A file a command will write, and what it is (for the message): `--out`, "the pairs table
/// beside --out", "report file metrics.csv".
pub struct Output {
    pub path: PathBuf,
    pub role: String,
}

impl Output {
    pub fn new(path: impl Into<PathBuf>, role: impl Into<String>) -> Self {
        Output {
            path: path.into(),
            role: role.into(),
        }
    }
}

/// Checks `outputs` against every file in `inputs` and against each other, then makes sure
/// each output's directory exists and takes a new file.
///
/// # Errors
/// [`PipelineError::Request`] naming the output, what it would replace and what to do; or the
/// directory that cannot be created or written.
pub fn check(inputs: &[&Path], outputs: &[Output]) -> Result<(), PipelineError> {
    let resolved: Vec<PathBuf> = outputs.iter().map(|o| resolve(&o.path)).collect();
    // An input can be an output only if its resolved name is an output's: only those inputs,
    // and inputs that are links themselves, are resolved (triangulate reads thousands of
    // frames; resolving each costs several system calls).
    let names: HashSet<&OsStr> = resolved.iter().filter_map(|p| p.file_name()).collect();
    let read: HashMap<PathBuf, &Path> = inputs
        .iter()
        .filter(|p| {
            p.file_name().is_some_and(|n| names.contains(n))
                || p.symlink_metadata()
                    .is_ok_and(|m| m.file_type().is_symlink())
        })
        .filter_map(|p| p.canonicalize().ok().map(|c| (c, *p)))
        .collect();
    let mut seen: HashMap<PathBuf, &Output> = HashMap::new();
    for (out, resolved) in outputs.iter().zip(resolved) {
        if let Some(input) = read.get(&resolved) {
            return Err(PipelineError::Request(format!(
                "{} ({}) would replace the input {}; outputs never overwrite inputs, choose another name",
                out.path.display(),
                out.role,
                input.display()
            )));
        }
        if let Some(first) = seen.insert(resolved, out) {
            return Err(PipelineError::Request(format!(
                "{} would be written twice: as {} and as {}; rename one (e.g. another --out)",
                out.path.display(),
                first.role,
                out.role
            )));
        }
        if out.path.is_dir() {
            return Err(PipelineError::Request(format!(
                "{} ({}) is a directory; give a file name",
                out.path.display(),
                out.role
            )));
        }
    }
    let mut checked = HashSet::new();
    for out in outputs {
        let dir = directory(&out.path);
        if !checked.insert(dir) {
            continue;
        }
        writable(dir).map_err(|why| {
            PipelineError::Place(format!(
                "cannot write {} ({}): {why}",
                out.path.display(),
                out.role
            ))
        })?;
    }
    Ok(())
}

/// A directory that takes new files: created when missing (each folder made kept in
/// [`made_folders`]), then probed with a temporary file.
fn writable(dir: &Path) -> Result<(), String> {
    if let Some(existing) = dir.ancestors().find(|a| a.exists()) {
        if !existing.is_dir() {
            return Err(format!("{} is not a directory", existing.display()));
        }
    }
    let missing: Vec<PathBuf> = dir
        .ancestors()
        .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
        .map(Path::to_path_buf)
        .collect();
    std::fs::create_dir_all(dir)
        .map_err(|e| format!("cannot create the directory {}: {}", dir.display(), os(&e)))?;
    MADE.lock().expect("made folders").extend(missing);
    crate::fsio::temp_beside(&dir.join("probe"), ".probe")
        .map(drop)
        .map_err(|e| format!("{} does not take new files: {}", dir.display(), os(&e)))
}

/// The folders [`check`] made for outputs, innermost first.
static MADE: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Removes the folders [`check`] made that are still empty (a command that failed before it
/// wrote into them): a failed run leaves no empty folder behind. A folder with anything in it
/// stays.
pub fn remove_empty_made_folders() {
    for dir in MADE.lock().expect("made folders").drain(..) {
        let _ = std::fs::remove_dir(dir);
    }
}

/// An I/O error's text without the "(os error N)" tail.
fn os(e: &std::io::Error) -> String {
    let text = e.to_string();
    match text.find(" (os error") {
        Some(k) => text[..k].to_string(),
        None => text,
    }
}

/// The directory a file is written into.
fn directory(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The path an output will have: the file itself when it exists (links resolved), else its
/// resolved directory and name, else the absolute path with `.` and `..` removed.
fn resolve(path: &Path) -> PathBuf {
    if let Ok(p) = path.canonicalize() {
        return p;
    }
    if let (Ok(dir), Some(name)) = (directory(path).canonicalize(), path.file_name()) {
        return dir.join(name);
    }
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = PathBuf::new();
    for c in absolute.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_naming_an_input_or_another_output_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("train.csv");
        std::fs::write(&input, "x\n").unwrap();
        // The same file through another spelling.
        let other = dir.path().join("sub/../train.csv");
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        let err = check(&[&input], &[Output::new(&other, "--out")]).unwrap_err();
        assert!(err.to_string().contains("would replace the input"), "{err}");
        // Two outputs, one file (neither exists yet).
        let a = dir.path().join("d_pairs.csv");
        let b = dir.path().join("./d_pairs.csv");
        let err = check(
            &[],
            &[
                Output::new(&a, "the pairs table"),
                Output::new(&b, "phase `pairs`"),
            ],
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("written twice") && err.contains("phase `pairs`"),
            "{err}"
        );
        // A new file in new directories is fine, and the directories are made; a run that
        // fails before it writes there has them removed.
        let fine = dir.path().join("new/deeper/out.csv");
        check(&[&input], &[Output::new(&fine, "--out")]).unwrap();
        assert!(dir.path().join("new/deeper").is_dir());
        remove_empty_made_folders();
        assert!(!dir.path().join("new").exists());
    }

    #[test]
    fn unwritable_places_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a_file");
        std::fs::write(&file, "x").unwrap();
        let err = check(&[], &[Output::new(file.join("out.csv"), "--out")])
            .unwrap_err()
            .to_string();
        assert!(err.contains("is not a directory"), "{err}");
        let err = check(&[], &[Output::new(dir.path(), "--out")])
            .unwrap_err()
            .to_string();
        assert!(err.contains("is a directory"), "{err}");
        if Path::new("/proc/self").is_dir() {
            let err = check(&[], &[Output::new("/proc/x", "--out")])
                .unwrap_err()
                .to_string();
            assert!(err.contains("does not take new files"), "{err}");
            assert!(!err.contains("os error"), "{err}");
        }
    }
}
