use std::path::{Path, PathBuf};

use proptest::prelude::*;

use super::*;

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().expect("tempdir")
}

/// Names in `dir` other than `keep`.
fn others(dir: &Path, keep: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .expect("read_dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect()
}

#[test]
fn text_is_written_with_a_final_newline() {
    let d = tmp();
    let p = d.path().join("a.txt");
    write_text(&p, "one").expect("write");
    assert_eq!(std::fs::read_to_string(&p).expect("read"), "one\n");
    write_text(&p, "two\n").expect("write");
    assert_eq!(std::fs::read_to_string(&p).expect("read"), "two\n");
    assert!(others(d.path(), &["a.txt"]).is_empty());
}

#[test]
fn a_writer_failing_half_way_leaves_the_old_file_and_no_temporary_file() {
    let d = tmp();
    let p = d.path().join("drive.csv");
    std::fs::write(&p, "the previous content\n").expect("seed");
    let e = write_atomically(&p, |w| {
        w.write_all(&vec![b'x'; 1 << 20])?;
        Err(std::io::Error::other("disk full"))
    })
    .expect_err("fails");
    assert!(e.to_string().contains("drive.csv") && e.to_string().contains("disk full"), "{e}");
    assert_eq!(std::fs::read_to_string(&p).expect("read"), "the previous content\n");
    assert!(others(d.path(), &["drive.csv"]).is_empty(), "{:?}", others(d.path(), &["drive.csv"]));
}

#[test]
fn a_failed_first_write_leaves_nothing() {
    let d = tmp();
    let p = d.path().join("new.json");
    write_atomically(&p, |w| {
        w.write_all(b"{\"half\": ")?;
        Err(std::io::Error::other("interrupted"))
    })
    .expect_err("fails");
    assert!(!p.exists());
    assert!(others(d.path(), &[]).is_empty());
}

#[test]
fn a_directory_is_not_replaced() {
    let d = tmp();
    let e = write_text(d.path(), "x").expect_err("dir").to_string();
    assert!(e.contains("directory"), "{e}");
}

#[test]
fn a_missing_folder_is_an_error_naming_the_file() {
    let d = tmp();
    let p = d.path().join("no/such/dir/out.csv");
    let e = write_text(&p, "x").expect_err("no folder").to_string();
    assert!(e.contains("out.csv"), "{e}");
    assert!(e.contains("No such file or directory") && !e.contains(".out.csv."), "the temporary file named: {e}");
    assert!(e.contains("cannot create a file in the folder"), "{e}");
}

#[cfg(unix)]
#[test]
fn permissions_are_those_of_a_new_file_or_kept() {
    use std::os::unix::fs::PermissionsExt;
    let d = tmp();
    let plain = d.path().join("plain");
    std::fs::File::create(&plain).expect("create");
    let p = d.path().join("atomic");
    write_text(&p, "x").expect("write");
    let mode = |p: &Path| std::fs::metadata(p).expect("meta").permissions().mode() & 0o777;
    assert_eq!(mode(&p), mode(&plain), "a new file: 0666 less the umask");
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o640)).expect("chmod");
    write_text(&p, "y").expect("write");
    assert_eq!(mode(&p), 0o640, "a replaced file keeps its mode");
}

#[cfg(unix)]
#[test]
fn a_symbolic_link_is_followed_and_kept() {
    let d = tmp();
    let target = d.path().join("real.csv");
    std::fs::write(&target, "old\n").expect("seed");
    let link = d.path().join("link.csv");
    std::os::unix::fs::symlink(&target, &link).expect("symlink");
    write_text(&link, "new").expect("write");
    assert!(std::fs::symlink_metadata(&link).expect("meta").file_type().is_symlink());
    assert_eq!(std::fs::read_to_string(&target).expect("read"), "new\n");
}

#[cfg(unix)]
#[test]
fn a_device_is_written_in_place() {
    write_text(Path::new("/dev/null"), "discarded").expect("write /dev/null");
    assert!(!std::fs::metadata("/dev/null").expect("meta").is_file(), "/dev/null is still the device");
}

#[test]
fn an_output_onto_an_input_is_refused_by_any_name() {
    let d = tmp();
    let input = d.path().join("in.csv");
    std::fs::write(&input, "x").expect("seed");
    std::fs::create_dir(d.path().join("sub")).expect("mkdir");
    let ins = [FileRole { role: "the drive being calibrated".into(), path: input.clone() }];
    for alias in [input.clone(), d.path().join("./in.csv"), d.path().join("sub/../in.csv")] {
        let e = check_collisions(&ins, &[FileRole { role: "--json".into(), path: alias.clone() }])
            .expect_err("collision")
            .to_string();
        assert!(e.starts_with(&format!("--json {} is also the drive being calibrated", alias.display())), "{e}");
    }
    #[cfg(unix)]
    {
        let hard = d.path().join("hard.csv");
        std::fs::hard_link(&input, &hard).expect("hard link");
        assert!(
            check_collisions(&ins, &[FileRole { role: "--report".into(), path: hard.clone() }]).is_err(),
            "hard link"
        );
        let soft = d.path().join("soft.csv");
        std::os::unix::fs::symlink(&input, &soft).expect("symlink");
        assert!(
            check_collisions(&ins, &[FileRole { role: "--report".into(), path: soft.clone() }]).is_err(),
            "symlink"
        );
    }
    check_collisions(&ins, &[FileRole { role: "--json".into(), path: d.path().join("out.json") }]).expect("a new file");
    check_collisions(
        &ins,
        &[FileRole { role: "--json".into(), path: "-".into() }, FileRole { role: "--report".into(), path: "-".into() }],
    )
    .expect("stdout");
}

