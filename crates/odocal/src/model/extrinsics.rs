//! Reference-sensor extrinsics: where the pose reference sits on the vehicle.
//!
//! The odometry model (docs/method.md §1) moves the rear-axle centre with the vehicle
//! heading ψ. A real pose reference often measures another point with
//! another heading: on the PSU mapping van it is the midpoint of two rear
//! GNSS antennas, heading along their baseline. [`Extrinsics`] describes
//! that mount in the vehicle frame:
//!
//! ```text
//! p_ref = p_axle + R(ψ)·[l_x, l_y]        (lever arm: x forward, y left, m)
//! ψ_ref = ψ + δ                            (heading offset, rad)
//! ```
//!
//! Identification and validation start each segment from the *axle* pose
//! the reference implies ([`axle_pose`], the inverse map) and compare the
//! model's *reference* pose ([`reference_pose`]) with the measured one. With
//! every value 0 both maps are the identity and every result is the paper's model (docs/method.md §1).
//!
//! Observability: the lever arm acts only through heading *changes* (on a
//! drive that never turns, `R(ψ_k) − R(ψ_0) = 0` and it has no effect at
//! all); the heading offset rotates the whole dead-reckoned path about its
//! start, so it is seen through position drift on any drive.
//!
//! The analytic Jacobians ([`reference_jacobians`], [`axle_pose_jacobian`])
//! are tested against central finite differences.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::param::{Param, ParamSet};
use super::State;
use crate::error::{Error, Result};

/// The pose reference's mount on the vehicle (see the module docs).
///
/// Field names are the parameter names of [`Param::LeverX`],
/// [`Param::LeverY`] and [`Param::HeadingOffset`] (JSON, `--fix`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Extrinsics {
    /// Lever arm along the vehicle's forward axis, from the rear-axle centre
    /// to the reference point, m.
    pub lever_x: f64,
    /// Lever arm along the vehicle's left axis, m.
    pub lever_y: f64,
    /// Reference heading minus vehicle heading, rad.
    pub heading_offset: f64,
}

impl Extrinsics {
    /// The reference at the rear-axle centre, aligned with the vehicle (the
    /// `Default`; outside the crate: `Extrinsics::default()`).
    pub(crate) const ZERO: Extrinsics = Extrinsics { lever_x: 0.0, lever_y: 0.0, heading_offset: 0.0 };

    /// True when every value is exactly 0 (the paper's reference point, the rear-axle centre).
    pub(crate) fn is_zero(&self) -> bool {
        self.to_array().iter().all(|v| *v == 0.0)
    }

    /// `[lever_x, lever_y, heading_offset]` (outside the crate:
    /// `<[f64; 3]>::from(extrinsics)`).
    pub(crate) fn to_array(self) -> [f64; 3] {
        [self.lever_x, self.lever_y, self.heading_offset]
    }

    /// Builds the extrinsics from `[lever_x, lever_y, heading_offset]`.
    pub(crate) fn from_array(a: [f64; 3]) -> Self {
        Extrinsics { lever_x: a[0], lever_y: a[1], heading_offset: a[2] }
    }

    /// The value of an extrinsics parameter; `None` for a θ parameter.
    pub(crate) fn get(&self, p: Param) -> Option<f64> {
        p.extrinsics_index().map(|i| self.to_array()[i])
    }

    /// Checks that every value is finite.
    pub(crate) fn validate(&self) -> Result<()> {
        for (p, v) in Param::EXTRINSICS.iter().zip(self.to_array()) {
            if !v.is_finite() {
                return Err(Error::InvalidOption { field: "extrinsics", reason: format!("{p} = {v} is not finite") });
            }
        }
        Ok(())
    }
}

/// `[lever_x, lever_y, heading_offset]`.
impl From<Extrinsics> for [f64; 3] {
    fn from(e: Extrinsics) -> Self {
        e.to_array()
    }
}

/// `[lever_x, lever_y, heading_offset]`.
impl From<&Extrinsics> for [f64; 3] {
    fn from(e: &Extrinsics) -> Self {
        e.to_array()
    }
}

impl std::fmt::Display for Extrinsics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "lever arm = [{:.4}, {:.4}] m, heading offset = {:.4} mrad",
            self.lever_x,
            self.lever_y,
            self.heading_offset * 1e3
        )
    }
}

