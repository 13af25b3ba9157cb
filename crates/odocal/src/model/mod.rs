//! The wheel-odometry model (docs/method.md §1) and its analytic derivatives.
//!
//! Expert API: for programs that run the model or its derivatives themselves
//! (dead reckoning, their own estimator). [`crate::Theta`] is also at the root.
//!
//! State `x = [p_x, p_y, ψ]`, inputs `u = [n_rl, n_rr, β, a_y]`, parameters
//! `θ = [c_e, c_d, t_r, d]`:
//!
//! ```text
//! c_rl = c_e + c_d/2 + d·a_y          c_rr = c_e − c_d/2 − d·a_y
//! v    = (n_rl·c_rl + n_rr·c_rr)/2    ω    = (n_rr·c_rr − n_rl·c_rl)/t_r
//! φ    = ψ + ω·t_s/2 + β
//! p_x' = p_x + v·t_s·cos φ   p_y' = p_y + v·t_s·sin φ   ψ' = ψ + ω·t_s
//! ```
//!
//! Every derivative the method needs is analytic (`step_jacobians`,
//! research-visible) and tested against central finite differences.

use nalgebra::{Matrix3, Matrix3x2, Matrix3x4, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

pub(crate) mod extrinsics;
pub(crate) mod limits;
pub(crate) mod param;

pub use limits::PhysicalLimits;

/// Model state `[p_x (m), p_y (m), ψ (rad, unwrapped)]`.
pub type State = Vector3<f64>;

/// The calibrated parameters θ of the odometry model, SI units.
///
/// Field names follow the paper's symbols because they are the stable JSON
/// interface (docs/reference.md); units are in each field's doc.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Theta {
    /// Effective rear wheel circumference c_e, metres per revolution.
    pub c_e: f64,
    /// Circumference difference c_d (left minus right), metres.
    pub c_d: f64,
    /// Rear track width t_r, metres.
    pub t_r: f64,
    /// Load-transfer coefficient d, metres of circumference per m/s² of
    /// lateral acceleration.
    pub d: f64,
}

/// Names of the four parameters, in vector order.
pub const THETA_NAMES: [&str; 4] = ["c_e", "c_d", "t_r", "d"];

impl Theta {
    /// The paper's nominal (datasheet) parameters `[1.98, 0, 1.55, 0]`.
    pub const PAPER_NOMINAL: Theta = Theta { c_e: 1.98, c_d: 0.0, t_r: 1.55, d: 0.0 };
    /// The paper's Gauss-Newton initial guess θ_0 = `[2.0, 0, 1.6, 0]`.
    pub const PAPER_INITIAL: Theta = Theta { c_e: 2.0, c_d: 0.0, t_r: 1.6, d: 0.0 };
    research_pub! {
        /// The simulator's default true parameters `[1.950, −2.0 mm, 1.530, 0.8 mm/(m/s²)]`
        /// (outside the crate: `SimOptions::default().theta_true`).
        const SIM_DEFAULT_TRUE: Theta = Theta { c_e: 1.950, c_d: -0.002, t_r: 1.530, d: 0.0008 };
    }

    /// Builds θ from `[c_e, c_d, t_r, d]`.
    pub(crate) fn from_vector(v: &Vector4<f64>) -> Self {
        Theta { c_e: v[0], c_d: v[1], t_r: v[2], d: v[3] }
    }

    /// θ from `[c_e, c_d, t_r, d]` (the inverse of `Theta::to_array`;
    /// outside the crate: `Theta::from([c_e, c_d, t_r, d])`).
    pub(crate) fn from_array(a: [f64; 4]) -> Self {
        Theta { c_e: a[0], c_d: a[1], t_r: a[2], d: a[3] }
    }

    /// `[c_e, c_d, t_r, d]` as a vector.
    pub(crate) fn to_vector(self) -> Vector4<f64> {
        Vector4::new(self.c_e, self.c_d, self.t_r, self.d)
    }

    /// `[c_e, c_d, t_r, d]` as an array (outside the crate:
    /// `<[f64; 4]>::from(theta)`).
    pub(crate) fn to_array(self) -> [f64; 4] {
        [self.c_e, self.c_d, self.t_r, self.d]
    }

    /// Effective rear wheel circumferences `(c_rl, c_rr)` at lateral
    /// acceleration `a_y` (3a, 3b), m.
    #[inline]
    pub(crate) fn wheel_circumferences(&self, a_y: f64) -> (f64, f64) {
        (self.c_e + self.c_d / 2.0 + self.d * a_y, self.c_e - self.c_d / 2.0 - self.d * a_y)
    }

