//! Hot passes compiled for the wider instruction sets of the CPU they run on.
//!
//! The build targets baseline x86-64 (SSE2), so that one binary runs everywhere. [`widest`]
//! runs a [`Kernel`] compiled again with AVX2, FMA and BMI (x86-64-v3) when the CPU has them:
//! wider loads and stores, three-operand instructions, fewer register spills. The results are
//! the same bit for bit: Rust never fuses a multiply and an add into an FMA on its own (only
//! `mul_add` does, which is fused on every target), and the compiler may not reorder
//! floating-point sums.
#![allow(unsafe_code)]

/// Work for [`widest`]: `call` runs it, and must be `#[inline(always)]`, as must be what it
/// calls in the hot path, for them to be compiled with the wider instruction sets. (Not a
/// closure: a closure's body is a function of its own, which the compiler need not inline
/// when it is large, and then compiles for the baseline; the assembly's pass was.)
pub(crate) trait Kernel {
    type Output;

    fn call(self) -> Self::Output;
}

/// `kernel.call()`, compiled with AVX2, FMA and BMI when this CPU has them.
#[inline(always)]
pub(crate) fn widest<K: Kernel>(kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2")
        && std::is_x86_feature_detected!("fma")
        && std::is_x86_feature_detected!("bmi1")
        && std::is_x86_feature_detected!("bmi2")
        && std::is_x86_feature_detected!("lzcnt")
        && std::is_x86_feature_detected!("movbe")
    {
        #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,movbe")]
        fn enabled<K: Kernel>(kernel: K) -> K::Output {
            kernel.call()
        }
        // SAFETY: the CPU has every feature `enabled` is compiled with (checked just above).
        return unsafe { enabled(kernel) };
    }
    kernel.call()
}
