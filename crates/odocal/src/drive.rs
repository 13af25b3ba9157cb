//! A drive: one uniformly sampled time series of reference poses and model
//! inputs (SPEC §2), its canonical CSV reader and writer.
//!
//! A drive may consist of several continuous *parts* (after a gap in a real
//! log, say); time is uniform within each part and segments never span two.

use std::io::Read;
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::model::{Input, State};

/// Relative tolerance on the uniformity of the sample step (SPEC/issue: 1 %).
pub const STEP_UNIFORMITY_TOL: f64 = 0.01;

/// The noise-free truth of a simulated drive.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Truth {
    /// True reference x position, m.
    pub px: Vec<f64>,
    /// True reference y position, m.
    pub py: Vec<f64>,
    /// True heading, rad (unwrapped).
    pub psi: Vec<f64>,
    /// True rear-left wheel rotation, rev/s.
    pub n_rl: Vec<f64>,
    /// True rear-right wheel rotation, rev/s.
    pub n_rr: Vec<f64>,
    /// True sideslip, rad.
    pub beta: Vec<f64>,
    /// True lateral acceleration, m/s².
    pub a_y: Vec<f64>,
}

/// One drive, stored column by column.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Drive {
    /// Time stamps, s.
    pub t: Vec<f64>,
    /// Reference x position, m (local metric frame).
    pub px: Vec<f64>,
    /// Reference y position, m.
    pub py: Vec<f64>,
    /// Reference heading, rad, unwrapped.
    pub psi: Vec<f64>,
    /// Measured rear-left wheel rotation speed, rev/s.
    pub n_rl: Vec<f64>,
    /// Measured rear-right wheel rotation speed, rev/s.
    pub n_rr: Vec<f64>,
    /// Sideslip angle, rad (0 when unknown).
    pub beta: Vec<f64>,
    /// Lateral acceleration, m/s², positive to the left.
    pub a_y: Vec<f64>,
    /// The truth, for simulated drives.
    pub truth: Option<Truth>,
    /// Extra named columns carried along (written after the standard ones).
    pub extra: Vec<(String, Vec<f64>)>,
    /// Continuous parts as index ranges, in order, covering every sample.
    pub parts: Vec<Range<usize>>,
    /// Sample time t_s, s.
    pub sample_time_s: f64,
}

/// The columns a canonical drive CSV must have.
pub const REQUIRED_COLUMNS: [&str; 8] = ["t", "px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"];
const TRUTH_COLUMNS: [&str; 7] = ["px_true", "py_true", "psi_true", "n_rl_true", "n_rr_true", "beta_true", "a_y_true"];

impl Drive {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when the drive has no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Reference pose at sample `i`.
    #[inline]
    pub fn pose(&self, i: usize) -> State {
        State::new(self.px[i], self.py[i], self.psi[i])
    }

    /// Measured inputs at sample `i`.
    #[inline]
    pub fn input(&self, i: usize) -> Input {
        Input { n_rl: self.n_rl[i], n_rr: self.n_rr[i], beta: self.beta[i], a_y: self.a_y[i] }
    }

    /// Total path length of the reference, m (sum of position increments within parts).
    pub fn distance_m(&self) -> f64 {
        self.parts
            .iter()
            .flat_map(|r| {
                (r.start + 1..r.end).map(|i| (self.px[i] - self.px[i - 1]).hypot(self.py[i] - self.py[i - 1]))
            })
            .sum()
    }

    /// The samples with `t_start_s ≤ t < t_end_s` as a new drive; parts are
    /// clipped to the window (extra columns and truth come along).
    pub fn window(&self, t_start_s: f64, t_end_s: f64) -> Result<Drive> {
        let idx: Vec<usize> = (0..self.len()).filter(|&i| self.t[i] >= t_start_s && self.t[i] < t_end_s).collect();
        let (Some(&a), Some(&b)) = (idx.first(), idx.last()) else {
            return Err(Error::InvalidDrive {
                context: "time window".into(),
                reason: format!(
                    "no samples in [{t_start_s}, {t_end_s}) s; the drive spans {:.3} … {:.3} s",
                    self.t.first().copied().unwrap_or(f64::NAN),
                    self.t.last().copied().unwrap_or(f64::NAN)
                ),
            });
        };
        let r = a..b + 1;
        let cut = |v: &Vec<f64>| v[r.clone()].to_vec();
        let truth = self.truth.as_ref().map(|t| Truth {
            px: cut(&t.px),
            py: cut(&t.py),
            psi: cut(&t.psi),
            n_rl: cut(&t.n_rl),
            n_rr: cut(&t.n_rr),
            beta: cut(&t.beta),
            a_y: cut(&t.a_y),
        });
        let parts = self
            .parts
            .iter()
            .filter_map(|p| {
                let (s, e) = (p.start.max(a), p.end.min(b + 1));
                (s < e).then(|| s - a..e - a)
            })
            .collect();
        Ok(Drive {
            t: cut(&self.t),
            px: cut(&self.px),
            py: cut(&self.py),
            psi: cut(&self.psi),
            n_rl: cut(&self.n_rl),
            n_rr: cut(&self.n_rr),
            beta: cut(&self.beta),
            a_y: cut(&self.a_y),
            truth,
            extra: self.extra.iter().map(|(n, v)| (n.clone(), cut(v))).collect(),
            parts,
            sample_time_s: self.sample_time_s,
        })
    }

