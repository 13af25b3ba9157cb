//! Careless command lines end before any work with an error that names the
//! option and says what to give instead: usage errors (exit 2) for a value
//! the option cannot take, exit 1 for an output that cannot be written
//! where it is asked for.

use crate::common::{odocal, stderr};

fn assert_fails(args: &[&str], code: i32, needles: &[&str]) -> String {
    let o = odocal(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {e}");
    assert!(o.stdout.is_empty(), "{args:?}: stdout {:?}", String::from_utf8_lossy(&o.stdout));
    for n in needles {
        assert!(e.contains(n), "{args:?}: '{n}' not in: {e}");
    }
    e
}

#[test]
fn threads_outside_1_to_the_ceiling_are_usage_errors() {
    let v = ["validate", "drive.csv", "--theta", "2,0,1.6,0"];
    let with = |n: &'static str| [&["--threads", n][..], &v[..]].concat();
    assert_fails(&with("0"), 2, &["--threads", "must be at least 1"]);
    assert_fails(&with("5000"), 2, &["--threads", "above the ceiling of 1024"]);
}
