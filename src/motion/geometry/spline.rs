//! Spline paths: cubic ([`Motion::Cubic`]) and quadratic ([`Motion::Quadratic`])
//! Bézier curves, in exact integers.
//!
//! A block's curve P(u), u ∈ [0, 1], from its start P₀ to its target P₃, is kept in the
//! power basis P(u) = P₀ + a₁u + a₂u² + a₃u³ with integer coefficients formed exactly
//! from the control points (so P(1) is the target exactly): for a cubic with control
//! points C₁ = P₀ + c₁ and C₂ = P₃ + c₂ and Δ = P₃ − P₀, a₁ = 3c₁, a₂ = 3(Δ + c₂ − 2c₁),
//! a₃ = 3(c₁ − c₂) − 2Δ; for a quadratic with control point P₀ + c, a₁ = 2c,
//! a₂ = Δ − 2c, a₃ = 0 — a parabola, exactly.
//!
//! The parameter advances linearly with the path distance: u = s / S, where the
//! block's length S is the largest |dP/du| over X Y Z along the curve. The tool's
//! speed is then |dP/ds| = |dP/du| / S ≤ 1 times the path speed everywhere: the
//! planned path speed is an upper bound of the real one (equal where the curve is
//! fastest), and a curve the host fitted with a near-uniform parameter runs within a
//! few per cent of it. Per tick the controller forms u in Q32 with one multiplication
//! by ⌊2⁶⁴/S⌋ (sent with the plan, checked without a division) and evaluates the cubic
//! per axis by Horner's rule, each product a 64-bit coefficient times the 32-bit u
//! as two 32 × 32-bit multiplications ([`mul_q32`]): the parameter's step of 2⁻³²
//! moves an axis by at most |dP/du|·2⁻³² (a hundredth of a nanometre on a 100 mm
//! curve, 7 n° on a 30° swing), far inside the planner's margin on every limit, and
//! the end is snapped to the target.

use super::{Course, Form, GeometryError};
use crate::config::AXES;
use crate::motion::block::Motion;

/// The part of a spline beyond its [`Course`] (whose `unit` holds a₁).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Curve {
    /// a₂ per axis, axis units.
    pub a2: [i64; AXES],
    /// a₃ per axis, axis units.
    pub a3: [i64; AXES],
    /// ⌊2⁶⁴ / length⌋: u (Q32) = (s·rate) ≫ 48 for s in nm Q16.
    pub rate: u64,
}

/// Largest |a₁| + |a₂| + |a₃| of any axis (2³⁹ units: 550 m, or 550° on a rotary
/// axis): Horner's partial sums then stay within 2³⁹, and [`mul_q32`]'s high part
/// within 32 bits.
pub const MAX_SPLINE_SPAN: i64 = 1 << 39;

/// Shortest spline, nm (a shorter curve is sent as a line).
pub const MIN_SPLINE_NM: i64 = 2;

/// The power-basis coefficients (a₁, a₂, a₃) of a spline block from `start` to `end`,
/// exactly; `None` for other motions or coefficients beyond [`MAX_SPLINE_SPAN`].
pub fn coefficients(
    motion: &Motion,
    start: &[i64; AXES],
    end: &[i64; AXES],
) -> Option<[[i64; AXES]; 3]> {
    let mut a = [[0i64; AXES]; 3];
    let [a1, a2, a3] = &mut a;
    coefficients_into(motion, start, end, a1, a2, a3).then_some(a)
}

/// [`coefficients`] written into `a1`, `a2`, `a3` (the controller's course and curve,
/// where they stay); false when out of range (they then hold some values).
fn coefficients_into(
    motion: &Motion,
    start: &[i64; AXES],
    end: &[i64; AXES],
    a1: &mut [i64; AXES],
    a2: &mut [i64; AXES],
    a3: &mut [i64; AXES],
) -> bool {
    // Every input below 2³⁹ in size keeps the sums below 2⁴⁵: 64-bit arithmetic
    // (the controller's receive path has no 128-bit products to spare).
    let small = |x: i64| x.unsigned_abs() < MAX_SPLINE_SPAN as u64;
    for i in 0..AXES {
        let d = end[i].wrapping_sub(start[i]);
        let (b1, b2, b3) = match motion {
            Motion::Cubic { c1, c2 } if d == 0 && c1[i] == 0 && c2[i] == 0 => (0, 0, 0),
            Motion::Quadratic { c } if d == 0 && c[i] == 0 => (0, 0, 0),
            Motion::Cubic { c1, c2 } if small(d) && small(c1[i]) && small(c2[i]) => {
                let (c1, c2) = (c1[i], c2[i]);
                (3 * c1, 3 * (d + c2 - 2 * c1), 3 * (c1 - c2) - 2 * d)
            }
            Motion::Quadratic { c } if small(d) && small(c[i]) => (2 * c[i], d - 2 * c[i], 0),
            _ => return false,
        };
        if b1.abs() + b2.abs() + b3.abs() >= MAX_SPLINE_SPAN {
            return false;
        }
        a1[i] = b1;
        a2[i] = b2;
        a3[i] = b3;
    }
    true
}

