//! Where does EIV's t_r bias with the known noise model under large white
//! wheel noise come from? (The measurements behind the 5 mm position floor,
//! `ResearchOptions::position_floor_m`.)
//!
//! Per seed, on one simulated drive with white relative wheel noise only
//! (perfect reference, no quantisation, no slip), it prints the t_r, c_d, d
//! errors of: batch G-N; EIV with the simulator's noise model (`known`);
//! independent per-sample errors-in-variables estimators that need no
//! filter, each the root of a Deming-type cost on the *reference* increments
//! `y_{k+1} − f(y_k, ñ_k, θ)` (a perfect reference makes consecutive samples
//! independent):
//! - `head`: the heading channel alone, `Σ (t_r Δψ_k − x̃_k(θ))² / σ_x,k²`,
//!   c_e at its truth (the heading channel only sees ratios);
//! - `step3`: the full 3-dof step innovation with `S_k(θ) = F_n Σ_n F_nᵀ + R`
//!   (the per-sample profile cost, S following θ, F_n and Σ_n at the measured
//!   input), minimised by Gauss-Newton on the whitened residuals.
//!
//! The EIV fits start from the base formulation of docs/method.md's Notes
//! (`EivOptions::spec`: the measured-input noise scale, no input log-Jacobian term, the 1 mm floor)
//! with the heading tied to the position scale. `--preset` replaces the
//! white-noise drive built from `--sigma`/`--sim-*`; the `CRB σ` row's mean
//! column is the mean Cramér–Rao σ over the drives, `CRBmean σ` its
//! mean-only version (without `½ tr(S⁻¹∂S S⁻¹∂S)`), `CRB5 σ` the full bound
//! with a 5 mm position floor.

use nalgebra::{Matrix3, Vector3};
use odocal::eiv::{estimate, CovarianceMode, EivInput, EivOptions, HeadingScale, NoiseModel, ResearchOptions};
use odocal::model::wrap_angle;
use odocal::model::{step_jacobians, Input, State};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{Drive, Theta};
use odocal_lab::{batch_gn_all, errors, format_errors, noise_preset, Args, Res};

const USAGE: &str = "eiv_white_bias [--km 12] [--seeds 8] [--first-seed 1] [--sigma 0.02] [--substeps 10]
    [--eiv known,…] [--sim-pos σ_m] [--sim-head σ_rad] [--preset white|paper|high|highnoquant|coloured]
    [--per-sample on|off]

--eiv: variants, tokens joined by '+': `known` (the simulator's model), `held` (covariance held at the
reference), `est` (η estimated from the production-car model; put it first), `w<N>` (window samples),
`p<σ_m>` / `h<σ_rad>` (reference white noise assumed by the filter), `x<σ>` (white wheel σ assumed),
`f<σ_m>` (the position floor)";

const POS_FLOOR: f64 = 1e-3;
const HEAD_FLOOR: f64 = 1e-5;

/// Which input scales the white wheel noise in the per-sample costs.
#[derive(Clone, Copy, PartialEq)]
enum Scale {
    Measured,
    True,
}

/// Per-sample step innovation, whitened: `r_k = L_k⁻¹ ν_k`, S following θ.
fn step_residuals(d: &Drive, th: &Theta, sigma: f64, scale: Scale, out: &mut Vec<f64>) {
    let m = d.measured();
    let tru = d.truth();
    let ts = d.sample_time_s();
    out.clear();
    for k in 0..m.px.len() - 1 {
        let (nl, nr) = (m.n_rl[k], m.n_rr[k]);
        if nl == 0.0 && nr == 0.0 {
            continue;
        }
        let x = State::new(m.px[k], m.py[k], m.psi[k]);
        let u = Input { n_rl: nl, n_rr: nr, beta: m.beta[k], a_y: m.a_y[k] };
        let j = step_jacobians(&x, &u, th, ts);
        let (sl, sr) = match (scale, tru) {
            (Scale::True, Some(t)) => (t.n_rl[k], t.n_rr[k]),
            _ => (nl, nr),
        };
        let (fl, fr) = (j.f_n.column(0).into_owned(), j.f_n.column(1).into_owned());
        let s = fl * fl.transpose() * (sigma * sigma * sl * sl)
            + fr * fr.transpose() * (sigma * sigma * sr * sr)
            + Matrix3::from_diagonal(&Vector3::new(POS_FLOOR.powi(2), POS_FLOOR.powi(2), HEAD_FLOOR.powi(2)));
        let nu = Vector3::new(m.px[k + 1] - j.next[0], m.py[k + 1] - j.next[1], wrap_angle(m.psi[k + 1] - j.next[2]));
        let Some(ch) = s.cholesky() else { continue };
        let r = ch.l().solve_lower_triangular(&nu).unwrap_or_else(Vector3::zeros);
        out.extend_from_slice(r.as_slice());
    }
}

