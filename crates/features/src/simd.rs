//! Run-time selection of AVX2 builds of the hot, vectorisable loops.
//!
//! The default x86-64 target only assumes SSE2. Each hot loop is written once
//! as an `#[inline(always)]` kernel in plain Rust; [`multiversion!`] makes a
//! copy compiled with AVX2 enabled (twice the lanes) and a dispatcher that
//! picks it when the CPU has AVX2. Results are identical: the kernels use
//! integer arithmetic only.

/// True when the CPU supports AVX2 (cached by the standard library).
#[inline]
pub(crate) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `multiversion!(name, kernel, (args: types...) [-> ret])` defines
/// `fn name(args) -> ret` that calls `kernel(args)` compiled with AVX2 when
/// available.
macro_rules! multiversion {
    ($name:ident, $kernel:ident, ($($arg:ident: $ty:ty),* $(,)?)) => {
        crate::simd::multiversion!($name, $kernel, ($($arg: $ty),*) -> ());
    };
    ($name:ident, $kernel:ident, ($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty) => {
        #[inline]
        fn $name($($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2")]
                fn avx2($($arg: $ty),*) -> $ret {
                    $kernel($($arg),*)
                }
                if crate::simd::has_avx2() {
                    // SAFETY: a `target_feature` function may be called when
                    // the CPU supports the feature, checked just above.
                    return unsafe { avx2($($arg),*) };
                }
            }
            $kernel($($arg),*)
        }
    };
}

pub(crate) use multiversion;
