//! The files a command reads and writes: outputs checked against the
//! inputs and each other before any work ([`Files::check`]), `-` for
//! stdout, and every file written atomically (the library's
//! [`odocal::output`]).

use std::io::Write;
use std::path::Path;

use anyhow::{bail, Result};
use odocal::output::{check_collisions, FileRole};

/// The inputs and outputs of one command, by role.
#[derive(Default)]
pub struct Files {
    inputs: Vec<FileRole>,
    outputs: Vec<FileRole>,
    /// The command creates its outputs' folder (`experiment --out DIR`).
    creates_folder: bool,
}

impl Files {
    /// An input file in a role ("the --theta parameter file").
    pub fn input(&mut self, role: impl Into<String>, path: &Path) -> &mut Self {
        self.inputs.push(FileRole { role: role.into(), path: path.into() });
        self
    }

    /// A drive the command reads in a role ("the drive being calibrated"):
    /// the CSV and the simulator sidecar beside it, or the manifest and
    /// every stream file it names.
    pub fn drive(&mut self, role: &str, path: &Path) -> &mut Self {
        if odocal::is_manifest_path(path) {
            return self.manifest(role, path);
        }
        self.input(role, path);
        if let Some(side) = odocal::sim::SimSidecar::file_beside(path) {
            self.input(format!("the simulator sidecar of {}", path.display()), &side);
        }
        self
    }

    /// A manifest the command reads, every stream file it names and the
    /// parameter file its `[calibration] theta0` names.
    pub fn manifest(&mut self, role: &str, path: &Path) -> &mut Self {
        self.input(role, path);
        // A manifest that cannot be read fails later, with the importer's message.
        if let Ok(m) = odocal::Manifest::from_path(path) {
            for (stream, file) in m.stream_files() {
                self.input(format!("stream '{stream}' of the manifest {}", path.display()), &file);
            }
            if let Some(file) = m.theta0_file() {
                self.input(
                    format!("the [calibration] theta0 parameter file of the manifest {}", path.display()),
                    &file,
                );
            }
        }
        self
    }

    /// An output in a role ("--json"), when it is asked for.
    pub fn output(&mut self, role: impl Into<String>, path: Option<&Path>) -> &mut Self {
        if let Some(p) = path {
            self.outputs.push(FileRole { role: role.into(), path: p.into() });
        }
        self
    }

    /// The command creates the folder its outputs go to: it need not exist.
    pub fn creates_folder(&mut self) -> &mut Self {
        self.creates_folder = true;
        self
    }

    /// Refuses an output that is an input or another output, two outputs
    /// on stdout, and an output that cannot be written where it is asked
    /// for (a directory, or in a folder that does not exist), all before
    /// any work.
    pub fn check(&self) -> Result<()> {
        let stdout: Vec<&str> = self.outputs.iter().filter(|o| is_stdout(&o.path)).map(|o| o.role.as_str()).collect();
        if let [first, second, ..] = stdout[..] {
            // A bad command line: a usage error.
            return Err(odocal::Error::InvalidFlags(format!(
                "{first} and {second} both go to stdout (-): give one of them a file name"
            ))
            .into());
        }
        for o in self.outputs.iter().filter(|o| !is_stdout(&o.path)) {
            check_writable_place(o, self.creates_folder)?;
        }
        check_collisions(&self.inputs, &self.outputs)?;
        Ok(())
    }

    /// True when an output goes to stdout (the text report then stays off it).
    pub fn any_stdout(&self) -> bool {
        self.outputs.iter().any(|o| is_stdout(&o.path))
    }
}

/// Refuses an output path that is a directory, or whose folder does not
/// exist, is not a folder or cannot be written in (unless the command
/// creates it): the write at the end of the work would fail.
fn check_writable_place(o: &FileRole, creates_folder: bool) -> Result<()> {
    let path = o.path.display();
    if o.path.is_dir() {
        bail!("{} {path}: is a directory; give a file name", o.role);
    }
    if creates_folder {
        return Ok(());
    }
    // A symbolic link is written where it points (odocal::output), so its
    // target's folder is the one that must take the file.
    let target = match std::fs::symlink_metadata(&o.path) {
        Ok(m) if m.file_type().is_symlink() => std::fs::canonicalize(&o.path).unwrap_or_else(|_| o.path.clone()),
        _ => o.path.clone(),
    };
    let folder = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match std::fs::metadata(folder) {
        Ok(m) if m.is_dir() => check_folder_takes_files(o, folder),
        Ok(_) => bail!("{} {path}: {} is not a folder", o.role, folder.display()),
        Err(_) => bail!("{} {path}: the folder {} does not exist; create it first", o.role, folder.display()),
    }
}

