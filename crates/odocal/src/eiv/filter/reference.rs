//! The covariance recursion's terms linearised along the reference (the
//! reference heading and the measured inputs) with their θ-gradients, and
//! the input derivatives of the θ-sensitivity for the corrected score.

use nalgebra::{Matrix3x4, Vector3};

use super::dual::Dual;
use crate::model::{Input, Theta};

/// `∂(∂f/∂θ)/∂u` (3×4) for the noisy inputs `u = [n_rl, n_rr, a_y]` at
/// `(ψ, u, θ)`: how the noise on an input moves the θ-sensitivity of a step.
pub(super) fn theta_jacobian_input_derivatives(
    psi: f64,
    u: &Input,
    th: &Theta,
    ts: f64,
) -> [(Matrix3x4<f64>, f64, f64); 3] {
    let (c_rl, c_rr) = th.wheel_circumferences(u.a_y);
    let (nl, nr, tr) = (u.n_rl, u.n_rr, th.t_r);
    let v = (nl * c_rl + nr * c_rr) / 2.0;
    let num = nr * c_rr - nl * c_rl;
    let omega = num / tr;
    let h = ts / 2.0;
    let phi = psi + omega * h + u.beta;
    let (s, c) = phi.sin_cos();
    let dcrl = [1.0, 0.5, 0.0, u.a_y];
    let dcrr = [1.0, -0.5, 0.0, -u.a_y];
    let dv: [f64; 4] = std::array::from_fn(|j| (nl * dcrl[j] + nr * dcrr[j]) / 2.0);
    let dw: [f64; 4] =
        std::array::from_fn(|j| (nr * dcrr[j] - nl * dcrl[j]) / tr - if j == 2 { num / (tr * tr) } else { 0.0 });
    // Per input: (∂v/∂u, ∂ω/∂u, ∂dv_j/∂u, ∂dω_j/∂u).
    let d = th.d;
    let inputs: [(f64, f64, [f64; 4], [f64; 4]); 3] = [
        (
            c_rl / 2.0,
            -c_rl / tr,
            std::array::from_fn(|j| dcrl[j] / 2.0),
            std::array::from_fn(|j| -dcrl[j] / tr + if j == 2 { c_rl / (tr * tr) } else { 0.0 }),
        ),
        (
            c_rr / 2.0,
            c_rr / tr,
            std::array::from_fn(|j| dcrr[j] / 2.0),
            std::array::from_fn(|j| dcrr[j] / tr - if j == 2 { c_rr / (tr * tr) } else { 0.0 }),
        ),
        (
            (nl * d - nr * d) / 2.0,
            (-nr * d - nl * d) / tr,
            std::array::from_fn(|j| if j == 3 { (nl - nr) / 2.0 } else { 0.0 }),
            std::array::from_fn(|j| match j {
                3 => (-nr - nl) / tr,
                2 => (nr * d + nl * d) / (tr * tr),
                _ => 0.0,
            }),
        ),
    ];
    inputs.map(|(v_u, w_u, dv_u, dw_u)| {
        let phi_u = w_u * h;
        let mut a = Matrix3x4::zeros();
        for j in 0..4 {
            a[(0, j)] =
                ts * (-s * phi_u * dv[j] + c * dv_u[j] - (v_u * s + v * c * phi_u) * h * dw[j] - v * s * h * dw_u[j]);
            a[(1, j)] =
                ts * (c * phi_u * dv[j] + s * dv_u[j] + (v_u * c - v * s * phi_u) * h * dw[j] + v * c * h * dw_u[j]);
            a[(2, j)] = ts * dw_u[j];
        }
        // ∂F_x[0,2]/∂u and ∂F_x[1,2]/∂u.
        (a, -ts * (v_u * s + v * c * phi_u), ts * (v_u * c - v * s * phi_u))
    })
}

/// The terms of the covariance recursion at one step, evaluated on the
/// reference (reference heading ψ, measured inputs) at θ, with their
/// θ-gradients when `N = 4`: `F̄[0,2], F̄[1,2]`, `∂f/∂n_l`, `∂f/∂n_r`,
/// `∂f/∂a_y` (as [`step_jacobians`](crate::model::step_jacobians) and the module docs).
pub(super) struct ReferenceTerms<const N: usize> {
    pub(super) f02: Dual<N>,
    pub(super) f12: Dual<N>,
    pub(super) fn_l: [Dual<N>; 3],
    pub(super) fn_r: [Dual<N>; 3],
    pub(super) f_a: [Dual<N>; 3],
}

