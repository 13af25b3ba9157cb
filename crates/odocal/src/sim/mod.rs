//! The drive simulator (docs/method.md §8): city and suburb routes with a known true θ.
//!
//! [`simulate`] with [`SimOptions`] makes a drive; the route, speed,
//! vehicle and noise settings and the sidecar file are here too, for
//! studies on drives with a known θ.
//!
//! Real logs of wheel rotations with a GNSS/INS reference rarely are public,
//! and they never carry the true parameters. [`simulate`] makes drives that
//! do, reproducibly from a seed.
//!
//! ## How a drive is made
//!
//! 1. **Route.** A curvature-versus-distance profile κ(s), piecewise linear:
//!    straights, bends of varied radius (some S-bends), 90° crossroad turns
//!    and roundabouts, joined by clothoid transitions (curvature linear in s)
//!    so that the yaw rate is continuous. The route alternates between city
//!    and suburb zones.
//! 2. **Speed.** A cruise speed per manoeuvre (city 30–50 km/h, suburb
//!    60–90 km/h), limited by `sqrt(a_lat,max/|κ|)` in curves and brought to
//!    standstill for a few seconds at some crossroads; a forward pass
//!    (acceleration limit) and a backward pass (deceleration limit) on a
//!    0.5 m grid give v(s), integrated in time with constant acceleration
//!    per grid cell.
//! 3. **Truth.** At every fine step `t_s/substeps`, evaluated at the step's
//!    midpoint time: `ω = v·κ`, `a_y = v·ω`, steady-state rear-axle sideslip
//!    of the linear single-track model `β = −m·l_f·a_y/(L·C_r)`, and the
//!    wheel rotations obtained by inverting the model (2a, 2b, 3a, 3b) with
//!    the true θ:
//!
//!    ```text
//!    n_rr = (v + ω·t_r/2)/c_rr      n_rl = (v − ω·t_r/2)/c_rl
//!    ```
//!
//!    The true pose is integrated with [`model::step`] at the fine step.
//! 4. **Output sample k** carries the true pose at `t_k = k·t_s` and, as its
//!    true inputs, the *mean* of the fine-step inputs over the interval
//!    `[t_k, t_k+1)` — for the wheel rotations that is the number of
//!    revolutions turned in the interval divided by `t_s`, which is what a
//!    counting encoder reports. With `substeps = 1` the output inputs are
//!    exactly the ones the truth was integrated with, so [`model::step`]
//!    from a truth pose with the truth inputs reproduces the next truth pose
//!    bit for bit and calibration recovers θ_true to rounding. With more
//!    substeps the one-step model is no longer exact (midpoint rule over
//!    t_s, mean of products), a small model error as in real data.
//! 5. **Measurements.** Wheel rotations get slip proportional to the
//!    longitudinal acceleration, coloured (first-order Gauss-Markov) noise
//!    common to both wheels and, smaller, independent per wheel, white
//!    relative noise per wheel, then encoder quantization: ticks are counted
//!    over each sample interval (the remainder carries over). The reference
//!    pose gets a slow Gauss-Markov drift plus white noise on position and
//!    heading; a_y gets white noise (IMU), β a Gauss-Markov error (filtered
//!    estimate); the reference heading, a_y and β can carry a constant
//!    error too. Each source has its own setting; the `off` preset
//!    (`"off".parse::<NoiseOptions>()`) makes every measured column equal to its truth column.
//!
//! Each noise source draws from its own ChaCha8 stream of the seed, so
//! switching one source off leaves the route, the truth and the other
//! sources' realisations unchanged; the same options give byte-identical
//! output on every platform.
//!
//! ## Random noise worlds
//!
//! The presets (`NoiseOptions`'s `FromStr`: `paper`, the default, and its relatives) are dominated by
//! white wheel noise. `random:N` (`"random:7".parse::<NoiseOptions>()`)
//! draws a whole noise world from wide ranges instead — each source's size, its correlation
//! time, the constant errors — reproducibly from a world seed, and
//! [`NoiseOptions::world_summary`] says which kind of wheel noise dominates
//! it. `odocal simulate --noise random:N` simulates world N.

use std::path::Path;

use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::drive::{Drive, DriveBuilder, Signals};
use crate::error::{Error, Result};
use crate::model::{self, Input, State, Theta};

mod options;
mod route;
mod truth;
mod world;

use options::invalid;
pub(crate) use options::SpeedOptions;
pub use options::{CdStep, DriftOptions, NoiseOptions, SimOptions};
pub(crate) use route::GaussMarkov;
use route::{build_route, stream, Encoder, Route, SpeedProfile, White};
research_use! { world::{NoiseRegime, WorldSummary} }

/// Grid step of the speed profile along the route, m.
const SPEED_GRID_M: f64 = 0.5;
/// A sample counts as moving (for [`SimStats::wheel_rotation_rel_error_rms`])
/// when its true speed exceeds this, m/s.
pub(crate) const MOVING_SPEED_M_PER_S: f64 = 1.0;
/// Longest drive accepted, km (memory guard: about 40 MB of samples per 100 km).
const MAX_LENGTH_KM: f64 = 2000.0;

/// Summary numbers of a simulated drive (all from the truth).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimStats {
    /// Output samples.
    pub samples: usize,
    /// Length of the true path, m.
    pub distance_m: f64,
    /// Duration, s (`(samples − 1)·t_s`).
    pub duration_s: f64,
    /// Peak absolute true yaw rate, rad/s.
    pub max_yaw_rate_rad_per_s: f64,
    /// Peak absolute true lateral acceleration, m/s².
    pub max_abs_lateral_acceleration_m_per_s2: f64,
    /// RMS of `(measured − true)/true` wheel rotation over both rear wheels
    /// and every moving sample (true speed above `MOVING_SPEED_M_PER_S`).
    pub wheel_rotation_rel_error_rms: f64,
}

