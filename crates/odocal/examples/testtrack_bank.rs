//! Diagnostic: does the road bank explain the direction-dependent
//! c_d on the test track? Imports the runs without the manifests'
//! `[lateral_acceleration.bank]` (a_y = v·ω from the wheels), then feeds
//! the lateral specific force
//! f_y = a_y·cos φ − g·sin φ (φ the roll from the two rear antennas'
//! altitude difference) instead of the kinematic a_y, optionally moves the
//! reference by the antenna's roll displacement h·sin φ, and refits.
//!
//! ```text
//! cargo run --release -p odocal --example testtrack_bank -- VARIANT…
//! ```
//! VARIANT: `kin` (as imported); containing `fy`: the specific force;
//! `w`: the wheel yaw rate divided by cos φ; `hH`: the reference moved back
//! by H m × sin φ (antenna roll displacement), e.g. `fy`, `fy-w`, `fy-h2.0`.
use std::error::Error;
use std::path::PathBuf;

use odocal::calibrate::crossrun::{cross_run, CROSS_RUN_OWN_FIT_RATIO};
use odocal::{calibrate, CalibrationOptions, Drive, Method, Param};

const RUNS: [&str; 6] = ["14-45-26", "15-28-33", "16-06-28", "16-47-33", "17-45-46", "18-01-26"];
const G: f64 = 9.80665;

/// (gps time, roll) where both rear antennas are mode 6: roll > 0 left side lower.
fn roll_series(dir: &std::path::Path) -> Result<(Vec<f64>, Vec<f64>), Box<dyn Error>> {
    let read = |name: &str| -> Result<std::collections::BTreeMap<i64, [f64; 4]>, Box<dyn Error>> {
        let text = std::fs::read_to_string(dir.join(name))?;
        let mut out = std::collections::BTreeMap::new();
        let mut lines = text.lines();
        let head: Vec<&str> = lines.next().ok_or("empty")?.split(',').collect();
        let col = |n: &str| head.iter().position(|h| *h == n).ok_or(format!("no {n}"));
        let (ct, cla, clo, cal, cf) =
            (col("gps_time_s")?, col("lat_deg")?, col("lon_deg")?, col("alt_m")?, col("fix_mode")?);
        for l in lines {
            let f: Vec<&str> = l.split(',').collect();
            let t: f64 = f[ct].parse()?;
            out.insert((t * 10.0).round() as i64, [f[cla].parse()?, f[clo].parse()?, f[cal].parse()?, f[cf].parse()?]);
        }
        Ok(out)
    };
    let (l, r) = (read("gnss_left_rear.csv")?, read("gnss_right_rear.csv")?);
    let (mut ts, mut phi) = (Vec::new(), Vec::new());
    for (k, a) in &l {
        let Some(b) = r.get(k) else { continue };
        if (a[3] - 6.0).abs() > 0.5 || (b[3] - 6.0).abs() > 0.5 {
            continue;
        }
        let re = 6_378_137.0;
        let dn = (b[0] - a[0]).to_radians() * re;
        let de = (b[1] - a[1]).to_radians() * re * a[0].to_radians().cos();
        let dz = b[2] - a[2]; // right minus left: > 0 when left is lower
        ts.push(*k as f64 / 10.0);
        phi.push(dz.atan2(dn.hypot(de)));
    }
    Ok((ts, phi))
}

fn interp(ts: &[f64], v: &[f64], t: f64) -> f64 {
    let i = ts.partition_point(|x| *x < t);
    if i == 0 {
        return v[0];
    }
    if i >= ts.len() {
        return v[v.len() - 1];
    }
    let w = (t - ts[i - 1]) / (ts[i] - ts[i - 1]);
    v[i - 1] * (1.0 - w) + v[i] * w
}

fn variant(d: &Drive, phi: &[f64], fy: bool, w: bool, h: f64) -> Result<Drive, Box<dyn Error>> {
    let mut s = d.measured().clone();
    if w {
        // wheels turn about the road normal: world yaw rate = wheel yaw rate / cos φ
        for (i, p) in phi.iter().enumerate() {
            let (m, half) = ((s.n_rl[i] + s.n_rr[i]) / 2.0, (s.n_rr[i] - s.n_rl[i]) / 2.0 / p.cos());
            s.n_rl[i] = m - half;
            s.n_rr[i] = m + half;
        }
    }
    if fy {
        s.a_y = d.a_y().iter().zip(phi).map(|(a, p)| a * p.cos() - G * p.sin()).collect();
    }
    if h != 0.0 {
        // antenna moved h·sin φ to the left (+y) of the axle: take it back
        for (i, p) in phi.iter().enumerate() {
            let (sn, cs) = d.psi()[i].sin_cos();
            let off = h * p.sin();
            s.px[i] -= -sn * off;
            s.py[i] -= cs * off;
        }
    }
    let mut b = Drive::builder(d.t().to_vec(), s).sample_time_s(d.sample_time_s()).parts(d.parts().to_vec());
    if let Some(m) = d.reference_measured() {
        b = b.reference_measured(m.to_vec());
    }
    Ok(b.build()?)
}

