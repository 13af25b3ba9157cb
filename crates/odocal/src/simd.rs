//! The instruction-set choice of the hand-vectorised builds (the EIV
//! filter's kernels, the structured QP solver's iteration): the AVX2 build
//! where the running CPU has what that build needs, unless the environment
//! variable `ODOCAL_SIMD=baseline` asks for the binary's baseline
//! instruction set. Both builds compile the same Rust code and give results
//! identical to the bit; the choice changes speed only.

/// True when `ODOCAL_SIMD=baseline` (any case) asks for the baseline build.
pub(crate) fn baseline_forced() -> bool {
    std::env::var("ODOCAL_SIMD").is_ok_and(|s| s.eq_ignore_ascii_case("baseline"))
}

/// Whether the running CPU has AVX2, and FMA too when `with_fma`; false off
/// x86-64.
pub(crate) fn avx2_available(with_fma: bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && (!with_fma || std::arch::is_x86_feature_detected!("fma"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = with_fma;
        false
    }
}