/// Creates and removes a hidden file in `folder`, as the atomic write does
/// at the end: a folder odocal cannot create files in (no permission, a
/// read-only file system, `/proc`) is refused before the work.
fn check_folder_takes_files(o: &FileRole, folder: &Path) -> Result<()> {
    let probe = folder.join(format!(".odocal-probe.{}.tmp", std::process::id()));
    match std::fs::OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(_) => {
            // A probe left behind (the folder lost its permission meanwhile) is harmless.
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        // Another output of this command probes the same folder: it takes files.
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => bail!(
            "{} {}: cannot create a file in the folder {} ({e}); give a folder you can write to",
            o.role,
            o.path.display(),
            folder.display()
        ),
    }
}

/// True for `-`, which stands for stdout where an output path is asked for,
/// and for `/dev/stdout`, which names the same (Unix): either keeps the
/// text report off stdout and counts as the one output there.
pub fn is_stdout(path: &Path) -> bool {
    path.as_os_str() == "-" || (cfg!(unix) && path.as_os_str() == "/dev/stdout")
}

/// Prints a line of the text report: on stdout, or on stderr when an
/// output (`-`) takes stdout, so that stdout holds that output alone.
pub fn report_line(stdout_taken: bool, line: &str) {
    if stdout_taken {
        eprintln!("{line}");
    } else {
        println!("{line}");
    }
}

/// Refuses `-` (stdout, also as `/dev/stdout`), a device or a pipe for an
/// output that needs a file (a drive with its sidecar beside it), saying
/// why.
pub fn refuse_stdout(role: &str, path: &Path, why: &str) -> Result<()> {
    if is_stdout(path) {
        bail!("{role} {}: {why}; give a path", path.display());
    }
    // A device or a pipe (`/dev/null`) has no folder to put a file beside.
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir()) {
        bail!("{role} {}: not a file, and {why}; give a path", path.display());
    }
    Ok(())
}

/// Refuses a drive `--out` whose sidecar path (the name with `.json`) is
/// itself: the truth would replace the drive.
pub fn refuse_sidecar_onto_drive(role: &str, path: &Path) -> Result<()> {
    if odocal::sim::SimSidecar::path_beside(path) == path {
        bail!(
            "{role} {}: the sidecar (the truth) is written beside the drive CSV under the name with .json, which is \
             this file; give {role} a name ending in .csv",
            path.display()
        );
    }
    Ok(())
}

/// Refuses to write a simulated drive's sidecar beside `csv` (the drive
/// `role` names) over a file that is not a simulator sidecar: the user
/// named the CSV, not the JSON beside it, which may be anything (a
/// calibration's report, say). An older sidecar is replaced, as its CSV is.
pub fn refuse_foreign_sidecar(role: &str, csv: &Path) -> Result<()> {
    let side = odocal::sim::SimSidecar::path_beside(csv);
    if side.exists() && odocal::sim::SimSidecar::file_beside(csv).is_none() {
        bail!(
            "{}: the drive's sidecar (the truth) is written here, beside {role} under its name with .json, and this \
             file is not a simulator sidecar; move it away or give {role} another name",
            side.display()
        );
    }
    Ok(())
}

/// Writes `text` to `path` atomically, or to stdout for `-`; it ends with
/// a newline either way.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    if is_stdout(path) {
        let mut out = std::io::stdout().lock();
        out.write_all(text.as_bytes())?;
        if !text.ends_with('\n') {
            out.write_all(b"\n")?;
        }
        out.flush()?;
    } else {
        odocal::output::write_text(path, text)?;
    }
    Ok(())
}

/// Writes several outputs as one ([`odocal::output::write_texts`]): none
/// is in place before every file is written, so a failed write (a full
/// disk) leaves every file as it was; the one on stdout (`-`), if any, is
/// printed after the files are in place.
pub fn write_texts(files: &[(&Path, String)]) -> Result<()> {
    let (to_stdout, to_files): (Vec<_>, Vec<_>) = files.iter().partition(|(p, _)| is_stdout(p));
    let to_files: Vec<(&Path, &str)> = to_files.iter().map(|(p, t)| (*p, t.as_str())).collect();
    odocal::output::write_texts(&to_files, true)?;
    for (p, text) in to_stdout {
        write_text(p, text)?;
    }
    Ok(())
}

/// Writes a drive CSV to `path` atomically, or to stdout for `-`.
pub fn write_drive(drive: &odocal::Drive, path: &Path) -> Result<()> {
    if is_stdout(path) {
        let mut out = std::io::stdout().lock();
        drive.write_csv_to(&mut out)?;
        out.flush()?;
    } else {
        drive.write_csv(path)?;
    }
    Ok(())
}
