//! `odocal inspect BAG`: what a ROS 2 bag (MCAP) holds, like `ros2 bag info`,
//! plus the manifest column names of each topic odocal reads; with
//! `--manifest`, a draft manifest that imports it.

use std::path::{Path, PathBuf};

use crate::output::is_stdout;
use anyhow::{bail, Context, Result};
use clap::Args;

use crate::output::Files;

/// Arguments of `odocal inspect`.
#[derive(Args)]
pub struct InspectArgs {
    /// The bag: an `.mcap` file (or a bag directory holding one).
    bag: PathBuf,
    /// Write a draft manifest that imports the bag (wheel, pose and IMU
    /// topics chosen by message type; guesses marked CHECK) to this file, or
    /// to stdout without a file name (then nothing else is printed). An
    /// existing file is not replaced unless `--force` is given.
    #[arg(long, value_name = "OUT.toml", num_args = 0..=1, default_missing_value = "-")]
    manifest: Option<PathBuf>,
    /// Replace an existing `--manifest` file.
    #[arg(long, requires = "manifest")]
    force: bool,
}

/// Prints the bag's topics, types, counts and rates, then the columns a
/// manifest can take from each readable topic; or writes a draft manifest.
pub fn run(a: InspectArgs) -> Result<()> {
    if is_stdout(&a.bag) {
        bail!("-: a bag is read from a file, not from stdin (MCAP is read by its index): save it first and give that path");
    }
    if let Some(out) = &a.manifest {
        return draft(&a.bag, out, a.force);
    }
    let info = odocal::io::bag::inspect(&a.bag)?;
    print!("{info}");
    let columns = info.manifest_columns()?;
    if !columns.is_empty() {
        print!("{columns}");
        println!("A draft manifest of the drive: odocal inspect {} --manifest OUT.toml", a.bag.display());
    }
    Ok(())
}

/// The bag as the manifest at `out` names it: relative to the manifest's
/// folder when the bag is inside it, else absolute (stdout: absolute).
fn bag_path_for(bag: &Path, out: Option<&Path>) -> Result<String> {
    let bag = bag.canonicalize().with_context(|| format!("{}", bag.display()))?;
    if let Some(dir) = out.and_then(|o| o.parent()) {
        let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
        if let Ok(dir) = dir.canonicalize() {
            if let Ok(rel) = bag.strip_prefix(&dir) {
                return Ok(rel.display().to_string());
            }
        }
    }
    Ok(bag.display().to_string())
}

/// `s` as one word of a POSIX shell command line: as it is when it holds
/// only characters no shell treats specially, else in single quotes (a
/// quote inside written `'\''`).
fn shell_word(s: &str) -> String {
    let plain = |c: char| c.is_ascii_alphanumeric() || "-_./+,:@%=".contains(c);
    if !s.is_empty() && s.chars().all(plain) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

fn draft(bag: &Path, out: &Path, force: bool) -> Result<()> {
    let to_stdout = is_stdout(out);
    let exists = || format!("--manifest {}: exists; give another name, or --force to replace it", out.display());
    let mut files = Files::default();
    files.input("the bag", bag);
    if let Ok(entries) = std::fs::read_dir(bag) {
        for e in entries.flatten() {
            files.input(format!("a file of the bag {}", bag.display()), &e.path());
        }
    }
    // The bag and a directory first: --force would not help there.
    files.output("--manifest", Some(out)).check()?;
    if !to_stdout && !force && out.symlink_metadata().is_ok() {
        bail!(exists());
    }
    let file = bag_path_for(bag, (!to_stdout).then_some(out))?;
    let text = odocal::io::bag::inspect(bag)?.draft_manifest(&file)?;
    if to_stdout {
        print!("{text}");
    } else {
        if force {
            odocal::output::write_text(out, &text)?;
        } else {
            // Created only if still absent: a file that appeared meanwhile is kept.
            odocal::output::write_texts(&[(out, &text)], false).map_err(|e| match &e {
                odocal::Error::Io { source, .. } if source.kind() == std::io::ErrorKind::AlreadyExists => {
                    anyhow::anyhow!(exists())
                }
                _ => e.into(),
            })?;
        }
        println!(
            "wrote {} (check the lines marked CHECK, then: odocal import {} --out drive.csv)",
            out.display(),
            shell_word(&out.display().to_string())
        );
    }
    Ok(())
}
