//! Shared fixtures of the EIV tests: inputs, filter records, drives.

use crate::drive::segment::{select_segments, SegmentData, SegmentOptions};
use crate::drive::Drive;
use crate::eiv::filter::{run_window, InnovationRecord};
use crate::eiv::*;
use crate::identify::{batch_gauss_newton, IdentifyOptions};
use crate::sim::{simulate, NoiseOptions, SimOptions};
use crate::Theta;

pub(super) fn input_of(d: &Drive) -> EivInput<'_> {
    EivInput::from_drive(d)
}

/// Batch Gauss-Newton on every cut segment (no yaw-rate selection).
pub(super) fn batch_gn_all(d: &Drive) -> Theta {
    let sel = select_segments(d, &SegmentOptions::default()).expect("segments");
    let data: Vec<SegmentData> = sel.all.iter().map(|s| SegmentData::new(d, s)).collect();
    let opts = IdentifyOptions { max_iterations: 20, ..Default::default() };
    batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("batch G-N").theta
}

pub(super) fn records(
    input: &EivInput<'_>,
    w: &Window,
    th: &Theta,
    th_ref: &Theta,
    eta: &[f64; 6],
    follows: bool,
) -> Vec<InnovationRecord> {
    records_with(input, w, th, th_ref, eta, follows, (false, false))
}

pub(super) fn records_with(
    input: &EivInput<'_>,
    w: &Window,
    th: &Theta,
    th_ref: &Theta,
    eta: &[f64; 6],
    follows: bool,
    // (fitted input, counting quantisation)
    (fitted_input, counting): (bool, bool),
) -> Vec<InnovationRecord> {
    records_quant(input, w, th, th_ref, eta, follows, (fitted_input, counting), Held::NONE)
}

/// Which variances η_0 leaves alone in a derivative test: the quantisation
/// ([`QuantisationLevel::Given`]), a_y and β ([`LateralNoise::Stated`]), or
/// a_y alone (`ResearchOptions::a_y_sigma_held`).
#[derive(Clone, Copy)]
pub(super) struct Held {
    pub(super) quant: bool,
    pub(super) lateral: bool,
    pub(super) a_y: bool,
}

impl Held {
    pub(super) const NONE: Held = Held { quant: false, lateral: false, a_y: false };
    pub(super) const QUANT: Held = Held { quant: true, lateral: false, a_y: false };
    pub(super) const LATERAL: Held = Held { quant: false, lateral: true, a_y: false };
    pub(super) const A_Y: Held = Held { quant: false, lateral: false, a_y: true };
}

/// [`records_with`]; `given`: the variances η_0 does not scale ([`Held`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn records_quant(
    input: &EivInput<'_>,
    w: &Window,
    th: &Theta,
    th_ref: &Theta,
    eta: &[f64; 6],
    follows: bool,
    (fitted_input, counting): (bool, bool),
    given: Held,
) -> Vec<InnovationRecord> {
    let mut v = variances_quant(eta, input.sample_time_s, given);
    v.fitted_input = fitted_input;
    v.quant_counting = counting;
    let mut rec = Vec::new();
    run_window(input, w, th, th_ref, &v, filter::Mode::full(follows, true), Some(&mut rec)).expect("window");
    rec
}

/// The default model's variances at η; with `given.quant` the quantisation
/// is held at q²/12, with `given.lateral` a_y and β at the model's σ (as
/// `Problem::evaluate_with` does for [`QuantisationLevel::Given`] and
/// [`LateralNoise::Stated`]), with `given.a_y` a_y alone at 0.07 m/s².
pub(super) fn variances_quant(eta: &[f64; 6], ts: f64, given: Held) -> filter::Variances {
    let m = NoiseModel::default();
    let mut v = m.variances(eta, ts);
    if given.quant {
        v.quant = m.quantisation_step_rev_per_s * m.quantisation_step_rev_per_s / 12.0;
        v.quant_scaled = false;
    }
    if given.lateral {
        let unscaled = m.variances(&[0.0; 6], ts);
        (v.a_y, v.beta, v.lateral_scaled) = (unscaled.a_y, unscaled.beta, false);
    }
    if given.a_y {
        // Held apart from the model's 0.05 m/s², as `Problem::evaluate_with` does.
        (v.a_y, v.a_y_scaled) = (0.07 * 0.07, false);
    }
    v
}

pub(super) fn perturb(th: &Theta, i: usize, h: f64) -> Theta {
    let mut a = th.to_vector();
    a[i] += h;
    Theta::from_vector(&a)
}

/// The central-difference pair for unknown `p` of [θ, η] (0–3 θ, 4– η):
/// (θ₊, θ₋, η₊, η₋, h), with h 1e-6 relative for θ and 1e-5 for η.
pub(super) fn perturbed_pair(th: &Theta, eta: &[f64; 6], p: usize) -> (Theta, Theta, [f64; 6], [f64; 6], f64) {
    if p < 4 {
        let h = 1e-6 * [th.c_e, 1.0, th.t_r, 1.0][p];
        (perturb(th, p, h), perturb(th, p, -h), *eta, *eta, h)
    } else {
        let h = 1e-5;
        let (mut ep, mut em) = (*eta, *eta);
        ep[p - 4] += h;
        em[p - 4] -= h;
        (*th, *th, ep, em, h)
    }
}

