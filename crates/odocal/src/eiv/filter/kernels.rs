//! The structured covariance kernels of the filter: `F P Fᵀ` for the
//! structured transition, the Joseph update `(I − KH) A (I − KH)ᵀ` for
//! `H = [I₃ 0 I₃]`, and `K D Kᵀ`. The symmetric ones compute the lower
//! triangle and mirror it, so their results are exactly symmetric.

use nalgebra::{Matrix3, SMatrix};

use super::{M3x2, M3xZ, MZx3, IB, IW, MZ};

/// `A B` for an inner dimension of 3, written out so that it inlines into
/// the window loop (nalgebra's product is a call there, and in the AVX2
/// build a call to its baseline code). Each entry is summed as nalgebra
/// sums it, `(a₀b₀ + a₁b₁) + a₂b₂`: the same bits.
#[inline(always)]
pub(super) fn mul3<const R: usize, const C: usize>(
    a: &SMatrix<f64, R, 3>,
    b: &SMatrix<f64, 3, C>,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    for c in 0..C {
        let (b0, b1, b2) = (b[(0, c)], b[(1, c)], b[(2, c)]);
        for r in 0..R {
            out[(r, c)] = a[(r, 0)] * b0 + a[(r, 1)] * b1 + a[(r, 2)] * b2;
        }
    }
    out
}

/// `Aᵀ B` for a 3-row `A`, as [`mul3`] sums `A.transpose() * B`.
#[inline(always)]
pub(super) fn mul3_tn<const R: usize, const C: usize>(
    a: &SMatrix<f64, 3, R>,
    b: &SMatrix<f64, 3, C>,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    for c in 0..C {
        let (b0, b1, b2) = (b[(0, c)], b[(1, c)], b[(2, c)]);
        for r in 0..R {
            out[(r, c)] = a[(0, r)] * b0 + a[(1, r)] * b1 + a[(2, r)] * b2;
        }
    }
    out
}

/// The structured transition of one step,
/// `F = [[F_x, F_xs, 0, F_xβ, F_xw], [0, diag(a_s), 0, 0, 0], [0, 0, a_b I, 0, 0], [0, 0, 0, a_β, 0],
/// [0, 0, 0, 0, diag(a_w)]]`, `F_x = I + e_0 f02 e_2ᵀ + e_1 f12 e_2ᵀ`, `F_xβ = −(f02, f12, 0)ᵀ` (the
/// sideslip enters the step as the heading does, `φ = ψ + ωt_s/2 + β`), `diag` the diagonal of rows 3..S.
#[derive(Clone, Copy)]
pub(super) struct Transition<const S: usize> {
    pub(super) f02: f64,
    pub(super) f12: f64,
    pub(super) fxs: Matrix3<f64>,
    pub(super) fxw: M3x2,
    pub(super) diag: [f64; S],
}

impl<const S: usize> Transition<S> {
    /// Rows 0..3 of `F v` for the vector with entries `v(k)` (the dense rows
    /// of F; [`propagate_in_place`] writes the same sums out column-wise).
    #[inline(always)]
    pub(super) fn top(&self, v: impl Fn(usize) -> f64) -> [f64; 3] {
        let (fxs, fxw) = (&self.fxs, &self.fxw);
        let fr = [self.f02, self.f12, 0.0];
        let (v2, v3, v4, v5, vb) = (v(2), v(3), v(4), v(5), v(IB));
        let (v9, v10) = if S > IW { (v(IW), v(IW + 1)) } else { (0.0, 0.0) };
        std::array::from_fn(|i| {
            v(i) + fr[i] * v2 + fxs[(i, 0)] * v3 + fxs[(i, 1)] * v4 + fxs[(i, 2)] * v5 - fr[i] * vb
                + if S > IW { fxw[(i, 0)] * v9 + fxw[(i, 1)] * v10 } else { 0.0 }
        })
    }
}

/// `F P Fᵀ` for the structured transition `t` and a symmetric `P` as a new
/// matrix: [`propagate_in_place`] on a copy. (The filter calls
/// [`propagate_in_place`]; this copy is for the kernel tests.)
#[cfg(test)]
pub(super) fn propagate<const S: usize>(p: &MZ<S>, t: &Transition<S>) -> MZ<S> {
    let mut out = *p;
    propagate_in_place(&mut out, t);
    out
}