#[test]
fn two_outputs_onto_one_new_file_are_refused() {
    let d = tmp();
    let a = FileRole { role: "--out".into(), path: d.path().join("x.csv") };
    let b = FileRole { role: "--json".into(), path: d.path().join("sub/../x.csv") };
    std::fs::create_dir(d.path().join("sub")).expect("mkdir");
    let e = check_collisions(&[], &[a, b]).expect_err("same file").to_string();
    assert!(e.contains("--json") && e.contains("is also --out ("), "{e}");
}

/// A file of the property test: `(group, spelling)`; files of one group are
/// one file on disk (one name, or two names hard-linked).
#[derive(Debug, Clone, Copy)]
struct Pick {
    group: usize,
    spelling: usize,
}

/// The names on disk: groups 0..3 exist (group 2 as two hard-linked names),
/// groups 3..6 do not.
const GROUPS: usize = 6;

fn spell(dir: &Path, p: Pick) -> PathBuf {
    let name = match (p.group, p.spelling % 2) {
        (2, 1) => "g2-link".to_string(),
        (g, _) => format!("g{g}"),
    };
    match p.spelling % 4 {
        0 | 1 => dir.join(&name),
        2 => dir.join(".").join(&name),
        _ => dir.join("sub").join("..").join(&name),
    }
}

fn setup() -> tempfile::TempDir {
    let d = tmp();
    std::fs::create_dir(d.path().join("sub")).expect("mkdir");
    for g in 0..3 {
        std::fs::write(d.path().join(format!("g{g}")), "x").expect("seed");
    }
    #[cfg(unix)]
    std::fs::hard_link(d.path().join("g2"), d.path().join("g2-link")).expect("link");
    #[cfg(not(unix))]
    std::fs::write(d.path().join("g2-link"), "x").expect("seed");
    d
}

fn pick() -> impl Strategy<Value = Pick> {
    (0..GROUPS, 0usize..4).prop_map(|(group, spelling)| Pick { group, spelling })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// No output equal to an input or another output (by any spelling, or a
    /// hard link) is accepted, and outputs onto distinct new files are.
    #[test]
    fn no_output_equal_to_an_input_or_another_output_is_accepted(
        inputs in proptest::collection::vec(pick(), 0..4),
        outputs in proptest::collection::vec(pick(), 0..4),
    ) {
        let d = setup();
        let group_of = |p: &Pick| if cfg!(unix) || p.group != 2 || p.spelling.is_multiple_of(2) { p.group } else { GROUPS };
        let ins: Vec<FileRole> =
            inputs.iter().enumerate().map(|(i, p)| FileRole { role: format!("input {i}"), path: spell(d.path(), *p) }).collect();
        let outs: Vec<FileRole> =
            outputs.iter().enumerate().map(|(i, p)| FileRole { role: format!("output {i}"), path: spell(d.path(), *p) }).collect();
        let clash = outputs.iter().enumerate().any(|(k, o)| {
            inputs.iter().any(|i| group_of(i) == group_of(o)) || outputs[..k].iter().any(|x| group_of(x) == group_of(o))
        });
        let got = check_collisions(&ins, &outs);
        prop_assert_eq!(got.is_err(), clash, "{:?}", got);
    }
}

/// `write_new` creates a file but never replaces one, also when the file
/// appears while it writes (the rename refuses it), and leaves no temporary
/// file behind.
#[test]
fn a_new_file_never_replaces_one() {
    let d = tmp();
    let p = d.path().join("m.toml");
    write_texts(&[(&p, "draft")], false).expect("new");
    assert_eq!(std::fs::read_to_string(&p).expect("read"), "draft\n");
    let e = write_texts(&[(&p, "again")], false).expect_err("exists");
    assert!(matches!(&e, Error::Io { source, .. } if source.kind() == std::io::ErrorKind::AlreadyExists), "{e}");
    let q = d.path().join("n.toml");
    let e = write_new(&q, |w| {
        std::fs::write(&q, "the user's file\n")?;
        w.write_all(b"draft\n")
    })
    .expect_err("appeared meanwhile");
    assert!(matches!(&e, Error::Io { source, .. } if source.kind() == std::io::ErrorKind::AlreadyExists), "{e}");
    assert_eq!(std::fs::read_to_string(&q).expect("read"), "the user's file\n");
    assert_eq!(std::fs::read_to_string(&p).expect("read"), "draft\n");
    assert!(others(d.path(), &["m.toml", "n.toml"]).is_empty());
}

/// Several files written as one: when one of them cannot be written, none
/// is replaced (the files before it keep their content) and no temporary
/// file is left; when all can, all are.
#[test]
fn several_files_are_written_as_one() {
    let d = tmp();
    let (a, b) = (d.path().join("a.yaml"), d.path().join("b.json"));
    std::fs::write(&a, "old a\n").expect("a");
    std::fs::write(&b, "old b\n").expect("b");
    let missing = d.path().join("no-such-folder").join("r.html");
    let e = write_texts(&[(&a, "new a"), (&b, "new b"), (&missing, "page")], true).expect_err("folder");
    assert!(e.to_string().contains("no-such-folder"), "{e}");
    assert_eq!(std::fs::read_to_string(&a).expect("a"), "old a\n");
    assert_eq!(std::fs::read_to_string(&b).expect("b"), "old b\n");
    assert!(others(d.path(), &["a.yaml", "b.json"]).is_empty());
    write_texts(&[(&a, "new a"), (&b, "new b")], true).expect("both");
    assert_eq!(std::fs::read_to_string(&a).expect("a"), "new a\n");
    assert_eq!(std::fs::read_to_string(&b).expect("b"), "new b\n");
    assert!(others(d.path(), &["a.yaml", "b.json"]).is_empty());
}
