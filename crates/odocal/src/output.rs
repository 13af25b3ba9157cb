//! Writing output files safely: every file odocal writes (drive CSVs,
//! sidecars, reports, parameter files, figures) is written atomically (a
//! front end's own text files with [`write_text`]), and every command checks its output paths against
//! its inputs and each other first ([`check_collisions`]).
//!
//! # Atomic writes
//!
//! An atomic write ([`write_text`], [`write_texts`]) writes to a temporary file in the target's folder
//! (`.NAME.XXXXXX.tmp`), flushes it, syncs it to disk and renames it over
//! the target. A reader never sees a half-written file: an error (a full
//! disk, a failing writer) leaves the previous file untouched and removes the
//! temporary one. A new file gets the usual permissions (`0666` less the
//! umask); a replaced file keeps its own. A symbolic link is followed: the
//! file it points to is replaced, the link stays. Special files that exist
//! (`/dev/null`, a FIFO, a terminal) are written to directly.
//!
//! # Collisions
//!
//! A file is the same as another when both name the same canonical path or,
//! when they exist, the same device and inode (hard links). An output that
//! does not exist yet is named by its folder's canonical path and its file
//! name. `-` (stdout) is never a file.
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use odocal::output::{check_collisions, FileRole};
//! let dir = tempfile::tempdir()?;
//! let drive = dir.path().join("drive.csv");
//! std::fs::write(&drive, "t,px\n")?;
//! let inputs = [FileRole { role: "the drive being calibrated".into(), path: drive.clone() }];
//! let outputs = [FileRole { role: "--json".into(), path: dir.path().join("./drive.csv") }];
//! let e = check_collisions(&inputs, &outputs).unwrap_err().to_string();
//! assert!(e.contains("--json") && e.contains("is also the drive being calibrated"), "{e}");
//! # Ok(()) }
//! ```

/// `text` as a terminal or a message may show it: control characters
/// (newlines, escape sequences, NUL), the line and paragraph separators,
/// the bidirectional-text controls and the BOM escaped visibly (`\n`,
/// `\u{1b}`), everything else as is. Every name taken from a file or a
/// path and echoed (a topic, a column, a key) goes through it.
///
/// ```
/// assert_eq!(odocal::output::visible("a\x1b[2Jb\nc"), "a\\u{1b}[2Jb\\nc");
/// assert_eq!(odocal::output::visible("/vehicle/odom"), "/vehicle/odom");
/// ```
pub fn visible(text: &str) -> std::borrow::Cow<'_, str> {
    let hidden = |c: char| {
        c.is_control()
            || matches!(c, '\u{2028}' | '\u{2029}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}' | '\u{feff}')
    };
    if !text.chars().any(hidden) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for c in text.chars() {
        if hidden(c) {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    std::borrow::Cow::Owned(out)
}

use std::io::Write;
use std::path::{Component, Path, PathBuf};

use crate::error::{Error, Result};

/// True for `-`, which stands for stdout where an output path is asked for,
/// and for `/dev/stdout`, which names the same (Unix): never a file to
/// compare or to write atomically.
pub(crate) fn is_stdout(path: &Path) -> bool {
    path.as_os_str() == "-" || (cfg!(unix) && path.as_os_str() == "/dev/stdout")
}

/// Writes `path` through `write`, atomically: to a temporary file in the
/// same folder, flushed and synced, then renamed over `path`. When `write`
/// (or the disk) fails, `path` keeps its previous content (or stays absent)
/// and no temporary file is left behind.
///
/// # Errors
/// [`Error::Io`] naming `path`: the folder cannot be written, `path` is a
/// directory, or `write`, the flush, the sync or the rename failed.
pub(crate) fn write_atomically<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    write_file(path, write, true)
}