/// The sidecar of a simulated drive: the truth that the CSV cannot hold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimSidecar {
    /// The true θ (SI units).
    pub theta_true: Theta,
    /// Every simulator setting.
    pub settings: SimOptions,
    /// Summary numbers.
    pub stats: SimStats,
    /// The [`Drive::fingerprint`] of the simulated drive: binds the
    /// sidecar to its CSV ([`SimSidecar::for_drive`]). `None` when not recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_fingerprint: Option<String>,
    /// With drifting parameters ([`SimOptions::drift`]): the true θ at the
    /// last sample (`theta_true` is θ at the first). `None` without drift.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_true_end: Option<Theta>,
}

impl SimSidecar {
    /// Writes the sidecar as pretty JSON to `path`, atomically.
    fn write_json(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|source| Error::Json { context: format!("writing {}", path.display()), source })?;
        crate::output::write_text(path, &text)
    }

    /// Reads a sidecar written by [`SimSidecar::write_beside`].
    pub(crate) fn read_json(path: &Path) -> Result<Self> {
        let text = crate::output::limited::read_text_limited(
            path,
            crate::output::limited::MAX_SETTINGS_BYTES,
            "a simulator sidecar",
        )
        .map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        serde_json::from_str(&text).map_err(|source| Error::Json { context: path.display().to_string(), source })
    }
}

/// A simulated drive and its sidecar.
#[derive(Debug, Clone, PartialEq)]
pub struct SimOutput {
    /// The drive, with [`Drive::truth`] filled.
    pub drive: Drive,
    /// θ_true, the settings and summary numbers.
    pub sidecar: SimSidecar,
}

// ---------------------------------------------------------------------------

/// The drift of a drive of `duration_s`: θ at its end usable and, from a
/// plausible θ, still plausible (a ramp or step the user mistyped, `1e9`
/// or a c_d step in metres, does not write a drive of a vehicle that cannot
/// exist); a c_d step within the drive.
fn check_drift(drift: &DriftOptions, start: &Theta, end: &Theta, duration_s: f64) -> Result<()> {
    if let Some(step) = drift.c_d_step.filter(|s| s.at_s > duration_s) {
        let at = crate::drive::echo_num(step.at_s);
        return Err(invalid(
            "drift",
            format!("the c_d step at {at} s comes after the drive's end at {duration_s:.0} s: give a time within it"),
        ));
    }
    let check = if crate::model::limits::check_theta(start).is_ok() {
        crate::model::limits::check_theta(end)
    } else {
        end.validate()
    };
    check.map_err(|e| invalid("drift", format!("θ at the end of the drive, {duration_s:.0} s, with the drift: {e}")))
}

/// Simulates one drive (docs/method.md §8).
///
/// The same options (seed included) give an identical drive, byte for byte
/// when written as CSV. The measured columns carry the noise of
/// [`SimOptions::noise`]; [`Drive::truth`] holds the true poses and inputs,
/// the sidecar θ_true, the settings and [`SimStats`].
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::sim::{simulate, SimOptions};
/// let out = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(42) })?;
/// let drive = &out.drive;
/// assert_eq!(drive.len(), out.sidecar.stats.samples);
/// assert!((out.sidecar.stats.distance_m - 1000.0).abs() < 20.0);
/// assert!(drive.truth().is_some());
/// # Ok(()) }
/// ```
pub fn simulate(opts: &SimOptions) -> Result<SimOutput> {
    opts.validate()?;
    let theta = opts.theta_true;
    let mut route_rng = stream(opts.seed, 0);
    let route = build_route(opts, &mut route_rng);
    let profile = SpeedProfile::new(&route, &opts.speed);
    let psi0 = route_rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);

    let ts = 1.0 / opts.sample_rate_hz;
    let n = (profile.duration() * opts.sample_rate_hz).floor() as usize + 1;
    if n < 2 {
        return Err(invalid("length_km", "the drive is shorter than two samples"));
    }
    let theta_end = (!opts.drift.is_zero()).then(|| opts.drift.theta_at(&theta, (n - 1) as f64 * ts));
    if let Some(th) = theta_end {
        check_drift(&opts.drift, &theta, &th, (n - 1) as f64 * ts)?;
    }
    let truth = integrate_truth(opts, &route, &profile, psi0, n, ts);
    let (measured, wheel_rotation_rel_error_rms) = measure(opts, &truth, ts);

    let Truth { signals: truth, max_yaw, max_ay, .. } = truth;
    let distance_m = (1..n).map(|k| (truth.px[k] - truth.px[k - 1]).hypot(truth.py[k] - truth.py[k - 1])).sum::<f64>();
    let stats = SimStats {
        samples: n,
        distance_m,
        duration_s: (n - 1) as f64 * ts,
        max_yaw_rate_rad_per_s: max_yaw,
        max_abs_lateral_acceleration_m_per_s2: max_ay,
        wheel_rotation_rel_error_rms,
    };
    let t = (0..n).map(|k| k as f64 / opts.sample_rate_hz).collect();
    let drive = DriveBuilder {
        t,
        measured,
        truth: Some(truth),
        sample_time_s: Some(ts),
        context: "simulator".into(),
        ..Default::default()
    }
    .build()?;
    let drive_fingerprint = Some(drive.fingerprint());
    Ok(SimOutput {
        drive,
        sidecar: SimSidecar {
            theta_true: theta,
            settings: opts.clone(),
            stats,
            drive_fingerprint,
            theta_true_end: theta_end,
        },
    })
}

/// The true signals of a simulated drive.
struct Truth {
    /// The pose at each sample; the inputs as their means over the
    /// sample's substeps.
    signals: Signals,
    /// Longitudinal acceleration, m/s² (mean over the substeps).
    a_x: Vec<f64>,
    /// Largest |yaw rate|, rad/s.
    max_yaw: f64,
    /// Largest |a_y|, m/s².
    max_ay: f64,
}

