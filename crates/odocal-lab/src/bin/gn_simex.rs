//! Batch Gauss-Newton's errors-in-variables bias predicted from the drive:
//! SIMEX (simulation-extrapolation). Adding white relative wheel noise of
//! the drive's own level σ_w to the wheel rotations and refitting from θ̂
//! moves θ by about the bias the drive's noise already gave it (the bias
//! grows linearly with the noise variance); antithetic pairs (+e, −e)
//! cancel the first-order scatter.
//!
//! σ_w is estimated from the drive: over windows of 1 s and 4 s the
//! wheel-odometry heading change at θ̂ minus the reference's has variance
//! `a + σ_w² · Σ 2 (v dt / t_r)²` (a: the reference's white heading
//! noise, twice; the sum over the window's samples: what white relative
//! noise σ_w on each wheel adds). Least squares over both lengths gives σ_w².
//!
//! Per seed: the error of batch G-N over its robust σ (t_r, c_e), the
//! predicted bias over σ with σ_w known (the preset's white level) and
//! estimated, and σ_w known vs estimated.

use odocal::identify::{batch_gauss_newton, IdentifyOptions};
use odocal::segment::{calibration_segments, SegmentData, SegmentOptions};
use odocal::sim::SimOptions;
use odocal::Theta;
use odocal_lab::{simulate_preset, Args, Res, Summary};

const USAGE: &str = "gn_simex [SEEDS 12] [KM 12] [PRESET paper|real] [PAIRS 2]";

/// The real drives of the repository (PRESET `real`).
const REAL: [&str; 8] = [
    "examples/psu-mapping-van/manifest.toml",
    "examples/psu-mapping-van-testtrack/run-14-45-26.toml",
    "examples/psu-mapping-van-testtrack/run-15-28-33.toml",
    "examples/psu-mapping-van-testtrack/run-16-06-28.toml",
    "examples/psu-mapping-van-testtrack/run-16-47-33.toml",
    "examples/psu-mapping-van-testtrack/run-17-45-46.toml",
    "examples/psu-mapping-van-testtrack/run-18-01-26.toml",
    "examples/comma2k19-rav4/manifest.toml",
];

/// Per real drive: batch G-N (`--method batch-gn --estimate heading-offset`)
/// and the default, σ_w estimated, the SIMEX bias over the batch-gn result's σ.
fn real(pairs: usize) -> Res<()> {
    use odocal::{calibrate, CalibrationOptions, Method, Param};
    println!("drive | σ_w est | bias/σ c_e c_d t_r d | (default − gn)/σ c_e c_d t_r d | gn verdict");
    for path in REAL {
        let drive = odocal_lab::load(path)?;
        let mut o = CalibrationOptions { method: Method::BatchGn(Default::default()), ..Default::default() };
        o.identify.free = o.identify.free.with(Param::HeadingOffset);
        let gn = calibrate(&drive, &o)?;
        let def = calibrate(&drive, &CalibrationOptions::default())?;
        let sig: [Option<f64>; 4] = gn.result_sigma().into();
        let th = gn.theta;
        let sel = calibration_segments(&drive, &o.segments)?;
        let data: Vec<SegmentData> = sel.selected.iter().map(|s| SegmentData::new(&drive, s)).collect();
        let sw = sigma_w_estimate(&data, &th).sqrt();
        let mut io = o.identify.clone();
        if let Some(x) = &gn.extrinsics {
            io.extrinsics = x.value;
        }
        let b = simex_with(&data, &th, &io, sw, pairs, 1)?;
        let a = <[f64; 4]>::from(th);
        let e = <[f64; 4]>::from(def.theta);
        let f = |v: [f64; 4]| -> String {
            (0..4).map(|i| sig[i].map_or("-".into(), |s| format!("{:+.2}", v[i] / s))).collect::<Vec<_>>().join(" ")
        };
        let diff: [f64; 4] = std::array::from_fn(|i| e[i] - a[i]);
        println!("{path} | {sw:.4} | {} | {} | {:?}", f(b), f(diff), gn.verdict.level);
    }
    Ok(())
}

