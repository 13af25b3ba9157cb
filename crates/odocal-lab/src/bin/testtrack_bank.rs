//! Diagnostic: does the road bank explain the direction-dependent
//! c_d on the test track? Imports the runs without the manifests'
//! `[lateral_acceleration.bank]` (a_y = v·ω from the wheels), then feeds
//! the lateral specific force
//! f_y = a_y·cos φ − g·sin φ (φ the roll from the two rear antennas'
//! altitude difference) instead of the kinematic a_y, optionally moves the
//! reference by the antenna's roll displacement h·sin φ, and refits.
//!
//! VARIANT: `kin` (as imported); containing `fy`: the specific force;
//! `w`: the wheel yaw rate divided by cos φ; `hH`: the reference moved back
//! by H m × sin φ (antenna roll displacement), e.g. `fy`, `fy-w`, `fy-h2.0`.
//! docs/validation.md ("The road bank") quotes `kin fy`.
use std::path::Path;

use odocal::Drive;
use odocal::{import, Manifest};
use odocal_lab::{
    print_cross_runs, print_joint_fits, repo_path, testtrack_manifest, with_signals, Args, Res, TESTTRACK_RUNS,
};

const USAGE: &str = "testtrack_bank VARIANT…   (kin, fy, fy-w, fy-h2.0, …)";

const G: f64 = 9.80665;

/// (gps time, roll) where both rear antennas are mode 6: roll > 0 left side lower.
fn roll_series(dir: &Path) -> Res<(Vec<f64>, Vec<f64>)> {
    let read = |name: &str| -> Res<std::collections::BTreeMap<i64, [f64; 4]>> {
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

fn variant(d: &Drive, phi: &[f64], fy: bool, w: bool, h: f64) -> Res<Drive> {
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
        s.a_y = d.measured().a_y.iter().zip(phi).map(|(a, p)| a * p.cos() - G * p.sin()).collect();
    }
    if h != 0.0 {
        // antenna moved h·sin φ to the left (+y) of the axle: take it back
        for (i, p) in phi.iter().enumerate() {
            let (sn, cs) = d.measured().psi[i].sin_cos();
            let off = h * p.sin();
            s.px[i] -= -sn * off;
            s.py[i] -= cs * off;
        }
    }
    Ok(with_signals(d, s)?)
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let a = Args::parse(USAGE, &[])?;
    let variants = a.positional().to_vec();
    a.finish()?;
    let data = repo_path("data/psu-mapping-van-testtrack-2024-08-05");
    let mut base = Vec::new();
    for (run, _) in TESTTRACK_RUNS {
        // the manifests' a_y without their bank: the kinematic v·ω
        let path = repo_path(&testtrack_manifest(run));
        let mut toml: toml::Table = toml::from_str(&std::fs::read_to_string(&path)?)?;
        if let Some(toml::Value::Table(a_y)) = toml.get_mut("lateral_acceleration") {
            a_y.remove("bank");
        }
        let m = Manifest::parse(&toml.to_string(), &path)?;
        let (d, rep) = import(&m)?;
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
        let turn = m(&|i| d.measured().a_y[i].abs() > 0.5);
        let straight = m(&|i| d.measured().a_y[i].abs() < 0.1);
        let fyc: Vec<f64> = (0..d.len())
            .filter(|i| d.measured().a_y[*i].abs() > 0.5)
            .map(|i| d.measured().a_y[i] * phi[i].cos() - G * phi[i].sin())
            .collect();
        let ayc: Vec<f64> =
            (0..d.len()).filter(|i| d.measured().a_y[*i].abs() > 0.5).map(|i| d.measured().a_y[i]).collect();
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
    for v in variants {
        let fy = v.contains("fy");
        let w = v.contains('w');
        let h: f64 = v.split('h').nth(1).map(|x| x.parse()).transpose()?.unwrap_or(0.0);
        let drives: Vec<Drive> = base.iter().map(|(d, p)| variant(d, p, fy, w, h)).collect::<Result<_, _>>()?;
        println!("=== {v}: f_y {fy}, yaw / cos φ {w}, antenna height {h} m");
        print_joint_fits(&drives)?;
        print_cross_runs(&drives, true)?;
    }
    Ok(())
}
