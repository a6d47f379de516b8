//! Which vector unit the particle kernels run on, chosen at run time.
//!
//! The build targets the baseline of its architecture (x86-64: SSE2), so that one `mpm`
//! binary runs on every machine of a campaign. The particle update is written over blocks of
//! particles ([`crate::material::update_lanes`]) with branch-free selects, and the step
//! compiles it three times: for the baseline and with AVX2 enabled (`#[target_feature]`) over
//! blocks of [`LANES`] = 4 ([`F4`], one 256-bit register), and with AVX-512F enabled over
//! blocks of [`LANES8`] = 8 ([`F8`], one 512-bit register). The step calls the widest one the
//! CPU has ([`SimdLevel::detected`], through `is_x86_feature_detected!`), or the one
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

/// `[e(0), e(1), e(2), e(3)]` for the expression `e` of the lane `l`, written out: no
/// closure, so that the arithmetic costs little in the unoptimised build (o0) too.
macro_rules! each_lane {
    ($l:ident => $e:expr) => {
        [
            {
                let $l = 0;
                $e
            },
            {
                let $l = 1;
                $e
            },
            {
                let $l = 2;
                $e
            },
            {
                let $l = 3;
                $e
            },
        ]
    };
}

/// [`each_lane`] for the 8 lanes of [`F8`].
macro_rules! each_lane8 {
    ($l:ident => $e:expr) => {
        [
            {
                let $l = 0;
                $e
            },
            {
                let $l = 1;
                $e
            },
            {
                let $l = 2;
                $e
            },
            {
                let $l = 3;
                $e
            },
            {
                let $l = 4;
                $e
            },
            {
                let $l = 5;
                $e
            },
            {
                let $l = 6;
                $e
            },
            {
                let $l = 7;
                $e
            },
        ]
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
    /// `f64::max`.
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
        f64::max(self, other)
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

/// [`LANES`] `f64` lanes, one operation for all (a 256-bit register where AVX2 is on).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct F4(pub [f64; LANES]);

/// A comparison of [`F4`]s: all bits set in a lane where it holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct M4(pub [u64; LANES]);

impl M4 {
    /// Lane `l` as a `bool`.
    #[inline(always)]
    pub fn get(self, l: usize) -> bool {
        self.0[l] != 0
    }

    /// From one `bool` per lane.
    #[inline(always)]
    pub fn from_bools(b: [bool; LANES]) -> Self {
        M4(array(|l| if b[l] { u64::MAX } else { 0 }))
    }
}

macro_rules! lane_op {
    ($t:ident, $trait:ident, $method:ident, $op:tt) => {
        impl std::ops::$trait for $t {
            type Output = $t;
            #[inline(always)]
            fn $method(self, o: $t) -> $t {
                $t(each_lane!(l => self.0[l] $op o.0[l]))
            }
        }
    };
}
lane_op!(F4, Add, add, +);
lane_op!(F4, Sub, sub, -);
lane_op!(F4, Mul, mul, *);
lane_op!(F4, Div, div, /);
lane_op!(M4, BitAnd, bitand, &);
lane_op!(M4, BitOr, bitor, |);

impl std::ops::Neg for F4 {
    type Output = F4;
    #[inline(always)]
    fn neg(self) -> F4 {
        F4(array(|l| -self.0[l]))
    }
}

impl std::ops::Not for M4 {
    type Output = M4;
    #[inline(always)]
    fn not(self) -> M4 {
        M4(array(|l| !self.0[l]))
    }
}

impl F4 {
    #[inline(always)]
    fn compare(self, o: F4, f: impl Fn(f64, f64) -> bool) -> M4 {
        M4(each_lane!(l => if f(self.0[l], o.0[l]) { u64::MAX } else { 0 }))
    }
}

impl Real for F4 {
    type Mask = M4;
    #[inline(always)]
    fn splat(v: f64) -> Self {
        F4([v; LANES])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F4(array(|l| self.0[l].sqrt()))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        F4(array(|l| self.0[l].max(o.0[l])))
    }
    #[inline(always)]
    fn le(self, o: Self) -> M4 {
        self.compare(o, |a, b| a <= b)
    }
    #[inline(always)]
    fn lt(self, o: Self) -> M4 {
        self.compare(o, |a, b| a < b)
    }
    #[inline(always)]
    fn ge(self, o: Self) -> M4 {
        self.compare(o, |a, b| a >= b)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> M4 {
        self.compare(o, |a, b| a > b)
    }
    #[inline(always)]
    fn select(m: M4, a: Self, b: Self) -> Self {
        F4(each_lane!(l => f64::from_bits((m.0[l] & a.0[l].to_bits()) | (!m.0[l] & b.0[l].to_bits()))))
    }
    #[inline(always)]
    fn mask(v: bool) -> M4 {
        M4([if v { u64::MAX } else { 0 }; LANES])
    }
    const WIDTH: usize = LANES;
    #[inline(always)]
    fn lane(self, l: usize) -> f64 {
        self.0[l]
    }
    #[inline(always)]
    fn from_lanes(f: impl FnMut(usize) -> f64) -> Self {
        F4(array(f))
    }
}

/// [`LANES8`] `f64` lanes, one operation for all (a 512-bit register where AVX-512 is on):
/// [`F4`] twice as wide, each operation its `f64` operation lane by lane.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(64))]
pub struct F8(pub [f64; LANES8]);

/// A comparison of [`F8`]s: all bits set in a lane where it holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C, align(64))]
pub struct M8(pub [u64; LANES8]);

macro_rules! lane_op8 {
    ($t:ident, $trait:ident, $method:ident, $op:tt) => {
        impl std::ops::$trait for $t {
            type Output = $t;
            #[inline(always)]
            fn $method(self, o: $t) -> $t {
                $t(each_lane8!(l => self.0[l] $op o.0[l]))
            }
        }
    };
}
lane_op8!(F8, Add, add, +);
lane_op8!(F8, Sub, sub, -);
lane_op8!(F8, Mul, mul, *);
lane_op8!(F8, Div, div, /);
lane_op8!(M8, BitAnd, bitand, &);
lane_op8!(M8, BitOr, bitor, |);

impl std::ops::Neg for F8 {
    type Output = F8;
    #[inline(always)]
    fn neg(self) -> F8 {
        F8(each_lane8!(l => -self.0[l]))
    }
}

impl std::ops::Not for M8 {
    type Output = M8;
    #[inline(always)]
    fn not(self) -> M8 {
        M8(each_lane8!(l => !self.0[l]))
    }
}

impl Real for F8 {
    type Mask = M8;
    #[inline(always)]
    fn splat(v: f64) -> Self {
        F8([v; LANES8])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F8(each_lane8!(l => self.0[l].sqrt()))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        F8(each_lane8!(l => self.0[l].max(o.0[l])))
    }
    #[inline(always)]
    fn le(self, o: Self) -> M8 {
        M8(each_lane8!(l => if self.0[l] <= o.0[l] { u64::MAX } else { 0 }))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> M8 {
        M8(each_lane8!(l => if self.0[l] < o.0[l] { u64::MAX } else { 0 }))
    }
    #[inline(always)]
    fn ge(self, o: Self) -> M8 {
        M8(each_lane8!(l => if self.0[l] >= o.0[l] { u64::MAX } else { 0 }))
    }
    #[inline(always)]
    fn gt(self, o: Self) -> M8 {
        M8(each_lane8!(l => if self.0[l] > o.0[l] { u64::MAX } else { 0 }))
    }
    #[inline(always)]
    fn select(m: M8, a: Self, b: Self) -> Self {
        F8(each_lane8!(l => f64::from_bits((m.0[l] & a.0[l].to_bits()) | (!m.0[l] & b.0[l].to_bits()))))
    }
    #[inline(always)]
    fn mask(v: bool) -> M8 {
        M8([if v { u64::MAX } else { 0 }; LANES8])
    }
    const WIDTH: usize = LANES8;
    #[inline(always)]
    fn lane(self, l: usize) -> f64 {
        self.0[l]
    }
    #[inline(always)]
    fn from_lanes(f: impl FnMut(usize) -> f64) -> Self {
        F8(array(f))
    }
}

/// A block of particles in the blocked update: [`F4`] or [`F8`] with its width `N` as a
/// type parameter, so that the per-lane arrays of a block (`[_; N]`) can be sized by it.
pub trait Block<const N: usize>: Real {
    /// The lanes as an array.
    fn from_array(a: [f64; N]) -> Self;
    /// Lane `l` of a mask.
    fn mask_lane(m: Self::Mask, l: usize) -> bool;
    /// The mask whose lane `l` is `f(l)`.
    fn mask_from(f: impl FnMut(usize) -> bool) -> Self::Mask;
}

impl Block<LANES> for F4 {
    #[inline(always)]
    fn from_array(a: [f64; LANES]) -> Self {
        F4(a)
    }
    #[inline(always)]
    fn mask_lane(m: M4, l: usize) -> bool {
        m.get(l)
    }
    #[inline(always)]
    fn mask_from(mut f: impl FnMut(usize) -> bool) -> M4 {
        M4(array(|l| if f(l) { u64::MAX } else { 0 }))
    }
}

impl Block<LANES8> for F8 {
    #[inline(always)]
    fn from_array(a: [f64; LANES8]) -> Self {
        F8(a)
    }
    #[inline(always)]
    fn mask_lane(m: M8, l: usize) -> bool {
        m.0[l] != 0
    }
    #[inline(always)]
    fn mask_from(mut f: impl FnMut(usize) -> bool) -> M8 {
        M8(array(|l| if f(l) { u64::MAX } else { 0 }))
    }
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
}