/// Writes a new file at `path` as [`write_atomically`] does, but never
/// replaces one: the rename into place fails when `path` exists, also when
/// it appeared while the file was being written (no check-then-write race).
///
/// # Errors
/// As [`write_atomically`]; [`Error::Io`] of kind `AlreadyExists` when
/// `path` exists.
#[cfg(test)]
pub(crate) fn write_new<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    write_file(path, write, false)
}

/// [`write_atomically`] (`replace`), or the same refusing to replace an existing file.
fn write_file<F>(path: &Path, write: F, replace: bool) -> Result<()>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    match Staged::open(path, replace)? {
        Staged::InPlace(path) => write_in_place(&path, write).map_err(|e| Error::io(&path, e)),
        Staged::Temporary(mut t) => {
            t.fill(write)?;
            t.persist(replace)
        }
    }
}

/// Where a write goes before it is in place.
enum Staged {
    /// A special file (a device, a FIFO, a socket), written where it is
    /// opened: there is nothing to replace.
    InPlace(PathBuf),
    /// A temporary file beside the target, renamed over it when complete.
    Temporary(TemporaryFile),
}

/// A temporary file beside `target`, listed in [`IN_FLIGHT`] while it lives.
struct TemporaryFile {
    /// The path as given (the context of errors).
    path: PathBuf,
    /// The file a symbolic link at `path` points to, else `path`.
    target: PathBuf,
    dir: PathBuf,
    tmp: tempfile::NamedTempFile,
    _in_flight: InFlight,
}

impl Staged {
    /// Checks `path` and opens its temporary file (or names the special
    /// file to write in place).
    fn open(path: &Path, replace: bool) -> Result<Staged> {
        let io = |source| Error::io(path, source);
        // What `path` names, its links followed by the system: also through a
        // link that names no path, such as `/dev/stdout` on a pipe
        // (`/proc/self/fd/1` → `pipe:[…]`), which `resolve_link` cannot follow.
        match std::fs::metadata(path) {
            Ok(_) if !replace => {
                return Err(io(std::io::Error::new(std::io::ErrorKind::AlreadyExists, "exists; it is not replaced")))
            }
            Ok(m) if m.is_dir() => {
                return Err(io(std::io::Error::new(std::io::ErrorKind::IsADirectory, "is a directory, not a file")))
            }
            Ok(m) if !m.is_file() => return Ok(Staged::InPlace(path.to_path_buf())),
            _ => {}
        }
        let target = resolve_link(path);
        let dir = match target.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let prefix = format!(".{name}.");
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).suffix(".tmp");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            // What `File::create` gives a new file: 0666 less the umask.
            builder.permissions(std::fs::Permissions::from_mode(0o666));
        }
        let tmp = builder.tempfile_in(&dir).map_err(|e| {
            // tempfile's error ends with the temporary file's random name ("…
            // at path \"/d/.x.json.eE2tpV.tmp\""), which means nothing to the
            // user: name the folder instead, with the operating system's reason.
            let text = e.to_string();
            let why = text.rsplit_once(" at path ").map_or(text.as_str(), |(why, _)| why);
            io(std::io::Error::new(e.kind(), format!("cannot create a file in the folder {}: {why}", dir.display())))
        })?;
        let _in_flight = InFlight::new(tmp.path());
        Ok(Staged::Temporary(TemporaryFile { path: path.to_path_buf(), target, dir, tmp, _in_flight }))
    }
}

impl TemporaryFile {
    /// Writes the content through `write`, flushed and synced to disk.
    fn fill<F>(&mut self, write: F) -> Result<()>
    where
        F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
    {
        let io = |source| Error::io(&self.path, source);
        {
            let mut w = std::io::BufWriter::new(self.tmp.as_file_mut());
            write(&mut w).map_err(io)?;
            w.flush().map_err(io)?;
        }
        self.tmp.as_file().sync_all().map_err(io)
    }