/// (a·u) ≫ 32 rounded, for |a| < 2³⁹ and u a Q32 fraction: a's high and low words
/// times u, two 32 × 32-bit multiplications (no 128-bit product).
#[inline(always)]
pub fn mul_q32(a: i64, u: u32) -> i64 {
    let (hi, lo) = ((a >> 32) as i32, a as u32);
    hi as i64 * u as i64 + ((lo as u64 * u as u64 + (1 << 31)) >> 32) as i64
}

/// |dP/du| over X Y Z at `u` (f64, host).
fn speed_at(a: &[[i64; AXES]; 3], u: f64) -> f64 {
    libm::sqrt(
        (0..3)
            .map(|i| {
                let d = a[0][i] as f64 + 2.0 * a[1][i] as f64 * u + 3.0 * a[2][i] as f64 * u * u;
                d * d
            })
            .sum::<f64>(),
    )
}

/// The length the host gives a spline: the largest |dP/du| over X Y Z, found on a grid
/// and refined around the best point, then raised by 10⁻⁶ (and a unit) so that the
/// refinement's residue cannot make the tool faster than the path speed.
pub fn host_length(a: &[[i64; AXES]; 3]) -> f64 {
    const GRID: usize = 64;
    let (mut best, mut at) = (0.0f64, 0.0f64);
    for k in 0..=GRID {
        let u = k as f64 / GRID as f64;
        let v = speed_at(a, u);
        if v > best {
            best = v;
            at = u;
        }
    }
    // |dP/du|² is a quartic: golden-section search within the grid cell each side.
    let (mut lo, mut hi) = (
        (at - 1.0 / GRID as f64).max(0.0),
        (at + 1.0 / GRID as f64).min(1.0),
    );
    for _ in 0..60 {
        let m1 = lo + (hi - lo) * 0.381_966;
        let m2 = hi - (hi - lo) * 0.381_966;
        if speed_at(a, m1) < speed_at(a, m2) {
            lo = m1;
        } else {
            hi = m2;
        }
    }
    let best = best.max(speed_at(a, (lo + hi) / 2.0));
    libm::ceil(best * (1.0 + 1e-6)) + 1.0
}

/// ⌊2⁶⁴ / length⌋ (length ≥ [`MIN_SPLINE_NM`]).
pub fn rate_of(length: i64) -> u64 {
    ((1u128 << 64) / length.max(MIN_SPLINE_NM) as u128) as u64
}

/// The spline's derivative control points over X Y Z: dP/du is the Bézier of these
/// (the curve's own hull bounds it); cubic: 3c₁, 3(Δ + c₂ − c₁), −3c₂; quadratic:
/// 2c, 2(Δ − c) (the third repeats the second).
fn hull(motion: &Motion, start: &[i64; AXES], end: &[i64; AXES]) -> [[f32; 3]; 3] {
    let f = crate::math::i64_to_f32;
    let mut h = [[0f32; 3]; 3];
    for i in 0..3 {
        let d = f(end[i].wrapping_sub(start[i]));
        match motion {
            Motion::Cubic { c1, c2 } => {
                h[0][i] = 3.0 * f(c1[i]);
                h[1][i] = 3.0 * (d + f(c2[i]) - f(c1[i]));
                h[2][i] = -3.0 * f(c2[i]);
            }
            Motion::Quadratic { c } => {
                h[0][i] = 2.0 * f(c[i]);
                h[1][i] = 2.0 * (d - f(c[i]));
                h[2][i] = h[1][i];
            }
            _ => {}
        }
    }
    h
}

