//! The instruction-set choice of the hand-vectorised builds (the EIV
//! filter's kernels, the structured QP solver's iteration): the AVX2 build
//! where the running CPU has what that build needs, unless the environment
//! variable `ODOCAL_SIMD=baseline` asks for the binary's baseline
//! instruction set. Both builds compile the same Rust code and give results
//! identical to the bit; the choice changes speed only.

/// Whether to run the AVX2 build: the CPU has AVX2 (and FMA when
/// `with_fma`) and `ODOCAL_SIMD=baseline` (any case) does not ask for the
/// baseline build. Decided once per process for each of the two answers.
pub(crate) fn use_avx2(with_fma: bool) -> bool {
    static CHOICE: [std::sync::OnceLock<bool>; 2] = [std::sync::OnceLock::new(), std::sync::OnceLock::new()];
    *CHOICE[usize::from(with_fma)].get_or_init(|| !baseline_forced() && avx2_available(with_fma))
}

/// True when `ODOCAL_SIMD=baseline` (any case) asks for the baseline build.
fn baseline_forced() -> bool {
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
