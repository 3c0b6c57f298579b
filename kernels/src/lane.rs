//! One number or several side by side: the element kernels and the rigid bodies' pose
//! update are written once over [`Lane`] and run as the scalar twin (`f64`) or on SIMD
//! vectors, with the same operations in the same order in every lane (so the bits agree).

use std::ops::{Add, Div, Mul, Neg, Sub};
use wide::{f64x4, f64x8};

/// One value per element or body: `f64` (the scalar twin) or `f64x4`, `f64x8` (four or
/// eight at once, every operation applied to each lane alike).
pub trait Lane:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// Every lane `v`.
    fn splat(v: f64) -> Self;
    /// `self * m + a`, fused.
    fn fma(self, m: Self, a: Self) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Lane-wise maximum.
    fn max(self, o: Self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    /// `if a < b { x } else { y }`, lane by lane.
    fn if_lt(a: Self, b: Self, x: Self, y: Self) -> Self;
    /// Whether `self <= 0` (or NaN) in any lane.
    fn any_not_positive(self) -> bool;
}

impl Lane for f64 {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn fma(self, m: Self, a: Self) -> Self {
        self.mul_add(m, a)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        f64::max(self, o)
    }
    #[inline(always)]
    fn ln(self) -> Self {
        f64::ln(self)
    }
    #[inline(always)]
    fn if_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
        if a < b {
            x
        } else {
            y
        }
    }
    #[inline(always)]
    fn any_not_positive(self) -> bool {
        self.is_nan() || self <= 0.0
    }
}

macro_rules! wide_lane {
    ($t:ident) => {
        impl Lane for $t {
            #[inline(always)]
            fn splat(v: f64) -> Self {
                $t::splat(v)
            }
            #[inline(always)]
            fn fma(self, m: Self, a: Self) -> Self {
                self.mul_add(m, a)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                $t::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                $t::abs(self)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                $t::max(self, o)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                $t::ln(self)
            }
            #[inline(always)]
            fn if_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
                a.simd_lt(b).bitselect(x, y)
            }
            #[inline(always)]
            fn any_not_positive(self) -> bool {
                // Not (all lanes > 0): NaN lanes compare false.
                !$t::ZERO.simd_lt(self).all()
            }
        }
    };
}

wide_lane!(f64x4);
wide_lane!(f64x8);