impl Course {
    /// The controller's check of a spline plan (see [`Course::set_from_plan`]): exact
    /// coefficients within range, some motion over X Y Z, a length between the chord
    /// and the derivative's hull (which bound the largest |dP/du| from below and above),
    /// and the rate ⌊2⁶⁴/length⌋; no `f64`, no division. Fills `self` and `curve`.
    pub(super) fn set_spline(
        &mut self,
        curve: &mut Curve,
        motion: &Motion,
        start: &[i64; AXES],
        length: i64,
        rate: u64,
    ) -> Result<(), GeometryError> {
        let bad = Err(GeometryError::PlanMismatch);
        if !coefficients_into(
            motion,
            start,
            &self.end,
            &mut self.unit,
            &mut curve.a2,
            &mut curve.a3,
        ) {
            return Err(GeometryError::SplineOutOfRange);
        }
        if !(MIN_SPLINE_NM..MAX_SPLINE_SPAN).contains(&length) {
            return bad;
        }
        let l = length as u128;
        let e = (rate as u128 * l).abs_diff(1u128 << 64);
        if e >= l {
            return bad;
        }
        let f = crate::math::i64_to_f32;
        let norm = |v: &[f32; 3]| crate::math::sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        let delta: [f32; 3] = core::array::from_fn(|i| f(self.end[i].wrapping_sub(start[i])));
        let h = hull(motion, start, &self.end);
        let top = h.iter().map(norm).fold(0.0, crate::math::fmax);
        let (chord, len) = (norm(&delta), f(length));
        if top == 0.0 || len < chord * (1.0 - 1e-5) - 2.0 || len > top * (1.0 + 1e-5) + 2.0 {
            return bad;
        }
        self.length = length;
        self.rotary_only = false;
        self.form = Form::Spline;
        curve.rate = rate;
        Ok(())
    }

    /// The spline's pose at `s` (nm Q16, 0 ≤ s ≤ length·2¹⁶) from `start`.
    pub(super) fn eval_spline(
        &self,
        curve: &Curve,
        start: &[i64; AXES],
        s: i64,
        pose: &mut [i64; AXES],
    ) {
        let u = ((s as i128 * curve.rate as i128) >> 48).min(u32::MAX as i128) as u32;
        for i in 0..AXES {
            let (a1, a2, a3) = (self.unit[i], curve.a2[i], curve.a3[i]);
            pose[i] = if a1 | a2 | a3 == 0 {
                start[i]
            } else {
                let t = a2 + mul_q32(a3, u);
                let t = a1 + mul_q32(t, u);
                start[i] + mul_q32(t, u)
            };
        }
    }

    /// dP/ds at `s` (nm Q16) per axis (per nm of path; at most 1 over X Y Z), host.
    pub(super) fn spline_tangent(&self, curve: &Curve, s: i64) -> [f32; AXES] {
        let len = self.length.max(1) as f64;
        let u = (s as f64 / 65_536.0 / len).clamp(0.0, 1.0);
        core::array::from_fn(|i| {
            let d = self.unit[i] as f64
                + 2.0 * curve.a2[i] as f64 * u
                + 3.0 * curve.a3[i] as f64 * u * u;
            (d / len) as f32
        })
    }

    /// d²P/ds² at `s` (nm Q16) per axis (per nm²), host.
    pub(super) fn spline_bend(&self, curve: &Curve, s: i64) -> [f32; AXES] {
        let len = self.length.max(1) as f64;
        let u = (s as f64 / 65_536.0 / len).clamp(0.0, 1.0);
        core::array::from_fn(|i| {
            ((2.0 * curve.a2[i] as f64 + 6.0 * curve.a3[i] as f64 * u) / (len * len)) as f32
        })
    }