/// The extrinsics part of an identification or calibration: initial and
/// estimated values, their model σ and covariance, and their sensitivity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExtrinsicsEstimate {
    /// The value the estimate started from (and the value of held entries).
    pub initial: Extrinsics,
    /// The estimate.
    pub value: Extrinsics,
    /// Which of the three were estimated (the others were held).
    pub free: ParamSet,
    /// Model 1σ of each (0 for held entries), same units as the values.
    pub std_dev: Extrinsics,
    /// Covariance of `[lever_x, lever_y, heading_offset]`, 3×3, row-major.
    pub covariance: [[f64; 3]; 3],
    /// Cross-covariance of θ `[c_e, c_d, t_r, d]` (rows) with the
    /// extrinsics (columns), 4×3.
    pub cross_covariance: [[f64; 3]; 4],
    /// RMS change of the predicted poses (weighted metres per residual
    /// pose) when each moves by its resolution
    /// ([`crate::identify::IdentifyOptions::extrinsics_resolution`]); 0 for held entries.
    pub sensitivity_m: [f64; 3],
    /// The cluster-robust σ and covariance
    /// (`crate::identify::RobustCovariance`), when computed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robust: Option<RobustExtrinsics>,
    /// A joint calibration of several drives ([`crate::Drive::concat`])
    /// with the heading offset estimated: each drive's own offset (the
    /// reference's heading bias changes from drive to drive), in drive
    /// order. `value.heading_offset` is then their mean (the value carried
    /// to another drive by `--carry-heading-offset`) and
    /// `std_dev.heading_offset` its σ. Empty otherwise. In JSON
    /// `per_drive`; the reports' `heading_offset_per_drive` names each
    /// drive.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(crate) per_drive: Vec<DriveHeadingOffset>,
}

research_pub! {
    /// One drive's reference heading offset in a joint calibration
    /// (`ExtrinsicsEstimate::per_drive`).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    struct DriveHeadingOffset {
        /// The drive's index among the drives joined
        /// ([`crate::Drive::drive_starts`]).
        pub drive: usize,
        /// Its heading offset, rad.
        pub value: f64,
        /// Its model 1σ, rad.
        pub std_dev: f64,
        /// Its cluster-robust 1σ, rad, when computed.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub robust_std_dev: Option<f64>,
    }
}

impl DriveHeadingOffset {
    /// The 1σ that stands for the value: the cluster-robust one when
    /// computed, else the model one (as [`ExtrinsicsEstimate::result_std_dev`]).
    pub(crate) fn result_std_dev(&self) -> f64 {
        self.robust_std_dev.unwrap_or(self.std_dev)
    }
}

/// The extrinsics part of the cluster-robust covariance
/// ([`crate::identify::RobustCovariance`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobustExtrinsics {
    /// Cluster-robust 1σ of each (0 for held entries).
    pub std_dev: Extrinsics,
    /// Covariance of `[lever_x, lever_y, heading_offset]`, 3×3, row-major.
    pub covariance: [[f64; 3]; 3],
}

impl ExtrinsicsEstimate {
    research_pub! {
        /// A joint calibration's heading offset of each drive, in drive order
        /// (empty for one drive or the heading offset held).
        fn per_drive(&self) -> &[DriveHeadingOffset] {
            &self.per_drive
        }
    }

    /// The 1σ that stands for the estimate: the cluster-robust σ when it
    /// was computed (as for θ's result σ), else the model σ; 0 for held entries.
    pub(crate) fn result_std_dev(&self) -> Extrinsics {
        self.robust.as_ref().map_or(self.std_dev, |r| r.std_dev)
    }

    /// The extrinsics that apply to drive `k` of a joint calibration: its
    /// own heading offset when `per_drive` has it,
    /// else `value`.
    pub(crate) fn for_drive(&self, k: usize) -> Extrinsics {
        match self.per_drive.iter().find(|p| p.drive == k) {
            Some(p) => Extrinsics { heading_offset: p.value, ..self.value },
            None => self.value,
        }
    }

    /// Held extrinsics: `value` = `initial`, no σ.
    #[cfg(test)]
    pub(crate) fn held(initial: Extrinsics) -> Self {
        ExtrinsicsEstimate {
            initial,
            value: initial,
            free: ParamSet::EMPTY,
            std_dev: Extrinsics::ZERO,
            covariance: [[0.0; 3]; 3],
            cross_covariance: [[0.0; 3]; 4],
            sensitivity_m: [0.0; 3],
            robust: None,
            per_drive: Vec::new(),
        }
    }
}

