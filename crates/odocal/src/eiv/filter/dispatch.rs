//! Which build of the window loop runs: the one compiled for AVX2 and FMA
//! (chosen at run time where the CPU has them; one of the crate's two
//! `#[allow(unsafe_code)]` calls, the other entering the 3-step QP
//! solver's AVX2 build) or the baseline one.

use nalgebra::Matrix3;

use super::kernels::{joseph_in_place, joseph_in_place_with, propagate_in_place, Transition};
use super::sums::{InnovationRecord, WindowSums};
use super::window::run_window_s;
use super::{M3xZ, MZx3, Mode, Variances, IW, MZ, NZ};
use crate::eiv::{EivInput, Window};
use crate::error::Result;
use crate::model::Theta;

/// Runs the filter over one window at θ (mean). The covariance recursion
/// is linearised along the reference (reference heading, measured wheel
/// rotations) at `theta_ref`, or at θ when `mode.follows_theta` (then
/// `theta_ref` is ignored). Accumulates the objective and, with
/// `mode.derivs`, its gradient and the Fisher information. With `record`,
/// every innovation and its derivatives are returned.
///
/// Speed: P and every `∂P/∂p_j` are symmetric and are propagated as such
/// (lower triangle, mirrored; [`propagate_in_place`], [`joseph_in_place`]); a sensitivity
/// column whose covariance derivative is identically zero (η_5 when the
/// heading noise is tied to the position noise) is not propagated; the
/// θ-gradients of the covariance terms are differentiated only when
/// `∂P/∂θ` is propagated; nothing is allocated per sample.
pub(crate) fn run_window(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    #[cfg(target_arch = "x86_64")]
    if kernels() == Kernels::Avx2 {
        // SAFETY: `kernels()` returns `Avx2` only when the running CPU reports
        // both AVX2 and FMA (`is_x86_feature_detected!`), the features
        // `run_window_avx2` is compiled for.
        #[allow(unsafe_code)]
        return unsafe { run_window_avx2(input, window, theta, theta_ref, v, mode, record) };
    }
    run_window_baseline(input, window, theta, theta_ref, v, mode, record)
}

/// The instruction set the filter's kernels run with ([`kernels`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kernels {
    /// The build's target features (SSE2 on a default x86-64 build).
    Baseline,
    /// AVX2 and FMA, detected at run time (x86-64 only).
    Avx2,
}

/// The kernels [`run_window`] uses: AVX2 where the CPU has AVX2 and FMA
/// (x86-64), unless the environment variable `ODOCAL_SIMD=baseline` asks
/// for the build's baseline instruction set. Decided once per process.
///
/// Both compile the same Rust code; Rust never contracts a multiply and an
/// add into a fused one on its own, so the two give results identical to
/// the bit (test `avx2_kernels_equal_the_baseline_to_the_bit`). AVX2's
/// four-wide registers make the covariance kernels about 1.3× faster
/// (docs/performance.md).
pub(crate) fn kernels() -> Kernels {
    if crate::simd::use_avx2(true) {
        Kernels::Avx2
    } else {
        Kernels::Baseline
    }
}

/// [`run_window_baseline`] compiled for AVX2 and FMA: the window loop and
/// every kernel it calls are inlined ([`Inlined`]), so all of it is
/// compiled for them.
///
/// # Safety
/// The running CPU must support AVX2 and FMA
/// ([`crate::simd::avx2_available`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn run_window_avx2(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    // One function per state size: two smaller functions for the compiler
    // (they can be optimised in parallel) than one with both inlined.
    if v.quant_counting {
        run_window_avx2_s::<NZ>(input, window, theta, theta_ref, v, mode, record)
    } else {
        run_window_avx2_s::<IW>(input, window, theta, theta_ref, v, mode, record)
    }
}

/// [`run_window_avx2`] at the state size `S`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
pub(super) fn run_window_avx2_s<const S: usize>(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    run_window_s::<S, Inlined>(input, window, theta, theta_ref, v, mode, record)
}

/// [`run_window`] with the build's baseline target features.
pub(crate) fn run_window_baseline(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    run_window_sized::<OutOfLine>(input, window, theta, theta_ref, v, mode, record)
}

/// [`run_window_s`] at the state size of `v`, the big kernels called as `K` says.
#[inline(always)]
pub(super) fn run_window_sized<K: KernelCalls>(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    // The remainder states exist only with counting quantisation: the other
    // models run the 10-state filter (the same arithmetic, no 12-row storage).
    if v.quant_counting {
        run_window_s::<NZ, K>(input, window, theta, theta_ref, v, mode, record)
    } else {
        run_window_s::<IW, K>(input, window, theta, theta_ref, v, mode, record)
    }
}

/// How the window loop calls its three big covariance kernels (the
/// propagation and the two Joseph updates).
///
/// The AVX2 copy inlines them ([`Inlined`]), so that they are compiled for
/// AVX2 with it. The baseline copy calls one out-of-line instance of each
/// ([`OutOfLine`]): inlined at their call sites they make the baseline
/// 5–10 % slower and every build of the crate slower to compile.
pub(super) trait KernelCalls {
    fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<S>);
    fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>);
    fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>);
}

/// [`KernelCalls`] inlining the kernels (the AVX2 copy).
pub(super) struct Inlined;

/// [`KernelCalls`] calling out-of-line kernels (the baseline copy).
pub(super) struct OutOfLine;

impl KernelCalls for Inlined {
    #[inline(always)]
    fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<S>) {
        propagate_in_place(p, t);
    }
    #[inline(always)]
    fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>) {
        joseph_in_place(a, k, d);
    }
    #[inline(always)]
    fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>) {
        joseph_in_place_with(a, k, d, ha);
    }
}

impl KernelCalls for OutOfLine {
    #[inline(never)]
    fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<S>) {
        propagate_in_place(p, t);
    }
    #[inline(never)]
    fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>) {
        joseph_in_place(a, k, d);
    }
    #[inline(never)]
    fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>) {
        joseph_in_place_with(a, k, d, ha);
    }
}