    /// Checks that θ is usable: all finite, `c_e > 0` and `t_r > 0`
    /// (outside the crate: [`Theta::check_physical_limits`], which includes it).
    pub(crate) fn validate(&self) -> Result<()> {
        for (name, v) in THETA_NAMES.iter().zip(self.to_array()) {
            if !v.is_finite() {
                return Err(Error::InvalidTheta(format!("{name} = {v} is not finite")));
            }
        }
        if self.c_e <= 0.0 {
            return Err(Error::InvalidTheta(format!("c_e = {} m must be positive", self.c_e)));
        }
        if self.t_r <= 0.0 {
            return Err(Error::InvalidTheta(format!("t_r = {} m must be positive", self.t_r)));
        }
        Ok(())
    }

    /// Checks θ against the physical limits every θ a user gives is held
    /// to (`--theta`, a parameter file, Python's θ arguments, a recorded
    /// history row): c_e within 0.05 … 20 m, t_r within 0.05 … 10 m, |c_d|
    /// at most 5 % of c_e, |d| at most 0.05 m per m/s².
    ///
    /// # Errors
    /// [`Error::InvalidTheta`] naming the parameter, with a hint that θ is
    /// in SI units.
    pub fn check_physical_limits(&self) -> Result<()> {
        limits::check_theta(self)
    }
}

/// θ from `[c_e, c_d, t_r, d]`.
impl From<[f64; 4]> for Theta {
    fn from(a: [f64; 4]) -> Self {
        Theta::from_array(a)
    }
}

/// `[c_e, c_d, t_r, d]`.
impl From<Theta> for [f64; 4] {
    fn from(theta: Theta) -> Self {
        theta.to_array()
    }
}

/// `[c_e, c_d, t_r, d]`.
impl From<&Theta> for [f64; 4] {
    fn from(theta: &Theta) -> Self {
        theta.to_array()
    }
}

/// How text prints θ and its σ (θ's `Display`, the θ table): per parameter
/// its name, the factor from SI, the unit and the decimals.
pub(crate) const THETA_UNITS: [(&str, f64, &str, usize); 4] =
    [("c_e", 1.0, "m", 6), ("c_d", 1e3, "mm", 4), ("t_r", 1.0, "m", 6), ("d", 1e3, "mm/(m/s²)", 4)];

/// Each parameter named with its value and unit: `c_e = 1.950000 m, c_d =
/// -2.0000 mm, t_r = 1.530000 m, d = 0.8000 mm/(m/s²)`. It names the
/// parameters itself, so text around it introduces it without a `θ =`
/// (`at c_e = …`, `θ: c_e = …`, `θ_0 (c_e = …)`).
///
/// ```
/// use odocal::Theta;
/// let th = Theta { c_e: 1.95, c_d: -0.002, t_r: 1.53, d: 0.0008 };
/// assert_eq!(th.to_string(), "c_e = 1.950000 m, c_d = -2.0000 mm, t_r = 1.530000 m, d = 0.8000 mm/(m/s²)");
/// ```
impl std::fmt::Display for Theta {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (i, (&(name, scale, unit, digits), x)) in THETA_UNITS.iter().zip(self.to_array()).enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            write!(f, "{name} = {:.digits$} {unit}", x * scale)?;
        }
        Ok(())
    }
}

impl Theta {
    /// θ with a 1σ `sigma` beside each value, in the units and digits of
    /// θ's `Display`.
    ///
    /// ```
    /// use odocal::Theta;
    /// let th = Theta { c_e: 1.95, c_d: -0.002, t_r: 1.53, d: 0.0008 };
    /// let s = Theta { c_e: 3e-4, c_d: 1e-4, t_r: 4e-3, d: 5e-5 };
    /// assert_eq!(
    ///     th.display_with_sigma(&s).to_string(),
    ///     "c_e = 1.950000 ± 0.000300 m, c_d = -2.0000 ± 0.1000 mm, t_r = 1.530000 ± 0.004000 m, \
    ///      d = 0.8000 ± 0.0500 mm/(m/s²)"
    /// );
    /// ```
    pub fn display_with_sigma<'a>(&'a self, sigma: &'a Theta) -> impl std::fmt::Display + 'a {
        ThetaWithSigma { theta: self, sigma }
    }
}

/// [`Theta::display_with_sigma`].
struct ThetaWithSigma<'a> {
    theta: &'a Theta,
    sigma: &'a Theta,
}