    /// Builds a single-part drive from columns, inferring and checking t_s and
    /// unwrapping the heading. `context` names the source in error messages.
    #[allow(clippy::too_many_arguments)]
    pub fn from_columns(
        context: &str,
        t: Vec<f64>,
        px: Vec<f64>,
        py: Vec<f64>,
        psi: Vec<f64>,
        n_rl: Vec<f64>,
        n_rr: Vec<f64>,
        beta: Vec<f64>,
        a_y: Vec<f64>,
    ) -> Result<Drive> {
        let n = t.len();
        let mut d = Drive { t, px, py, psi, n_rl, n_rr, beta, a_y, parts: vec![0..n], ..Default::default() };
        d.finish(context, None)?;
        Ok(d)
    }

    /// Checks lengths, finiteness, time monotonicity and uniformity, infers
    /// t_s, unwraps the heading. `part_ids`, when given, splits the drive.
    fn finish(&mut self, context: &str, part_ids: Option<&[i64]>) -> Result<()> {
        let n = self.t.len();
        let invalid = |reason: String| Error::InvalidDrive { context: context.to_string(), reason };
        if n == 0 {
            return Err(invalid("no samples".into()));
        }
        for (name, col) in [
            ("px", &self.px),
            ("py", &self.py),
            ("psi", &self.psi),
            ("n_rl", &self.n_rl),
            ("n_rr", &self.n_rr),
            ("beta", &self.beta),
            ("a_y", &self.a_y),
        ] {
            if col.len() != n {
                return Err(invalid(format!("column {name} has {} samples, t has {n}", col.len())));
            }
            if let Some(i) = col.iter().position(|v| !v.is_finite()) {
                return Err(invalid(format!("column {name} is not finite at sample {i}")));
            }
        }
        // Parts.
        self.parts = match part_ids {
            None => vec![0..n],
            Some(ids) => {
                let mut parts = Vec::new();
                let mut start = 0;
                for i in 1..=n {
                    if i == n || ids[i] != ids[i - 1] {
                        parts.push(start..i);
                        start = i;
                    }
                }
                parts
            }
        };
        // Time strictly increasing everywhere.
        for i in 1..n {
            if self.t[i].partial_cmp(&self.t[i - 1]) != Some(std::cmp::Ordering::Greater) {
                return Err(Error::Csv {
                    path: PathBuf::from(context),
                    line: i as u64 + 2,
                    column: Some("t".into()),
                    reason: format!("time is not strictly increasing ({} after {})", self.t[i], self.t[i - 1]),
                });
            }
        }
        // t_s: mean step over all parts; every step within 1 %.
        let (mut span, mut steps) = (0.0, 0usize);
        for r in &self.parts {
            if r.len() >= 2 {
                span += self.t[r.end - 1] - self.t[r.start];
                steps += r.len() - 1;
            }
        }
        if steps == 0 {
            return Err(invalid(format!("{n} sample(s): too few to infer the sample time")));
        }
        let ts = span / steps as f64;
        for r in &self.parts {
            for i in r.start + 1..r.end {
                let dt = self.t[i] - self.t[i - 1];
                if (dt - ts).abs() > STEP_UNIFORMITY_TOL * ts {
                    return Err(Error::Csv {
                        path: PathBuf::from(context),
                        line: i as u64 + 2,
                        column: Some("t".into()),
                        reason: format!(
                            "sample step {dt:.6} s differs from the mean step {ts:.6} s by more than 1 %; \
                             the time must be uniform (resample the log, or mark gaps with a 'part' column)"
                        ),
                    });
                }
            }
        }
        self.sample_time_s = ts;
        unwrap_in_place(&mut self.psi);
        if let Some(tr) = self.truth.as_mut() {
            unwrap_in_place(&mut tr.psi);
        }
        Ok(())
    }

