//! Byte vectors for kernels written once over the vector width: [`U8Lanes`], with 16 lanes
//! (`wide::u8x16`, the baseline's SSE2) and 32 lanes ([`U8x32`], AVX2, on x86-64 only).
//!
//! Byte arithmetic is exact, so a kernel gives the same results at either width; the wider
//! one does half the steps. (Float kernels keep `wide`'s four and eight lanes in both copies:
//! another width would sum in another order.)

use wide::u8x16;

/// The byte-vector operations FAST's segment test uses, per lane.
pub trait U8Lanes: Copy {
    /// What a vector is made with: `()` for 16 lanes, the proof of AVX2 ([`crate::Avx2`]) for
    /// 32.
    type Isa: Copy;
    /// Lanes per vector.
    const LANES: usize;
    /// Every lane `v`.
    fn splat(isa: Self::Isa, v: u8) -> Self;
    /// The first [`Self::LANES`] bytes of `s` (which must have them: it panics otherwise).
    fn load(isa: Self::Isa, s: &[u8]) -> Self;
    /// Stores the lanes into the first [`Self::LANES`] bytes of `out` (panics if shorter).
    fn store(self, out: &mut [u8]);
    /// `min(a + b, 255)`.
    fn saturating_add(self, b: Self) -> Self;
    /// `max(a − b, 0)`.
    fn saturating_sub(self, b: Self) -> Self;
    /// Lane minimum.
    fn min(self, b: Self) -> Self;
    /// Lane maximum.
    fn max(self, b: Self) -> Self;
    /// Bitwise or.
    fn or(self, b: Self) -> Self;
    /// Whether every lane is 0.
    fn all_zero(self) -> bool;
    /// Lane `k`'s value where lane `k` of `cond` is not 0, else 0.
    fn where_nonzero(self, cond: Self) -> Self;
    /// Bit `k` set where lane `k` is not 0.
    fn nonzero_bits(self) -> u64;
}

impl U8Lanes for u8x16 {
    type Isa = ();
    const LANES: usize = 16;

    #[inline(always)]
    fn splat(_: (), v: u8) -> Self {
        u8x16::splat(v)
    }
    #[inline(always)]
    fn load(_: (), s: &[u8]) -> Self {
        let a: [u8; 16] = s[..16].try_into().expect("16 bytes");
        u8x16::new(a)
    }
    #[inline(always)]
    fn store(self, out: &mut [u8]) {
        out[..16].copy_from_slice(&self.to_array());
    }
    #[inline(always)]
    fn saturating_add(self, b: Self) -> Self {
        u8x16::saturating_add(self, b)
    }
    #[inline(always)]
    fn saturating_sub(self, b: Self) -> Self {
        u8x16::saturating_sub(self, b)
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        u8x16::min(self, b)
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        u8x16::max(self, b)
    }
    #[inline(always)]
    fn or(self, b: Self) -> Self {
        self | b
    }
    #[inline(always)]
    fn all_zero(self) -> bool {
        self.simd_eq(u8x16::ZERO).all()
    }
    #[inline(always)]
    fn where_nonzero(self, cond: Self) -> Self {
        self & !cond.simd_eq(u8x16::ZERO)
    }
    #[inline(always)]
    fn nonzero_bits(self) -> u64 {
        u64::from(!self.simd_eq(u8x16::ZERO).to_bitmask() & 0xffff)
    }
}

