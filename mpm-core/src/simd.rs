//! Which vector unit the particle kernels run on, chosen at run time.
//!
//! The build targets the baseline of its architecture (x86-64: SSE2), so that one `mpm`
//! binary runs on every machine of a campaign. The particle update is written over blocks of
//! particles ([`crate::material::update_lanes`]) with branch-free selects, and the step
//! compiles it three times: for the baseline and with AVX2 enabled (`#[target_feature]`) over
//! blocks of [`LANES`] = 4 ([`F4`], one 256-bit register), and with AVX-512F enabled over
//! blocks of [`LANES8`] = 8 (`F8`, crate-private: one 512-bit register, its operations
//! AVX-512F intrinsics, so that it exists only where they run). The step calls the widest
//! one the CPU has ([`SimdLevel::detected`], through `is_x86_feature_detected!`), or the one
//! [`crate::SimConfig::simd`] asks for.
//!
//! All are the same source: the same operations in the same order on every lane (a lane is
//! a particle; the block width changes which particles share an instruction, not what any
//! particle computes), and no fused multiply-add (Rust never contracts `a * b + c` by
//! itself, and the kernels call no `mul_add`), so the levels give **bitwise the same
//! results** (test `dispatch_levels_agree_bitwise` in `tests/equivalence.rs`, every level the
//! CPU has against the baseline).

use serde::Serialize;

/// Particles per block of the blocked particle update at the baseline and AVX2 levels: one
/// AVX2 register of `f64`.
pub const LANES: usize = 4;

/// Particles per block at the AVX-512 level: one AVX-512 register of `f64`.
pub const LANES8: usize = 8;

/// An instruction-set level of the particle kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SimdLevel {
    /// The build target's own level (x86-64: SSE2, two `f64` lanes per instruction).
    Baseline,
    /// x86-64 with AVX2 (four `f64` lanes per instruction).
    Avx2,
    /// x86-64 with AVX-512F (eight `f64` lanes per instruction; the particle update in
    /// blocks of 8, the scatters as at AVX2).
    Avx512,
}

impl SimdLevel {
    /// Every level, lowest first.
    pub const ALL: [SimdLevel; 3] = [SimdLevel::Baseline, SimdLevel::Avx2, SimdLevel::Avx512];

    /// The widest level this CPU runs.
    pub fn detected() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx2") {
                return SimdLevel::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return SimdLevel::Avx2;
            }
        }
        SimdLevel::Baseline
    }

    /// Whether this CPU runs `self`.
    pub fn is_available(self) -> bool {
        self <= Self::detected()
    }

    /// Double-precision flops one core can retire per cycle at this level with the
    /// kernels' instructions (separate multiply and add, no fused multiply-add: one vector
    /// multiply and one vector add per cycle): 4 for SSE2's 2 lanes, 8 for AVX2's 4, 16 for
    /// AVX-512's 8.
    pub fn flops_per_cycle(self) -> f64 {
        match self {
            SimdLevel::Baseline => 4.0,
            SimdLevel::Avx2 => 8.0,
            SimdLevel::Avx512 => 16.0,
        }
    }

    /// Stable name (`baseline`, `avx2`, `avx512`).
    pub fn name(self) -> &'static str {
        match self {
            SimdLevel::Baseline => "baseline",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Avx512 => "avx512",
        }
    }
}

impl std::fmt::Display for SimdLevel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for SimdLevel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "baseline" => Ok(SimdLevel::Baseline),
            "avx2" => Ok(SimdLevel::Avx2),
            "avx512" => Ok(SimdLevel::Avx512),
            _ => Err(format!("unknown SIMD level '{s}': use 'baseline', 'avx2' or 'avx512'")),
        }
    }
}

/// `[f(0), .., f(N - 1)]`, inlined (`std::array::from_fn` stayed a call inside the AVX2
/// kernels, its closure compiled without AVX2).
#[inline(always)]
pub fn array<T: Copy + Default, const N: usize>(mut f: impl FnMut(usize) -> T) -> [T; N] {
    let mut a = [T::default(); N];
    for (i, v) in a.iter_mut().enumerate() {
        *v = f(i);
    }
    a
}