    /// Renames the temporary file over the target (`replace`) or to it
    /// when it does not exist.
    fn persist(self, replace: bool) -> Result<()> {
        let io = |source| Error::io(&self.path, source);
        if let Ok(m) = std::fs::metadata(&self.target) {
            // A replaced file keeps its permissions.
            std::fs::set_permissions(self.tmp.path(), m.permissions()).map_err(io)?;
        }
        if replace {
            self.tmp.persist(&self.target).map_err(|e| io(e.error))?;
        } else {
            self.tmp.persist_noclobber(&self.target).map_err(|e| io(e.error))?;
        }
        sync_dir(&self.dir);
        Ok(())
    }
}

/// The temporary files being written now ([`remove_temporary_files`]).
static IN_FLIGHT: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// A temporary file listed in [`IN_FLIGHT`] while it lives.
struct InFlight(PathBuf);

impl InFlight {
    fn new(path: &Path) -> InFlight {
        if let Ok(mut v) = IN_FLIGHT.lock() {
            v.push(path.to_path_buf());
        }
        InFlight(path.to_path_buf())
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        if let Ok(mut v) = IN_FLIGHT.lock() {
            v.retain(|p| *p != self.0);
        }
    }
}

/// Removes the temporary files of the writes in progress, for a program
/// about to exit on a signal (Ctrl-C), which runs no destructors: the final
/// paths keep their previous files and no temporary file is left behind.
/// The `odocal` tool calls it from its signal handler.
pub fn remove_temporary_files() {
    // A write that holds the lock at the signal must not block the exit.
    if let Ok(v) = IN_FLIGHT.try_lock() {
        for p in v.iter() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Writes `text` to `path`, ending it with a newline when it does not end
/// with one, atomically: to a temporary file in the same folder, flushed
/// and synced, then renamed over `path`. When the write (or the disk)
/// fails, `path` keeps its previous content (or stays absent) and no
/// temporary file is left behind.
///
/// # Errors
/// [`Error::Io`] naming `path`: the folder cannot be written, `path` is a
/// directory, or the write, the flush, the sync or the rename failed.
pub fn write_text(path: impl AsRef<Path>, text: &str) -> Result<()> {
    let path = path.as_ref();
    write_atomically(path, |w| write_with_newline(w, text))
}

/// Writes several files as one: each text to its path as [`write_text`]
/// writes one (`replace`), or to a new file that is never replaced
/// ([`Error::Io`] of kind `AlreadyExists` when it exists, also when it
/// appeared during the write), but none is renamed into place before every
/// one is written and synced. A write that fails (a full disk, a folder
/// that cannot be written) leaves every path as it was. A special file
/// (`/dev/null`, a FIFO) is written directly, after the others are in
/// place.
///
/// # Errors
/// [`Error::Io`] naming the path whose write, flush, sync or rename failed.
pub fn write_texts(files: &[(&Path, &str)], replace: bool) -> Result<()> {
    let mut staged = Vec::with_capacity(files.len());
    for (path, text) in files {
        let mut s = Staged::open(path, replace)?;
        if let Staged::Temporary(t) = &mut s {
            t.fill(|w| write_with_newline(w, text))?;
        }
        staged.push((s, *text));
    }
    let mut in_place = Vec::new();
    for (s, text) in staged {
        match s {
            Staged::Temporary(t) => t.persist(replace)?,
            Staged::InPlace(p) => in_place.push((p, text)),
        }
    }
    for (p, text) in in_place {
        write_in_place(&p, |w| write_with_newline(w, text)).map_err(|e| Error::io(&p, e))?;
    }
    Ok(())
}

fn write_with_newline(w: &mut dyn Write, text: &str) -> std::io::Result<()> {
    w.write_all(text.as_bytes())?;
    if !text.ends_with('\n') {
        w.write_all(b"\n")?;
    }
    Ok(())
}

/// The file a symbolic link points to (followed to the end), else `path`.
fn resolve_link(path: &Path) -> PathBuf {
    let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    if !is_link {
        return path.to_path_buf();
    }
    // A dangling link: write where it points, as `File::create` would.
    std::fs::canonicalize(path).unwrap_or_else(|_| {
        let mut p = path.to_path_buf();
        for _ in 0..40 {
            match std::fs::read_link(&p) {
                Ok(t) => p = p.parent().map_or(t.clone(), |d| d.join(&t)),
                Err(_) => break,
            }
        }
        p
    })
}

/// Writes a special file (a device, a FIFO) directly.
fn write_in_place<F>(path: &Path, write: F) -> std::io::Result<()>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let file = std::fs::OpenOptions::new().write(true).open(path)?;
    let mut w = std::io::BufWriter::new(file);
    write(&mut w)?;
    w.flush()
}

/// Syncs a folder, so the rename survives a crash (best effort: not every
/// platform can open a folder).
fn sync_dir(dir: &Path) {
    #[cfg(unix)]
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    #[cfg(not(unix))]
    let _ = dir;
}

/// A file a command reads or writes, and the role it plays there, as the
/// user named it (`"--json"`, `"the drive being calibrated"`); errors say
/// "`ROLE PATH` is also `OTHER ROLE`".
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileRole {
    /// What the file is to the command.
    pub role: String,
    /// The path as given.
    pub path: PathBuf,
}

/// What identifies a file: its canonical path and, when it exists, its
/// device and inode.
#[derive(Debug, Clone)]
struct FileId {
    path: PathBuf,
    inode: Option<(u64, u64)>,
}

impl FileId {
    fn of(path: &Path) -> FileId {
        if let Ok(c) = std::fs::canonicalize(path) {
            return FileId { inode: inode(&c), path: c };
        }
        // Not there (yet): the canonical folder and the file name.
        let abs = lexical_absolute(path);
        let canonical = match (abs.parent(), abs.file_name()) {
            (Some(dir), Some(name)) => std::fs::canonicalize(dir).map(|d| d.join(name)).unwrap_or(abs),
            _ => abs,
        };
        FileId { path: canonical, inode: None }
    }

    fn same(&self, other: &FileId) -> bool {
        self.path == other.path || (self.inode.is_some() && self.inode == other.inode)
    }
}

#[cfg(unix)]
fn inode(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

#[cfg(not(unix))]
fn inode(_: &Path) -> Option<(u64, u64)> {
    None
}

/// `path` made absolute against the working folder, with `.` and `..`
/// resolved lexically (for paths that do not exist).
fn lexical_absolute(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            c => out.push(c.as_os_str()),
        }
    }
    out
}