/// Central differences with h ~1e-6 relative on a ~1000-step filter: the
/// truncation error is ~1e-10 relative, round-off amplified by the
/// recursion stays below ~1e-6 of the column scale.
pub(super) const FD_REL_TOL: f64 = 2e-5;

pub(super) fn known_noise_fit(km: f64, seed: u64) -> (crate::sim::SimOutput, EivOptions) {
    let out = simulate(&SimOptions { length_km: km, ..SimOptions::paper(seed) }).expect("sim");
    let noise = NoiseModel::from_sim(&out.sidecar.settings.noise, out.drive.sample_time_s());
    (out, EivOptions { noise, fix_noise: true, ..Default::default() })
}

/// A straight, noise-free drive (heading constant; 10 m/s) at
/// θ = [`Theta::SIM_DEFAULT_TRUE`], owning the signals an [`EivInput`]
/// borrows.
pub(crate) struct StraightDrive {
    ts: f64,
    parts: [std::ops::Range<usize>; 1],
    pub px: Vec<f64>,
    pub py: Vec<f64>,
    pub psi: Vec<f64>,
    pub n_rl: Vec<f64>,
    pub n_rr: Vec<f64>,
    pub zero: Vec<f64>,
}

impl StraightDrive {
    /// `n` samples of `ts` seconds.
    pub(crate) fn new(n: usize, ts: f64) -> Self {
        let th = Theta::SIM_DEFAULT_TRUE;
        let (n_rl, n_rr) = crate::model::wheel_rotations(10.0, 0.0, 0.0, &th);
        let (mut px, mut py, mut psi) = (vec![0.0], vec![0.0], vec![0.3]);
        for k in 1..n {
            let x = crate::model::step(
                &crate::model::State::new(px[k - 1], py[k - 1], psi[k - 1]),
                &crate::model::Input { n_rl, n_rr, beta: 0.0, a_y: 0.0 },
                &th,
                ts,
            );
            px.push(x[0]);
            py.push(x[1]);
            psi.push(x[2]);
        }
        StraightDrive { ts, parts: [0..n], px, py, psi, n_rl: vec![n_rl; n], n_rr: vec![n_rr; n], zero: vec![0.0; n] }
    }

    /// Signals of `ts`-second samples as one drive (β and a_y zero), for
    /// drives other than the straight one.
    pub(crate) fn from_columns(
        ts: f64,
        px: Vec<f64>,
        py: Vec<f64>,
        psi: Vec<f64>,
        n_rl: Vec<f64>,
        n_rr: Vec<f64>,
    ) -> Self {
        let n = px.len();
        StraightDrive { ts, parts: [0..n], px, py, psi, n_rl, n_rr, zero: vec![0.0; n] }
    }

    /// The drive as one part, β and a_y zero, the reference measured everywhere.
    pub(crate) fn input(&self) -> EivInput<'_> {
        EivInput {
            sample_time_s: self.ts,
            parts: &self.parts,
            px: &self.px,
            py: &self.py,
            psi: &self.psi,
            n_rl: &self.n_rl,
            n_rr: &self.n_rr,
            beta: &self.zero,
            a_y: &self.zero,
            reference_measured: None,
        }
    }

    /// The same samples as a [`crate::Drive`] (β and a_y zero), for tests
    /// that calibrate it end to end.
    pub(crate) fn drive(self) -> crate::Drive {
        let n = self.px.len();
        let t = (0..n).map(|k| k as f64 * self.ts).collect();
        let measured = crate::drive::Signals {
            px: self.px,
            py: self.py,
            psi: self.psi,
            n_rl: self.n_rl,
            n_rr: self.n_rr,
            beta: self.zero.clone(),
            a_y: self.zero,
        };
        crate::DriveBuilder { t, measured, ..Default::default() }.build().expect("drive")
    }
}

/// The 1 km white-noise drive of the convergence tests, and the
/// options they share: η estimated, the heading scale separate, counting
/// quantisation.
pub(super) fn separate_counting_white_drive() -> (crate::sim::SimOutput, EivOptions) {
    let out = simulate(&SimOptions { length_km: 1.0, noise: NoiseOptions::white_wheel_only(), ..SimOptions::paper(1) })
        .expect("sim");
    let opts = EivOptions {
        window_samples: 1000,
        heading_scale: HeadingScale::Separate,
        quantisation: QuantisationModel::Counting,
        ..Default::default()
    };
    (out, opts)
}

/// White wheel noise (0.2 %) and a reference whose drift is slower (τ 200
/// s) than the filter's model (100 s), with white position and heading
/// noise and a_y and β noise: a drive of this kind sends the pose drift to
/// its lower clamp in the first scoring steps.
pub(crate) fn slow_drift_noise() -> crate::sim::NoiseOptions {
    use crate::sim::NoiseOptions;
    NoiseOptions {
        wheel_white_rel_sigma: 0.002,
        position_white_sigma_m: 0.02,
        position_drift_sigma_m: 0.2,
        position_drift_time_constant_s: 200.0,
        heading_white_sigma_rad: 3e-4,
        heading_drift_sigma_rad: 1e-3,
        heading_drift_time_constant_s: 200.0,
        lateral_acceleration_white_sigma_m_per_s2: 0.05,
        sideslip_sigma_rad: 1e-3,
        ..NoiseOptions::off()
    }
}