/// `[e(0), e(1), ..]` for the expression `e` of the lane `l` over the lanes listed, written
/// out: no closure, so that the arithmetic costs little in the unoptimised build (o0) too.
macro_rules! lanes {
    ($l:ident => $e:expr; $($i:literal)*) => {
        [$({
            let $l = $i;
            $e
        }),*]
    };
}

/// A floating-point value the material kernels are written over: one `f64`, or [`F4`], the
/// same operation on [`LANES`] particles at once. Every operation of `F4` is its `f64`
/// operation lane by lane (IEEE arithmetic, correctly rounded `sqrt`, `f64::max`), so a
/// kernel gives each lane the bits it gives one `f64`.
pub trait Real:
    Copy
    + Default
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
{
    /// The result of a comparison, lane by lane.
    type Mask: Copy
        + std::ops::BitAnd<Output = Self::Mask>
        + std::ops::BitOr<Output = Self::Mask>
        + std::ops::Not<Output = Self::Mask>;
    /// `v` in every lane.
    fn splat(v: f64) -> Self;
    /// `f64::sqrt`.
    fn sqrt(self) -> Self;
    /// `self > other ? self : other`: the larger, `other` where they tie and where either is
    /// NaN. `f64::max` where `other` is not NaN (every call's is a constant), with the sign
    /// of a tie of zeros fixed (`f64::max` leaves it to the compiler, whose choice differed
    /// between scalar and vector code): `other`'s, as x86's max instructions give it.
    fn max(self, other: Self) -> Self;
    /// `self <= other`.
    fn le(self, other: Self) -> Self::Mask;
    /// `self < other`.
    fn lt(self, other: Self) -> Self::Mask;
    /// `self >= other`.
    fn ge(self, other: Self) -> Self::Mask;
    /// `self > other`.
    fn gt(self, other: Self) -> Self::Mask;
    /// `a` where `m` holds, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// `v` in every lane (a mask).
    fn mask(v: bool) -> Self::Mask;
    /// Lanes (1 or [`LANES`]).
    const WIDTH: usize;
    /// Lane `l`.
    fn lane(self, l: usize) -> f64;
    /// Lane `l` is `f(l)`.
    fn from_lanes(f: impl FnMut(usize) -> f64) -> Self;
}

impl Real for f64 {
    type Mask = bool;
    #[inline(always)]
    fn splat(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        if self > other {
            self
        } else {
            other
        }
    }
    #[inline(always)]
    fn le(self, other: Self) -> bool {
        self <= other
    }
    #[inline(always)]
    fn lt(self, other: Self) -> bool {
        self < other
    }
    #[inline(always)]
    fn ge(self, other: Self) -> bool {
        self >= other
    }
    #[inline(always)]
    fn gt(self, other: Self) -> bool {
        self > other
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        if m {
            a
        } else {
            b
        }
    }
    #[inline(always)]
    fn mask(v: bool) -> bool {
        v
    }
    const WIDTH: usize = 1;
    #[inline(always)]
    fn lane(self, _l: usize) -> f64 {
        self
    }
    #[inline(always)]
    fn from_lanes(mut f: impl FnMut(usize) -> f64) -> Self {
        f(0)
    }
}