/// splitmix64, then Box-Muller: a seeded normal stream.
struct Normal(u64);
impl Normal {
    fn u(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn n(&mut self) -> f64 {
        let (a, b) = (self.u(), self.u());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

/// σ_w² from the heading residual over windows of 100 and 400 samples.
fn sigma_w_estimate(data: &[SegmentData<'_>], theta: &Theta) -> f64 {
    let mut rows: Vec<(f64, f64)> = Vec::new(); // (x, r²)
    for len in [100usize, 400] {
        let mut rs = Vec::new();
        for s in data {
            let k = s.n_rl.len();
            let dt = s.sample_time_s;
            let mut i = 0;
            while i + len <= k {
                let (mut dpsi, mut x) = (0.0, 0.0);
                for j in i..i + len {
                    let (c_rl, c_rr) = (theta.c_e + theta.c_d / 2.0 + theta.d * s.a_y[j], theta.c_e - theta.c_d / 2.0 - theta.d * s.a_y[j]);
                    dpsi += (s.n_rr[j] * c_rr - s.n_rl[j] * c_rl) / theta.t_r * dt;
                    let v = 0.5 * (s.n_rr[j] * c_rr + s.n_rl[j] * c_rl);
                    x += 2.0 * (v * dt / theta.t_r).powi(2);
                }
                let mut r = dpsi - (s.psi[i + len] - s.psi[i]);
                r = (r + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
                rs.push((x, r));
                i += len;
            }
        }
        // remove each length's mean residual (δ-like constant drift per window)
        let m = rs.iter().map(|p| p.1).sum::<f64>() / rs.len().max(1) as f64;
        rows.extend(rs.into_iter().map(|(x, r)| (x, (r - m).powi(2))));
    }
    // least squares r² = a + s·x
    let n = rows.len() as f64;
    let (sx, sy) = rows.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mx, my) = (sx / n, sy / n);
    let (sxx, sxy) = rows.iter().fold((0.0, 0.0), |a, p| (a.0 + (p.0 - mx).powi(2), a.1 + (p.0 - mx) * (p.1 - my)));
    (sxy / sxx).max(0.0)
}

fn fit(data: &[SegmentData<'_>], from: &Theta, opts: &IdentifyOptions) -> Res<Theta> {
    Ok(batch_gauss_newton(data, from, opts)?.theta)
}

/// Mean shift of θ when white relative noise σ_w is added to both wheels.
fn simex(data: &[SegmentData<'_>], theta: &Theta, sigma_w: f64, pairs: usize, seed: u64) -> Res<[f64; 4]> {
    simex_with(data, theta, &IdentifyOptions::default(), sigma_w, pairs, seed)
}

/// [`simex`] with the calibration's identification options; the shift is
/// measured from a refit of the unperturbed data with the same options.
fn simex_with(
    data: &[SegmentData<'_>],
    theta: &Theta,
    base_opts: &IdentifyOptions,
    sigma_w: f64,
    pairs: usize,
    seed: u64,
) -> Res<[f64; 4]> {
    let opts = IdentifyOptions { max_iterations: 3, ..base_opts.clone() };
    let theta = &fit(data, theta, &opts)?;
    let mut rng = Normal(seed);
    let mut sum = [0.0; 4];
    for _ in 0..pairs {
        let noise: Vec<(Vec<f64>, Vec<f64>)> = data
            .iter()
            .map(|s| ((0..s.n_rl.len()).map(|_| rng.n()).collect(), (0..s.n_rr.len()).map(|_| rng.n()).collect()))
            .collect();
        for sign in [1.0, -1.0] {
            let owned: Vec<(Vec<f64>, Vec<f64>)> = data
                .iter()
                .zip(&noise)
                .map(|(s, (el, er))| {
                    (
                        s.n_rl.iter().zip(el).map(|(n, e)| n * (1.0 + sign * sigma_w * e)).collect(),
                        s.n_rr.iter().zip(er).map(|(n, e)| n * (1.0 + sign * sigma_w * e)).collect(),
                    )
                })
                .collect();
            let pert: Vec<SegmentData<'_>> = data
                .iter()
                .zip(&owned)
                .map(|(s, (l, r))| SegmentData { n_rl: l, n_rr: r, ..*s })
                .collect();
            let t = fit(&pert, theta, &opts)?;
            let d = [t.c_e - theta.c_e, t.c_d - theta.c_d, t.t_r - theta.t_r, t.d - theta.d];
            for i in 0..4 {
                sum[i] += d[i] / (2 * pairs) as f64;
            }
        }
    }
    Ok(sum)
}

/// One simulated CSV with its sidecar: batch G-N (θ only), σ_w estimated
/// and known, the SIMEX bias and the error, over the robust σ.
fn csv(path: &str, pairs: usize) -> Res<()> {
    let (drive, _) = odocal::load_drive(std::path::Path::new(path))?;
    let side: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path.replace(".csv", ".json"))?)?;
    let t = &side["theta_true"];
    let truth = Theta { c_e: t["c_e"].as_f64().unwrap_or(0.0), c_d: t["c_d"].as_f64().unwrap_or(0.0), t_r: t["t_r"].as_f64().unwrap_or(0.0), d: t["d"].as_f64().unwrap_or(0.0) };
    let sw_true = side["settings"]["noise"]["wheel_white_rel_sigma"].as_f64().unwrap_or(0.0);
    let sel = calibration_segments(&drive, &SegmentOptions::default())?;
    let data: Vec<SegmentData> = sel.selected.iter().map(|s| SegmentData::new(&drive, s)).collect();
    let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &IdentifyOptions::default())?;
    let th = r.theta;
    let sig: [f64; 4] = std::array::from_fn(|i| r.robust.as_ref().map_or(r.covariance[i][i], |b| b.covariance[i][i]).sqrt());
    let sw = sigma_w_estimate(&data, &th).sqrt();
    let err = [th.c_e - truth.c_e, th.c_d - truth.c_d, th.t_r - truth.t_r, th.d - truth.d];
    println!("σ_w est {sw:.5} true {sw_true:.5}");
    println!("err/σ {:?}", (0..4).map(|i| format!("{:+.2}", err[i] / sig[i])).collect::<Vec<_>>());
    for (name, s) in [("est", sw), ("true", sw_true)] {
        let b = simex(&data, &th, s, pairs, 1)?;
        println!("bias/σ ({name}) {:?}", (0..4).map(|i| format!("{:+.2}", b[i] / sig[i])).collect::<Vec<_>>());
    }
    Ok(())
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let seeds: u64 = args.pos(0, 12)?;
    let km: f64 = args.pos(1, 12.0)?;
    let preset: String = args.pos(2, "paper".to_string())?;
    let pairs: usize = args.pos(3, 2)?;
    if preset == "real" {
        return real(pairs);
    }
    if let Some(path) = preset.strip_prefix("csv:") {
        return csv(path, pairs);
    }
    let truth = SimOptions::paper(1).theta_true;
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); 8];
    println!("seed | t_r err/σ | t_r bias known/σ | est/σ | c_e err/σ | c_e bias est/σ | σ_w true | σ_w est");
    for seed in 1..=seeds {
        let out = simulate_preset(&preset, km, seed)?;
        let drive = &out.drive;
        let sel = calibration_segments(drive, &SegmentOptions::default())?;
        let data: Vec<SegmentData> = sel.selected.iter().map(|s| SegmentData::new(drive, s)).collect();
        let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &IdentifyOptions::default())?;
        let th = r.theta;
        let sig: [f64; 4] = std::array::from_fn(|i| {
            r.robust.as_ref().map_or(r.covariance[i][i], |b| b.covariance[i][i]).sqrt()
        });
        let sw_true = odocal_lab::noise_preset(&preset)?.wheel_white_rel_sigma;
        let sw_est = sigma_w_estimate(&data, &th).sqrt();
        let bk = simex(&data, &th, sw_true, pairs, seed)?;
        let be = simex(&data, &th, sw_est, pairs, seed)?;
        let err = [th.c_e - truth.c_e, th.c_d - truth.c_d, th.t_r - truth.t_r, th.d - truth.d];
        let row = [err[2] / sig[2], bk[2] / sig[2], be[2] / sig[2], err[0] / sig[0], be[0] / sig[0], sw_true, sw_est, err[2] / truth.t_r * 100.0];
        println!(
            "{seed} | {:+.2} | {:+.2} | {:+.2} | {:+.2} | {:+.2} | {:.4} | {:.4} | t_r err {:+.3} % bias est {:+.3} %",
            row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7], be[2] / truth.t_r * 100.0
        );
        for (c, v) in cols.iter_mut().zip(row) {
            c.push(v);
        }
    }
    for (name, c) in ["t_r err/σ", "t_r bias known/σ", "t_r bias est/σ", "c_e err/σ", "c_e bias est/σ", "σ_w true", "σ_w est", "t_r err %"].iter().zip(&cols) {
        let s = Summary::of(c);
        println!("{name}: mean {:+.3} sd {:.3}", s.mean, s.sd);
    }
    Ok(())
}