/// `F P Fᵀ` for the structured transition `t` ([`Transition`]) and a
/// symmetric `P`, overwriting `p` (no S×S temporary, no copy of the result).
///
/// Only the lower triangle is computed (through `W = P F_topᵀ`, S×3, `F_top`
/// the first three rows of F) and mirrored, so the result is exactly
/// symmetric.
///
/// Safe in place: the pose rows and columns of the result depend on P only
/// through `W`, computed first, and every other lower-triangle entry
/// `diag_c·diag_i·P[i, c]` only on the same entry of P.
#[inline(always)]
pub(super) fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<S>) {
    // W = P F_topᵀ: row r of W is F_top applied to row r of P. Computed
    // column by column (`W[:, c] = Σ_k F[c, k] P[:, k]`, the sum in the order
    // of [`Transition::top`], so every entry is the same to the bit): the
    // inner loop runs down contiguous columns of P and vectorises.
    let mut w = MZx3::<S>::zeros();
    let fr = [t.f02, t.f12, 0.0];
    for c in 0..3 {
        let (a2, a3, a4, a5) = (fr[c], t.fxs[(c, 0)], t.fxs[(c, 1)], t.fxs[(c, 2)]);
        let (a9, a10) = (t.fxw[(c, 0)], t.fxw[(c, 1)]);
        let (pc, p2, p3, p4, p5) = (p.column(c), p.column(2), p.column(3), p.column(4), p.column(5));
        let pb = p.column(IB);
        let mut wc = w.column_mut(c);
        if S > IW {
            let (p9, p10) = (p.column(IW), p.column(IW + 1));
            for r in 0..S {
                wc[r] = pc[r] + a2 * p2[r] + a3 * p3[r] + a4 * p4[r] + a5 * p5[r] - a2 * pb[r]
                    + (a9 * p9[r] + a10 * p10[r]);
            }
        } else {
            for r in 0..S {
                wc[r] = pc[r] + a2 * p2[r] + a3 * p3[r] + a4 * p4[r] + a5 * p5[r] - a2 * pb[r] + 0.0;
            }
        }
    }
    let out = p;
    // Pose block: F_top W (lower triangle).
    for c in 0..3 {
        let col = t.top(|k| w[(k, c)]);
        for i in c..3 {
            out[(i, c)] = col[i];
        }
    }
    // Rows 3..S: diagonal rows of F.
    // (Column by column, down contiguous memory.)
    let diag = &t.diag;
    for c in 0..3 {
        for i in 3..S {
            out[(i, c)] = diag[i] * w[(i, c)];
        }
    }
    for c in 3..S {
        for i in c..S {
            out[(i, c)] = diag[c] * (diag[i] * out[(i, c)]);
        }
    }
    mirror_lower(out);
}

/// Copies the strict lower triangle onto the upper one.
#[inline(always)]
pub(super) fn mirror_lower<const S: usize>(m: &mut MZ<S>) {
    for c in 1..S {
        for r in 0..c {
            m[(r, c)] = m[(c, r)];
        }
    }
}

/// `H A` for `H = [I₃ 0 I₃]`: rows 0..3 plus rows 6..9.
#[inline(always)]
pub(super) fn h_rows<const S: usize, const C: usize>(a: &SMatrix<f64, S, C>) -> SMatrix<f64, 3, C> {
    let mut out = SMatrix::<f64, 3, C>::zeros();
    for r in 0..3 {
        for c in 0..C {
            out[(r, c)] = a[(r, c)] + a[(r + 6, c)];
        }
    }
    out
}

/// `B Hᵀ` for a 3×S `B`: columns 0..3 plus columns 6..9.
#[inline(always)]
pub(super) fn h_cols<const S: usize>(b: &M3xZ<S>) -> Matrix3<f64> {
    let mut out = Matrix3::zeros();
    for r in 0..3 {
        for c in 0..3 {
            out[(r, c)] = b[(r, c)] + b[(r, c + 6)];
        }
    }
    out
}

/// `(I − K H) A (I − K H)ᵀ` for `H = [I₃ 0 I₃]` and a symmetric `A` as a
/// new matrix: [`joseph_in_place`] on a copy, without `d`. (The filter calls
/// [`joseph_in_place`]; this copy is for the kernel tests.)
#[cfg(test)]
pub(super) fn joseph<const S: usize>(a: &MZ<S>, k: &MZx3<S>) -> MZ<S> {
    let mut out = *a;
    joseph_in_place(&mut out, k, None);
    out
}

