//! Runtime CPU detection for the solver's own hand-vectorised kernels. The crate is built for
//! baseline x86-64 (SSE2) so that the binary runs on any lab PC; faer and rustfft pick AVX
//! kernels at run time, and so do these.

/// Whether the CPU has AVX2 and FMA (std caches the detection).
#[inline]
pub fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU has AVX-512F (the split-format FFT's kernels).
#[inline]
pub fn has_avx512f() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU's vector gathers are fast (Intel), rather than microcoded and slower than
/// scalar loads (AMD's Zen: measured on an EPYC (Zen 4), the Gram fill's AVX2 gathers took
/// 0.16-0.20 ms at m = 600 against 0.10-0.17 ms for the scalar loop).
pub fn fast_gathers() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static INTEL: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *INTEL.get_or_init(|| {
            let r = std::arch::x86_64::__cpuid(0);
            // "GenuineIntel": ebx, edx, ecx.
            (r.ebx, r.edx, r.ecx) == (0x756e_6547, 0x4965_6e69, 0x6c65_746e)
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
