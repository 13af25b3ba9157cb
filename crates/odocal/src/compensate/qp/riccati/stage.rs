//! One stage of the Riccati recursion: the stage's products with its
//! sparse dynamics (`A` the identity but for its heading column, `B` by its
//! columns), the factorisation step, the vector pass and the forward
//! rollout. Every function is inlined into the solver's passes, so the
//! AVX2 build of [`super`] compiles them with its instruction set.

use super::super::{QpError, StageQp};

/// A per-stage value packed `[w_i; z_{i+1}]`: entries 0..2 input, 2..5 state.
pub(super) type S5 = [f64; 5];
/// A per-stage state value.
pub(super) type S3 = [f64; 3];
/// A per-stage input value.
pub(super) type S2 = [f64; 2];

/// `A v` for `A = [[1, 0, a0], [0, 1, a1], [0, 0, 1]]` (see [`StageQp::a`]).
#[inline(always)]
pub(super) fn a_mul(a: &S2, v: &S3) -> S3 {
    [v[0] + a[0] * v[2], v[1] + a[1] * v[2], v[2]]
}

/// `Aᵀ v` for `A = [[1, 0, a0], [0, 1, a1], [0, 0, 1]]`.
#[inline(always)]
pub(super) fn at_mul(a: &S2, v: &S3) -> S3 {
    [v[0], v[1], a[0] * v[0] + a[1] * v[1] + v[2]]
}

/// `B_iᵀ v` for `B_i` given by its columns.
#[inline(always)]
pub(super) fn bt_mul(b: &[S3; 2], v: &S3) -> S2 {
    [b[0][0] * v[0] + b[0][1] * v[1] + b[0][2] * v[2], b[1][0] * v[0] + b[1][1] * v[1] + b[1][2] * v[2]]
}

/// The stage's heading column of `A` and the columns of `B`.
#[inline(always)]
pub(super) fn stage_ab(qp: &StageQp, i: usize) -> (&S2, &[S3; 2]) {
    (&qp.a[i].data.0[0], &qp.b[i].data.0)
}

/// The Riccati factors of stage i that the vector passes read.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StageFactor {
    /// Cost-to-go Hessian block of `z_{i+1}`, its own stage cost
    /// `2Q + Σ_z` included (3×3, symmetric).
    p11: [S3; 3],
    /// Cross block of `z_{i+1}` and `w_i` (3×2, `p12[row][col]`).
    p12: [S2; 3],
    /// `H_uu⁻¹` (2×2, symmetric; zero rows and columns for pinned inputs).
    hinv: [S2; 2],
    /// The state block of `H_us`, `G = (P11 B + P12)ᵀ A` (2×3, `g[row][col]`).
    g: [S3; 2],
}

/// The cost-to-go Hessian of `s_{i+1} = [z_{i+1}; w_i]` carried backward,
/// without `z_{i+1}`'s own stage cost (added by the stage that owns it).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CostToGo {
    p11: [S3; 3],
    p12: [S2; 3],
    p22: [S2; 2],
}

/// Closed-form inverse of the symmetric 2×2 `H_uu = [[h00, h01], [h01, h11]]`;
/// positive definiteness checked on the leading minors. A pinned input is
/// no decision variable: `H_uu` is inverted on the free inputs only and
/// padded with zeros, so its step (and feedback) is 0.
#[inline(always)]
fn invert_huu(i: usize, h00: f64, h01: f64, h11: f64, free: &S5) -> Result<[S2; 2], QpError> {
    if free[0] > 0.0 && free[1] > 0.0 {
        let det = h00 * h11 - h01 * h01;
        if !(h00 > 0.0 && det > f64::EPSILON * h00 * h11) {
            return Err(QpError::Numerical(format!(
                "Riccati recursion: input Hessian not positive definite at stage {i} (det {det:.3e})"
            )));
        }
        let inv = 1.0 / det;
        return Ok([[h11 * inv, -h01 * inv], [-h01 * inv, h00 * inv]]);
    }
    let mut out = [[0.0; 2]; 2];
    for (j, h) in [(0, h00), (1, h11)] {
        if free[j] > 0.0 {
            if h.is_nan() || h <= 0.0 {
                return Err(QpError::Numerical(format!(
                    "Riccati recursion: input Hessian not positive at stage {i} (h {h:.3e})"
                )));
            }
            out[j][j] = 1.0 / h;
        }
    }
    Ok(out)
}