/// `(I − K H) A (I − K H)ᵀ` for `H = [I₃ 0 I₃]` and a symmetric `A`,
/// overwriting `a` (no S×S temporaries, no copy of the result).
///
/// In the factored order of the Joseph form (`X = A − K(HA)`, then
/// `X − (XHᵀ)Kᵀ`; the expanded `A − KHA − (KHA)ᵀ + K(HAHᵀ)Kᵀ` is
/// numerically unstable here), but only the entries of X that the lower
/// triangle of the result needs, and only that triangle, mirrored.
///
/// Safe in place: `HA` is taken first; then every entry of X depends on A
/// only through the same entry, and every lower-triangle entry of the result
/// on X only through the same entry and `XHᵀ` (taken before them); the upper
/// triangle is mirrored last.
///
/// With `d`, `K D Kᵀ` is added as well, to the lower triangle
/// ([`add_kdk_lower`]) before the one mirror: the same to the bit as adding
/// it to both triangles after the mirrored Joseph form (the kernel tests'
/// `add_kdk`).
#[inline(always)]
pub(super) fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>) {
    // HA (3×S): rows 0..3 plus rows 6..9.
    let ha = h_rows(a);
    joseph_in_place_with(a, k, d, &ha);
}

/// [`joseph_in_place`] given `ha = HA` (`h_rows(a)`), which the filter has
/// already formed for the innovation covariance.
#[inline(always)]
pub(super) fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>) {
    debug_assert!(*ha == h_rows(a), "joseph_in_place_with: ha is not HA");
    // X = A − K HA: every row of columns 0..3 and 6..9 (for XHᵀ), and the
    // lower triangle of the other columns (the rest of A is left as it is:
    // the mirror overwrites it).
    let x = a;
    for c in 0..S {
        let first = if c < 3 || (6..9).contains(&c) { 0 } else { c };
        let (h0, h1, h2) = (ha[(0, c)], ha[(1, c)], ha[(2, c)]);
        for r in first..S {
            x[(r, c)] -= k[(r, 0)] * h0 + k[(r, 1)] * h1 + k[(r, 2)] * h2;
        }
    }
    // XHᵀ (S×3).
    let mut xh = MZx3::<S>::zeros();
    for m in 0..3 {
        for r in 0..S {
            xh[(r, m)] = x[(r, m)] + x[(r, m + 6)];
        }
    }
    // Lower triangle of X − (XHᵀ)Kᵀ.
    for c in 0..S {
        let (k0, k1, k2) = (k[(c, 0)], k[(c, 1)], k[(c, 2)]);
        for r in c..S {
            x[(r, c)] -= xh[(r, 0)] * k0 + xh[(r, 1)] * k1 + xh[(r, 2)] * k2;
        }
    }
    if let Some(d) = d {
        add_kdk_lower(x, k, d);
    }
    mirror_lower(x);
}

/// `(I − K H) A (I − K H)ᵀ` for `H = [I₃ 0 I₃]` and any `A` (the
/// cross-covariances X of the corrected score are not symmetric).
#[inline(always)]
pub(super) fn joseph_general<const S: usize>(a: &MZ<S>, k: &MZx3<S>) -> MZ<S> {
    let x = a - k * h_rows(a);
    let mut xh = MZx3::<S>::zeros();
    for r in 0..S {
        for c in 0..3 {
            xh[(r, c)] = x[(r, c)] + x[(r, c + 6)];
        }
    }
    x - xh * k.transpose()
}

/// `F A Fᵀ` for the structured transition `t` ([`Transition`]) and any `A`,
/// not only a symmetric one as in [`propagate_in_place`], as a new matrix.
#[inline(always)]
pub(super) fn propagate_general<const S: usize>(p: &MZ<S>, t: &Transition<S>) -> MZ<S> {
    // M = F P (row operations).
    let mut m = MZ::<S>::zeros();
    for j in 0..S {
        let col = t.top(|k| p[(k, j)]);
        for (r, v) in col.into_iter().enumerate() {
            m[(r, j)] = v;
        }
        for r in 3..S {
            m[(r, j)] = t.diag[r] * p[(r, j)];
        }
    }
    // F P Fᵀ = M Fᵀ (column operations).
    let mut out = MZ::<S>::zeros();
    for i in 0..S {
        let row = t.top(|k| m[(i, k)]);
        for (c, v) in row.into_iter().enumerate() {
            out[(i, c)] = v;
        }
        for c in 3..S {
            out[(i, c)] = t.diag[c] * m[(i, c)];
        }
    }
    out
}