/// The operations of a block type `$f` of `$n` `f64` lanes and its mask `$m`, every one its
/// `f64` operation lane by lane (IEEE arithmetic, correctly rounded `sqrt`, `f64::max`,
/// selects by bits), over the lanes listed: [`Real`], [`Block`], the arithmetic and mask
/// operators.
macro_rules! lane_block {
    ($f:ident, $m:ident, $n:expr, [$($i:literal)*]) => {
        lane_block!(@op $f, Add, add, +, [$($i)*]);
        lane_block!(@op $f, Sub, sub, -, [$($i)*]);
        lane_block!(@op $f, Mul, mul, *, [$($i)*]);
        lane_block!(@op $f, Div, div, /, [$($i)*]);
        lane_block!(@op $m, BitAnd, bitand, &, [$($i)*]);
        lane_block!(@op $m, BitOr, bitor, |, [$($i)*]);

        impl std::ops::Neg for $f {
            type Output = $f;
            #[inline(always)]
            fn neg(self) -> $f {
                $f(lanes!(l => -self.0[l]; $($i)*))
            }
        }

        impl std::ops::Not for $m {
            type Output = $m;
            #[inline(always)]
            fn not(self) -> $m {
                $m(lanes!(l => !self.0[l]; $($i)*))
            }
        }

        impl Real for $f {
            type Mask = $m;
            #[inline(always)]
            fn splat(v: f64) -> Self {
                $f([v; $n])
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                $f(lanes!(l => self.0[l].sqrt(); $($i)*))
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                $f(lanes!(l => if self.0[l] > o.0[l] { self.0[l] } else { o.0[l] }; $($i)*))
            }
            #[inline(always)]
            fn le(self, o: Self) -> $m {
                $m(lanes!(l => if self.0[l] <= o.0[l] { u64::MAX } else { 0 }; $($i)*))
            }
            #[inline(always)]
            fn lt(self, o: Self) -> $m {
                $m(lanes!(l => if self.0[l] < o.0[l] { u64::MAX } else { 0 }; $($i)*))
            }
            #[inline(always)]
            fn ge(self, o: Self) -> $m {
                $m(lanes!(l => if self.0[l] >= o.0[l] { u64::MAX } else { 0 }; $($i)*))
            }
            #[inline(always)]
            fn gt(self, o: Self) -> $m {
                $m(lanes!(l => if self.0[l] > o.0[l] { u64::MAX } else { 0 }; $($i)*))
            }
            #[inline(always)]
            fn select(m: $m, a: Self, b: Self) -> Self {
                $f(lanes!(l => f64::from_bits((m.0[l] & a.0[l].to_bits()) | (!m.0[l] & b.0[l].to_bits())); $($i)*))
            }
            #[inline(always)]
            fn mask(v: bool) -> $m {
                $m([if v { u64::MAX } else { 0 }; $n])
            }
            const WIDTH: usize = $n;
            #[inline(always)]
            fn lane(self, l: usize) -> f64 {
                self.0[l]
            }
            #[inline(always)]
            fn from_lanes(f: impl FnMut(usize) -> f64) -> Self {
                $f(array(f))
            }
        }

        impl Block<$n> for $f {
            #[inline(always)]
            fn from_array(a: [f64; $n]) -> Self {
                $f(a)
            }
            #[inline(always)]
            fn mask_from(mut f: impl FnMut(usize) -> bool) -> $m {
                $m(array(|l| if f(l) { u64::MAX } else { 0 }))
            }
            #[inline(always)]
            fn to_array(self) -> [f64; $n] {
                self.0
            }
            #[inline(always)]
            fn floor(self) -> Self {
                $f(lanes!(l => self.0[l].floor(); $($i)*))
            }
            #[inline(always)]
            fn mask_bools(m: $m) -> [bool; $n] {
                lanes!(l => m.0[l] != 0; $($i)*)
            }
        }
    };
    (@op $t:ident, $trait:ident, $method:ident, $op:tt, [$($i:literal)*]) => {
        impl std::ops::$trait for $t {
            type Output = $t;
            #[inline(always)]
            fn $method(self, o: $t) -> $t {
                $t(lanes!(l => self.0[l] $op o.0[l]; $($i)*))
            }
        }
    };
}

/// [`LANES`] `f64` lanes, one operation for all (a 256-bit register where AVX2 is on).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct F4(pub [f64; LANES]);

/// A comparison of [`F4`]s: all bits set in a lane where it holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct M4(pub [u64; LANES]);

lane_block!(F4, M4, LANES, [0 1 2 3]);

#[cfg(not(target_arch = "x86_64"))]
pub(crate) use portable8::F8;

/// [`F8`] and [`M8`] as arrays where there is no AVX-512.
#[cfg(not(target_arch = "x86_64"))]
mod portable8 {
    use super::*;

    /// [`LANES8`] `f64` lanes, one operation for all.
    #[derive(Clone, Copy, Debug, Default, PartialEq)]
    #[repr(C, align(64))]
    pub struct F8(pub [f64; LANES8]);

    /// A comparison of [`F8`]s: all bits set in a lane where it holds.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    #[repr(C, align(64))]
    pub struct M8(pub [u64; LANES8]);