/// One step of the backward Riccati factorisation at stage i.
///
/// Adds `z_{i+1}`'s stage cost `2Q + Σ_z` to the carried cost-to-go `ctg`
/// of `s_{i+1}`, forms `H_uu = [B; I]ᵀ P [B; I] + Σ_w (+ 2R)` and
/// `H_us = [(P11 B + P12)ᵀ A, −2R]`, writes the stage's
/// factor to `out` and returns the cost-to-go of `s_i`,
/// `blockdiag(AᵀP11A, 2R) − H_usᵀ H_uu⁻¹ H_us` (z_i's stage cost left to
/// stage i−1). Every product is written out for the sparse `A` and the
/// diagonal `R`; symmetric blocks are formed from their upper triangle.
#[inline(always)]
pub(super) fn factor_stage(
    i: usize,
    ctg: &CostToGo,
    (q2, r2): (&S3, &S2),
    sigma: &S5,
    free: &S5,
    (a, b): (&S2, &[S3; 2]),
    out: &mut StageFactor,
) -> Result<CostToGo, QpError> {
    let mut p11 = ctg.p11;
    for j in 0..3 {
        p11[j][j] += q2[j] + sigma[2 + j];
    }
    let p12 = ctg.p12;
    // g = P11 B + P12 (3×2).
    let mut g = [[0.0; 2]; 3];
    for r in 0..3 {
        for j in 0..2 {
            g[r][j] = p11[r][0] * b[j][0] + p11[r][1] * b[j][1] + p11[r][2] * b[j][2] + p12[r][j];
        }
    }
    // H_uu = Bᵀ g + P12ᵀ B + P22 + Σ_w, plus 2R where w_{i−1} exists.
    let h = |j: usize, l: usize| {
        b[j][0] * g[0][l]
            + b[j][1] * g[1][l]
            + b[j][2] * g[2][l]
            + (p12[0][j] * b[l][0] + p12[1][j] * b[l][1] + p12[2][j] * b[l][2])
            + ctg.p22[j][l]
    };
    let rate = if i > 0 { *r2 } else { [0.0; 2] };
    let hinv = invert_huu(i, h(0, 0) + sigma[0] + rate[0], h(0, 1), h(1, 1) + sigma[1] + rate[1], free)?;
    // G = gᵀ A.
    let gt = |j: usize| [g[0][j], g[1][j], a[0] * g[0][j] + a[1] * g[1][j] + g[2][j]];
    let gg = [gt(0), gt(1)];
    *out = StageFactor { p11, p12, hinv, g: gg };
    if i == 0 {
        return Ok(CostToGo::default()); // s_0 = 0: P_0 is never used.
    }
    // M = H_uu⁻¹ G (2×3).
    let mrow = |j: usize| {
        let (h0, h1) = (hinv[j][0], hinv[j][1]);
        [h0 * gg[0][0] + h1 * gg[1][0], h0 * gg[0][1] + h1 * gg[1][1], h0 * gg[0][2] + h1 * gg[1][2]]
    };
    let m = [mrow(0), mrow(1)];
    // AᵀP11A: only the heading row and column change, through v = P11 (a0, a1, 1).
    let v = [
        p11[0][0] * a[0] + p11[0][1] * a[1] + p11[0][2],
        p11[1][0] * a[0] + p11[1][1] * a[1] + p11[1][2],
        p11[2][0] * a[0] + p11[2][1] * a[1] + p11[2][2],
    ];
    let ata =
        [[p11[0][0], p11[0][1], v[0]], [p11[1][0], p11[1][1], v[1]], [v[0], v[1], a[0] * v[0] + a[1] * v[1] + v[2]]];
    let mut next = CostToGo::default();
    for r in 0..3 {
        for c in r..3 {
            let e = ata[r][c] - (gg[0][r] * m[0][c] + gg[1][r] * m[1][c]);
            next.p11[r][c] = e;
            next.p11[c][r] = e;
        }
        // −Gᵀ H_uu⁻¹ (−2R) = Mᵀ 2R.
        next.p12[r] = [m[0][r] * r2[0], m[1][r] * r2[1]];
    }
    // 2R − 2R H_uu⁻¹ 2R.
    next.p22 = [
        [r2[0] - r2[0] * hinv[0][0] * r2[0], -(r2[0] * hinv[0][1] * r2[1])],
        [-(r2[1] * hinv[1][0] * r2[0]), r2[1] - r2[1] * hinv[1][1] * r2[1]],
    ];
    Ok(next)
}

