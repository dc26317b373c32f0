//! The instruction set the image kernels run with, chosen at run time (issue 39).
//!
//! A release build targets the x86-64 baseline, so it runs on any x86-64 CPU (a binary built
//! for the build machine's own CPU died with "Illegal instruction" on another). The kernels
//! (FAST, the pyramids, the KLT, the undistortion, the depth conversion) are written once, with
//! `wide`'s portable vectors; [`dispatch!`] compiles each a second time with AVX2 and FMA
//! enabled and picks that copy where the CPU has both.
//!
//! The two copies compute the same values: Rust never contracts a multiply and an add into an
//! FMA or reorders float operations on its own, so enabling the instructions changes only
//! their encoding (three-operand VEX forms, 256-bit registers where LLVM merges lanes), not
//! the arithmetic. `wide`'s own `mul_add` chooses its form when `wide` is compiled (baseline),
//! so it is not fused either.

pub mod lanes;

use std::sync::atomic::{AtomicU8, Ordering};

pub use lanes::U8Lanes;
#[cfg(target_arch = "x86_64")]
pub use lanes::U8x32;

/// The choice, once made: [`UNDECIDED`], [`WIDE`] or [`BASELINE`].
static CHOICE: AtomicU8 = AtomicU8::new(UNDECIDED);
const UNDECIDED: u8 = 0;
const WIDE: u8 = 1;
const BASELINE: u8 = 2;

/// The environment variable that, set to `baseline`, keeps every kernel on its baseline copy:
/// to compare the two copies' speed, or their outputs (which are the same), on one machine.
pub const ENV: &str = "TRACKER_ISA";

/// Whether the kernels run their AVX2 + FMA copies ([`dispatch!`]): where the CPU has both,
/// unless [`ENV`] says `baseline` or [`force_baseline`] was called. Decided once (one atomic
/// load after that).
#[inline]
pub fn avx2_fma() -> bool {
    match CHOICE.load(Ordering::Relaxed) {
        WIDE => true,
        BASELINE => false,
        _ => decide(),
    }
}

#[cold]
fn decide() -> bool {
    let wide = cpu_has_avx2_fma() && std::env::var(ENV).map_or(true, |v| v != "baseline");
    CHOICE.store(if wide { WIDE } else { BASELINE }, Ordering::Relaxed);
    wide
}

/// Whether the CPU has AVX2 and FMA.
pub fn cpu_has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Keeps the kernels on their baseline copies (`true`) or lets them use the CPU's AVX2 and
/// FMA again (`false`, where it has them): for benchmarks that time both in one run.
pub fn force_baseline(baseline: bool) {
    let wide = !baseline && cpu_has_avx2_fma();
    CHOICE.store(if wide { WIDE } else { BASELINE }, Ordering::Relaxed);
}

/// Runs `f` with the kernels on their baseline copies, then (where the CPU has AVX2 and FMA)
/// on the AVX2 copies, passing [`name`]; leaves the choice as it was (so [`ENV`] still holds
/// afterwards). For tests that check every copy and benchmarks that time each. The choice is
/// global: kernels that run meanwhile on other threads may run either copy (which give the
/// same values).
pub fn each_copy(mut f: impl FnMut(&'static str)) {
    let before = CHOICE.load(Ordering::Relaxed);
    for baseline in [true, false] {
        if !baseline && !cpu_has_avx2_fma() {
            break;
        }
        force_baseline(baseline);
        f(name());
    }
    CHOICE.store(before, Ordering::Relaxed);
}

/// The proof that the kernels' AVX2 + FMA copies run on this CPU ([`avx2_fma`]), which
/// [`U8x32`] vectors are made with.
#[derive(Clone, Copy, Debug)]
pub struct Avx2(());

impl Avx2 {
    /// `Some` where [`avx2_fma`] holds.
    #[inline]
    pub fn detect() -> Option<Self> {
        avx2_fma().then_some(Self(()))
    }
}

/// The instruction set [`dispatch!`] picks on this CPU, for benchmarks and logs to print.
pub fn name() -> &'static str {
    if avx2_fma() { "AVX2+FMA" } else { "baseline" }
}