    lane_block!(F8, M8, LANES8, [0 1 2 3 4 5 6 7]);
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx512::F8;

/// [`F8`] as one AVX-512 register, every operation one AVX-512F instruction (`std::arch`).
///
/// [`F4`]'s form, an array whose operations are written lane by lane, leaves it to the
/// compiler's SLP vectoriser to make one instruction of each operation's lanes; in the
/// particle update at AVX-512 it did so only in part (the node sums and the shape
/// functions went through the stack, a store and a load for each addition), and with the
/// intrinsics the update took 0.88 of its time (serial Model 1, medians of 6 alternated
/// runs, bitwise the same results; 0.75 with the located arrays' gathers inlined as well,
/// 8 runs).
///
/// Every operation is its `f64` operation lane by lane, as [`F4`]'s: IEEE arithmetic and
/// correctly rounded `sqrt` (the instructions are), comparisons ordered and quiet (`false`
/// where either side is NaN, as Rust's), [`Real::max`] as `vmaxpd` computes it,
/// [`Block::floor`] rounding down; test `f8_lanes_are_the_f64_operations`.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::*;
    use std::arch::x86_64::*;

    /// An AVX-512F instruction, from code that may not be compiled for AVX-512F.
    macro_rules! avx512 {
        ($e:expr) => {
            // SAFETY: the only `unsafe` in calling a `std::arch` intrinsic is that the CPU
            // must execute its instruction set. An `F8` exists only where AVX-512F runs:
            // the type is crate-private, and the crate makes one only in code that runs
            // after `SimdLevel::Avx512.is_available()` has held: the particle update's and
            // the locate pass's AVX-512 copies (`#[target_feature(enable = "avx512f")]`,
            // called after an assertion of it) and tests that return first where the CPU
            // lacks it. Its two constructors (`splat`, `from_array`; the others go through
            // them) check it again in builds with debug assertions (plain `cargo test`).
            // No intrinsic here reads or writes memory but through a reference of the
            // right length.
            unsafe { $e }
        };
    }

    /// [`LANES8`] `f64` lanes in one AVX-512 register.
    #[derive(Clone, Copy)]
    #[repr(transparent)]
    pub struct F8(__m512d);

    /// A comparison of [`F8`]s: bit `l` set where it holds in lane `l` (an AVX-512 mask).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct M8(u8);

    impl Default for F8 {
        #[inline(always)]
        fn default() -> Self {
            F8::splat(0.0)
        }
    }