/// The truth: `n` samples along the route at the speed profile from
/// heading `psi0`, the model integrated at the fine step `ts / substeps`
/// with the inputs θ_true implies (θ at each fine step's midpoint time when
/// the parameters drift).
fn integrate_truth(opts: &SimOptions, route: &Route, profile: &SpeedProfile, psi0: f64, n: usize, ts: f64) -> Truth {
    let theta0 = opts.theta_true;
    let drifting = !opts.drift.is_zero();
    let sub = opts.substeps;
    let dtf = ts / sub as f64;
    let beta_gain = opts.vehicle.sideslip_gain_rad_per_m_per_s2();
    let mut truth = Signals::with_capacity(n);
    let mut a_x = Vec::with_capacity(n);
    let mut x = State::new(0.0, 0.0, psi0);
    let (mut pcur, mut kcur) = (0usize, 0usize);
    let (mut max_yaw, mut max_ay) = (0.0f64, 0.0f64);
    for k in 0..n {
        truth.px.push(x[0]);
        truth.py.push(x[1]);
        truth.psi.push(x[2]);
        let mut sum = [0.0f64; 5];
        for j in 0..sub {
            let t_mid = ((k * sub + j) as f64 + 0.5) * dtf;
            let m = profile.at(t_mid, &mut pcur);
            let kappa = route.kappa_at(m.s, &mut kcur);
            let omega = m.v * kappa;
            let a_y = m.v * omega;
            let beta = beta_gain * a_y;
            let theta = if drifting { opts.drift.theta_at(&theta0, t_mid) } else { theta0 };
            let (n_rl, n_rr) = model::wheel_rotations(m.v, omega, a_y, &theta);
            let u = Input { n_rl, n_rr, beta, a_y };
            x = model::step(&x, &u, &theta, dtf);
            for (acc, v) in sum.iter_mut().zip([u.n_rl, u.n_rr, u.beta, u.a_y, m.a]) {
                *acc += v;
            }
            max_yaw = max_yaw.max(omega.abs());
            max_ay = max_ay.max(a_y.abs());
        }
        let div = sub as f64;
        truth.n_rl.push(sum[0] / div);
        truth.n_rr.push(sum[1] / div);
        truth.beta.push(sum[2] / div);
        truth.a_y.push(sum[3] / div);
        a_x.push(sum[4] / div);
    }
    Truth { signals: truth, a_x, max_yaw, max_ay }
}

/// The noise sources of the sensors, each on its own random stream of the
/// seed, sampled every `ts`.
struct Sensors {
    /// Slip common to both wheels (relative).
    gm_common: GaussMarkov,
    /// Rear-left wheel's own coloured error (relative).
    gm_rl: GaussMarkov,
    /// Rear-right wheel's own coloured error (relative).
    gm_rr: GaussMarkov,
    /// White wheel error (relative).
    white_wheel: White,
    /// Rear-left encoder (random tick phase).
    enc_rl: Encoder,
    /// Rear-right encoder (random tick phase).
    enc_rr: Encoder,
    /// Position drift east, m.
    drift_x: GaussMarkov,
    /// Position drift north, m.
    drift_y: GaussMarkov,
    /// White position noise, m.
    white_pos: White,
    /// Heading drift, rad.
    drift_psi: GaussMarkov,
    /// White heading noise, rad.
    white_psi: White,
    /// White a_y noise, m/s².
    white_ay: White,
    /// Sideslip error, rad.
    beta_err: GaussMarkov,
}

impl Sensors {
    /// The sources of the noise settings `no`.
    fn new(no: &NoiseOptions, seed: u64, ts: f64) -> Sensors {
        let tau_w = no.wheel_coloured_time_constant_s;
        let gm_common = GaussMarkov::new(stream(seed, 1), no.wheel_coloured_rel_sigma, tau_w, ts);
        let tau_d = no.wheel_coloured_differential_time_constant_s.unwrap_or(tau_w);
        let wheel_gm = |id| GaussMarkov::new(stream(seed, id), no.wheel_coloured_differential_rel_sigma, tau_d, ts);
        let (gm_rl, gm_rr) = (wheel_gm(2), wheel_gm(12));
        let white_wheel = White { rng: stream(seed, 3), sigma: no.wheel_white_rel_sigma };
        let ticks = f64::from(no.encoder_ticks_per_revolution);
        let mut phase_rng = stream(seed, 4);
        let enc_rl = Encoder { ticks, revolutions: phase_rng.random::<f64>() / ticks.max(1.0) };
        let enc_rr = Encoder { ticks, revolutions: phase_rng.random::<f64>() / ticks.max(1.0) };
        let pos_gm =
            |id| GaussMarkov::new(stream(seed, id), no.position_drift_sigma_m, no.position_drift_time_constant_s, ts);
        let (drift_x, drift_y) = (pos_gm(5), pos_gm(6));
        Sensors {
            gm_common,
            gm_rl,
            gm_rr,
            white_wheel,
            enc_rl,
            enc_rr,
            drift_x,
            drift_y,
            white_pos: White { rng: stream(seed, 7), sigma: no.position_white_sigma_m },
            drift_psi: GaussMarkov::new(
                stream(seed, 8),
                no.heading_drift_sigma_rad,
                no.heading_drift_time_constant_s,
                ts,
            ),
            white_psi: White { rng: stream(seed, 9), sigma: no.heading_white_sigma_rad },
            white_ay: White { rng: stream(seed, 10), sigma: no.lateral_acceleration_white_sigma_m_per_s2 },
            beta_err: GaussMarkov::new(stream(seed, 11), no.sideslip_sigma_rad, no.sideslip_time_constant_s, ts),
        }
    }
}

