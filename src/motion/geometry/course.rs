//! The controller's side of a path: a streamed plan checked and written in place
//! ([`Course::set_from_plan`]), the pose at a distance, the tangent and the bend.

use super::*;

/// Does an arc's planned `length` agree with its radius (`r0`, `dr`), its `sweep`
/// (turns Q64, as its rate stands for it) and its `helix` (nm)? The controller's check
/// of [`Path::from_plan`], in `f32`.
#[inline(always)]
fn arc_length_ok(r0: i64, dr: i64, sweep: i128, helix: i64, length: i64) -> bool {
    // Length: √((r̄·|sweep|)² + helix²), to 10⁻⁵ (single precision). The
    // sweep is converted whole (its turns, then its fraction): cut to 2⁻³²
    // turn, a sweep of 10⁻⁵ turn (0.2 mm on a 4 m radius) was off by 3·10⁻⁵
    // and its plan refused.
    let f = crate::math::i64_to_f32;
    let sw = sweep.unsigned_abs();
    let sweep_turns = crate::math::u64_to_f32((sw >> 64) as u64)
        + crate::math::u64_to_f32(sw as u64) * (1.0 / 18_446_744_073_709_551_616.0);
    let planar = (f(r0) + f(dr) / 2.0) * (sweep_turns * core::f32::consts::TAU);
    let helix = f(helix);
    let want = planar * planar + helix * helix;
    let got = f(length) * f(length);
    // The radii are whole nanometres here (the host's are not): r̄ may
    // differ by 0.75 nm, the planar length by that times the sweep in
    // radians (2·10⁻⁵ of a 45 µm radius: more than the relative bound).
    let rounding = 2.0 + 0.75 * sweep_turns * core::f32::consts::TAU;
    (got - want).abs() <= 1e-5 * want + 2.0 * f(length) * (2.0 + rounding)
}

impl Course {
    /// [`Path::from_plan`] written into `self` and, for an arc, `bend`, for the
    /// controller's receive path: the course and bend are built where they will stay,
    /// not returned and moved. On error they hold some path, not the block's; `bend`
    /// is written only for an arc.
    pub fn set_from_plan(
        &mut self,
        bend: &mut Bend,
        block: &Block,
        start: &[i64; AXES],
        length: i64,
        shape: &Shape,
    ) -> Result<(), GeometryError> {
        let end = match block.motion {
            Motion::Dwell(_) | Motion::Aux(_) => *start,
            _ => block.target,
        };
        let delta: [i64; AXES] = core::array::from_fn(|i| end[i].wrapping_sub(start[i]));
        // A point until proven otherwise.
        self.end = end;
        self.length = 0;
        self.rotary_only = false;
        self.form = Form::Point;
        let bad = Err(GeometryError::PlanMismatch);
        match (block.motion, shape) {
            (Motion::Dwell(_) | Motion::Aux(_), Shape::Point) if length == 0 => Ok(()),
            (Motion::Rapid | Motion::Linear, Shape::Point) if length == 0 && delta == [0; AXES] => {
                Ok(())
            }
            (Motion::Rapid | Motion::Linear, Shape::Line { unit }) => {
                self.set_line(bend, start, &end, &delta, length, unit)
            }
            (
                Motion::Arc {
                    center,
                    plane,
                    clockwise,
                    turns,
                },
                &Shape::Arc {
                    r0,
                    dr,
                    phi0,
                    phi_rate,
                    r_rate,
                    ref unit,
                    ..
                },
            ) => {
                // The sweep the rate stands for (the host's, less at most
                // length/2¹⁶ + 1 units: the rate was rounded toward zero).
                let sweep = phi_rate.wrapping_mul(length as i128) >> 16;
                let slack = (length as u128 >> 16) + 2;
                let whole = |n: u32| (n as u128) << 64;
                let turns_ok = sweep.unsigned_abs() + slack > whole(turns as u32)
                    && sweep.unsigned_abs() <= whole(turns as u32 + 1);
                let (i, j, k) = plane.axes();
                if length <= 0
                    || !(1..=MAX_ARC_RADIUS_NM).contains(&r0)
                    || r0 + dr < 1
                    || dr.unsigned_abs() > ARC_RADIUS_SLACK_NM as u64
                    || clockwise != (phi_rate < 0)
                    || !turns_ok
                    || unit[i] != 0
                    || unit[j] != 0
                    || !rate_of(r_rate as i128, (dr as i128) << 24, length)
                {
                    return bad;
                }
                if !arc_length_ok(r0, dr, sweep, delta[k], length) {
                    return bad;
                }
                self.length = length;
                self.form = Form::Arc;
                self.unit = *unit;
                // The plane and centre are the block's (they are not sent twice).
                // Written where it stays, field by field: a whole bend built aside and
                // moved in cost a byte-wise copy of it.
                if !matches!(bend, Bend::Arc(_)) {
                    *bend = Bend::Arc(Circle::default());
                }
                let Bend::Arc(circle) = bend else {
                    return bad;
                };
                circle.plane = plane;
                circle.center = center;
                circle.r0 = r0;
                circle.dr = dr;
                circle.phi0 = phi0;
                circle.phi_rate = phi_rate;
                circle.r_rate = r_rate;
                let mut at = [0; AXES];
                self.eval(bend, start, 0, &mut at);
                if !near(&at, start) {
                    return bad;
                }
                self.eval(bend, start, length << 16, &mut at);
                if near(&at, &end) {
                    Ok(())
                } else {
                    bad
                }
            }
            (Motion::Cubic { .. } | Motion::Quadratic { .. }, &Shape::Spline { rate, dip }) => {
                // Written where it stays (no curve built aside and moved in), its dip
                // beside it (inside the curve: not at its start).
                if !matches!(bend, Bend::Spline(..)) {
                    *bend = Bend::Spline(Curve::default(), Dip::NONE);
                }
                let Bend::Spline(curve, kept) = bend else {
                    return bad;
                };
                *kept = match dip {
                    Some(d) if d.at == 0 => return bad,
                    Some(d) => d,
                    None => Dip::NONE,
                };
                self.set_spline(curve, &block.motion, start, length, rate)
            }
            _ => bad,
        }
    }