    impl std::fmt::Debug for F8 {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            self.to_array().fmt(f)
        }
    }

    impl PartialEq for F8 {
        fn eq(&self, o: &Self) -> bool {
            self.to_array() == o.to_array()
        }
    }

    macro_rules! op {
        ($trait:ident, $method:ident, $intrinsic:ident) => {
            impl std::ops::$trait for F8 {
                type Output = F8;
                #[inline(always)]
                fn $method(self, o: F8) -> F8 {
                    F8(avx512!($intrinsic(self.0, o.0)))
                }
            }
        };
    }
    /// A comparison of [`Real`], ordered and quiet (`false` where either side is NaN).
    macro_rules! compare {
        ($method:ident, $predicate:ident) => {
            #[inline(always)]
            fn $method(self, o: Self) -> M8 {
                M8(avx512!(_mm512_cmp_pd_mask::<$predicate>(self.0, o.0)))
            }
        };
    }

    op!(Add, add, _mm512_add_pd);
    op!(Sub, sub, _mm512_sub_pd);
    op!(Mul, mul, _mm512_mul_pd);
    op!(Div, div, _mm512_div_pd);

    impl std::ops::Neg for F8 {
        type Output = F8;
        /// The sign bit flipped, as `f64`'s `-` (of NaN and zeros too).
        #[inline(always)]
        fn neg(self) -> F8 {
            let sign = avx512!(_mm512_set1_epi64(i64::MIN));
            F8(avx512!(_mm512_castsi512_pd(_mm512_xor_si512(_mm512_castpd_si512(self.0), sign))))
        }
    }

    impl std::ops::BitAnd for M8 {
        type Output = M8;
        #[inline(always)]
        fn bitand(self, o: M8) -> M8 {
            M8(self.0 & o.0)
        }
    }

    impl std::ops::BitOr for M8 {
        type Output = M8;
        #[inline(always)]
        fn bitor(self, o: M8) -> M8 {
            M8(self.0 | o.0)
        }
    }

    impl std::ops::Not for M8 {
        type Output = M8;
        #[inline(always)]
        fn not(self) -> M8 {
            M8(!self.0)
        }
    }

    impl Real for F8 {
        type Mask = M8;
        #[inline(always)]
        fn splat(v: f64) -> Self {
            debug_assert!(SimdLevel::Avx512.is_available(), "an F8 on a CPU without AVX-512F");
            F8(avx512!(_mm512_set1_pd(v)))
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            F8(avx512!(_mm512_sqrt_pd(self.0)))
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            // `self > o ? self : o` is what `vmaxpd` computes.
            F8(avx512!(_mm512_max_pd(self.0, o.0)))
        }
        compare!(le, _CMP_LE_OQ);
        compare!(lt, _CMP_LT_OQ);
        compare!(ge, _CMP_GE_OQ);
        compare!(gt, _CMP_GT_OQ);
        #[inline(always)]
        fn select(m: M8, a: Self, b: Self) -> Self {
            F8(avx512!(_mm512_mask_blend_pd(m.0, b.0, a.0)))
        }
        #[inline(always)]
        fn mask(v: bool) -> M8 {
            M8(if v { u8::MAX } else { 0 })
        }
        const WIDTH: usize = LANES8;
        #[inline(always)]
        fn lane(self, l: usize) -> f64 {
            self.to_array()[l]
        }
        #[inline(always)]
        fn from_lanes(f: impl FnMut(usize) -> f64) -> Self {
            Self::from_array(array(f))
        }
    }

    impl Block<LANES8> for F8 {
        #[inline(always)]
        fn from_array(a: [f64; LANES8]) -> Self {
            debug_assert!(SimdLevel::Avx512.is_available(), "an F8 on a CPU without AVX-512F");
            F8(avx512!(_mm512_loadu_pd(a.as_ptr())))
        }
        #[inline(always)]
        fn mask_from(mut f: impl FnMut(usize) -> bool) -> M8 {
            let mut m = 0;
            for l in 0..LANES8 {
                m |= u8::from(f(l)) << l;
            }
            M8(m)
        }
        #[inline(always)]
        fn to_array(self) -> [f64; LANES8] {
            let mut a = [0.0; LANES8];
            avx512!(_mm512_storeu_pd(a.as_mut_ptr(), self.0));
            a
        }
        #[inline(always)]
        fn floor(self) -> Self {
            F8(avx512!(_mm512_roundscale_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(self.0)))
        }
        #[inline(always)]
        fn mask_bools(m: M8) -> [bool; LANES8] {
            lanes!(l => m.0 >> l & 1 != 0; 0 1 2 3 4 5 6 7)
        }
    }
}

/// Whether a test of AVX-512 code (`F8`) can run here: `true` where the CPU executes
/// AVX-512F. Where it does not, the test says so and is skipped, unless
/// `MPM_CPU_HAS_AVX512=1` (`scripts/test.sh` sets it from `/proc/cpuinfo`'s flags), which
/// fails it: under the test command a skip happens only on a CPU that really lacks it.
#[cfg(test)]
pub(crate) fn avx512_for_test(what: &str) -> bool {
    if SimdLevel::Avx512.is_available() {
        return true;
    }
    assert!(
        std::env::var("MPM_CPU_HAS_AVX512").as_deref() != Ok("1"),
        "{what}: MPM_CPU_HAS_AVX512=1 (the CPU's flags list avx512f and avx2) but the run-time detection finds no AVX-512"
    );
    eprintln!("this CPU has no AVX-512F: {what} not checked");
    false
}

/// A block of particles in the blocked update: [`F4`] or `F8` with its width `N` as a
/// type parameter, so that the per-lane arrays of a block (`[_; N]`) can be sized by it.
pub trait Block<const N: usize>: Real {
    /// The lanes as an array.
    fn from_array(a: [f64; N]) -> Self;
    /// The mask whose lane `l` is `f(l)`.
    fn mask_from(f: impl FnMut(usize) -> bool) -> Self::Mask;
    /// The lanes as an array: every lane at once, where a loop over the lanes should read
    /// them (a lane taken from a register inside such a loop was stored whole and read back
    /// at each step, a store-forwarding stall each time).
    fn to_array(self) -> [f64; N];
    /// `f64::floor` lane by lane (one rounding instruction at AVX and up; a library call
    /// per lane on the x86-64 baseline, which has none).
    fn floor(self) -> Self;
    /// A mask's lanes as `bool`s, at once (as [`Block::to_array`]).
    fn mask_bools(m: Self::Mask) -> [bool; N];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detected_level_is_available_and_names_parse_back() {
        assert!(SimdLevel::detected().is_available());
        assert!(SimdLevel::Baseline.is_available());
        for l in SimdLevel::ALL {
            assert_eq!(l.name().parse::<SimdLevel>().unwrap(), l);
        }
        #[cfg(target_arch = "x86_64")]
        {
            assert_eq!(SimdLevel::Avx2.is_available(), std::arch::is_x86_feature_detected!("avx2"));
            assert_eq!(
                SimdLevel::Avx512.is_available(),
                std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx2")
            );
        }
        assert!("avx1024".parse::<SimdLevel>().is_err());
    }