/// The measured signals: wheel rotations with slip, coloured and white
/// errors through the encoders; the reference pose (at the mount) with
/// drift and white noise; a_y and β with their errors. Also the RMS
/// relative error of the measured wheel rotations while moving.
fn measure(opts: &SimOptions, truth: &Truth, ts: f64) -> (Signals, f64) {
    let theta = opts.theta_true;
    let no = &opts.noise;
    let mut s = Sensors::new(no, opts.seed, ts);
    let tr = &truth.signals;
    let mut measured = Signals::with_capacity(tr.px.len());
    let (mut sq, mut count) = (0.0f64, 0usize);
    for (k, &ax) in truth.a_x.iter().enumerate() {
        let slip = no.wheel_slip_per_m_per_s2 * ax + s.gm_common.next();
        let rel_rl = slip + s.gm_rl.next() + s.white_wheel.next();
        let rel_rr = slip + s.gm_rr.next() + s.white_wheel.next();
        let n_rl = s.enc_rl.measure(tr.n_rl[k] * (1.0 + rel_rl), ts);
        let n_rr = s.enc_rr.measure(tr.n_rr[k] * (1.0 + rel_rr), ts);
        measured.n_rl.push(n_rl);
        measured.n_rr.push(n_rr);
        let tu = Input { n_rl: tr.n_rl[k], n_rr: tr.n_rr[k], beta: tr.beta[k], a_y: tr.a_y[k] };
        if model::kinematics(&tu, &theta).speed_m_per_s > MOVING_SPEED_M_PER_S {
            for (m, t) in [(n_rl, tu.n_rl), (n_rr, tu.n_rr)] {
                let e = (m - t) / t;
                sq += e * e;
                count += 1;
            }
        }
        let mut reference = State::new(tr.px[k], tr.py[k], tr.psi[k]);
        if !opts.reference_mount.is_zero() {
            reference = crate::model::extrinsics::reference_pose(&reference, &opts.reference_mount);
        }
        measured.px.push(reference[0] + s.drift_x.next() + s.white_pos.next());
        measured.py.push(reference[1] + s.drift_y.next() + s.white_pos.next());
        measured.psi.push(with_bias(reference[2] + s.drift_psi.next() + s.white_psi.next(), no.heading_bias_rad));
        measured.a_y.push(with_bias(tr.a_y[k] + s.white_ay.next(), no.lateral_acceleration_bias_m_per_s2));
        measured.beta.push(with_bias(tr.beta[k] + s.beta_err.next(), no.sideslip_bias_rad));
    }
    (measured, if count > 0 { (sq / count as f64).sqrt() } else { 0.0 })
}

