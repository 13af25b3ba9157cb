//! The HTML report says which data its Ē_p, map and residuals come from, as
//! the text report heads them: the calibrated drive itself, its held-out
//! half, or the `--validate-on` drives (each with its Ē_p).

use crate::common::{odocal, simulated_drive, stderr};

/// The validation section of `calibrate ARGS… --report PAGE`.
fn validation_section(args: &[&str], page: &std::path::Path) -> String {
    let mut all = vec!["calibrate", "--method", "batch-gn", "--report", page.to_str().expect("utf8")];
    all.extend_from_slice(args);
    let o = odocal(&all);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = std::fs::read_to_string(page).expect("page");
    let start = html.find("<section id=\"validation\">").expect("validation section");
    let end = html[start..].find("</section>").expect("section end") + start;
    html[start..end].to_string()
}

#[test]
fn the_page_says_what_its_validation_data_is() {
    let dir = tempfile::tempdir().expect("tmp");
    let a = simulated_drive(dir.path(), "a.csv", &["--length-km", "2", "--seed", "1"]);
    let b = simulated_drive(dir.path(), "b.csv", &["--length-km", "2", "--seed", "2"]);
    let page = dir.path().join("r.html");
    let own = validation_section(&[&a], &page);
    assert!(own.contains("The calibrated drive itself: Ē_p there flatters the fit"), "{own}");
    let half = validation_section(&[&a, "--holdout", "second-half"], &page);
    assert!(half.contains("Held-out data, not used for calibration: the half of the drive held out"), "{half}");
    let other = validation_section(&[&a, "--validate-on", &b], &page);
    assert!(other.contains("Held-out data, not used for calibration: 1 other drive(s)"), "{other}");
    assert!(other.contains(&format!("<li>{b}: ")) && other.contains(" segments)</li>"), "{other}");
}