/// One step of the Riccati vector pass at stage i for the linear term `rt`
/// and the dynamics offset `−r_p`: updates the carried cost-to-go gradient
/// `(pz, pw)` of `s_{i+1}` (without `z_{i+1}`'s own term, added here) to
/// that of `s_i`, and returns the feed-forward `kff = −H_uu⁻¹ h_u`.
#[inline(always)]
pub(super) fn vector_stage(
    f: &StageFactor,
    rt: &S5,
    r_p: &S3,
    (a, b): (&S2, &[S3; 2]),
    r2: &S2,
    p: (&mut S3, &mut S2),
) -> S2 {
    let (pz, pw) = p;
    let ch = [-r_p[0], -r_p[1], -r_p[2]];
    let row = |r: usize| f.p11[r][0] * ch[0] + f.p11[r][1] * ch[1] + f.p11[r][2] * ch[2] + (pz[r] + rt[2 + r]);
    let e1 = [row(0), row(1), row(2)];
    let col = |j: usize| f.p12[0][j] * ch[0] + f.p12[1][j] * ch[1] + f.p12[2][j] * ch[2] + pw[j];
    let e2 = [col(0), col(1)];
    let bte = bt_mul(b, &e1);
    let hu = [rt[0] + bte[0] + e2[0], rt[1] + bte[1] + e2[1]];
    let kff = [-(f.hinv[0][0] * hu[0] + f.hinv[0][1] * hu[1]), -(f.hinv[1][0] * hu[0] + f.hinv[1][1] * hu[1])];
    let ae = at_mul(a, &e1);
    for r in 0..3 {
        pz[r] = ae[r] + (f.g[0][r] * kff[0] + f.g[1][r] * kff[1]);
    }
    *pw = [-(r2[0] * kff[0]), -(r2[1] * kff[1])];
    kff
}

/// One step of the forward rollout at stage i from `s_i = (sz, sw)`:
/// `u_i = kff_i − H_uu⁻¹ H_us s_i`, `Δz_{i+1} = A s_z + B u_i − r_p`.
#[inline(always)]
pub(super) fn rollout_stage(
    i: usize,
    f: &StageFactor,
    kff: &S2,
    (a, b): (&S2, &[S3; 2]),
    r2: &S2,
    r_p: &S3,
    s: (&S3, &S2),
) -> S5 {
    let (sz, sw) = s;
    let u = if i == 0 {
        *kff
    } else {
        let hs = |j: usize| f.g[j][0] * sz[0] + f.g[j][1] * sz[1] + f.g[j][2] * sz[2] - r2[j] * sw[j];
        let hs = [hs(0), hs(1)];
        [kff[0] - (f.hinv[0][0] * hs[0] + f.hinv[0][1] * hs[1]), kff[1] - (f.hinv[1][0] * hs[0] + f.hinv[1][1] * hs[1])]
    };
    let az = a_mul(a, sz);
    let dz = |r: usize| az[r] + (b[0][r] * u[0] + b[1][r] * u[1]) - r_p[r];
    [u[0], u[1], dz(0), dz(1), dz(2)]
}