/// Gauss-Newton on whitened residuals with central-difference Jacobians.
fn gn_whitened(
    d: &Drive,
    start: &Theta,
    free: [bool; 4],
    f: &dyn Fn(&Drive, &Theta, &mut Vec<f64>),
) -> (Theta, f64, usize) {
    let mut th = nalgebra::Vector4::from(<[_; 4]>::from(start));
    let hstep = [1e-6, 1e-7, 1e-6, 1e-7];
    let (mut r0, mut rp, mut rm) = (Vec::new(), Vec::new(), Vec::new());
    let mut cost = f64::INFINITY;
    let mut it = 0;
    for _ in 0..30 {
        it += 1;
        f(d, &Theta::from(<[f64; 4]>::from(th)), &mut r0);
        cost = 0.5 * r0.iter().map(|x| x * x).sum::<f64>();
        let mut jac: Vec<Vec<f64>> = Vec::new();
        let idx: Vec<usize> = (0..4).filter(|i| free[*i]).collect();
        for &i in &idx {
            let (mut a, mut b) = (th, th);
            a[i] += hstep[i];
            b[i] -= hstep[i];
            f(d, &Theta::from(<[f64; 4]>::from(a)), &mut rp);
            f(d, &Theta::from(<[f64; 4]>::from(b)), &mut rm);
            jac.push(rp.iter().zip(&rm).map(|(p, q)| (p - q) / (2.0 * hstep[i])).collect());
        }
        let n = idx.len();
        let mut h = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut g = nalgebra::DVector::<f64>::zeros(n);
        for a in 0..n {
            g[a] = jac[a].iter().zip(&r0).map(|(x, y)| x * y).sum();
            for b in 0..n {
                h[(a, b)] = jac[a].iter().zip(&jac[b]).map(|(x, y)| x * y).sum();
            }
        }
        let Some(step) = h.clone().cholesky().map(|c| c.solve(&(-g))) else { break };
        // Step halving on the cost.
        let mut fac = 1.0;
        let mut accepted = false;
        for _ in 0..20 {
            let mut t2 = th;
            for (a, &i) in idx.iter().enumerate() {
                t2[i] += fac * step[a];
            }
            f(d, &Theta::from(<[f64; 4]>::from(t2)), &mut rp);
            let c2 = 0.5 * rp.iter().map(|x| x * x).sum::<f64>();
            if c2 <= cost {
                th = t2;
                accepted = true;
                break;
            }
            fac *= 0.5;
        }
        let rel = idx.iter().enumerate().map(|(a, &i)| (step[a] / th[i]).abs()).fold(0.0, f64::max);
        if !accepted || rel < 1e-9 {
            break;
        }
    }
    (Theta::from(<[f64; 4]>::from(th)), cost, it)
}