    /// Per axis, the largest |dP/ds| and |d²P/ds²| along the spline (per nm and nm²),
    /// exactly: dP/du = a₁ + 2a₂u + 3a₃u² peaks at an end or at its vertex, and
    /// d²P/du² = 2a₂ + 6a₃u at an end.
    pub fn spline_bounds(&self, curve: &Curve) -> ([f32; AXES], [f32; AXES]) {
        let len = self.length.max(1) as f64;
        let (mut d1, mut d2) = ([0f32; AXES], [0f32; AXES]);
        for i in 0..AXES {
            let (a1, a2, a3) = (self.unit[i] as f64, curve.a2[i] as f64, curve.a3[i] as f64);
            let at = |u: f64| (a1 + 2.0 * a2 * u + 3.0 * a3 * u * u).abs();
            let mut m = at(0.0).max(at(1.0));
            if a3 != 0.0 {
                let v = -a2 / (3.0 * a3);
                if (0.0..=1.0).contains(&v) {
                    m = m.max(at(v));
                }
            }
            d1[i] = (m / len) as f32;
            d2[i] = ((2.0 * a2).abs().max((2.0 * a2 + 6.0 * a3).abs()) / (len * len)) as f32;
        }
        (d1, d2)
    }
}

#[cfg(test)]
mod tests {
    use super::super::Path;
    use crate::config::AXES;
    use crate::motion::block::{Block, Motion};

    fn cubic(target: [i64; AXES], c1: [i64; AXES], c2: [i64; AXES]) -> Block {
        Block {
            line: 1,
            motion: Motion::Cubic { c1, c2 },
            target,
            feed: 1_000_000,
            tolerance_nm: 1000,
        }
    }

    /// The Bézier in f64 from its control points.
    fn bezier(p: [[f64; AXES]; 4], u: f64) -> [f64; AXES] {
        let w = [
            (1.0 - u).powi(3),
            3.0 * (1.0 - u).powi(2) * u,
            3.0 * (1.0 - u) * u * u,
            u.powi(3),
        ];
        core::array::from_fn(|i| (0..4).map(|k| w[k] * p[k][i]).sum())
    }

    fn controls(start: [i64; AXES], b: &Block) -> [[f64; AXES]; 4] {
        let f = |a: [i64; AXES]| a.map(|x| x as f64);
        let (s, e) = (f(start), f(b.target));
        match b.motion {
            Motion::Cubic { c1, c2 } => [
                s,
                core::array::from_fn(|i| s[i] + c1[i] as f64),
                core::array::from_fn(|i| e[i] + c2[i] as f64),
                e,
            ],
            Motion::Quadratic { c } => {
                // Degree elevation: the same parabola as a cubic.
                let q: [f64; AXES] = core::array::from_fn(|i| s[i] + c[i] as f64);
                [
                    s,
                    core::array::from_fn(|i| s[i] + 2.0 / 3.0 * (q[i] - s[i])),
                    core::array::from_fn(|i| e[i] + 2.0 / 3.0 * (q[i] - e[i])),
                    e,
                ]
            }
            _ => unreachable!(),
        }
    }

    proptest::proptest! {
        /// The controller accepts what the host computes; the curve it interpolates
        /// is the Bézier (within 2 nm plus the parameter's step), ends exactly on the
        /// target, and the tool never moves faster than the path distance.
        #[test]
        fn splines_follow_their_bezier_end_exactly_and_never_outrun_the_path(
            d in proptest::array::uniform6(-50_000_000i64..50_000_000),
            c1 in proptest::array::uniform6(-20_000_000i64..20_000_000),
            c2 in proptest::array::uniform6(-20_000_000i64..20_000_000),
            start in proptest::array::uniform6(-100_000_000i64..100_000_000),
            quadratic in proptest::bool::ANY,
        ) {
            let mut target = start;
            for i in 0..AXES {
                target[i] += d[i];
            }
            let mut b = cubic(target, c1, c2);
            if quadratic {
                b.motion = Motion::Quadratic { c: c1 };
            }
            let host = Path::new(&b, &start).unwrap();
            let ctl = Path::from_plan(&b, &start, host.length, host.shape());
            proptest::prop_assert_eq!(ctl, Ok(host));
            let p = host;
            let ctrl = controls(start, &b);
            let n = 400i64;
            let mut prev = start;
            let mut pose = [0; AXES];
            // The parameter's step moves an axis by at most |dP/du|·2⁻³² (X Y Z: at
            // most length·2⁻³²), Horner's roundings by 1.5.
            let super::super::Bend::Spline(cv, _) = p.bend else { panic!("not a spline") };
            let step_of = |i: usize| {
                (p.unit[i].abs() as f64 + 2.0 * cv.a2[i].abs() as f64 + 3.0 * cv.a3[i].abs() as f64)
                    / 4_294_967_296.0 + 1.5
            };
            let step = p.length as f64 / 4_294_967_296.0 + 1.5;
            for k in 0..=n {
                let s = (p.length << 16) / n * k;
                p.pose_at(&start, s, &mut pose);
                let want = bezier(ctrl, s as f64 / 65_536.0 / p.length as f64);
                for i in 0..AXES {
                    // Quadratics are compared with their degree elevation (exact in
                    // f64 up to its rounding).
                    proptest::prop_assert!((pose[i] as f64 - want[i]).abs() <= step_of(i) + 1.0,
                        "axis {} at {}: {} vs {}", i, k, pose[i], want[i]);
                }
                if k > 0 {
                    let ds = (p.length as f64) / n as f64;
                    let moved = (0..3).map(|i| ((pose[i] - prev[i]) as f64).powi(2)).sum::<f64>().sqrt();
                    proptest::prop_assert!(moved <= ds * (1.0 + 1e-6) + 2.0 * step + 2.0,
                        "moved {} over {}", moved, ds);
                }
                prev = pose;
            }
            p.pose_at(&start, p.length << 16, &mut pose);
            proptest::prop_assert_eq!(pose, target);
        }
    }