impl std::fmt::Display for ThetaWithSigma<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let values = self.theta.to_array().into_iter().zip(self.sigma.to_array());
        for (i, (&(name, scale, unit, digits), (x, s))) in THETA_UNITS.iter().zip(values).enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            write!(f, "{name} = {:.digits$} ± {:.digits$} {unit}", x * scale, s * scale)?;
        }
        Ok(())
    }
}

impl std::str::FromStr for Theta {
    type Err = Error;
    /// Parses `c_e,c_d,t_r,d` in SI units (the CLI's `--theta`) and checks
    /// its absolute physical sanity (`crate::model::limits::check_theta`).
    fn from_str(s: &str) -> Result<Self> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if parts.len() != 4 {
            return Err(Error::InvalidTheta(format!(
                "expected 4 comma-separated values c_e,c_d,t_r,d (SI units), got {} in '{s}'",
                parts.len()
            )));
        }
        let mut v = [0.0; 4];
        for (i, p) in parts.iter().enumerate() {
            v[i] = p
                .parse::<f64>()
                .map_err(|_| Error::InvalidTheta(format!("{} = '{p}' is not a number", THETA_NAMES[i])))?;
        }
        let theta = Theta { c_e: v[0], c_d: v[1], t_r: v[2], d: v[3] };
        crate::model::limits::check_theta(&theta)?;
        Ok(theta)
    }
}

/// One sample of model inputs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Input {
    /// Rear-left wheel rotation speed, rev/s.
    pub n_rl: f64,
    /// Rear-right wheel rotation speed, rev/s.
    pub n_rr: f64,
    /// Sideslip angle, rad.
    pub beta: f64,
    /// Lateral acceleration, m/s², positive to the left.
    pub a_y: f64,
}

/// Velocity and yaw rate of the model for one input sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Kinematics {
    /// Speed of the reference point, m/s.
    pub speed_m_per_s: f64,
    /// Yaw rate, rad/s.
    pub yaw_rate_rad_per_s: f64,
}

/// Speed and yaw rate (2a, 2b) for one input and θ.
#[inline]
pub(crate) fn kinematics(u: &Input, theta: &Theta) -> Kinematics {
    let (c_rl, c_rr) = theta.wheel_circumferences(u.a_y);
    Kinematics {
        speed_m_per_s: (u.n_rl * c_rl + u.n_rr * c_rr) / 2.0,
        yaw_rate_rad_per_s: (u.n_rr * c_rr - u.n_rl * c_rl) / theta.t_r,
    }
}

/// The wheel rotations `(n_rl, n_rr)`, rev/s, that give speed `v` and yaw
/// rate `ω` at lateral acceleration `a_y` under θ: the inverse of (2a, 2b),
/// `n_rl = (v − ω·t_r/2)/c_rl`, `n_rr = (v + ω·t_r/2)/c_rr`.
#[inline]
pub(crate) fn wheel_rotations(speed_m_per_s: f64, yaw_rate_rad_per_s: f64, a_y: f64, theta: &Theta) -> (f64, f64) {
    let (c_rl, c_rr) = theta.wheel_circumferences(a_y);
    let half = yaw_rate_rad_per_s * theta.t_r / 2.0;
    ((speed_m_per_s - half) / c_rl, (speed_m_per_s + half) / c_rr)
}

/// One step of the model (1): the state after `t_s` seconds.
#[inline]
pub fn step(x: &State, u: &Input, theta: &Theta, t_s: f64) -> State {
    let k = kinematics(u, theta);
    let phi = x[2] + k.yaw_rate_rad_per_s * t_s / 2.0 + u.beta;
    let (s, c) = phi.sin_cos();
    Vector3::new(x[0] + k.speed_m_per_s * t_s * c, x[1] + k.speed_m_per_s * t_s * s, x[2] + k.yaw_rate_rad_per_s * t_s)
}

research_pub! {
    /// The next state and the analytic Jacobians of one model step.
    #[derive(Debug, Clone, Copy, PartialEq)]
    struct StepJacobians {
        /// The next state `f(x, u, θ)`.
        pub next: State,
        /// `∂f/∂x`, 3×3.
        pub f_x: Matrix3<f64>,
        /// `∂f/∂[n_rl, n_rr]`, 3×2.
        pub f_n: Matrix3x2<f64>,
        /// `∂f/∂θ`, 3×4 (columns c_e, c_d, t_r, d).
        pub f_theta: Matrix3x4<f64>,
    }
}

