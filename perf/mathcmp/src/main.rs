//! The core's own math against `micromath`'s, `fixed`'s and `cordic`'s: the compared
//! functions behind C-ABI entry points (`bench_<name>(input, output)`).
//!
//! For `thumbv7em-none-eabihf` this is a `no_std`, `no_main` image with no start-up
//! code: `.ci/mathcmp.py` loads it into `.ci/m4count.py`'s emulator, writes a case's
//! input at one pointer, calls `bench_<name>` and reads the result at the other,
//! counting the executed instructions. Built for the host, `main` sweeps each
//! function's domain densely against an `f64` reference (`host.rs`) and prints, per
//! function, one `fn` line (what it is, its domain and its worst error) and the sample
//! `case` lines whose emulated results must equal the host's bit for bit.
//!
//! Each function takes its input as the core would hand it (the core's functions their
//! own argument types; the others the nearest type they accept) and returns its result
//! unconverted, so the counts are of the function alone plus the few loads and stores
//! of its entry point.
#![cfg_attr(target_os = "none", no_std, no_main)]

use fixed::types::extra::{U0, U29, U32};
use fixed::{FixedI32, FixedI64, FixedU64};
use micromath::F32Ext;

/// `fixed`'s Q3.29 (range ±4, holds ±π).
pub type I3F29 = FixedI32<U29>;
/// `fixed`'s Q32.32.
pub type I32F32 = FixedI64<U32>;
/// `fixed`'s Q0.32: its product is the rounded or truncated high word of `i32 × i32`,
/// the operation of the core's [`pkmc::math::mulhr`].
pub type I0F32 = FixedI32<U32>;
/// `fixed`'s unsigned 64-bit integer (no fractional bits): its `sqrt` is an integer root.
pub type U64F0 = FixedU64<U0>;

/// Radians per n° as `f32` (for `micromath` on the core's angles).
const RAD_PER_NDEG: f32 = (core::f64::consts::PI / 180e9) as f32;

pub mod f {
    //! The compared functions, shared by the entry points and the host's sweeps.
    use super::*;

