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