/// `F C` for an S×3 `C` and the structured transition `t` ([`Transition`]).
#[inline(always)]
pub(super) fn propagate_cols<const S: usize>(c: &MZx3<S>, t: &Transition<S>) -> MZx3<S> {
    let mut out = MZx3::<S>::zeros();
    for j in 0..3 {
        let col = t.top(|k| c[(k, j)]);
        for (r, v) in col.into_iter().enumerate() {
            out[(r, j)] = v;
        }
        for r in 3..S {
            out[(r, j)] = t.diag[r] * c[(r, j)];
        }
    }
    out
}

/// `dst += K D Kᵀ` for a symmetric 3×3 `D` and an exactly symmetric `dst`
/// (every covariance and covariance derivative of the filter), exactly
/// symmetric: the lower triangle is added ([`add_kdk_lower`]) and mirrored,
/// which for a symmetric `dst` is the same to the bit as adding the same
/// product to both triangles. (The filter adds it inside
/// [`joseph_in_place`]; this copy is for the kernel tests.)
#[cfg(test)]
pub(super) fn add_kdk<const S: usize>(dst: &mut MZ<S>, k: &MZx3<S>, d: &Matrix3<f64>) {
    debug_assert!(*dst == dst.transpose(), "add_kdk: dst not exactly symmetric");
    add_kdk_lower(dst, k, d);
    mirror_lower(dst);
}

/// The lower triangle of `dst += K D Kᵀ` (down contiguous columns).
#[inline(always)]
pub(super) fn add_kdk_lower<const S: usize>(dst: &mut MZ<S>, k: &MZx3<S>, d: &Matrix3<f64>) {
    let kd = mul3(k, d);
    for c in 0..S {
        let (k0, k1, k2) = (k[(c, 0)], k[(c, 1)], k[(c, 2)]);
        for r in c..S {
            dst[(r, c)] += kd[(r, 0)] * k0 + kd[(r, 1)] * k1 + kd[(r, 2)] * k2;
        }
    }
}

/// `A + Aᵀ` added to `dst` for a 3×S `A` occupying rows 0..3.
#[inline(always)]
pub(super) fn add_sym_rows<const S: usize>(dst: &mut MZ<S>, a: &M3xZ<S>) {
    for r in 0..3 {
        for c in 0..S {
            dst[(r, c)] += a[(r, c)];
            dst[(c, r)] += a[(r, c)];
        }
    }
}

#[cfg(test)]
mod kernel_tests {
    //! The structured, symmetric kernels against the plain dense formulas.
    use super::*;
    use crate::eiv::filter::NZ;

    /// Rounding of ~100 products of O(1) numbers: far above it would be a
    /// wrong index, far below any effect on a fit.
    const KERNEL_REL_TOL: f64 = 1e-13;