    proptest::proptest! {
        #[test]
        fn mul_q32_is_the_rounded_product(a in -(1i64 << 39) + 1..(1i64 << 39), u in proptest::num::u32::ANY) {
            let want = ((a as i128 * u as i128 + (1i128 << 31)) >> 32) as i64;
            proptest::prop_assert_eq!(super::mul_q32(a, u), want);
        }
    }

    #[test]
    fn a_quadratic_is_a_parabola_exactly() {
        let start = [0; AXES];
        let b = Block {
            motion: Motion::Quadratic {
                c: [5_000_000, 10_000_000, 0, 0, 0, 0],
            },
            ..cubic([10_000_000, 0, 0, 0, 0, 0], [0; AXES], [0; AXES])
        };
        let p = Path::new(&b, &start).unwrap();
        let super::super::Bend::Spline(c, _) = p.bend else {
            panic!("not a spline")
        };
        assert_eq!(c.a3, [0; AXES]);
        // y = 2·10⁷·u(1 − u), x = 10⁷·u: y = 2x(1 − x/10⁷), at u = ½: (5, 5) mm.
        let mut pose = [0; AXES];
        let half = super::host_length(&[p.unit, c.a2, c.a3]);
        assert!((half - p.length as f64).abs() <= 1.0);
        // u = ½ through the rate (s = length/2 gives u within a step of ½).
        p.pose_at(&start, p.length << 15, &mut pose);
        assert!((pose[0] - 5_000_000).abs() <= 2, "{pose:?}");
        assert!((pose[1] - 5_000_000).abs() <= 2, "{pose:?}");
    }

    #[test]
    fn a_plan_for_another_curve_or_length_is_refused() {
        use crate::motion::geometry::GeometryError;
        let start = [0; AXES];
        let b = cubic(
            [10_000_000, 0, 0, 0, 0, 0],
            [3_000_000, 3_000_000, 0, 0, 0, 0],
            [-3_000_000, 3_000_000, 0, 0, 0, 0],
        );
        let p = Path::new(&b, &start).unwrap();
        let bad = Err(GeometryError::PlanMismatch);
        // Shorter than the chord, longer than the hull, or a wrong rate.
        assert_eq!(Path::from_plan(&b, &start, 9_000_000, p.shape()), bad);
        assert_eq!(Path::from_plan(&b, &start, p.length * 4, p.shape()), bad);
        let wrong = crate::motion::block::Shape::Spline {
            rate: super::rate_of(p.length) + (1 << 20),
            dip: None,
        };
        assert_eq!(Path::from_plan(&b, &start, p.length, wrong), bad);
        // A rotary-only curve, or one whose control points are out of range.
        let rot = cubic([0, 0, 0, 1_000_000_000, 0, 0], [0; AXES], [0; AXES]);
        assert_eq!(
            Path::new(&rot, &start),
            Err(GeometryError::SplineOutOfRange)
        );
        let far = cubic([1, 0, 0, 0, 0, 0], [1 << 40, 0, 0, 0, 0, 0], [0; AXES]);
        assert_eq!(
            Path::from_plan(&far, &start, 1000, p.shape()),
            Err(GeometryError::SplineOutOfRange)
        );
    }
}