/// The reference pose `[p_ref,x, p_ref,y, ψ_ref]` of the model's axle
/// state `x` under extrinsics `e`.
#[inline]
pub(crate) fn reference_pose(x: &State, e: &Extrinsics) -> Vector3<f64> {
    let (s, c) = x[2].sin_cos();
    Vector3::new(x[0] + c * e.lever_x - s * e.lever_y, x[1] + s * e.lever_x + c * e.lever_y, x[2] + e.heading_offset)
}

/// `(∂h/∂x, ∂h/∂e)` of [`reference_pose`] `h(x, e)`, each 3×3 (columns
/// of `∂h/∂e`: lever_x, lever_y, heading_offset).
#[inline]
pub(crate) fn reference_jacobians(x: &State, e: &Extrinsics) -> (Matrix3<f64>, Matrix3<f64>) {
    let (s, c) = x[2].sin_cos();
    let h_x =
        Matrix3::new(1.0, 0.0, -s * e.lever_x - c * e.lever_y, 0.0, 1.0, c * e.lever_x - s * e.lever_y, 0.0, 0.0, 1.0);
    let h_e = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    (h_x, h_e)
}

/// The axle state whose reference pose is `y` (the inverse of
/// [`reference_pose`]): `ψ = ψ_ref − δ`, `p = p_ref − R(ψ)·l`.
#[inline]
pub(crate) fn axle_pose(y: &Vector3<f64>, e: &Extrinsics) -> State {
    let psi = y[2] - e.heading_offset;
    let (s, c) = psi.sin_cos();
    State::new(y[0] - (c * e.lever_x - s * e.lever_y), y[1] - (s * e.lever_x + c * e.lever_y), psi)
}

/// `∂g/∂e` of [`axle_pose`] `g(y, e)`, 3×3.
#[inline]
pub(crate) fn axle_pose_jacobian(y: &Vector3<f64>, e: &Extrinsics) -> Matrix3<f64> {
    let psi = y[2] - e.heading_offset;
    let (s, c) = psi.sin_cos();
    // ∂p/∂δ = +dR/dψ·l (ψ falls by δ).
    Matrix3::new(-c, s, -s * e.lever_x - c * e.lever_y, -s, -c, c * e.lever_x - s * e.lever_y, 0.0, 0.0, -1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn arb() -> impl Strategy<Value = (State, Extrinsics)> {
        ((-1e3..1e3f64, -1e3..1e3f64, -20.0..20.0f64), (-3.0..3.0f64, -2.0..2.0f64, -0.1..0.1f64)).prop_map(
            |((px, py, psi), (lx, ly, d))| {
                (State::new(px, py, psi), Extrinsics { lever_x: lx, lever_y: ly, heading_offset: d })
            },
        )
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1.0)
    }

    proptest! {
        #[test]
        fn jacobians_match_central_differences((x, e) in arb()) {
            let (h_x, h_e) = reference_jacobians(&x, &e);
            let g_e = axle_pose_jacobian(&x, &e);
            let h = 1e-6;
            for i in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[i] += h;
                xm[i] -= h;
                let fd = (reference_pose(&xp, &e) - reference_pose(&xm, &e)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!(close(h_x[(r, i)], fd[r]), "h_x[{r},{i}] {} vs {}", h_x[(r, i)], fd[r]);
                }
                let (mut ap, mut am) = (e.to_array(), e.to_array());
                ap[i] += h;
                am[i] -= h;
                let (ep, em) = (Extrinsics::from_array(ap), Extrinsics::from_array(am));
                let fd = (reference_pose(&x, &ep) - reference_pose(&x, &em)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!(close(h_e[(r, i)], fd[r]), "h_e[{r},{i}] {} vs {}", h_e[(r, i)], fd[r]);
                }
                let fd = (axle_pose(&x, &ep) - axle_pose(&x, &em)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!(close(g_e[(r, i)], fd[r]), "g_e[{r},{i}] {} vs {}", g_e[(r, i)], fd[r]);
                }
            }
        }

        #[test]
        fn axle_pose_inverts_reference_pose((x, e) in arb()) {
            let back = axle_pose(&reference_pose(&x, &e), &e);
            prop_assert!((back - x).amax() < 1e-9, "{back} vs {x}");
        }
    }
}