#[cfg(target_arch = "x86_64")]
pub use x86::U8x32;

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    //! The 32-lane vector. Soundness: a [`U8x32`] is made only through [`U8Lanes::splat`] or
    //! [`U8Lanes::load`], which take an [`Avx2`], and an `Avx2` exists only where the CPU has
    //! AVX2 ([`Avx2::detect`]). Every operation on one therefore runs on such a CPU; that is
    //! the safety argument of each `unsafe` block below. Loads and stores go through slices
    //! whose length is checked first.
    use core::arch::x86_64::*;

    use super::U8Lanes;
    use crate::Avx2;

    /// 32 bytes in an AVX2 register.
    #[derive(Clone, Copy, Debug)]
    pub struct U8x32(__m256i);

    impl U8Lanes for U8x32 {
        type Isa = Avx2;
        const LANES: usize = 32;

        #[inline(always)]
        fn splat(_: Avx2, v: u8) -> Self {
            // SAFETY: the `Avx2` proves the CPU has AVX2 (module documentation).
            Self(unsafe { _mm256_set1_epi8(v as i8) })
        }
        #[inline(always)]
        fn load(_: Avx2, s: &[u8]) -> Self {
            let s = &s[..32];
            // SAFETY: AVX2 as above; `s` has 32 readable bytes, and `loadu` takes any
            // alignment.
            Self(unsafe { _mm256_loadu_si256(s.as_ptr().cast()) })
        }
        #[inline(always)]
        fn store(self, out: &mut [u8]) {
            let out = &mut out[..32];
            // SAFETY: AVX2 as above; `out` has 32 writable bytes, any alignment.
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), self.0) }
        }
        #[inline(always)]
        fn saturating_add(self, b: Self) -> Self {
            // SAFETY: AVX2 as above.
            Self(unsafe { _mm256_adds_epu8(self.0, b.0) })
        }
        #[inline(always)]
        fn saturating_sub(self, b: Self) -> Self {
            // SAFETY: AVX2 as above.
            Self(unsafe { _mm256_subs_epu8(self.0, b.0) })
        }
        #[inline(always)]
        fn min(self, b: Self) -> Self {
            // SAFETY: AVX2 as above.
            Self(unsafe { _mm256_min_epu8(self.0, b.0) })
        }
        #[inline(always)]
        fn max(self, b: Self) -> Self {
            // SAFETY: AVX2 as above.
            Self(unsafe { _mm256_max_epu8(self.0, b.0) })
        }
        #[inline(always)]
        fn or(self, b: Self) -> Self {
            // SAFETY: AVX2 as above.
            Self(unsafe { _mm256_or_si256(self.0, b.0) })
        }
        #[inline(always)]
        fn all_zero(self) -> bool {
            // SAFETY: AVX2 as above (`vptest` is AVX).
            unsafe { _mm256_testz_si256(self.0, self.0) == 1 }
        }
        #[inline(always)]
        fn where_nonzero(self, cond: Self) -> Self {
            // SAFETY: AVX2 as above.
            Self(unsafe {
                let zero = _mm256_cmpeq_epi8(cond.0, _mm256_setzero_si256());
                _mm256_andnot_si256(zero, self.0)
            })
        }
        #[inline(always)]
        fn nonzero_bits(self) -> u64 {
            // SAFETY: AVX2 as above.
            let zero =
                unsafe { _mm256_movemask_epi8(_mm256_cmpeq_epi8(self.0, _mm256_setzero_si256())) };
            u64::from(!(zero as u32))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each operation on bytes that cover the edge cases, per lane against the scalar rule,
    /// at 16 lanes and (where the CPU has AVX2) 32.
    fn check<V: U8Lanes>(isa: V::Isa) {
        let n = V::LANES;
        let a: Vec<u8> = (0..n)
            .map(|k| [0, 1, 7, 128, 200, 254, 255, 3][k % 8])
            .collect();
        let b: Vec<u8> = (0..n)
            .map(|k| [0, 255, 9, 127, 100, 2, 1, 3][k % 8])
            .collect();
        let (va, vb) = (V::load(isa, &a), V::load(isa, &b));
        let lanes = |v: V| {
            let mut out = vec![0u8; n];
            v.store(&mut out);
            out
        };
        let each = |f: fn(u8, u8) -> u8| a.iter().zip(&b).map(|(&x, &y)| f(x, y)).collect();
        let expect: Vec<u8> = each(u8::saturating_add);
        assert_eq!(lanes(va.saturating_add(vb)), expect);
        assert_eq!(lanes(va.saturating_sub(vb)), each(u8::saturating_sub));
        assert_eq!(lanes(va.min(vb)), each(std::cmp::min));
        assert_eq!(lanes(va.max(vb)), each(std::cmp::max));
        assert_eq!(lanes(va.or(vb)), each(|x, y| x | y));
        assert_eq!(
            lanes(va.where_nonzero(vb)),
            each(|x, y| if y != 0 { x } else { 0 })
        );
        let bits = a
            .iter()
            .enumerate()
            .fold(0u64, |m, (k, &x)| m | (u64::from(x != 0) << k));
        assert_eq!(va.nonzero_bits(), bits);
        assert!(V::splat(isa, 0).all_zero());
        assert!(!va.all_zero());
        assert_eq!(lanes(V::splat(isa, 42)), vec![42; n]);
    }

    #[test]
    fn both_widths_follow_the_scalar_rules() {
        check::<u8x16>(());
        #[cfg(target_arch = "x86_64")]
        match crate::Avx2::detect() {
            Some(avx2) => check::<U8x32>(avx2),
            None => eprintln!("SKIPPED: 32 lanes: this CPU has no AVX2"),
        }
    }
}