    /// The line case of [`Course::set_from_plan`]: the planned `length` must be the
    /// measured one (within half a unit) and `unit` must reach `end`.
    #[inline(always)]
    fn set_line(
        &mut self,
        bend: &Bend,
        start: &[i64; AXES],
        end: &[i64; AXES],
        delta: &[i64; AXES],
        length: i64,
        unit: &[i64; AXES],
    ) -> Result<(), GeometryError> {
        let squares = |r: core::ops::Range<usize>| -> u128 {
            delta[r]
                .iter()
                .map(|d| d.unsigned_abs() as u128 * d.unsigned_abs() as u128)
                .sum()
        };
        let (lin, rot) = (squares(0..3), squares(3..6));
        let rotary_only = lin == 0;
        let sq = if rotary_only { rot } else { lin };
        // length = round(√sq): (2L − 1)² ≤ 4·sq ≤ (2L + 1)².
        let l2 = 2 * length.max(0) as u128;
        if length <= 0
            || sq.saturating_mul(4) < (l2 - 1) * (l2 - 1)
            || sq.saturating_mul(4) > (l2 + 1) * (l2 + 1)
        {
            return Err(GeometryError::PlanMismatch);
        }
        self.length = length;
        self.rotary_only = rotary_only;
        self.form = Form::Line;
        self.unit = *unit;
        let mut at = [0; AXES];
        self.eval(bend, start, length << 16, &mut at);
        if near(&at, end) {
            Ok(())
        } else {
            Err(GeometryError::PlanMismatch)
        }
    }

    /// Pose after `s` (nm Q16) along the path from `start` (where it begins: the
    /// previous block's end); `s ≥ length` gives the exact end. `bend` is the arc's
    /// (ignored for other forms).
    pub fn pose_at(&self, bend: &Bend, start: &[i64; AXES], s: i64, pose: &mut [i64; AXES]) {
        if s >= self.length << 16 || self.length == 0 {
            *pose = self.end;
            return;
        }
        self.eval(bend, start, s.max(0), pose);
    }