/// `v` plus a constant error `bias`; `v` itself, bit for bit, without one.
fn with_bias(v: f64, bias: f64) -> f64 {
    if bias == 0.0 {
        v
    } else {
        v + bias
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::segment::{select_segments, SegmentData};
    use crate::identify::{batch_gauss_newton, IdentifyOptions};
    use crate::sim::options::RouteOptions;

    /// Rounding over one f64 model step of ~0.5 m at coordinates up to ~2 km.
    const STEP_REPRODUCTION_TOL_M: f64 = 1e-9;
    /// Noise-free, substeps = 1: the model is exact, G-N converges to rounding.
    const EXACT_RECOVERY_REL_TOL: f64 = 1e-8;
    /// Noise-free, 10 substeps: the one-step model's midpoint-rule error.
    const SUBSTEP_RECOVERY_REL_TOL: f64 = 1e-4;

    fn short(opts: SimOptions, km: f64) -> SimOutput {
        simulate(&SimOptions { length_km: km, ..opts }).expect("simulate")
    }

    fn csv_bytes(d: &Drive) -> Vec<u8> {
        let mut buf = Vec::new();
        d.write_csv_to(&mut buf).expect("write csv");
        buf
    }

    fn truth(d: &Drive) -> &Signals {
        d.truth().as_ref().expect("simulated drives carry the truth")
    }

    #[test]
    fn same_seed_same_bytes_other_seed_differs() {
        let a = short(SimOptions::paper(5), 1.5);
        let b = short(SimOptions::paper(5), 1.5);
        assert_eq!(a, b);
        assert_eq!(csv_bytes(&a.drive), csv_bytes(&b.drive));
        let c = short(SimOptions::paper(6), 1.5);
        assert_ne!(a.drive, c.drive);
        assert_ne!(csv_bytes(&a.drive), csv_bytes(&c.drive));
    }

    #[test]
    fn noise_sources_do_not_change_the_truth() {
        let a = short(SimOptions::paper(3), 1.0);
        let b = short(SimOptions::noise_free(3), 1.0);
        assert_eq!(a.drive.truth(), b.drive.truth());
        assert_ne!(a.drive.n_rl(), b.drive.n_rl());
    }

    #[test]
    fn noise_off_measured_equals_truth_and_model_reproduces_truth() {
        let out = short(SimOptions { substeps: 1, ..SimOptions::noise_free(11) }, 2.0);
        let d = &out.drive;
        let tr = truth(d);
        assert_eq!(d.px(), tr.px);
        assert_eq!(d.py(), tr.py);
        assert_eq!(d.psi(), tr.psi);
        assert_eq!(d.n_rl(), tr.n_rl);
        assert_eq!(d.n_rr(), tr.n_rr);
        assert_eq!(d.beta(), tr.beta);
        assert_eq!(d.a_y(), tr.a_y);
        assert_eq!(d.parts(), vec![0..d.len()]);
        approx::assert_relative_eq!(d.sample_time_s(), 0.025, max_relative = 1e-15);
        let theta = out.sidecar.theta_true;
        let mut worst = 0.0f64;
        for k in 0..d.len() - 1 {
            let next = model::step(&d.pose(k), &d.input(k), &theta, d.sample_time_s());
            worst = worst.max((next - d.pose(k + 1)).abs().max());
        }
        assert!(worst <= STEP_REPRODUCTION_TOL_M, "one-step model error {worst:e}");
        // With substeps the one-step model is close but no longer exact.
        let out = short(SimOptions::noise_free(11), 2.0);
        let d = &out.drive;
        let mut worst = 0.0f64;
        for k in 0..d.len() - 1 {
            let next = model::step(&d.pose(k), &d.input(k), &theta, d.sample_time_s());
            worst = worst.max((next - d.pose(k + 1)).abs().max());
        }
        assert!(worst > 0.0 && worst < 1e-5, "substep model error {worst:e}");
    }

    fn identify(out: &SimOutput) -> (Theta, usize) {
        let d = &out.drive;
        let sel = select_segments(d, &Default::default()).expect("segments");
        assert!(sel.selected.len() >= 5, "too few turning segments: {}", sel.selected.len());
        let data: Vec<_> = sel.selected.iter().map(|s| SegmentData::new(d, s)).collect();
        let opts = IdentifyOptions { max_iterations: 20, ..Default::default() };
        let report = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("identify");
        (report.theta, data.len())
    }

    fn rel_errors(est: &Theta, truth: &Theta) -> [f64; 4] {
        let (e, t) = (est.to_array(), truth.to_array());
        [0, 1, 2, 3].map(|i| ((e[i] - t[i]) / t[i]).abs())
    }

    #[test]
    fn noise_free_calibration_recovers_theta() {
        let truth_theta = Theta::SIM_DEFAULT_TRUE;
        // The start is off by more than 1 % in every parameter.
        for r in rel_errors(&Theta::PAPER_INITIAL, &truth_theta) {
            assert!(r > 0.01, "start too close: {r}");
        }
        let out = short(SimOptions { substeps: 1, ..SimOptions::noise_free(21) }, 3.0);
        let (est, _) = identify(&out);
        for (name, r) in crate::model::THETA_NAMES.iter().zip(rel_errors(&est, &truth_theta)) {
            assert!(r <= EXACT_RECOVERY_REL_TOL, "substeps 1: {name} off by {r:e} ({est})");
        }
        let out = short(SimOptions::noise_free(21), 3.0);
        let (est, _) = identify(&out);
        for (name, r) in crate::model::THETA_NAMES.iter().zip(rel_errors(&est, &truth_theta)) {
            assert!(r <= SUBSTEP_RECOVERY_REL_TOL, "substeps 10: {name} off by {r:e} ({est})");
        }
    }

    #[test]
    fn new_sources_at_their_defaults_change_nothing() {
        let paper = short(SimOptions::paper(17), 1.0);
        // The per-wheel time constant stated equal to the common one.
        let mut stated = SimOptions::paper(17);
        stated.noise.wheel_coloured_differential_time_constant_s = Some(stated.noise.wheel_coloured_time_constant_s);
        assert_eq!(csv_bytes(&short(stated, 1.0).drive), csv_bytes(&paper.drive));
        // Defaults are left out of the sidecar.
        let text = serde_json::to_string(&paper.sidecar).expect("json");
        for key in ["differential_time_constant", "heading_bias", "lateral_acceleration_bias", "sideslip_bias"] {
            assert!(!text.contains(key), "{key} in {text}");
        }
        // A sidecar without the new keys reads back with their defaults.
        let back: SimSidecar = serde_json::from_str(&text).expect("read back");
        assert_eq!(back.settings, paper.sidecar.settings);
    }

    #[test]
    fn no_drift_by_default_changes_nothing() {
        let paper = short(SimOptions::paper(17), 1.0);
        // A drift of zero stated explicitly: the same bytes, the same sidecar.
        let mut stated = SimOptions::paper(17);
        stated.drift = DriftOptions { c_e_relative_per_hour: 0.0, c_d_step: None };
        let again = short(stated, 1.0);
        assert_eq!(csv_bytes(&again.drive), csv_bytes(&paper.drive));
        let text = serde_json::to_string(&paper.sidecar).expect("json");
        assert_eq!(serde_json::to_string(&again.sidecar).expect("json"), text);
        assert!(!text.contains("\"drift\"") && !text.contains("theta_true_end"), "{text}");
        assert!(paper.sidecar.theta_true_end.is_none());
    }

    #[test]
    fn drifting_parameters_are_in_the_truth_and_the_sidecar() {
        let mut o = SimOptions { substeps: 1, ..SimOptions::noise_free(23) };
        o.drift = DriftOptions { c_e_relative_per_hour: -0.03, c_d_step: Some(CdStep { change_m: 2e-3, at_s: 60.0 }) };
        let out = short(o.clone(), 3.0);
        let d = &out.drive;
        let ts = d.sample_time_s();
        // With one substep the model reproduces each truth step with θ at the step's midpoint.
        let tr = truth(d);
        let step_error = |k: usize, theta: &Theta| {
            let x = State::new(tr.px[k], tr.py[k], tr.psi[k]);
            let u = Input { n_rl: tr.n_rl[k], n_rr: tr.n_rr[k], beta: tr.beta[k], a_y: tr.a_y[k] };
            (model::step(&x, &u, theta, ts) - State::new(tr.px[k + 1], tr.py[k + 1], tr.psi[k + 1])).abs().max()
        };
        let (mut drifting, mut fixed) = (0.0f64, 0.0f64);
        for k in 0..d.len() - 1 {
            drifting = drifting.max(step_error(k, &o.drift.theta_at(&o.theta_true, (k as f64 + 0.5) * ts)));
            fixed = fixed.max(step_error(k, &o.theta_true));
        }
        assert!(drifting < 1e-9 && fixed > 1e-4, "{drifting:e} {fixed:e}");
        let end = out.sidecar.theta_true_end.expect("θ at the end");
        let hours = (d.len() - 1) as f64 * ts / 3600.0;
        approx::assert_relative_eq!(end.c_e, o.theta_true.c_e * (1.0 - 0.03 * hours), max_relative = 1e-12);
        approx::assert_relative_eq!(end.c_d, o.theta_true.c_d + 2e-3, max_relative = 1e-12);
        let text = serde_json::to_string(&out.sidecar).expect("json");
        let back: SimSidecar = serde_json::from_str(&text).expect("read back");
        assert_eq!(back.settings.drift, o.drift);
        let bad = SimOptions { drift: DriftOptions { c_e_relative_per_hour: f64::NAN, c_d_step: None }, ..o };
        assert!(simulate(&bad).expect_err("a NaN ramp").to_string().contains("drift.c_e_relative_per_hour"));
    }

    /// A drift that carries a plausible θ out of the plausible region (a
    /// mistyped ramp, a c_d step in metres) or a c_d step after the drive's
    /// end is refused, naming the drift.
    #[test]
    fn a_drift_beyond_plausible_or_a_step_after_the_end_is_refused() {
        let o = SimOptions { length_km: 1.0, ..SimOptions::paper(5) };
        let with = |drift: DriftOptions| SimOptions { drift, ..o.clone() };
        let ramp = with(DriftOptions { c_e_relative_per_hour: 1e9, c_d_step: None });
        let e = simulate(&ramp).expect_err("c_e 1e9 × at the end").to_string();
        assert!(e.contains("drift") && e.contains("θ at the end of the drive") && e.contains("c_e ="), "{e}");
        let step =
            with(DriftOptions { c_e_relative_per_hour: 0.0, c_d_step: Some(CdStep { change_m: 1.0, at_s: 10.0 }) });
        let e = simulate(&step).expect_err("|c_d| of 1 m").to_string();
        assert!(e.contains("drift") && e.contains("|c_d|"), "{e}");
        let late =
            with(DriftOptions { c_e_relative_per_hour: 0.0, c_d_step: Some(CdStep { change_m: 5e-4, at_s: 1e9 }) });
        let e = simulate(&late).expect_err("a step after the end").to_string();
        assert!(e.contains("the c_d step at 1e9 s comes after the drive's end"), "{e}");
        let fine =
            with(DriftOptions { c_e_relative_per_hour: -0.003, c_d_step: Some(CdStep { change_m: 5e-4, at_s: 10.0 }) });
        assert!(simulate(&fine).is_ok());
    }

    #[test]
    fn constant_errors_add_to_their_columns_only() {
        let base = short(SimOptions::paper(19), 1.0);
        let mut o = SimOptions::paper(19);
        o.noise.heading_bias_rad = 0.02;
        o.noise.lateral_acceleration_bias_m_per_s2 = -0.07;
        o.noise.sideslip_bias_rad = 0.0015;
        let biased = short(o, 1.0);
        let (b, d) = (&base.drive, &biased.drive);
        assert_eq!((d.px(), d.py(), d.n_rl(), d.n_rr()), (b.px(), b.py(), b.n_rl(), b.n_rr()));
        for (got, want, bias) in [(d.psi(), b.psi(), 0.02), (d.a_y(), b.a_y(), -0.07), (d.beta(), b.beta(), 0.0015)] {
            assert!(got.iter().zip(want).all(|(g, w)| (g - w - bias).abs() < 1e-12));
        }
        // A heading bias acts as the reference mount's heading offset.
        let mount = SimOptions {
            reference_mount: crate::model::extrinsics::Extrinsics { heading_offset: 0.02, ..Default::default() },
            ..SimOptions::paper(19)
        };
        let mut bias = SimOptions::paper(19);
        bias.noise.heading_bias_rad = 0.02;
        let (m, h) = (short(mount, 1.0), short(bias, 1.0));
        assert_eq!((m.drive.px(), m.drive.py()), (h.drive.px(), h.drive.py()));
        assert!(m.drive.psi().iter().zip(h.drive.psi()).all(|(a, b)| (a - b).abs() < 1e-12));
    }

    #[test]
    fn constant_errors_are_equivalent_to_the_equivalent_truth() {
        // a_y, sideslip and heading biases only, the one-step model exact:
        // the model with the equivalent θ and heading offset, run on the
        // measured inputs from the axle pose the measured reference
        // implies, reproduces the next measured reference pose.
        let mut o = SimOptions { substeps: 1, ..SimOptions::noise_free(29) };
        o.noise.lateral_acceleration_bias_m_per_s2 = -0.08;
        o.noise.sideslip_bias_rad = 1.5e-3;
        o.noise.heading_bias_rad = -0.02;
        let (theta, mount) = o.equivalent_truth();
        approx::assert_relative_eq!(theta.c_d, o.theta_true.c_d + 2.0 * o.theta_true.d * 0.08, max_relative = 1e-12);
        approx::assert_relative_eq!(mount.heading_offset, -0.0185, max_relative = 1e-12);
        let out = short(o.clone(), 2.0);
        let d = &out.drive;
        let axle = |k: usize| State::new(d.px()[k], d.py()[k], d.psi()[k] - mount.heading_offset);
        let mut worst = 0.0f64;
        for k in 0..d.len() - 1 {
            let next = model::step(&axle(k), &d.input(k), &theta, d.sample_time_s());
            worst = worst.max((next - axle(k + 1)).abs().max());
        }
        assert!(worst <= 1e-8, "equivalent truth off by {worst:e}");
        // With the true θ and the heading bias alone it is not.
        let mut worst = 0.0f64;
        let axle = |k: usize| State::new(d.px()[k], d.py()[k], d.psi()[k] + 0.02);
        for k in 0..d.len() - 1 {
            let next = model::step(&axle(k), &d.input(k), &o.theta_true, d.sample_time_s());
            worst = worst.max((next - axle(k + 1)).abs().max());
        }
        assert!(worst > 1e-5, "{worst:e}");
        let plain = SimOptions::paper(1);
        assert_eq!(plain.equivalent_truth(), (plain.theta_true, plain.reference_mount));
    }

    #[test]
    fn differential_time_constant_of_its_own() {
        let mut o = SimOptions { noise: NoiseOptions::off(), ..SimOptions::paper(23) };
        o.noise.wheel_coloured_differential_rel_sigma = 0.002;
        let same = short(o.clone(), 1.0);
        o.noise.wheel_coloured_differential_time_constant_s = Some(0.2);
        let fast = short(o, 1.0);
        // A shorter correlation time: the per-wheel error changes faster
        // from sample to sample.
        let step_rms = |out: &SimOutput| {
            let d = &out.drive;
            let tr = truth(d);
            let e: Vec<f64> =
                d.n_rl().iter().zip(&tr.n_rl).filter(|(_, t)| **t > 1.0).map(|(m, t)| m / t - 1.0).collect();
            let steps = e.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>() / (e.len() - 1) as f64;
            steps.sqrt()
        };
        let (a, b) = (step_rms(&same), step_rms(&fast));
        assert!(b > 3.0 * a, "τ 5 s: {a:e}, τ 0.2 s: {b:e}");
    }

    #[test]
    fn noise_free_world_recovers_theta() {
        // A random world with every error at 0 keeps its time constants:
        // the measured columns equal the truth, and calibration finds θ_true.
        let (mut n, _) = NoiseOptions::random_world(5);
        let tau = n.wheel_coloured_differential_time_constant_s;
        n = NoiseOptions {
            wheel_coloured_time_constant_s: n.wheel_coloured_time_constant_s,
            wheel_coloured_differential_time_constant_s: tau,
            position_drift_time_constant_s: n.position_drift_time_constant_s,
            heading_drift_time_constant_s: n.heading_drift_time_constant_s,
            sideslip_time_constant_s: n.sideslip_time_constant_s,
            ..NoiseOptions::off()
        };
        assert!(tau.is_some());
        let out = short(SimOptions { substeps: 1, noise: n, ..SimOptions::paper(21) }, 3.0);
        let tr = truth(&out.drive);
        assert_eq!((out.drive.n_rl(), out.drive.psi(), out.drive.beta()), (&tr.n_rl[..], &tr.psi[..], &tr.beta[..]));
        let (est, _) = identify(&out);
        for (name, r) in crate::model::THETA_NAMES.iter().zip(rel_errors(&est, &Theta::SIM_DEFAULT_TRUE)) {
            assert!(r <= EXACT_RECOVERY_REL_TOL, "{name} off by {r:e} ({est})");
        }
    }

    #[test]
    fn random_world_drive_is_reproducible() {
        let o = SimOptions { noise: NoiseOptions::by_name("random:11").expect("world"), ..SimOptions::paper(2) };
        let (a, b) = (short(o.clone(), 1.0), short(o, 1.0));
        assert_eq!(csv_bytes(&a.drive), csv_bytes(&b.drive));
        assert_eq!(a.sidecar.settings.noise, NoiseOptions::random_world(11).0);
    }

    #[test]
    fn paper_noise_has_the_paper_size() {
        let out = short(SimOptions::paper(4), 3.0);
        let d = &out.drive;
        let tr = truth(d);
        let rms = out.sidecar.stats.wheel_rotation_rel_error_rms;
        assert!((0.005..0.02).contains(&rms), "wheel rms relative error {rms}");
        let n = d.len() as f64;
        let pos_rms = (d.px().iter().zip(&tr.px).zip(d.py().iter().zip(&tr.py)))
            .map(|((a, b), (c, e))| (a - b).powi(2) + (c - e).powi(2))
            .sum::<f64>()
            / n;
        let pos_rms = pos_rms.sqrt();
        assert!((0.05..1.0).contains(&pos_rms), "reference position error rms {pos_rms} m");
        let psi_rms = (d.psi().iter().zip(&tr.psi).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / n).sqrt();
        assert!((2e-4..0.02).contains(&psi_rms), "reference heading error rms {psi_rms} rad");
        // Measured wheels differ from the truth, and standstill reads zero.
        assert!(d.n_rl().iter().zip(&tr.n_rl).any(|(a, b)| (a - b).abs() > 1e-3));
        // At standstill the true rotation is exactly 0 (v = ω = 0) and so is the encoder count.
        #[allow(clippy::float_cmp)]
        for (m, t) in d.n_rr().iter().zip(&tr.n_rr) {
            if *t == 0.0 {
                assert_eq!(*m, 0.0);
            }
        }
    }

    #[test]
    fn presets_are_ordered() {
        let white = short(SimOptions { noise: NoiseOptions::white_wheel_only(), ..SimOptions::paper(8) }, 1.0);
        let paper = short(SimOptions::paper(8), 1.0);
        let high = short(SimOptions { noise: NoiseOptions::high(), ..SimOptions::paper(8) }, 1.0);
        let (w, p, h) = (
            white.sidecar.stats.wheel_rotation_rel_error_rms,
            paper.sidecar.stats.wheel_rotation_rel_error_rms,
            high.sidecar.stats.wheel_rotation_rel_error_rms,
        );
        assert!(w > 0.0 && w < p && p * 1.8 < h, "white {w}, paper {p}, high {h}");
        let tr = truth(&white.drive);
        assert_eq!(white.drive.px(), tr.px);
        assert_eq!(white.drive.a_y(), tr.a_y);
        assert_eq!(NoiseOptions::by_name("white").expect("preset"), NoiseOptions::white_wheel_only());
        assert_eq!(NoiseOptions::by_name("off").expect("preset"), NoiseOptions::off());
        let e = NoiseOptions::by_name("loud").expect_err("unknown preset");
        assert!(e.to_string().contains("loud") && e.to_string().contains("paper"), "{e}");
    }

    #[test]
    fn stats_are_sane_and_sidecar_round_trips() {
        let opts = SimOptions { length_km: 2.0, ..SimOptions::paper(9) };
        let out = simulate(&opts).expect("simulate");
        let st = &out.sidecar.stats;
        let d = &out.drive;
        assert_eq!(st.samples, d.len());
        approx::assert_relative_eq!(st.duration_s, d.t()[d.len() - 1], max_relative = 1e-12);
        assert!((st.distance_m - 2000.0).abs() < 10.0, "distance {}", st.distance_m);
        let mean_speed = st.distance_m / st.duration_s;
        assert!((5.0..25.0).contains(&mean_speed), "mean speed {mean_speed} m/s");
        assert!((0.15..2.0).contains(&st.max_yaw_rate_rad_per_s), "yaw rate {}", st.max_yaw_rate_rad_per_s);
        let ay_max = opts.speed.max_lateral_acceleration_m_per_s2;
        assert!(
            (0.5 * ay_max..=ay_max * (1.0 + 1e-9)).contains(&st.max_abs_lateral_acceleration_m_per_s2),
            "lateral acceleration {}",
            st.max_abs_lateral_acceleration_m_per_s2
        );
        let tr = truth(d);
        let truth_ay = tr.a_y.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        assert!(truth_ay <= st.max_abs_lateral_acceleration_m_per_s2 * (1.0 + 1e-12));
        // Heading unwrapped, time uniform.
        assert!(tr.psi.windows(2).all(|w| (w[1] - w[0]).abs() < 0.1));
        assert!(d.t().windows(2).all(|w| ((w[1] - w[0]) - 0.025).abs() < 1e-9));
        assert_eq!(out.sidecar.theta_true, opts.theta_true);
        assert_eq!(out.sidecar.settings, opts);

        let dir = std::env::temp_dir().join(format!("odocal-sim-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let csv = dir.join("drive.csv");
        let json = SimSidecar::path_beside(&csv);
        assert_eq!(json, dir.join("drive.json"));
        out.sidecar.write_json(&json).expect("write sidecar");
        let back = SimSidecar::read_json(&json).expect("read sidecar");
        assert_eq!(back, out.sidecar);
        let text = std::fs::read_to_string(&json).expect("read");
        assert!(text.contains("\"theta_true\"") && text.contains("\"c_e\""), "{text}");
        let e = SimSidecar::read_json(&dir.join("missing.json")).expect_err("missing file");
        assert!(e.to_string().contains("missing.json"), "{e}");
        std::fs::remove_dir_all(&dir).expect("clean up");
    }

    #[test]
    fn route_turns_enough() {
        let out = short(SimOptions::paper(13), 5.0);
        let sel = select_segments(&out.drive, &Default::default()).expect("segments");
        let frac = sel.selected.len() as f64 / sel.all.len() as f64;
        assert!((0.25..0.8).contains(&frac), "selected {} of {} segments", sel.selected.len(), sel.all.len());
        // And it also has straight stretches and stops.
        assert!(sel.selected.len() < sel.all.len());
        let tr = truth(&out.drive);
        // A standstill integrates v = 0 exactly: the pose does not change at all.
        #[allow(clippy::float_cmp)]
        let stopped = tr.px.windows(2).zip(tr.py.windows(2)).filter(|(x, y)| x[0] == x[1] && y[0] == y[1]).count();
        assert!(stopped > 40, "no standstill: {stopped} samples");
    }

    #[test]
    fn invalid_options_name_the_field() {
        let cases: Vec<(SimOptions, &str)> = vec![
            (SimOptions { length_km: 0.0, ..Default::default() }, "length_km"),
            (SimOptions { sample_rate_hz: f64::NAN, ..Default::default() }, "sample_rate_hz"),
            (SimOptions { substeps: 0, ..Default::default() }, "substeps"),
            (
                SimOptions { theta_true: Theta { t_r: -1.0, ..Theta::SIM_DEFAULT_TRUE }, ..Default::default() },
                "theta_true",
            ),
            (
                SimOptions {
                    route: RouteOptions { bend_radius_m: [50.0, 10.0], ..Default::default() },
                    ..Default::default()
                },
                "route.bend_radius_m",
            ),
            (
                SimOptions {
                    noise: NoiseOptions { wheel_white_rel_sigma: -0.1, ..NoiseOptions::paper() },
                    ..Default::default()
                },
                "noise.wheel_white_rel_sigma",
            ),
            (
                SimOptions {
                    noise: NoiseOptions { heading_bias_rad: f64::INFINITY, ..NoiseOptions::paper() },
                    ..Default::default()
                },
                "noise.heading_bias_rad",
            ),
            (
                SimOptions {
                    noise: NoiseOptions {
                        wheel_coloured_differential_time_constant_s: Some(0.0),
                        ..NoiseOptions::paper()
                    },
                    ..Default::default()
                },
                "noise.wheel_coloured_differential_time_constant_s",
            ),
            (
                SimOptions {
                    speed: SpeedOptions { stop_probability: 1.5, ..Default::default() },
                    ..Default::default()
                },
                "speed.stop_probability",
            ),
        ];
        for (opts, field) in cases {
            let e = simulate(&opts).expect_err(field);
            assert!(matches!(&e, Error::InvalidOption { field: f, .. } if *f == field), "{field}: {e}");
        }
        assert!(SimOptions::default().validate().is_ok());
        assert_eq!(SimOptions::default(), SimOptions::paper(0));
    }
}
