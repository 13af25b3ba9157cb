//! Checks on the repository as a whole.

use std::path::{Path, PathBuf};

/// Build output and version control, relative to the root: not sources.
const GENERATED: [&str; 6] = [".git", "target", "fuzz/target", "fuzz/artifacts", "fuzz/coverage", "out"];

/// Extensions of the text files that can refer to data: sources, tests,
/// manifests, scripts and their documentation. Files without an extension
/// (`.ci/run`) are read too.
const TEXT_EXTENSIONS: [&str; 11] = ["rs", "toml", "py", "sh", "md", "json", "yml", "yaml", "txt", "cff", "cfg"];

/// What a reference to the data folder beside the repository looks like
/// (built with `concat!` so this file does not name it).
const OUTSIDE_REFERENCES: [&str; 2] = [concat!("..", "/shared"), concat!("shared", "/data")];

fn repository_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The text files under `dir` (recursively), leaving out the paths in
/// `skip` (relative to `root`).
fn text_files(root: &Path, dir: &Path, skip: &[&str], out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let path = entry.unwrap_or_else(|e| panic!("{}: {e}", dir.display())).path();
        let relative = path.strip_prefix(root).expect("under the root");
        if skip.iter().any(|s| relative == Path::new(s)) {
            continue;
        }
        if path.is_dir() {
            text_files(root, &path, skip, out);
        } else if path.extension().is_none_or(|x| TEXT_EXTENSIONS.iter().any(|t| x == *t)) {
            out.push(path);
        }
    }
}

/// The repository is self-contained: the real logs are in `data/`, and no
/// source, test, example, manifest or script reads them from beside it.
#[test]
fn nothing_refers_to_shared_outside_the_repository() {
    let root = repository_root();
    let skip: Vec<&str> = GENERATED.to_vec();
    let mut files = Vec::new();
    text_files(&root, &root, &skip, &mut files);
    files.sort();
    assert!(files.len() > 100, "the walk found only {} files under {}", files.len(), root.display());
    let mut found = Vec::new();
    for file in &files {
        // Binary files without an extension (fuzz corpus inputs) are not text.
        let Ok(text) = std::fs::read_to_string(file) else { continue };
        for (i, line) in text.lines().enumerate() {
            if OUTSIDE_REFERENCES.iter().any(|r| line.contains(r)) {
                let relative = file.strip_prefix(&root).expect("under the root");
                found.push(format!("{}:{}: {}", relative.display(), i + 1, line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "{} line(s) refer to data outside the repository (use data/ at the repository root):\n{}",
        found.len(),
        found.join("\n")
    );
}