/// Heading channel alone: `Σ (t_r Δψ_k − x̃_k)² / σ_x,k²`, with
/// `x̃ = (c_rr ñ_r − c_rl ñ_l) t_s`, `σ_x² = σ² t_s² (c_rr² s_r² + c_rl² s_l²)`
/// (s = measured or true input); whitened residuals for [`gn_whitened`].
fn heading_residuals(d: &Drive, th: &Theta, sigma: f64, scale: Scale, out: &mut Vec<f64>) {
    let m = d.measured();
    let tru = d.truth();
    let ts = d.sample_time_s();
    out.clear();
    for k in 0..m.px.len() - 1 {
        let (nl, nr) = (m.n_rl[k], m.n_rr[k]);
        if nl == 0.0 && nr == 0.0 {
            continue;
        }
        let (c_rl, c_rr) = (th.c_e + th.c_d / 2.0 + th.d * m.a_y[k], th.c_e - th.c_d / 2.0 - th.d * m.a_y[k]);
        let (sl, sr) = match (scale, tru) {
            (Scale::True, Some(t)) => (t.n_rl[k], t.n_rr[k]),
            _ => (nl, nr),
        };
        let x = (c_rr * nr - c_rl * nl) * ts;
        let var =
            sigma * sigma * ts * ts * (c_rr * c_rr * sr * sr + c_rl * c_rl * sl * sl) + (th.t_r * HEAD_FLOOR).powi(2);
        let dpsi = wrap_angle(m.psi[k + 1] - m.psi[k]);
        out.push((th.t_r * dpsi - x) / var.sqrt());
    }
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let km: f64 = a.get("km", 12.0)?;
    let seeds: u64 = a.get("seeds", 8)?;
    let first: u64 = a.get("first-seed", 1)?;
    let sigma: f64 = a.get("sigma", 0.02)?;
    let substeps: usize = a.get("substeps", 10)?;
    let eiv_modes = a.list("eiv", &["known"]);
    let (sim_pos, sim_head): (f64, f64) = (a.get("sim-pos", 0.0)?, a.get("sim-head", 0.0)?);
    let preset: Option<String> = a.opt("preset")?;
    let per_sample = a.get("per-sample", "on".to_string())? == "on";
    a.finish()?;
    let noise = NoiseOptions {
        wheel_white_rel_sigma: sigma,
        position_white_sigma_m: sim_pos,
        heading_white_sigma_rad: sim_head,
        .."white".parse::<NoiseOptions>()?
    };
    let noise = match preset.as_deref() {
        None => noise,
        Some("highnoquant") => NoiseOptions { encoder_ticks_per_revolution: 0, ..NoiseOptions::high() },
        Some(p) => noise_preset(p)?,
    };
    let mut rows: Vec<(String, Vec<[f64; 4]>)> = Vec::new();
    let mut push = |label: &str, e: [f64; 4]| {
        if let Some(r) = rows.iter_mut().find(|r| r.0 == label) {
            r.1.push(e);
        } else {
            rows.push((label.to_string(), vec![e]));
        }
    };
    for seed in first..first + seeds {
        let sim = simulate(&SimOptions { length_km: km, noise: noise.clone(), substeps, ..SimOptions::paper(seed) })?;
        let d = &sim.drive;
        let truth = sim.sidecar.theta_true;
        let err = |t: &Theta| errors(t, &truth);
        let fmt = |e: [f64; 4]| format_errors(&e);
        let gn = batch_gn_all(d)?;
        println!("seed {seed}: G-N {}", fmt(err(&gn)));
        push("G-N", err(&gn));
        let input = EivInput::from_drive(d);
        let sim_noise = NoiseModel::from_sim(&noise, d.sample_time_s());
        for mode in &eiv_modes {
            // A variant: tokens joined by '+' (USAGE).
            let mut opts = EivOptions {
                noise: sim_noise,
                fix_noise: true,
                heading_scale: HeadingScale::TiedToPosition,
                max_iterations: 30,
                step_tolerance: 1e-3,
                ..EivOptions::spec()
            };
            for tok in mode.split('+') {
                if tok == "est" {
                    opts.fix_noise = false;
                    opts.noise = NoiseModel::PRODUCTION_CAR;
                    opts.max_iterations = 10;
                    opts.step_tolerance = 0.05;
                } else if tok == "held" {
                    opts.research.covariance = CovarianceMode::HeldAtReference;
                } else if let Some(v) = tok.strip_prefix('w') {
                    opts.window_samples = v.parse()?;
                } else if let Some(v) = tok.strip_prefix('p') {
                    opts.noise.position_white_sigma_m = v.parse()?;
                } else if let Some(v) = tok.strip_prefix('h') {
                    opts.noise.heading_white_sigma_rad = v.parse()?;
                } else if let Some(v) = tok.strip_prefix('f') {
                    opts.research.position_floor_m = v.parse()?;
                } else if let Some(v) = tok.strip_prefix('x') {
                    opts.noise.wheel_white_rel_sigma = v.parse()?;
                }
            }
            match estimate(&input, &gn, &opts) {
                Ok(r) => {
                    let nis = r.windows.iter().map(|w| w.nis).sum::<f64>() / r.windows.len().max(1) as f64;
                    println!(
                        "  EIV {mode:6} {} | it {} {} nis {nis:.3}",
                        fmt(err(&r.theta)),
                        r.iterations,
                        r.termination
                    );
                    push(&format!("EIV {mode}"), err(&r.theta));
                }
                Err(e) => println!("  EIV {mode}: failed {e}"),
            }
        }
        let along = odocal::eiv::EivInput::from_drive_truth(d)?;
        let crb = odocal::eiv::cramer_rao_bound(&along, &truth, &sim_noise, &EivOptions::spec())?;
        let cs = crb.sigma;
        push("CRB σ", [cs[0] / truth.c_e * 100.0, cs[1] * 1e3, cs[2] / truth.t_r * 100.0, cs[3] * 1e3]);
        let cs = crb.sigma_mean_only;
        push("CRBmean σ", [cs[0] / truth.c_e * 100.0, cs[1] * 1e3, cs[2] / truth.t_r * 100.0, cs[3] * 1e3]);
        // The same bound with a 5 mm position floor in R (the model of a
        // reference known to 5 mm rather than 1 mm).
        let crb5 = odocal::eiv::cramer_rao_bound(
            &along,
            &truth,
            &sim_noise,
            &EivOptions {
                research: ResearchOptions { position_floor_m: 0.005, ..EivOptions::spec().research },
                ..EivOptions::spec()
            },
        )?;
        let cs = crb5.sigma;
        push("CRB5 σ", [cs[0] / truth.c_e * 100.0, cs[1] * 1e3, cs[2] / truth.t_r * 100.0, cs[3] * 1e3]);
        let scales: &[(&str, Scale)] =
            if per_sample { &[("meas", Scale::Measured), ("true", Scale::True)] } else { &[] };
        for &(label, scale) in scales {
            let start = Theta { c_e: truth.c_e, ..gn };
            let (th, _, _) =
                gn_whitened(d, &start, [false, true, true, true], &|d, t, o| heading_residuals(d, t, sigma, scale, o));
            println!("  head-{label}  {}", fmt(err(&th)));
            push(&format!("head-{label}"), err(&th));
            let (th, cost, its) = gn_whitened(d, &gn, [true; 4], &|d, t, o| step_residuals(d, t, sigma, scale, o));
            println!("  step3-{label} {} | J {cost:.1} it {its}", fmt(err(&th)));
            push(&format!("step3-{label}"), err(&th));
            // The cost at the truth vs at the estimate.
            let mut r = Vec::new();
            step_residuals(d, &truth, sigma, scale, &mut r);
            let n = r.len() as f64;
            let j_true = 0.5 * r.iter().map(|x| x * x).sum::<f64>();
            println!("      J(θ_true) {j_true:.1}, per dof {:.4}", 2.0 * j_true / n);
        }
    }
    println!("\nsummary (mean ± sd over seeds; t = mean/(sd/√n); RMS/CRB against the mean CRB σ)");
    let crb_mean: [f64; 4] = rows
        .iter()
        .find(|r| r.0 == "CRB σ")
        .map(|r| std::array::from_fn(|p| r.1.iter().map(|e| e[p]).sum::<f64>() / r.1.len() as f64))
        .unwrap_or([f64::NAN; 4]);
    for (label, es) in &rows {
        let n = es.len() as f64;
        let mut line = format!("{label:12} n {n:2}");
        for (p, name) in ["c_e %", "c_d mm", "t_r %", "d"].iter().enumerate() {
            let v: Vec<f64> = es.iter().map(|e| e[p]).collect();
            let mean = v.iter().sum::<f64>() / n;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
            let rms = (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
            line +=
                &format!(" | {name} {mean:+.4} ± {sd:.4} (t {:.1}, {:.2}×)", mean / (sd / n.sqrt()), rms / crb_mean[p]);
        }
        println!("{line}");
    }
    Ok(())
}