    /// Reads a canonical drive CSV (SPEC §2). Accepts a UTF-8 BOM, CRLF line
    /// endings, extra columns (kept in [`Drive::extra`], truth columns in
    /// [`Drive::truth`]) and any column order. An optional integer `part`
    /// column marks continuous parts of a drive with gaps.
    pub fn read_csv(path: impl AsRef<Path>) -> Result<Drive> {
        let path = path.as_ref();
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|mut f| f.read_to_end(&mut bytes))
            .map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::parse_csv(&bytes, path)
    }

    /// Parses canonical CSV from bytes; `path` is used in error messages.
    pub fn parse_csv(bytes: &[u8], path: &Path) -> Result<Drive> {
        let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF".as_slice()).unwrap_or(bytes);
        if bytes.iter().all(|b| b.is_ascii_whitespace()) {
            return Err(Error::InvalidDrive {
                context: path.display().to_string(),
                reason: "the file is empty (expected a header row with columns t, px, py, psi, n_rl, n_rr, beta, a_y)"
                    .into(),
            });
        }
        let mut rdr = csv::ReaderBuilder::new().has_headers(true).trim(csv::Trim::All).from_reader(bytes);
        let csv_err = |e: csv::Error| {
            let line = e.position().map(|p| p.line()).unwrap_or(0);
            Error::Csv { path: path.to_path_buf(), line, column: None, reason: e.to_string() }
        };
        let headers: Vec<String> = rdr.headers().map_err(csv_err)?.iter().map(|h| h.to_string()).collect();
        let find = |name: &str| headers.iter().position(|h| h == name);
        let missing: Vec<String> =
            REQUIRED_COLUMNS.iter().filter(|c| find(c).is_none()).map(|c| c.to_string()).collect();
        if !missing.is_empty() {
            return Err(Error::MissingColumns { path: path.to_path_buf(), missing, found: headers.clone() });
        }
        let mut cols: Vec<Vec<f64>> = vec![Vec::new(); headers.len()];
        let mut record = csv::StringRecord::new();
        let mut line = 1u64;
        while rdr.read_record(&mut record).map_err(csv_err)? {
            line = record.position().map(|p| p.line()).unwrap_or(line + 1);
            if record.len() != headers.len() {
                return Err(Error::Csv {
                    path: path.to_path_buf(),
                    line,
                    column: None,
                    reason: format!("{} fields, the header has {}", record.len(), headers.len()),
                });
            }
            for (j, field) in record.iter().enumerate() {
                let v: f64 = field.parse().map_err(|_| Error::Csv {
                    path: path.to_path_buf(),
                    line,
                    column: Some(headers[j].clone()),
                    reason: format!("'{field}' is not a number"),
                })?;
                if !v.is_finite() {
                    return Err(Error::Csv {
                        path: path.to_path_buf(),
                        line,
                        column: Some(headers[j].clone()),
                        reason: format!("value '{field}' is not finite"),
                    });
                }
                cols[j].push(v);
            }
        }
        let n = cols.first().map(Vec::len).unwrap_or(0);
        if n == 0 {
            return Err(Error::InvalidDrive {
                context: path.display().to_string(),
                reason: "the file has a header but no data rows".into(),
            });
        }
        let mut take = |name: &str| -> Option<Vec<f64>> { find(name).map(|j| std::mem::take(&mut cols[j])) };
        let mut d = Drive {
            t: take("t").unwrap_or_default(),
            px: take("px").unwrap_or_default(),
            py: take("py").unwrap_or_default(),
            psi: take("psi").unwrap_or_default(),
            n_rl: take("n_rl").unwrap_or_default(),
            n_rr: take("n_rr").unwrap_or_default(),
            beta: take("beta").unwrap_or_default(),
            a_y: take("a_y").unwrap_or_default(),
            ..Default::default()
        };
        if TRUTH_COLUMNS.iter().all(|c| find(c).is_some()) {
            d.truth = Some(Truth {
                px: take("px_true").unwrap_or_default(),
                py: take("py_true").unwrap_or_default(),
                psi: take("psi_true").unwrap_or_default(),
                n_rl: take("n_rl_true").unwrap_or_default(),
                n_rr: take("n_rr_true").unwrap_or_default(),
                beta: take("beta_true").unwrap_or_default(),
                a_y: take("a_y_true").unwrap_or_default(),
            });
        }
        let part_ids: Option<Vec<i64>> = take("part").map(|v| v.iter().map(|x| *x as i64).collect());
        for (j, h) in headers.iter().enumerate() {
            if !cols[j].is_empty() {
                d.extra.push((h.clone(), std::mem::take(&mut cols[j])));
            }
        }
        d.finish(&path.display().to_string(), part_ids.as_deref())?;
        Ok(d)
    }

    /// Writes the canonical CSV (with truth, `part` when there are several
    /// parts, and extra columns). Numbers are written in full precision
    /// (shortest round-trip form), so a write/read round trip is exact.
    pub fn write_csv(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let file = std::fs::File::create(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        self.write_csv_to(std::io::BufWriter::new(file))
            .map_err(|source| Error::Io { path: path.to_path_buf(), source })
    }

    /// Writes the canonical CSV to any writer.
    pub fn write_csv_to<W: std::io::Write>(&self, mut w: W) -> std::io::Result<()> {
        let mut cols: Vec<(&str, &[f64])> = vec![
            ("t", &self.t),
            ("px", &self.px),
            ("py", &self.py),
            ("psi", &self.psi),
            ("n_rl", &self.n_rl),
            ("n_rr", &self.n_rr),
            ("beta", &self.beta),
            ("a_y", &self.a_y),
        ];
        if let Some(tr) = &self.truth {
            cols.extend([
                ("px_true", tr.px.as_slice()),
                ("py_true", &tr.py),
                ("psi_true", &tr.psi),
                ("n_rl_true", &tr.n_rl),
                ("n_rr_true", &tr.n_rr),
                ("beta_true", &tr.beta),
                ("a_y_true", &tr.a_y),
            ]);
        }
        for (name, v) in &self.extra {
            cols.push((name.as_str(), v.as_slice()));
        }
        let with_parts = self.parts.len() > 1;
        let mut header: Vec<&str> = cols.iter().map(|c| c.0).collect();
        if with_parts {
            header.push("part");
        }
        writeln!(w, "{}", header.join(","))?;
        let mut part_of = vec![0usize; self.len()];
        for (p, r) in self.parts.iter().enumerate() {
            part_of[r.clone()].fill(p);
        }
        let mut line = String::new();
        for i in 0..self.len() {
            line.clear();
            for (j, (_, c)) in cols.iter().enumerate() {
                if j > 0 {
                    line.push(',');
                }
                line.push_str(&format!("{}", c[i]));
            }
            if with_parts {
                line.push_str(&format!(",{}", part_of[i]));
            }
            line.push('\n');
            w.write_all(line.as_bytes())?;
        }
        w.flush()
    }
}