    /// The core: sine and cosine of an angle in n°, Q31 (`pkmc::math::sincos`).
    #[inline(always)]
    pub fn core_sincos(a: i64) -> [i32; 2] {
        let (s, c) = pkmc::math::sincos(a);
        [s, c]
    }
    /// `micromath`: `F32Ext::sin` of radians.
    #[inline(always)]
    pub fn mm_sin(x: f32) -> f32 {
        F32Ext::sin(x)
    }
    /// `micromath`: `F32Ext::cos` of radians.
    #[inline(always)]
    pub fn mm_cos(x: f32) -> f32 {
        F32Ext::cos(x)
    }
    /// `micromath` in the core's place: the angle in n° to `f32` radians (the core's
    /// two-conversion `i64_to_f32`, one multiply), then `F32Ext::sin_cos`.
    #[inline(always)]
    pub fn mm_sincos_ndeg(a: i64) -> [f32; 2] {
        let x = pkmc::math::i64_to_f32(a) * RAD_PER_NDEG;
        let (s, c) = F32Ext::sin_cos(x);
        [s, c]
    }
    /// `cordic` on `fixed`'s Q3.29: `sin_cos` of radians.
    #[inline(always)]
    pub fn cordic_sincos_i3f29(x: i32) -> [i32; 2] {
        let (s, c) = cordic::sin_cos(I3F29::from_bits(x));
        [s.to_bits(), c.to_bits()]
    }
    /// `cordic` on `fixed`'s Q32.32: `sin_cos` of radians.
    #[inline(always)]
    pub fn cordic_sincos_i32f32(x: i64) -> [i64; 2] {
        let (s, c) = cordic::sin_cos(I32F32::from_bits(x));
        [s.to_bits(), c.to_bits()]
    }
    /// The core: the correctly rounded `f32` root (`pkmc::math::sqrtf`, `VSQRT.F32`).
    #[inline(always)]
    pub fn core_sqrtf(x: f32) -> f32 {
        pkmc::math::sqrtf(x)
    }
    /// `micromath`: `F32Ext::sqrt`.
    #[inline(always)]
    pub fn mm_sqrt(x: f32) -> f32 {
        F32Ext::sqrt(x)
    }
    /// The core: `1 / √x` as the hexapod's Jacobian rows normalise a leg
    /// (`1.0 / pkmc::math::sqrt_f32(x)`: `VSQRT.F32`, `VDIV.F32`).
    #[inline(always)]
    pub fn core_inv_sqrt(x: f32) -> f32 {
        1.0 / pkmc::math::sqrt_f32(x)
    }
    /// `micromath`: `F32Ext::invsqrt`.
    #[inline(always)]
    pub fn mm_inv_sqrt(x: f32) -> f32 {
        F32Ext::invsqrt(x)
    }
    /// The core: the integer root of a leg length squared (`pkmc::math::isqrt`).
    #[inline(always)]
    pub fn core_isqrt(n: u64) -> u64 {
        pkmc::math::isqrt(n)
    }
    /// `fixed`: `sqrt` of a 64-bit integer (`FixedU64<U0>`, rounded down).
    #[inline(always)]
    pub fn fixed_sqrt_u64(n: u64) -> u64 {
        U64F0::from_bits(n).sqrt().to_bits()
    }
    /// `cordic` on `fixed`'s Q32.32: `sqrt`.
    #[inline(always)]
    pub fn cordic_sqrt_i32f32(x: i64) -> i64 {
        cordic::sqrt(I32F32::from_bits(x)).to_bits()
    }
    /// The core's arc angle (`libm::atan2` in `f64`, host side only: `Path::new`).
    #[inline(always)]
    pub fn core_atan2(yx: [f64; 2]) -> f64 {
        libm::atan2(yx[0], yx[1])
    }
    /// `micromath`: `F32Ext::atan2`.
    #[inline(always)]
    pub fn mm_atan2(yx: [f32; 2]) -> f32 {
        F32Ext::atan2(yx[0], yx[1])
    }
    /// `cordic` on `fixed`'s Q32.32: `atan2`.
    #[inline(always)]
    pub fn cordic_atan2_i32f32(yx: [i64; 2]) -> i64 {
        cordic::atan2(I32F32::from_bits(yx[0]), I32F32::from_bits(yx[1])).to_bits()
    }
    /// The core: the rounded high word of `i32 × i32` (`pkmc::math::mulhr`, `SMMULR`),
    /// the step of its sine and cosine polynomials.
    #[inline(always)]
    pub fn core_mulhr(ab: [i32; 2]) -> i32 {
        pkmc::math::mulhr(ab[0], ab[1])
    }
    /// `fixed`: the product of two Q0.32 numbers (the same high word).
    #[inline(always)]
    pub fn fixed_mul_i0f32(ab: [i32; 2]) -> i32 {
        (I0F32::from_bits(ab[0]) * I0F32::from_bits(ab[1])).to_bits()
    }
    /// `fixed`: the product of two Q32.32 numbers.
    #[inline(always)]
    pub fn fixed_mul_i32f32(ab: [i64; 2]) -> i64 {
        (I32F32::from_bits(ab[0]) * I32F32::from_bits(ab[1])).to_bits()
    }
}

/// One C-ABI entry point per compared function: `bench_<name>(input, output)`.
macro_rules! entry {
    ($($name:ident: $in:ty => $out:ty;)*) => {
        $(
            pub mod $name {
                /// The entry point of [`crate::f`]'s function of the same name.
                ///
                /// # Safety
                /// Valid, aligned pointers.
                #[export_name = concat!("bench_", stringify!($name))]
                pub unsafe extern "C" fn bench(input: *const $in, out: *mut $out) {
                    // SAFETY: the caller passes valid pointers.
                    unsafe { out.write(crate::f::$name(input.read())) }
                }
            }
        )*
    };
}

entry! {
    core_sincos: i64 => [i32; 2];
    mm_sin: f32 => f32;
    mm_cos: f32 => f32;
    mm_sincos_ndeg: i64 => [f32; 2];
    cordic_sincos_i3f29: i32 => [i32; 2];
    cordic_sincos_i32f32: i64 => [i64; 2];
    core_sqrtf: f32 => f32;
    mm_sqrt: f32 => f32;
    core_inv_sqrt: f32 => f32;
    mm_inv_sqrt: f32 => f32;
    core_isqrt: u64 => u64;
    fixed_sqrt_u64: u64 => u64;
    cordic_sqrt_i32f32: i64 => i64;
    core_atan2: [f64; 2] => f64;
    mm_atan2: [f32; 2] => f32;
    cordic_atan2_i32f32: [i64; 2] => i64;
    core_mulhr: [i32; 2] => i32;
    fixed_mul_i0f32: [i32; 2] => i32;
    fixed_mul_i32f32: [i64; 2] => i64;
}

#[cfg(target_os = "none")]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    // An undefined instruction stops the emulator with an error.
    // SAFETY: `udf` only traps.
    unsafe { core::arch::asm!("udf #0", options(noreturn)) }
}

#[cfg(not(target_os = "none"))]
mod host;

#[cfg(not(target_os = "none"))]
fn main() {
    host::print_all();
}
