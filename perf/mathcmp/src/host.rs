//! The host run: each compared function swept densely over its domain against an `f64`
//! reference, then sample cases for the emulator.
//!
//! Lines (fields separated by tabs in `fn`, by spaces in `case`):
//! `fn NAME CRATE FUNCTION DOMAIN UNIT WORST AT POINTS`: the worst error over the sweep
//! in UNIT and the input where it occurs; `case NAME NIN NOUT w…`: NIN input words and
//! NOUT result words (`u32`, little-endian order of the value's bytes).

use super::f::*;

/// Points of each dense sweep.
const POINTS: usize = 1 << 20;
/// Cases per function for the emulator (evenly spaced over the sweep, ends included).
const SAMPLES: usize = 201;

/// A value as the `u32` words the emulator writes and reads.
trait Words: Copy {
    fn words(&self, out: &mut Vec<u32>);
}
macro_rules! words32 {
    ($($t:ty),*) => {$(
        impl Words for $t {
            fn words(&self, out: &mut Vec<u32>) {
                out.push(u32::from_le_bytes(self.to_le_bytes()));
            }
        }
    )*};
}
macro_rules! words64 {
    ($($t:ty),*) => {$(
        impl Words for $t {
            fn words(&self, out: &mut Vec<u32>) {
                let b = self.to_le_bytes();
                out.push(u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
                out.push(u32::from_le_bytes([b[4], b[5], b[6], b[7]]));
            }
        }
    )*};
}
words32!(i32, u32, f32);
words64!(i64, u64, f64);
impl<T: Words> Words for [T; 2] {
    fn words(&self, out: &mut Vec<u32>) {
        self[0].words(out);
        self[1].words(out);
    }
}

/// What a row of the table is: `name` is the entry point's (`bench_<name>`).
struct Row {
    name: &'static str,
    krate: &'static str,
    function: &'static str,
    domain: &'static str,
    unit: &'static str,
}

/// Sweeps `f` over `inputs`, prints its `fn` line and its sample `case` lines.
fn run<I: Words + core::fmt::Debug, O: Words>(
    row: Row,
    inputs: &[I],
    f: fn(I) -> O,
    err: impl Fn(I, O) -> f64,
) {
    let (mut worst, mut at) = (0.0f64, inputs[0]);
    for &x in inputs {
        let e = err(x, f(x));
        assert!(!e.is_nan(), "{}: NaN error at {x:?}", row.name);
        if e > worst {
            (worst, at) = (e, x);
        }
    }
    println!(
        "fn\t{}\t{}\t{}\t{}\t{}\t{worst:.3e}\t{at:?}\t{}",
        row.name,
        row.krate,
        row.function,
        row.domain,
        row.unit,
        inputs.len()
    );
    for k in 0..SAMPLES {
        let x = inputs[k * (inputs.len() - 1) / (SAMPLES - 1)];
        let (mut wi, mut wo) = (Vec::new(), Vec::new());
        x.words(&mut wi);
        f(x).words(&mut wo);
        let w: Vec<String> = wi.iter().chain(&wo).map(|w| w.to_string()).collect();
        println!(
            "case {} {} {} {}",
            row.name,
            wi.len(),
            wo.len(),
            w.join(" ")
        );
    }
}

/// `n` points evenly spaced over [lo, hi], ends included.
fn linear(lo: f64, hi: f64, n: usize) -> impl Iterator<Item = f64> {
    (0..n).map(move |k| lo + (hi - lo) * k as f64 / (n - 1) as f64)
}

/// `n` points evenly spaced in the logarithm over [lo, hi], ends included.
fn logarithmic(lo: f64, hi: f64, n: usize) -> impl Iterator<Item = f64> {
    linear(lo.ln(), hi.ln(), n).map(f64::exp)
}

/// Knuth's MMIX LCG, for the products' operands and the arcs' radii.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        self.0
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

const PI: f64 = core::f64::consts::PI;
const Q31: f64 = 2_147_483_648.0;
const Q29: f64 = 536_870_912.0;
const Q32: f64 = 4_294_967_296.0;

/// Radians of an angle in n°.
fn rad(a: i64) -> f64 {
    (a as f64 / 1e9).to_radians()
}

/// Every row of the table, in order.
pub fn print_all() {
    let deg = 1_000_000_000i64;
    // --- sine and cosine: the kinematics' and arcs' angles, ±180° ----------------
    let ndeg: Vec<i64> = linear(-180.0 * deg as f64, 180.0 * deg as f64, POINTS)
        .map(|a| a.round() as i64)
        .collect();
    let radians: Vec<f32> = linear(-PI, PI, POINTS).map(|x| x as f32).collect();
    let sincos_err = |x: f64, s: f64, c: f64| (s - x.sin()).abs().max((c - x.cos()).abs());
    run(
        Row {
            name: "core_sincos",
            krate: "pkmc",
            function: "math::sincos (n° → Q31 sin, cos)",
            domain: "±180°",
            unit: "abs",
        },
        &ndeg,
        core_sincos,
        |a, [s, c]| sincos_err(rad(a), s as f64 / Q31, c as f64 / Q31),
    );
    run(
        Row {
            name: "mm_sincos_ndeg",
            krate: "micromath",
            function: "F32Ext::sin_cos (n° → f32 rad → sin, cos)",
            domain: "±180°",
            unit: "abs",
        },
        &ndeg,
        mm_sincos_ndeg,
        |a, [s, c]| sincos_err(rad(a), s as f64, c as f64),
    );
    run(
        Row {
            name: "mm_sin",
            krate: "micromath",
            function: "F32Ext::sin (f32 rad)",
            domain: "±π",
            unit: "abs",
        },
        &radians,
        mm_sin,
        |x, s| (s as f64 - (x as f64).sin()).abs(),
    );
    run(
        Row {
            name: "mm_cos",
            krate: "micromath",
            function: "F32Ext::cos (f32 rad)",
            domain: "±π",
            unit: "abs",
        },
        &radians,
        mm_cos,
        |x, c| (c as f64 - (x as f64).cos()).abs(),
    );
    let q29: Vec<i32> = linear(-PI, PI, POINTS)
        .map(|x| (x * Q29).round() as i32)
        .collect();
    run(
        Row {
            name: "cordic_sincos_i3f29",
            krate: "cordic on fixed",
            function: "cordic::sin_cos::<I3F29> (rad)",
            domain: "±π",
            unit: "abs",
        },
        &q29,
        cordic_sincos_i3f29,
        |x, [s, c]| sincos_err(x as f64 / Q29, s as f64 / Q29, c as f64 / Q29),
    );
    let q32: Vec<i64> = linear(-PI, PI, POINTS)
        .map(|x| (x * Q32).round() as i64)
        .collect();
    run(
        Row {
            name: "cordic_sincos_i32f32",
            krate: "cordic on fixed",
            function: "cordic::sin_cos::<I32F32> (rad)",
            domain: "±π",
            unit: "abs",
        },
        &q32,
        cordic_sincos_i32f32,
        |x, [s, c]| sincos_err(x as f64 / Q32, s as f64 / Q32, c as f64 / Q32),
    );

    // --- square roots --------------------------------------------------------------
    // The planner's and profile's speeds from squares (any magnitude: relative error).
    let squares: Vec<f32> = logarithmic(1e-6, 1e16, POINTS).map(|x| x as f32).collect();
    let rel = |x: f32, r: f32| ((r as f64 - (x as f64).sqrt()) / (x as f64).sqrt()).abs();
    run(
        Row {
            name: "core_sqrtf",
            krate: "pkmc",
            function: "math::sqrtf (f32, VSQRT.F32)",
            domain: "1e-6 … 1e16",
            unit: "rel",
        },
        &squares,
        core_sqrtf,
        rel,
    );
    run(
        Row {
            name: "mm_sqrt",
            krate: "micromath",
            function: "F32Ext::sqrt (f32)",
            domain: "1e-6 … 1e16",
            unit: "rel",
        },
        &squares,
        mm_sqrt,
        rel,
    );
    // A hexapod leg's length squared in mm² (100 mm … 1 m), to normalise it.
    let legs: Vec<f32> = logarithmic(1e4, 1e6, POINTS).map(|x| x as f32).collect();
    let inv_rel = |x: f32, r: f32| ((r as f64 * (x as f64).sqrt()) - 1.0).abs();
    run(
        Row {
            name: "core_inv_sqrt",
            krate: "pkmc",
            function: "1 / math::sqrt_f32 (f32)",
            domain: "1e4 … 1e6 mm²",
            unit: "rel",
        },
        &legs,
        core_inv_sqrt,
        inv_rel,
    );
    run(
        Row {
            name: "mm_inv_sqrt",
            krate: "micromath",
            function: "F32Ext::invsqrt (f32)",
            domain: "1e4 … 1e6 mm²",
            unit: "rel",
        },
        &legs,
        mm_inv_sqrt,
        inv_rel,
    );
    // The kinematics' integer roots: leg lengths squared in nm² (100 mm … 2.2 m).
    let n2: Vec<u64> = logarithmic(1e16, 4.8e18, POINTS)
        .map(|x| x as u64)
        .collect();
    // |r − √n| exactly enough: √n in f64 is within 3e-7 at 2.2e9.
    let root_err = |n: u64, r: u64| (r as f64 - (n as f64).sqrt()).abs();
    run(
        Row {
            name: "core_isqrt",
            krate: "pkmc",
            function: "math::isqrt (u64)",
            domain: "1e16 … 4.8e18 nm²",
            unit: "nm",
        },
        &n2,
        core_isqrt,
        root_err,
    );
    run(
        Row {
            name: "fixed_sqrt_u64",
            krate: "fixed",
            function: "FixedU64::<U0>::sqrt",
            domain: "1e16 … 4.8e18 nm²",
            unit: "nm",
        },
        &n2,
        fixed_sqrt_u64,
        root_err,
    );
    // The same squares in mm² as Q32.32 (the root in mm, its error in nm).
    let mm2: Vec<i64> = n2
        .iter()
        .map(|&n| (n as f64 * 1e-12 * Q32).round() as i64)
        .collect();
    run(
        Row {
            name: "cordic_sqrt_i32f32",
            krate: "cordic on fixed",
            function: "cordic::sqrt::<I32F32> (mm²)",
            domain: "1e4 … 4.8e6 mm²",
            unit: "nm",
        },
        &mm2,
        cordic_sqrt_i32f32,
        |x, r| (r as f64 / Q32 - (x as f64 / Q32).sqrt()).abs() * 1e6,
    );

    // --- atan2: an arc's end angles (host side, `Path::new`) -------------------------
    let mut rng = Lcg(31);
    let ends: Vec<[f64; 2]> = linear(-PI, PI, POINTS)
        .map(|t| {
            let r = 1e3 * (5e5f64).powf(rng.unit()); // 1 µm … 500 mm, in nm
            [(r * t.sin()).round(), (r * t.cos()).round()]
        })
        .collect();
    let angle_err = |got: f64, want: f64| {
        let d = (got - want).abs();
        d.min(2.0 * PI - d)
    };
    run(
        Row {
            name: "core_atan2",
            krate: "pkmc (libm)",
            function: "libm::atan2 (f64, host side only)",
            domain: "r 1 µm … 500 mm",
            unit: "rad",
        },
        &ends,
        core_atan2,
        |[y, x], a| angle_err(a, y.atan2(x)),
    );
    let ends32: Vec<[f32; 2]> = ends.iter().map(|e| e.map(|v| v as f32)).collect();
    run(
        Row {
            name: "mm_atan2",
            krate: "micromath",
            function: "F32Ext::atan2 (f32)",
            domain: "r 1 µm … 500 mm",
            unit: "rad",
        },
        &ends32,
        mm_atan2,
        |[y, x], a| angle_err(a as f64, (y as f64).atan2(x as f64)),
    );
    let ends_q32: Vec<[i64; 2]> = ends
        .iter()
        .map(|e| e.map(|v| (v * 1e-6 * Q32).round() as i64))
        .collect();
    run(
        Row {
            name: "cordic_atan2_i32f32",
            krate: "cordic on fixed",
            function: "cordic::atan2::<I32F32> (mm)",
            domain: "r 1 µm … 500 mm",
            unit: "rad",
        },
        &ends_q32,
        cordic_atan2_i32f32,
        |[y, x], a| angle_err(a as f64 / Q32, (y as f64).atan2(x as f64)),
    );

    // --- products -------------------------------------------------------------------
    let mut rng = Lcg(5);
    let pairs: Vec<[i32; 2]> = (0..POINTS)
        .map(|_| {
            let v = rng.next();
            [(v >> 32) as i32, v as i32]
        })
        .collect();
    // Error in units of the result's last place: (r·2^32 − a·b) / 2^32, exact.
    let high_word_err =
        |[a, b]: [i32; 2], r: i32| ((r as i128) << 32).abs_diff(a as i128 * b as i128) as f64 / Q32;
    run(
        Row {
            name: "core_mulhr",
            krate: "pkmc",
            function: "math::mulhr (i32 × i32 → rounded high word)",
            domain: "all i32",
            unit: "LSB",
        },
        &pairs,
        core_mulhr,
        high_word_err,
    );
    run(
        Row {
            name: "fixed_mul_i0f32",
            krate: "fixed",
            function: "I0F32 × I0F32 (the same high word)",
            domain: "all i32",
            unit: "LSB",
        },
        &pairs,
        fixed_mul_i0f32,
        high_word_err,
    );
    let wide: Vec<[i64; 2]> = (0..POINTS)
        .map(|_| {
            let h = |v: u64| (v as i64) >> 17; // |·| < 2^46: the product fits Q32.32
            [h(rng.next()), h(rng.next())]
        })
        .collect();
    run(
        Row {
            name: "fixed_mul_i32f32",
            krate: "fixed",
            function: "I32F32 × I32F32 (no core counterpart)",
            domain: "±2^14",
            unit: "LSB",
        },
        &wide,
        fixed_mul_i32f32,
        |[a, b], r| ((r as i128) << 32).abs_diff(a as i128 * b as i128) as f64 / Q32,
    );
}