/// Unwraps an angle series in place: every step larger than π in magnitude
/// is taken as a 2π wrap.
pub fn unwrap_in_place(a: &mut [f64]) {
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut offset = 0.0;
    let mut prev_raw = match a.first() {
        Some(v) => *v,
        None => return,
    };
    for v in a.iter_mut().skip(1) {
        let raw = *v;
        let d = raw - prev_raw;
        if d > std::f64::consts::PI {
            offset -= two_pi * ((d + std::f64::consts::PI) / two_pi).floor();
        } else if d < -std::f64::consts::PI {
            offset += two_pi * ((-d + std::f64::consts::PI) / two_pi).floor();
        }
        prev_raw = raw;
        *v = raw + offset;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv_text(rows: usize, ts: f64) -> String {
        let mut s = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
        for i in 0..rows {
            s.push_str(&format!("{},{},0,0,5,5,0,0\n", i as f64 * ts, i as f64 * 0.25));
        }
        s
    }

    #[test]
    fn parses_and_infers_sample_time() {
        let d = Drive::parse_csv(csv_text(10, 0.025).as_bytes(), Path::new("x.csv")).expect("valid");
        assert_eq!(d.len(), 10);
        approx::assert_relative_eq!(d.sample_time_s, 0.025, max_relative = 1e-12);
    }

    #[test]
    fn accepts_bom_crlf_extra_columns_any_order() {
        let s = "\u{feff}a_y,extra,beta,n_rr,n_rl,psi,py,px,t\r\n0,7,0,5,5,0,0,0,0\r\n0,8,0,5,5,0,0,0.25,0.025\r\n0,9,0,5,5,0,0,0.5,0.05\r\n";
        let d = Drive::parse_csv(s.as_bytes(), Path::new("x.csv")).expect("valid");
        assert_eq!(d.len(), 3);
        assert_eq!(d.extra.len(), 1);
        assert_eq!(d.extra[0].0, "extra");
        approx::assert_relative_eq!(d.px[2], 0.5);
    }

    #[test]
    fn missing_columns_are_listed() {
        let e = Drive::parse_csv(b"t,px,py\n0,0,0\n", Path::new("d.csv")).expect_err("missing");
        let m = e.to_string();
        assert!(m.contains("missing column(s) psi, n_rl, n_rr, beta, a_y"), "{m}");
        assert!(m.contains("columns found: t, px, py"), "{m}");
    }

    #[test]
    fn nan_and_text_name_line_and_column() {
        let mut s = csv_text(5, 0.025);
        s = s.replacen("0.05,0.5", "0.05,NaN", 1);
        let m = Drive::parse_csv(s.as_bytes(), Path::new("d.csv")).expect_err("nan").to_string();
        assert!(m.contains("line 4") && m.contains("column 'px'") && m.contains("not finite"), "{m}");
        let s = csv_text(5, 0.025).replacen("0.05,0.5", "0.05,abc", 1);
        let m = Drive::parse_csv(s.as_bytes(), Path::new("d.csv")).expect_err("text").to_string();
        assert!(m.contains("line 4") && m.contains("'abc' is not a number"), "{m}");
    }

    #[test]
    fn time_errors_name_line() {
        let s = csv_text(6, 0.025).replacen("0.05,", "0.01,", 1);
        let m = Drive::parse_csv(s.as_bytes(), Path::new("d.csv")).expect_err("nonmono").to_string();
        assert!(m.contains("line 4") && m.contains("not strictly increasing"), "{m}");
        let s = csv_text(6, 0.025).replacen("0.1,", "0.11,", 1);
        let m = Drive::parse_csv(s.as_bytes(), Path::new("d.csv")).expect_err("nonuni").to_string();
        assert!(m.contains("uniform"), "{m}");
    }

    #[test]
    fn empty_inputs() {
        let m = Drive::parse_csv(b"", Path::new("d.csv")).expect_err("empty").to_string();
        assert!(m.contains("empty"), "{m}");
        let m =
            Drive::parse_csv(b"t,px,py,psi,n_rl,n_rr,beta,a_y\n", Path::new("d.csv")).expect_err("no rows").to_string();
        assert!(m.contains("no data rows"), "{m}");
    }

    #[test]
    fn heading_is_unwrapped() {
        let mut a = vec![3.0, 3.1, -3.1, -3.0, 3.1];
        unwrap_in_place(&mut a);
        for w in a.windows(2) {
            assert!((w[1] - w[0]).abs() < 0.5, "{a:?}");
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let d = Drive::parse_csv(csv_text(20, 0.025).as_bytes(), Path::new("x.csv")).expect("valid");
        let mut buf = Vec::new();
        d.write_csv_to(&mut buf).expect("write");
        let d2 = Drive::parse_csv(&buf, Path::new("y.csv")).expect("valid");
        assert_eq!(d, d2);
    }

    #[test]
    fn window_clips_parts() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,0\n0.2,0,0,0,1,1,0,0,0\n5.0,0,0,0,1,1,0,0,1\n5.1,0,0,0,1,1,0,0,1\n";
        let d = Drive::parse_csv(s.as_bytes(), Path::new("x.csv")).expect("valid");
        let w = d.window(0.15, 5.05).expect("window");
        assert_eq!(w.len(), 2);
        assert_eq!(w.parts, vec![0..1, 1..2]);
        assert!(d.window(10.0, 11.0).is_err());
    }

    #[test]
    fn parts_allow_gaps() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,0\n0.2,0,0,0,1,1,0,0,0\n5.0,0,0,0,1,1,0,0,1\n5.1,0,0,0,1,1,0,0,1\n";
        let d = Drive::parse_csv(s.as_bytes(), Path::new("x.csv")).expect("valid");
        assert_eq!(d.parts, vec![0..3, 3..5]);
        approx::assert_relative_eq!(d.sample_time_s, 0.1, max_relative = 1e-9);
    }
}