/// Refuses outputs that would overwrite an input or another output of the
/// same command: each of `outputs` (but `-`, stdout) is compared with every
/// input and every other output.
///
/// # Errors
/// [`Error::PathCollision`] naming the output, its path and the role of the
/// file it would overwrite.
pub fn check_collisions(inputs: &[FileRole], outputs: &[FileRole]) -> Result<()> {
    let outs: Vec<(&FileRole, FileId)> =
        outputs.iter().filter(|o| !is_stdout(&o.path)).map(|o| (o, FileId::of(&o.path))).collect();
    let ins: Vec<(&FileRole, FileId)> =
        inputs.iter().filter(|i| !is_stdout(&i.path)).map(|i| (i, FileId::of(&i.path))).collect();
    for (k, (o, id)) in outs.iter().enumerate() {
        let clash = ins.iter().chain(&outs[..k]).find(|(_, other)| id.same(other));
        if let Some((other, _)) = clash {
            return Err(collision(o, other));
        }
    }
    Ok(())
}

fn collision(output: &FileRole, other: &FileRole) -> Error {
    let other_path = if other.path == output.path { String::new() } else { format!(" ({})", other.path.display()) };
    Error::PathCollision {
        role: output.role.clone(),
        path: output.path.clone(),
        other: format!("{}{other_path}", other.role),
    }
}

pub(crate) mod limited;
#[cfg(test)]
mod tests;