research_pub! {
    /// One model step with all analytic Jacobians (state, wheel rotations, θ).
    #[inline]
    fn step_jacobians(x: &State, u: &Input, theta: &Theta, t_s: f64) -> StepJacobians {
        let (c_rl, c_rr) = theta.wheel_circumferences(u.a_y);
        let v = (u.n_rl * c_rl + u.n_rr * c_rr) / 2.0;
        let num = u.n_rr * c_rr - u.n_rl * c_rl;
        let omega = num / theta.t_r;
        let phi = x[2] + omega * t_s / 2.0 + u.beta;
        let (s, c) = phi.sin_cos();
        let next = Vector3::new(x[0] + v * t_s * c, x[1] + v * t_s * s, x[2] + omega * t_s);

        let f_x = Matrix3::new(1.0, 0.0, -v * t_s * s, 0.0, 1.0, v * t_s * c, 0.0, 0.0, 1.0);

        // Chain rule through (v, ω): ∂p_x' = t_s (c ∂v − v s t_s/2 ∂ω), etc.
        let row = |dv: f64, domega: f64| -> Vector3<f64> {
            let dphi = domega * t_s / 2.0;
            Vector3::new(t_s * (c * dv - v * s * dphi), t_s * (s * dv + v * c * dphi), t_s * domega)
        };
        let f_n = Matrix3x2::from_columns(&[row(c_rl / 2.0, -c_rl / theta.t_r), row(c_rr / 2.0, c_rr / theta.t_r)]);

        // ∂c_rl/∂θ = [1, 1/2, 0, a_y], ∂c_rr/∂θ = [1, −1/2, 0, −a_y].
        let dcrl = [1.0, 0.5, 0.0, u.a_y];
        let dcrr = [1.0, -0.5, 0.0, -u.a_y];
        let mut f_theta = Matrix3x4::zeros();
        for j in 0..4 {
            let dv = (u.n_rl * dcrl[j] + u.n_rr * dcrr[j]) / 2.0;
            let mut domega = (u.n_rr * dcrr[j] - u.n_rl * dcrl[j]) / theta.t_r;
            if j == 2 {
                domega -= num / (theta.t_r * theta.t_r);
            }
            f_theta.set_column(j, &row(dv, domega));
        }
        StepJacobians { next, f_x, f_n, f_theta }
    }
}