    /// A deterministic pseudo-random number in [−1, 1).
    fn lcg(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn random_symmetric(state: &mut u64) -> MZ<NZ> {
        let a = MZ::<NZ>::from_fn(|_, _| lcg(state));
        a * a.transpose() + MZ::<NZ>::identity()
    }

    fn h() -> SMatrix<f64, 3, NZ> {
        let mut h = SMatrix::<f64, 3, NZ>::zeros();
        for i in 0..3 {
            h[(i, i)] = 1.0;
            h[(i, i + 6)] = 1.0;
        }
        h
    }

    fn assert_close(a: &MZ<NZ>, b: &MZ<NZ>, what: &str) {
        let scale = b.amax().max(1.0);
        assert!((a - b).amax() <= KERNEL_REL_TOL * scale, "{what}: {a} vs {b}");
    }

    #[test]
    fn structured_kernels_match_dense_formulas() {
        let mut st = 7u64;
        for _ in 0..20 {
            let p = random_symmetric(&mut st);
            let (f02, f12) = (lcg(&mut st), lcg(&mut st));
            let fxs = Matrix3::from_fn(|_, _| lcg(&mut st));
            let diag = [1.0, 1.0, 1.0, 0.9, 0.8, 0.8, 0.99, 0.99, 0.99, 0.95, 0.0, 1.0];
            let fxw = M3x2::from_fn(|_, _| lcg(&mut st));
            let mut f = MZ::<NZ>::zeros();
            for i in 0..NZ {
                f[(i, i)] = diag[i];
            }
            f[(0, 2)] = f02;
            f[(1, 2)] = f12;
            f[(0, IB)] = -f02;
            f[(1, IB)] = -f12;
            f.fixed_view_mut::<3, 3>(0, 3).copy_from(&fxs);
            f.fixed_view_mut::<3, 2>(0, IW).copy_from(&fxw);
            let dense = f * p * f.transpose();
            let t = Transition { f02, f12, fxs, fxw, diag };
            let fast = propagate(&p, &t);
            assert_close(&fast, &dense, "propagate");
            assert_eq!(fast, fast.transpose(), "propagate is not exactly symmetric");
            assert_close(&propagate_general(&p, &t), &dense, "propagate_general");
            let c = MZx3::<NZ>::from_fn(|_, _| lcg(&mut st));
            let fc = propagate_cols(&c, &t);
            let want = f * c;
            for (r, (a, b)) in fc.iter().zip(want.iter()).enumerate() {
                assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "propagate_cols entry {r}: {a} vs {b}");
            }
            // A non-symmetric A through the general kernels.
            let x = MZ::<NZ>::from_fn(|_, _| lcg(&mut st));
            assert_close(&propagate_general(&x, &t), &(f * x * f.transpose()), "general, asym");

            let k = MZx3::<NZ>::from_fn(|_, _| lcg(&mut st));
            let ikh = MZ::<NZ>::identity() - k * h();
            let dense = ikh * p * ikh.transpose();
            let fast = joseph(&p, &k);
            assert_close(&fast, &dense, "joseph");
            assert_eq!(fast, fast.transpose(), "joseph is not exactly symmetric");
            assert_close(&joseph_general(&x, &k), &(ikh * x * ikh.transpose()), "joseph_general, asym");

            let dm = Matrix3::from_fn(|_, _| lcg(&mut st));
            let dm = dm + dm.transpose();
            let mut acc = p;
            add_kdk(&mut acc, &k, &dm);
            assert_close(&acc, &(p + k * dm * k.transpose()), "add_kdk");
            assert_eq!(acc, acc.transpose(), "add_kdk is not exactly symmetric");

            // The fused Joseph form + K D Kᵀ the filter runs: the same to the
            // bit as the two steps (a reordering would break this).
            let mut fused = p;
            joseph_in_place(&mut fused, &k, Some(&dm));
            let mut two = joseph(&p, &k);
            add_kdk(&mut two, &k, &dm);
            assert_eq!(fused, two, "joseph_in_place with K D Kᵀ is not bitwise joseph then add_kdk");
            // The column-wise propagation: the same to the bit as the
            // row-wise formulation.
            assert_eq!(propagate(&p, &t), propagate_rowwise(&p, &t), "propagate is not bitwise the row-wise one");
        }
    }

    /// The row-wise `F P Fᵀ` (through [`Transition::top`]), the
    /// bitwise reference of [`propagate`].
    fn propagate_rowwise<const S: usize>(p: &MZ<S>, t: &Transition<S>) -> MZ<S> {
        let mut w = MZx3::<S>::zeros();
        for r in 0..S {
            let row = t.top(|k| p[(r, k)]);
            for (c, v) in row.into_iter().enumerate() {
                w[(r, c)] = v;
            }
        }
        let mut out = MZ::<S>::zeros();
        for c in 0..3 {
            let col = t.top(|k| w[(k, c)]);
            for i in c..3 {
                out[(i, c)] = col[i];
            }
        }
        for i in 3..S {
            for c in 0..3 {
                out[(i, c)] = t.diag[i] * w[(i, c)];
            }
            for c in 3..=i {
                out[(i, c)] = t.diag[c] * (t.diag[i] * p[(i, c)]);
            }
        }
        mirror_lower(&mut out);
        out
    }
}