fn main() -> Result<(), Box<dyn Error>> {
    let track = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/psu-mapping-van-testtrack");
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/psu-mapping-van-testtrack-2024-08-05");
    let mut base = Vec::new();
    for run in RUNS {
        // the manifests' a_y without their bank: the kinematic v·ω
        let mut m = odocal::io::import::Manifest::from_path(&track.join(format!("run-{run}.toml")))?;
        if let odocal::io::import::LateralAccelerationSpec::FromWheels { bank, .. } = &mut m.lateral_acceleration {
            *bank = None;
        }
        let odocal::io::import::ImportedDrive { drive: d, report: rep } = odocal::io::import::import(&m)?;
        let (ts, ph) = roll_series(&data.join(format!("run-{run}")))?;
        // gps time → drive time
        let shift = -0.006 + rep.clock_offset.applied_s - rep.time_origin_s;
        let ts: Vec<f64> = ts.iter().map(|t| t + shift).collect();
        let raw: Vec<f64> = d.t().iter().map(|t| interp(&ts, &ph, *t)).collect();
        // centred moving average over 1 s within parts
        let w = 20usize;
        let mut phi = raw.clone();
        for p in d.parts() {
            for i in p.clone() {
                let (a, b) = (i.saturating_sub(w).max(p.start), (i + w + 1).min(p.end));
                phi[i] = raw[a..b].iter().sum::<f64>() / (b - a) as f64;
            }
        }
        let m = |f: &dyn Fn(usize) -> bool| {
            let v: Vec<f64> = (0..d.len()).filter(|i| f(*i)).map(|i| phi[i]).collect();
            (v.iter().sum::<f64>() / v.len().max(1) as f64 * 1e3, v.len())
        };
        let turn = m(&|i| d.a_y()[i].abs() > 0.5);
        let straight = m(&|i| d.a_y()[i].abs() < 0.1);
        let fyc: Vec<f64> = (0..d.len())
            .filter(|i| d.a_y()[*i].abs() > 0.5)
            .map(|i| d.a_y()[i] * phi[i].cos() - G * phi[i].sin())
            .collect();
        let ayc: Vec<f64> = (0..d.len()).filter(|i| d.a_y()[*i].abs() > 0.5).map(|i| d.a_y()[i]).collect();
        eprintln!(
            "{run}: clock {:+.3} s, {} roll samples; roll in turns {:+.1} mrad (n {}), straights {:+.1} mrad (n {}); \
             a_y in turns {:+.3}, f_y {:+.3}",
            rep.clock_offset.applied_s,
            ts.len(),
            turn.0,
            turn.1,
            straight.0,
            straight.1,
            ayc.iter().sum::<f64>() / ayc.len() as f64,
            fyc.iter().sum::<f64>() / fyc.len() as f64
        );
        base.push((d, phi));
    }
    let gn = |fix_d: bool| {
        let mut o = CalibrationOptions { method: Method::from_name("batch-gn").expect("m"), ..Default::default() };
        o.segments.min_peak_yaw_rate_rad_per_s = 0.0;
        if fix_d {
            o.identify.free.remove(Param::D);
        }
        o
    };
    for v in std::env::args().skip(1) {
        let fy = v.contains("fy");
        let w = v.contains('w');
        let h: f64 = v.split('h').nth(1).map(|x| x.parse()).transpose()?.unwrap_or(0.0);
        let drives: Vec<Drive> = base.iter().map(|(d, p)| variant(d, p, fy, w, h)).collect::<Result<_, _>>()?;
        let refs: Vec<&Drive> = drives.iter().collect();
        println!("=== {v}: f_y {fy}, yaw / cos φ {w}, antenna height {h} m");
        for fix_d in [true, false] {
            let o = gn(fix_d);
            for (label, set) in [("CCW", &refs[..3]), ("CW", &refs[3..]), ("all", &refs[..])] {
                let j = Drive::concat(set)?;
                let r = calibrate(&j, &o, None)?;
                println!(
                    "joint {label:3} fix_d={fix_d}: c_e {:.5} c_d {:+.3} mm t_r {:.4} d {:+.3}  Ē_p {:.3} (θ_0 {:.3}) {}",
                    r.theta.c_e,
                    r.theta.c_d * 1e3,
                    r.theta.t_r,
                    r.theta.d * 1e3,
                    r.validation.mean_position_error_m,
                    r.initial.mean_position_error_m,
                    r.verdict.level
                );
            }
        }
        let named: Vec<(&str, &Drive)> = RUNS.iter().copied().zip(drives.iter()).collect();
        for (label, o) in [("default", CalibrationOptions::default()), ("gn fix d", gn(true)), ("gn", gn(false))] {
            let t = cross_run(&named, &o, None)?;
            let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
            let cd: Vec<String> = t
                .rows
                .iter()
                .map(|r| {
                    r.fit
                        .as_ref()
                        .map(|f| format!("{:+.2}/{:+.2}", f.theta.c_d * 1e3, f.theta.d * 1e3))
                        .unwrap_or("fail".into())
                })
                .collect();
            println!(
                "crossrun {label:9}: own {:.3} cross {:.3} ratio {:.2} worse {} rejected {} failed {}  c_d/d [{}]",
                c.mean_own_m,
                c.mean_cross_m,
                c.ratio,
                c.worse_than_initial.len(),
                c.rejected,
                c.failed,
                cd.join(" ")
            );
            if label == "default" {
                println!("{t}{c}");
            }
        }
    }
    Ok(())
}