research_pub! {
    /// Wraps an angle to (−π, π].
    #[inline]
    fn wrap_angle(a: f64) -> f64 {
        let two_pi = 2.0 * std::f64::consts::PI;
        let mut r = a.rem_euclid(two_pi);
        if r > std::f64::consts::PI {
            r -= two_pi;
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Central differences with h = 1e-6 relative carry ~1e-9 truncation and
    /// round-off error on these O(1) functions; 1e-6 relative is the issue's bar.
    const FD_REL_TOL: f64 = 1e-6;

    fn close(a: f64, b: f64, scale: f64) -> bool {
        (a - b).abs() <= FD_REL_TOL * scale.max(1e-3)
    }

    fn arb_case() -> impl Strategy<Value = (State, Input, Theta, f64)> {
        (
            (-1e3..1e3f64, -1e3..1e3f64, -20.0..20.0f64),
            (-5.0..15.0f64, -5.0..15.0f64, -0.1..0.1f64, -8.0..8.0f64),
            (1.5..2.5f64, -0.01..0.01f64, 1.2..2.0f64, -0.002..0.002f64),
            prop_oneof![Just(0.025), Just(0.01), Just(0.1)],
        )
            .prop_map(|((px, py, psi), (a, b, beta, ay), (ce, cd, tr, d), ts)| {
                (
                    Vector3::new(px, py, psi),
                    Input { n_rl: a, n_rr: b, beta, a_y: ay },
                    Theta { c_e: ce, c_d: cd, t_r: tr, d },
                    ts,
                )
            })
    }

    proptest! {
        #[test]
        fn step_jacobians_match_finite_differences((x, u, th, ts) in arb_case()) {
            let j = step_jacobians(&x, &u, &th, ts);
            prop_assert!((j.next - step(&x, &u, &th, ts)).norm() < 1e-12);
            // ∂f/∂x
            for i in 0..3 {
                let h = 1e-6 * x[i].abs().max(1.0);
                let mut xp = x; xp[i] += h;
                let mut xm = x; xm[i] -= h;
                let fd = (step(&xp, &u, &th, ts) - step(&xm, &u, &th, ts)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!(close(j.f_x[(r, i)], fd[r], fd.norm().max(1.0)),
                        "f_x[{r},{i}] {} vs {}", j.f_x[(r, i)], fd[r]);
                }
            }
            // ∂f/∂n and ∂f/∂θ do not depend on position: evaluate at the origin
            // so that round-off of large coordinates does not swamp the differences.
            let x = Vector3::new(0.0, 0.0, x[2]);
            let j = step_jacobians(&x, &u, &th, ts);
            // ∂f/∂n
            for i in 0..2 {
                let h = 1e-6;
                let (mut up, mut um) = (u, u);
                if i == 0 { up.n_rl += h; um.n_rl -= h; } else { up.n_rr += h; um.n_rr -= h; }
                let fd = (step(&x, &up, &th, ts) - step(&x, &um, &th, ts)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!(close(j.f_n[(r, i)], fd[r], fd.norm().max(ts)),
                        "f_n[{r},{i}] {} vs {}", j.f_n[(r, i)], fd[r]);
                }
            }
            // ∂f/∂θ
            let tv = th.to_vector();
            for i in 0..4 {
                let h = 1e-6;
                let mut tp = tv; tp[i] += h;
                let mut tm = tv; tm[i] -= h;
                let fd = (step(&x, &u, &Theta::from_vector(&tp), ts)
                    - step(&x, &u, &Theta::from_vector(&tm), ts)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!(close(j.f_theta[(r, i)], fd[r], fd.norm().max(ts)),
                        "f_theta[{r},{i}] {} vs {}", j.f_theta[(r, i)], fd[r]);
                }
            }
        }

        #[test]
        fn mirror_symmetry(v in 0.0..20.0f64, dn in -0.5..0.5f64, ay in -5.0..5.0f64) {
            // Swapping the wheels and mirroring c_d, d and a_y mirrors the yaw rate.
            let th = Theta { c_e: 1.95, c_d: 0.0, t_r: 1.53, d: 0.0008 };
            let u = Input { n_rl: v + dn, n_rr: v - dn, beta: 0.0, a_y: ay };
            let um = Input { n_rl: v - dn, n_rr: v + dn, beta: 0.0, a_y: -ay };
            let k = kinematics(&u, &th);
            let km = kinematics(&um, &th);
            prop_assert!((k.speed_m_per_s - km.speed_m_per_s).abs() < 1e-9);
            prop_assert!((k.yaw_rate_rad_per_s + km.yaw_rate_rad_per_s).abs() < 1e-9);
        }
    }

    proptest! {
        #[test]
        fn wheel_rotations_invert_kinematics(v in -5.0..30.0f64, omega in -1.0..1.0f64, ay in -6.0..6.0f64) {
            let th = Theta::SIM_DEFAULT_TRUE;
            let (n_rl, n_rr) = wheel_rotations(v, omega, ay, &th);
            let k = kinematics(&Input { n_rl, n_rr, beta: 0.0, a_y: ay }, &th);
            prop_assert!((k.speed_m_per_s - v).abs() < 1e-12);
            prop_assert!((k.yaw_rate_rad_per_s - omega).abs() < 1e-12);
        }
    }

    #[test]
    fn straight_line_with_equal_wheels() {
        let th = Theta::PAPER_NOMINAL;
        let u = Input { n_rl: 5.0, n_rr: 5.0, beta: 0.0, a_y: 0.0 };
        let x = step(&Vector3::zeros(), &u, &th, 0.025);
        approx::assert_relative_eq!(x[0], 5.0 * 1.98 * 0.025, epsilon = 1e-15);
        approx::assert_abs_diff_eq!(x[1], 0.0);
        approx::assert_abs_diff_eq!(x[2], 0.0);
    }

    #[test]
    fn theta_parse_and_validate() {
        let t: Theta = "1.95,-0.002,1.53,0.0008".parse().expect("valid");
        approx::assert_relative_eq!(t.c_d, -0.002);
        assert!("1,2,3".parse::<Theta>().is_err());
        assert!("1,0,-1,0".parse::<Theta>().is_err());
        assert!("1,x,1,0".parse::<Theta>().is_err());
    }

    #[test]
    fn wrap_angle_range() {
        use std::f64::consts::PI;
        approx::assert_abs_diff_eq!(wrap_angle(3.0 * PI), PI, epsilon = 1e-12);
        approx::assert_abs_diff_eq!(wrap_angle(-PI), PI, epsilon = 1e-12);
        approx::assert_abs_diff_eq!(wrap_angle(0.1), 0.1, epsilon = 1e-15);
    }
}