    /// An `f64` operation of two operands (unary ones ignore the second).
    type Op<T> = fn(f64, f64) -> T;

    /// Every operation of [`F8`] gives each lane the bits its `f64` operation gives, on
    /// values that tell the implementations apart: zeros of both signs, infinities, NaN,
    /// subnormals, equal and unequal finite values, every pair of them.
    #[test]
    fn f8_lanes_are_the_f64_operations() {
        if !avx512_for_test("F8's operations") {
            return;
        }
        let special = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            2.5,
            -2.5,
            1e-310,
            -1e-310,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
            f64::MAX,
            0.1,
            3.0,
            -7.75,
        ];
        let pairs: Vec<(f64, f64)> = special.iter().flat_map(|&a| special.iter().map(move |&b| (a, b))).collect();
        let bits = |v: f64| v.to_bits();
        for chunk in pairs.chunks(LANES8) {
            let lane = |l: usize| chunk[l.min(chunk.len() - 1)];
            let a = F8::from_lanes(|l| lane(l).0);
            let b = F8::from_lanes(|l| lane(l).1);
            let ops: [(&str, F8, Op<f64>); 7] = [
                ("+", a + b, |x, y| x + y),
                ("-", a - b, |x, y| x - y),
                ("*", a * b, |x, y| x * y),
                ("/", a / b, |x, y| x / y),
                ("max", a.max(b), |x, y| if x > y { x } else { y }),
                ("neg", -a, |x, _| -x),
                ("sqrt", a.sqrt(), |x, _| x.sqrt()),
            ];
            let cmps: [(&str, <F8 as Real>::Mask, Op<bool>); 4] = [
                ("<=", a.le(b), |x, y| x <= y),
                ("<", a.lt(b), |x, y| x < y),
                (">=", a.ge(b), |x, y| x >= y),
                (">", a.gt(b), |x, y| x > y),
            ];
            let floor = a.floor();
            let picked = F8::select(a.lt(b), a, b);
            for l in 0..LANES8 {
                let (x, y) = lane(l);
                for (name, got, f) in &ops {
                    assert_eq!(bits(got.lane(l)), bits(f(x, y)), "{x:?} {name} {y:?} in lane {l}");
                }
                for (name, got, f) in &cmps {
                    assert_eq!(F8::mask_bools(*got)[l], f(x, y), "{x:?} {name} {y:?} in lane {l}");
                }
                assert_eq!(bits(floor.lane(l)), bits(x.floor()), "floor({x:?}) in lane {l}");
                assert_eq!(bits(picked.lane(l)), bits(if x < y { x } else { y }), "select in lane {l}");
                assert_eq!(bits(a.to_array()[l]), bits(x), "to_array lane {l}");
            }
        }
        // `max` against a constant zero (its every use) is `f64::max`'s, the tie of zeros +0.
        for x in special {
            let got = F8::splat(x).max(F8::splat(0.0)).lane(0);
            let want = if x.is_nan() || x == 0.0 { 0.0 } else { x.max(0.0) };
            assert_eq!(bits(got), bits(want), "max({x:?}, 0)");
            assert_eq!(bits(Real::max(x, 0.0)), bits(want), "f64: max({x:?}, 0)");
        }
        let m = F8::mask_from(|l| l % 3 == 0);
        assert_eq!(F8::mask_bools(m), std::array::from_fn(|l| l % 3 == 0));
        assert_eq!(F8::mask_bools(!m & F8::mask(true) | F8::mask(false)), std::array::from_fn(|l| l % 3 != 0));
    }
}