    /// The path's formula at `s` (nm Q16, ≥ 0), without snapping to the end.
    fn eval(&self, bend: &Bend, start: &[i64; AXES], s: i64, pose: &mut [i64; AXES]) {
        let linear = |unit: &[i64; AXES], pose: &mut [i64; AXES]| {
            for (p, (st, u)) in pose.iter_mut().zip(start.iter().zip(unit)) {
                // (u Q44 × s Q16) >> 60, rounded; axes that do not move cost nothing.
                *p = if *u == 0 {
                    *st
                } else {
                    st + (((*u as i128 * s as i128) + (1i128 << 59)) >> 60) as i64
                };
            }
        };
        match self.form {
            Form::Point => *pose = self.end,
            Form::Line => linear(&self.unit, pose),
            Form::Spline => match bend {
                Bend::Spline(c, _) => self.eval_spline(c, start, s, pose),
                Bend::Arc(_) => *pose = self.end,
            },
            Form::Arc => {
                let Bend::Arc(Circle {
                    plane,
                    center,
                    r0,
                    phi0,
                    phi_rate,
                    r_rate,
                    ..
                }) = *bend
                else {
                    *pose = self.end;
                    return;
                };
                linear(&self.unit, pose);
                // At the start (the plan check's first point) no product is needed.
                let (phi, r) = if s == 0 {
                    (phi0, r0)
                } else {
                    let s = s as i128;
                    (
                        phi0.wrapping_add(((phi_rate * s) >> 32) as u64),
                        r0 + ((r_rate as i128 * s) >> 56) as i64,
                    )
                };
                // The angle as a signed fraction of a turn, then in n° within ±180°
                // (the sine's fast path).
                let turn = (phi as i64 as i128 * 360_000_000_000) >> 64;
                let (sin, cos) = crate::math::sincos(turn as i64);
                let (i, j, _) = plane.axes();
                pose[i] = center[0] + ((r as i128 * cos as i128 + (1 << 30)) >> 31) as i64;
                pose[j] = center[1] + ((r as i128 * sin as i128 + (1 << 30)) >> 31) as i64;
            }
        }
    }
}

impl Path {
    /// Unit tangent at `s` (nm Q16), in `f32` per axis (per nm of path).
    pub fn tangent_at(&self, s: i64) -> [f32; AXES] {
        let mut t = [0f32; AXES];
        match self.form {
            Form::Point => {}
            Form::Line => {
                for (t, u) in t.iter_mut().zip(&self.unit) {
                    *t = (*u as f64 / Q44) as f32;
                }
            }
            Form::Spline => {
                if let Bend::Spline(c, _) = &self.bend {
                    t = self.course.spline_tangent(c, s);
                }
            }
            Form::Arc => {
                let Circle {
                    plane,
                    phi0,
                    phi_rate,
                    r0,
                    dr,
                    ..
                } = self.bend.circle();
                for (t, u) in t.iter_mut().zip(&self.unit) {
                    *t = (*u as f64 / Q44) as f32;
                }
                let s = s.max(0);
                let f = (s as f64 / 65_536.0) / (self.length.max(1) as f64);
                let r = r0 as f64 + dr as f64 * f;
                // d(position)/ds in plane: r·dφ/ds·(−sin, cos) (radius drift ignored),
                // with the angle found as in `pose_at`; dφ/ds from the rate (turns Q64
                // per nm Q16).
                let dphi_ds = phi_rate as f64 / 65_536.0 / TURN_Q64 * core::f64::consts::TAU;
                let phi = phi0.wrapping_add(((phi_rate * s as i128) >> 32) as u64);
                let turn = (phi as i64 as i128 * 360_000_000_000) >> 64;
                let (sin, cos) = crate::math::sincos(turn as i64);
                let q31 = crate::math::ONE_Q31 as f64;
                let (i, j, _) = plane.axes();
                t[i] = (-r * dphi_ds * (sin as f64 / q31)) as f32;
                t[j] = (r * dphi_ds * (cos as f64 / q31)) as f32;
            }
        }
        t
    }

    /// d²P/ds² at `s` (nm Q16) per axis (per nm²): a spline's, or an arc's centripetal
    /// −r·(dφ/ds)²·(cos φ, sin φ) in its plane (its radius's drift ignored); 0 for lines
    /// and points (host).
    pub fn bend_at(&self, s: i64) -> [f32; AXES] {
        match &self.bend {
            Bend::Spline(c, _) if self.form == Form::Spline => self.course.spline_bend(c, s),
            Bend::Arc(c) if self.form == Form::Arc => {
                let s = s.clamp(0, self.length << 16);
                let f = (s as f64 / 65_536.0) / (self.length.max(1) as f64);
                let r = c.r0 as f64 + c.dr as f64 * f;
                let dphi_ds = c.phi_rate as f64 / 65_536.0 / TURN_Q64 * core::f64::consts::TAU;
                let phi = c.phi0.wrapping_add(((c.phi_rate * s as i128) >> 32) as u64);
                let angle = phi as f64 / TURN_Q64 * core::f64::consts::TAU;
                let k = -r * dphi_ds * dphi_ds;
                let (i, j, _) = c.plane.axes();
                let mut b = [0f32; AXES];
                b[i] = (k * libm::cos(angle)) as f32;
                b[j] = (k * libm::sin(angle)) as f32;
                b
            }
            _ => [0.0; AXES],
        }
    }

    /// Smallest radius of curvature, nm (`None` for straight paths).
    pub fn radius(&self) -> Option<i64> {
        let Circle { r0, dr, .. } = self.bend.circle();
        (self.form == Form::Arc).then_some(r0.min(r0 + dr))
    }
}
