//! The command outputs that README.md and docs/guide.md quote are what the
//! binary prints.
//!
//! Each ```` ```text ```` block that opens with `$ ` is a shell session:
//! its `$ ` lines (with their `\` continuations) run in bash, in a scratch
//! folder that links the repository's `examples/` and `data/`, with this
//! build's `odocal` first on `PATH`; the blocks of one document run in
//! order in the same folder, so a later block can use a file an earlier one
//! wrote, and the `NAME=value` lines of earlier blocks are set again. Every
//! other line of the block must appear in the session's output (stdout and
//! stderr together), in the order quoted. A line of `…` or `...` stands for
//! lines left out; a `…` inside a line for text left out of that line. A
//! block whose command is itself shortened with `…` is not run.

use std::path::Path;
use std::process::Command;

/// One quoted session: the shell lines and the lines it must print.
struct Session {
    /// Where the block starts (`FILE:LINE`), for the failure message.
    at: String,
    commands: Vec<String>,
    expected: Vec<String>,
}

/// The shell sessions of the markdown `text`, from the file `name`.
fn sessions(name: &str, text: &str) -> Vec<Session> {
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate();
    while let Some((i, line)) = lines.next() {
        if line.trim_end() != "```text" {
            continue;
        }
        let mut block = Vec::new();
        for (_, l) in lines.by_ref() {
            if l.trim_end() == "```" {
                break;
            }
            block.push(l.trim_end().to_owned());
        }
        if !block.first().is_some_and(|l| l.starts_with("$ ")) {
            continue;
        }
        let (mut commands, mut expected) = (Vec::new(), Vec::new());
        let mut continued = false;
        for l in block {
            if let Some(c) = l.strip_prefix("$ ") {
                commands.push(c.to_owned());
            } else if continued {
                if let Some(last) = commands.last_mut() {
                    last.push('\n');
                    last.push_str(&l);
                }
            } else {
                expected.push(l);
                continue;
            }
            continued = l.ends_with('\\');
        }
        out.push(Session { at: format!("{name}:{}", i + 1), commands, expected });
    }
    out
}

/// Whether `line` of the output matches the quoted `want`, whose `…` stand
/// for text left out.
fn line_matches(line: &str, want: &str) -> bool {
    let line = line.trim_end();
    let pieces: Vec<&str> = want.split('…').collect();
    let (first, last) = (pieces[0], pieces[pieces.len() - 1]);
    if pieces.len() == 1 {
        return line == first;
    }
    let Some(mut rest) = line.strip_prefix(first) else {
        return false;
    };
    for piece in &pieces[1..pieces.len() - 1] {
        match rest.find(piece) {
            Some(at) => rest = &rest[at + piece.len()..],
            None => return false,
        }
    }
    rest.ends_with(last)
}

/// The first quoted line the output does not hold in order, if any.
fn first_missing<'a>(output: &str, expected: &'a [String]) -> Option<&'a str> {
    let mut lines = output.lines();
    expected
        .iter()
        .filter(|w| !matches!(w.trim(), "…" | "..." | ""))
        .find(|w| !lines.by_ref().any(|l| line_matches(l, w)))
        .map(String::as_str)
}

/// Runs the sessions of the repository document `doc` and returns what
/// failed, one paragraph per session.
fn check(doc: &str) -> Vec<String> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = std::fs::read_to_string(repo.join(doc)).expect("read the document");
    let dir = tempfile::tempdir().expect("scratch folder");
    for link in ["examples", "data"] {
        std::os::unix::fs::symlink(repo.join(link), dir.path().join(link)).expect("link");
    }
    let bin = Path::new(env!("CARGO_BIN_EXE_odocal")).parent().expect("the binary's folder").to_owned();
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let mut assignments: Vec<String> = Vec::new();
    let mut failures = Vec::new();
    let all = sessions(doc, &text);
    assert!(!all.is_empty(), "{doc} quotes no shell session");
    for s in all {
        if s.commands.iter().any(|c| c.contains('…')) {
            continue;
        }
        let script = [assignments.clone(), s.commands.clone()].concat().join("\n");
        let out = Command::new("bash")
            .args(["-c", &format!("exec 2>&1\n{script}")])
            .current_dir(dir.path())
            .env("PATH", &path)
            .output()
            .expect("run bash");
        let printed = String::from_utf8_lossy(&out.stdout);
        if let Some(missing) = first_missing(&printed, &s.expected) {
            failures.push(format!(
                "{}: the output lacks, in the quoted order:\n  {missing}\nscript:\n{script}\noutput:\n{printed}",
                s.at
            ));
        }
        assignments.extend(s.commands.iter().filter(|c| is_assignment(c)).cloned());
    }
    failures
}

/// `NAME=value` with nothing after it: a shell variable the next sessions
/// of the document use.
fn is_assignment(command: &str) -> bool {
    command.split_once('=').is_some_and(|(name, value)| {
        !name.is_empty()
            && name.chars().all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
            && !value.contains(' ')
    })
}

#[test]
fn the_readme_quotes_what_the_binary_prints() {
    let failures = check("README.md");
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn the_guide_quotes_what_the_binary_prints() {
    let failures = check("docs/guide.md");
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn a_quote_with_a_changed_number_fails() {
    let quoted = vec!["a …".to_owned(), "  c_e  m   2.000000".to_owned()];
    assert!(first_missing("a b\n  c_e  m   2.000000\n", &quoted).is_none());
    assert_eq!(first_missing("a b\n  c_e  m   2.000001\n", &quoted), Some("  c_e  m   2.000000"));
    // Out of the quoted order.
    assert!(first_missing("  c_e  m   2.000000\na b\n", &quoted).is_some());
    // A whole quoted line is the whole output line.
    assert!(!line_matches("verdict: ACCEPTED and more", "verdict: ACCEPTED"));
    assert!(line_matches("result: FALLBACK (see the warnings; x y)", "result: FALLBACK (see …; …)"));
}

#[test]
fn sessions_take_continuations_and_leave_out_other_blocks() {
    let md = "```text\nplain\n```\n```text\n$ E=x\n$ odocal a \\\n      b\nout 1\n…\n```\n";
    let s = sessions("t.md", md);
    assert_eq!(s.len(), 1);
    assert_eq!(s[0].commands, vec!["E=x".to_owned(), "odocal a \\\n      b".to_owned()]);
    assert_eq!(s[0].expected, vec!["out 1".to_owned(), "…".to_owned()]);
    assert_eq!(s[0].at, "t.md:4");
    assert!(is_assignment("E=examples/psu") && !is_assignment("odocal x --a=b"));
}