pub(super) fn reference_terms<const N: usize>(psi: f64, u: &Input, th: &Theta, ts: f64) -> ReferenceTerms<N> {
    let (c_e, c_d, t_r, d) =
        (Dual::<N>::var(th.c_e, 0), Dual::<N>::var(th.c_d, 1), Dual::<N>::var(th.t_r, 2), Dual::<N>::var(th.d, 3));
    let (nl, nr) = (u.n_rl, u.n_rr);
    let c_rl = c_e + c_d * 0.5 + d * u.a_y;
    let c_rr = c_e - c_d * 0.5 - d * u.a_y;
    let v = (c_rl * nl + c_rr * nr) * 0.5;
    let num = c_rr * nr - c_rl * nl;
    let omega = num / t_r;
    let phi = omega * (ts / 2.0) + Dual::cst(psi + u.beta);
    let (s, c) = phi.sin_cos();
    let row = |dv: Dual<N>, domega: Dual<N>| -> [Dual<N>; 3] {
        let dphi = domega * (ts / 2.0);
        [(c * dv - v * s * dphi) * ts, (s * dv + v * c * dphi) * ts, domega * ts]
    };
    let fn_l = row(c_rl * 0.5, -(c_rl / t_r));
    let fn_r = row(c_rr * 0.5, c_rr / t_r);
    // ∂f/∂a_y = ∂f/∂c_rl·d − ∂f/∂c_rr·d with ∂f/∂c_w = (∂v/∂c_w, ∂ω/∂c_w) through `row`.
    let f_a = {
        let a = row(Dual::cst(nl * 0.5), Dual::cst(-nl) / t_r);
        let b = row(Dual::cst(nr * 0.5), Dual::cst(nr) / t_r);
        std::array::from_fn(|r| (a[r] - b[r]) * d)
    };
    ReferenceTerms { f02: -(v * s) * ts, f12: v * c * ts, fn_l, fn_r, f_a }
}

pub(super) fn vec_of<const N: usize>(a: &[Dual<N>; 3]) -> Vector3<f64> {
    Vector3::new(a[0].v, a[1].v, a[2].v)
}

pub(super) fn dvec_of(a: &[Dual<4>; 3], j: usize) -> Vector3<f64> {
    Vector3::new(a[0].d[j], a[1].d[j], a[2].d[j])
}

/// `C_w(θ_ref)/C_w(θ)` per wheel `[left, right]` with its θ-gradient: the
/// factor that turns the measured wheel rotation into the true rotation
/// fitted at θ, `n̂ = ñ·C(θ_ref)/C(θ)` (the distance `ñ·C(θ_ref)` is held,
/// so the relative wheel noise in metres does not grow with C(θ)).
pub(super) fn fitted_input_factors(a_y: f64, th: &Theta, th_ref: &Theta) -> [Dual<4>; 2] {
    let (c_e, c_d, d) = (Dual::var(th.c_e, 0), Dual::var(th.c_d, 1), Dual::var(th.d, 3));
    let c_rl = c_e + c_d * 0.5 + d * a_y;
    let c_rr = c_e - c_d * 0.5 - d * a_y;
    let (r_rl, r_rr) = th_ref.wheel_circumferences(a_y);
    [Dual::cst(r_rl) / c_rl, Dual::cst(r_rr) / c_rr]
}

/// The values of [`ReferenceTerms`]: `F̄[0,2], F̄[1,2]`, `∂f/∂n_l`, `∂f/∂n_r`, `∂f/∂a_y`.
pub(super) struct ReferenceValues {
    pub(super) f02: f64,
    pub(super) f12: f64,
    pub(super) fn_l: Vector3<f64>,
    pub(super) fn_r: Vector3<f64>,
    pub(super) f_a: Vector3<f64>,
}

impl<const N: usize> ReferenceTerms<N> {
    pub(super) fn values(&self) -> ReferenceValues {
        ReferenceValues {
            f02: self.f02.v,
            f12: self.f12.v,
            fn_l: vec_of(&self.fn_l),
            fn_r: vec_of(&self.fn_r),
            f_a: vec_of(&self.f_a),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The value-only reference terms are the values of the differentiated
    /// ones, to the bit (the same operations on the value).
    #[test]
    // Compared exactly on purpose.
    #[allow(clippy::float_cmp)]
    fn value_only_reference_terms_equal_the_differentiated_values() {
        let th = Theta::SIM_DEFAULT_TRUE;
        let u = Input { n_rl: 5.1, n_rr: 5.4, beta: 0.01, a_y: 1.3 };
        let a = reference_terms::<4>(0.7, &u, &th, 0.025).values();
        let b = reference_terms::<0>(0.7, &u, &th, 0.025).values();
        assert_eq!((a.f02, a.f12, a.fn_l, a.fn_r, a.f_a), (b.f02, b.f12, b.fn_l, b.fn_r, b.f_a));
    }
}