/// Defines a function whose body is compiled twice, for the baseline and with AVX2 and FMA,
/// and run in the second form where [`avx2_fma`] holds.
///
/// The function takes plain `name: Type` parameters (lifetimes allowed, no other generics).
/// Everything the body calls that is to run with the wider instructions must be inlined into
/// it (`#[inline]` or `#[inline(always)]`, as `wide`'s operations are); a call that is not
/// inlined runs its baseline code.
///
/// ```
/// isa::dispatch! {
///     /// Sums the squares of `v`.
///     pub fn sum_squares(v: &[f32]) -> f32 {
///         v.iter().map(|x| x * x).sum()
///     }
/// }
/// assert_eq!(sum_squares(&[1.0, 2.0]), 5.0);
/// ```
///
/// A kernel written over the vector width ([`U8Lanes`]) names its two forms instead of a
/// body; the second runs with AVX2 enabled and gets the proof, `avx2`, to make its vectors:
///
/// ```ignore
/// isa::dispatch! {
///     fn row(src: &[u8], out: &mut [u8]) {
///         baseline => row_with::<wide::u8x16>((), src, out),
///         avx2(proof) => row_with::<isa::U8x32>(proof, src, out),
///     }
/// }
/// ```
#[macro_export]
macro_rules! dispatch {
    (
        $(#[$meta:meta])*
        $vis:vis fn $name:ident $(<$($lt:lifetime),+>)?
        ($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)?
        {
            baseline => $base:expr,
            avx2($proof:ident) => $wide:expr $(,)?
        }
    ) => {
        $(#[$meta])*
        $vis fn $name $(<$($lt),+>)? ($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            fn wide_body $(<$($lt),+>)? ($proof: $crate::Avx2, $($arg: $ty),*) $(-> $ret)? {
                $wide
            }

            #[cfg(target_arch = "x86_64")]
            if let Some(proof) = $crate::Avx2::detect() {
                // SAFETY: `proof` exists only where the CPU has AVX2 and FMA, the only
                // features `wide_body` enables.
                #[allow(unsafe_code)]
                return unsafe { wide_body(proof, $($arg),*) };
            }
            $base
        }
    };
    (
        $(#[$meta:meta])*
        $vis:vis fn $name:ident $(<$($lt:lifetime),+>)?
        ($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)?
        $body:block
    ) => {
        $(#[$meta])*
        $vis fn $name $(<$($lt),+>)? ($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn body $(<$($lt),+>)? ($($arg: $ty),*) $(-> $ret)? $body

            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            fn wide_body $(<$($lt),+>)? ($($arg: $ty),*) $(-> $ret)? {
                body($($arg),*)
            }

            #[cfg(target_arch = "x86_64")]
            if $crate::avx2_fma() {
                // SAFETY: the CPU has AVX2 and FMA (checked just above), the only features
                // `wide_body` enables.
                #[allow(unsafe_code)]
                return unsafe { wide_body($($arg),*) };
            }
            body($($arg),*)
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    dispatch! {
        /// A float sum in a fixed order, the kind of loop the kernels run.
        fn weighted<'a>(a: &'a [f32], w: &'a [f32]) -> f32 {
            let mut s = 0.0f32;
            for (x, y) in a.iter().zip(w) {
                s += x * y + 0.25 * x;
            }
            s
        }
    }

    /// One test, since the choice is global: both copies give the same bits, and the name and
    /// the choice follow `force_baseline`.
    #[test]
    fn both_copies_give_the_same_bits() {
        let a: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.37).sin() * 1e3).collect();
        let w: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.11).cos()).collect();
        let mut expected = 0.0f32;
        for (x, y) in a.iter().zip(&w) {
            expected += x * y + 0.25 * x;
        }
        let before = avx2_fma();
        let mut copies = Vec::new();
        each_copy(|copy| {
            assert_eq!(copy, name());
            assert_eq!(name() == "AVX2+FMA", avx2_fma());
            assert_eq!(weighted(&a, &w).to_bits(), expected.to_bits());
            copies.push(copy);
        });
        let expected = if cpu_has_avx2_fma() {
            vec!["baseline", "AVX2+FMA"]
        } else {
            vec!["baseline"]
        };
        assert_eq!(copies, expected);
        // The choice is back where it was: the CPU's, or the baseline under `TRACKER_ISA`.
        assert_eq!(avx2_fma(), before);
    }
}
