//! The documentation against the code: `docs/cli.md` is what the command's own definitions say,
//! and `docs/architecture.md` names only files and folders that exist.

use std::path::{Path, PathBuf};

use clap::CommandFactory;

fn repository() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The command-line reference: every subcommand's `--help`, in the order `handcap --help`
/// lists them.
fn cli_reference() -> String {
    let mut command = handcap::cli::Cli::command();
    command.build();
    let mut text = String::from(
        "# Command-line reference\n\n\
         Generated from the command's own definitions (`tests/it/docs.rs` fails when it differs; \
         `HANDCAP_WRITE_DOCS=1 cargo test --release --test it docs::` writes it anew). \
         The same text is `handcap <command> --help`.\n\n",
    );
    let top = command.render_long_help().to_string();
    text += &format!("## handcap\n\n```text\n{}\n```\n", top.trim_end());
    for sub in command.get_subcommands_mut() {
        let name = sub.get_name().to_string();
        if name == "help" {
            continue;
        }
        let help = sub.render_long_help().to_string();
        text += &format!("\n## handcap {name}\n\n```text\n{}\n```\n", help.trim_end());
    }
    text
}

#[test]
fn the_cli_reference_is_what_the_command_says() {
    let path = repository().join("docs/cli.md");
    let want = cli_reference();
    if std::env::var_os("HANDCAP_WRITE_DOCS").is_some() {
        std::fs::write(&path, &want).unwrap();
    }
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        have == want,
        "docs/cli.md differs from the command's definitions: \
         run HANDCAP_WRITE_DOCS=1 cargo test --release --test it docs:: and commit it"
    );
    for name in [
        "synth",
        "calibrate",
        "triangulate",
        "model",
        "inverse",
        "export",
        "demo",
    ] {
        assert!(
            have.contains(&format!("## handcap {name}\n")),
            "{name} missing"
        );
    }
}

/// The paths `docs/architecture.md`'s layout names: each entry's first column, and the source
/// files and folders its description names, which lie under it (the files the code writes,
/// `calib.yml` or `report.md`, are not checked).
fn named_paths(layout: &str) -> Vec<(PathBuf, String)> {
    let block = layout
        .split("```")
        .nth(1)
        .expect("docs/architecture.md has its layout in a code block");
    let mut named = Vec::new();
    let mut folder = PathBuf::new();
    for line in block.lines().filter(|l| !l.trim().is_empty()) {
        let mut words = line.split_whitespace();
        if !line.starts_with(' ') {
            let entry = words.next().unwrap();
            folder = PathBuf::from(entry);
            named.push((folder.clone(), entry.to_string()));
            if folder.extension().is_some() {
                folder.pop();
            }
        }
        for word in words {
            let word = word.trim_matches(|c: char| "(),;:`".contains(c));
            let is_file = [".rs", ".sh", ".py"].iter().any(|ext| word.ends_with(ext));
            let plain = word
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c));
            if plain && (is_file || word.ends_with('/')) && !word.starts_with("../") {
                named.push((folder.clone(), word.to_string()));
            }
        }
    }
    named
}

/// A name that exists at `root/folder/name`, at `root/name`, or anywhere under the folder.
fn exists_under(root: &Path, folder: &Path, name: &str) -> bool {
    let direct = [root.join(folder).join(name), root.join(name)];
    if direct.iter().any(|p| p.exists()) {
        return true;
    }
    let name = name.trim_end_matches('/');
    let mut pending = vec![root.join(folder)];
    while let Some(dir) = pending.pop() {
        for entry in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.ends_with(name) {
                return true;
            }
            if path.is_dir() {
                pending.push(path);
            }
        }
    }
    false
}

#[test]
fn the_architecture_names_only_what_exists() {
    let root = repository();
    let layout = std::fs::read_to_string(root.join("docs/architecture.md")).unwrap();
    let named = named_paths(&layout);
    assert!(named.len() > 60, "only {} paths found", named.len());
    let missing: Vec<String> = named
        .iter()
        .filter(|(folder, name)| !exists_under(&root, folder, name))
        .map(|(folder, name)| format!("{name} (under {})", folder.display()))
        .collect();
    assert!(
        missing.is_empty(),
        "docs/architecture.md names what does not exist: {missing:?}"
    );
}

#[test]
fn the_architecture_check_finds_a_missing_file() {
    let root = repository();
    let layout = "```\nsrc/calib/   mod.rs (the steps), no_such_file.rs (gone)\n```\n";
    let named = named_paths(layout);
    let missing: Vec<&str> = named
        .iter()
        .filter(|(folder, name)| !exists_under(&root, folder, name))
        .map(|(_, name)| name.as_str())
        .collect();
    assert_eq!(missing, ["no_such_file.rs"]);
}
