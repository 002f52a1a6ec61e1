//! Path geometry of a block: where the tool is after `s` nanometres along it.
//!
//! Straight moves: pose = start + u·s with the direction u = Δ/S stored per axis in
//! Q20.44 (a rotary axis moving with X Y Z can turn hundreds of n° per nm), so a
//! pose is exact to well below a nanometre and the end (s = S) is snapped
//! to the programmed target. Arcs and helices follow the true circle, never chords:
//! the angle advances linearly with s (turns Q64), the radius moves linearly from the
//! start radius to the end radius (an end within tolerance of the circle makes a gentle
//! spiral, as LinuxCNC does), and the helix axis and A B C move linearly with s. The
//! in-plane position is centre + r·(cos φ, sin φ) with the kinematics' fixed-point
//! [`crate::math::sincos`] (Q31, within 7·10⁻¹⁰).
//!
//! Path length S is measured over X Y Z (arc: sqrt((r̄·|sweep|)² + helix²)); a move of
//! rotary axes only is measured in n° instead.

use crate::config::AXES;
use crate::motion::block::{Block, Motion, Plane};

mod spline;
pub use spline::{coefficients, Curve, MAX_SPLINE_SPAN, MIN_SPLINE_NM};

pub use crate::motion::block::Shape;

/// What a path is, an arc's in-plane part aside.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Form {
    /// No motion (dwell, auxiliary function, zero-length move).
    #[default]
    Point,
    /// Straight line.
    Line,
    /// Arc or helix; its in-plane part is a [`Circle`], in the path's [`Bend`].
    Arc,
    /// Cubic or quadratic spline ([`spline`]); a₁ is in the course's `unit`, the rest a
    /// [`Curve`], in the path's [`Bend`].
    Spline,
}

impl Form {
    /// Does a path of this form have a [`Bend`] (arcs and splines)?
    pub const fn bends(self) -> bool {
        matches!(self, Form::Arc | Form::Spline)
    }
}

/// What every path has: where it ends, its length, and its direction per axis. An
/// arc's in-plane part is its [`Bend`], kept apart: the controller's queue holds
/// hundreds of courses and only the arcs among them need a bend (`crate::motion::planner`
/// keeps bends in a ring of their own), which makes a queued line 72 bytes shorter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Course {
    /// End pose (exact).
    pub end: [i64; AXES],
    /// Length, nm (or n° for rotary-only moves).
    pub length: i64,
    /// Measured over rotary axes (rotary-only move).
    pub rotary_only: bool,
    /// Point, line or arc.
    pub form: Form,
    /// Direction per axis, Q20.44: a line's, or an arc's linear part (helix axis and
    /// A B C; in-plane entries are 0); a spline's a₁ (axis units).
    pub unit: [i64; AXES],
}

/// An arc's in-plane part, as in [`Shape::Arc`] (which see).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Circle {
    /// Plane.
    pub plane: Plane,
    /// Centre (first, second in-plane axis), nm.
    pub center: [i64; 2],
    /// Start radius, nm.
    pub r0: i64,
    /// End radius minus start radius, nm.
    pub dr: i64,
    /// Start angle, turns Q64 (wrapping).
    pub phi0: u64,
    /// Angle per path distance (turns Q64 per nm Q16, scaled by 2¹⁶).
    pub phi_rate: i128,
    /// Radius change per path distance (used as (k·s) ≫ 56).
    pub r_rate: i64,
}

/// The curved part of a path, kept apart from its [`Course`]: an arc's [`Circle`] or a
/// spline's [`Curve`] (ignored for lines and points).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bend {
    /// An arc's in-plane part.
    Arc(Circle),
    /// A spline's a₂, a₃ and rate.
    Spline(Curve),
}

impl Default for Bend {
    fn default() -> Self {
        Bend::Arc(Circle::default())
    }
}

impl Bend {
    /// The arc's in-plane part (a default circle for a spline's bend).
    pub fn circle(&self) -> Circle {
        match self {
            Bend::Arc(c) => *c,
            Bend::Spline(_) => Circle::default(),
        }
    }
}

/// A block's geometry: its [`Course`] and, for an arc or a spline, its [`Bend`]
/// (ignored otherwise). Its start is not kept: it is the previous block's end, which every user
/// has at hand. Reads of the course's fields go through (`path.end`, `path.length`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Path {
    /// End, length and direction.
    pub course: Course,
    /// In-plane part of an arc.
    pub bend: Bend,
}

impl core::ops::Deref for Path {
    type Target = Course;
    fn deref(&self) -> &Course {
        &self.course
    }
}

const Q44: f64 = 17_592_186_044_416.0;
const TURN_Q64: f64 = 18_446_744_073_709_551_616.0;

/// `x` modulo `m`, in [0, m).
fn wrap(x: f64, m: f64) -> f64 {
    x - libm::floor(x / m) * m
}

fn unit_q44(d: i64, length: f64) -> i64 {
    if length <= 0.0 {
        0
    } else {
        libm::round(d as f64 / length * Q44) as i64
    }
}

/// Why a block's geometry is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GeometryError {
    /// Start and end radius differ by more than the controller accepts.
    ArcEndOffCircle,
    /// An arc with zero radius.
    ArcWithoutRadius,
    /// A geometry sent with a block does not describe that block (wrong length,
    /// direction, centre, sweep or rates).
    PlanMismatch,
    /// A spline whose coefficients exceed [`MAX_SPLINE_SPAN`], or that does not move
    /// X Y Z at all (rotary-only curves are sent as lines), or shorter than
    /// [`MIN_SPLINE_NM`].
    SplineOutOfRange,
}

/// How far a host-computed path may miss the block's start or end, axis units (the
/// host's own rounding is within 2).
pub const PLAN_SLACK_UNITS: i64 = 8;

/// Is `got` within [`PLAN_SLACK_UNITS`] of `want` on every axis? (Directions are per
/// unit of the stored whole-unit length, so a path reaches its target at s = length.)
fn near(got: &[i64; AXES], want: &[i64; AXES]) -> bool {
    got.iter()
        .zip(want)
        .all(|(g, w)| g.wrapping_sub(*w).unsigned_abs() <= PLAN_SLACK_UNITS as u64)
}

/// Does `rate` equal `(x << 16) / len` as [`Path::new`] rounds it (toward zero)?
fn rate_of(rate: i128, x: i128, len: i64) -> bool {
    let e = (x << 16).wrapping_sub(rate.wrapping_mul(len as i128));
    e.unsigned_abs() < len as u128
}

/// Largest arc radius, nm (10 m): the in-plane position is centre + r·(cos φ, sin φ)
/// with sine and cosine in Q31 (within 7·10⁻¹⁰), so the interpolated path stays within
/// r × 7·10⁻¹⁰ ≤ 7 nm of the exact circle, and the arc starts and ends within the
/// controller's [`PLAN_SLACK_UNITS`] of its programmed points (at 41 m it no longer
/// did: the plan was refused as malformed). The controller refuses a plan with a
/// larger one ([`Path::checked`]); the host sends such an arc as chords along it.
pub const MAX_ARC_RADIUS_NM: i64 = 10_000_000_000;

/// Largest start/end radius difference accepted for an arc, nm (the host checks its
/// own, tighter, tolerance: LinuxCNC's, at most 71.8 µm in G20; this only guards the
/// controller).
pub const ARC_RADIUS_SLACK_NM: i64 = 80_000;

impl Path {
    /// Geometry of `block` starting at `start`.
    pub fn new(block: &Block, start: &[i64; AXES]) -> Result<Path, GeometryError> {
        let end = match block.motion {
            Motion::Dwell(_) | Motion::Aux(_) => *start,
            _ => block.target,
        };
        let mut delta = [0i64; AXES];
        for (d, (e, s)) in delta.iter_mut().zip(end.iter().zip(start)) {
            *d = e.wrapping_sub(*s);
        }
        let sq = |r: core::ops::Range<usize>| -> f64 {
            delta[r].iter().map(|d| (*d as f64) * (*d as f64)).sum()
        };
        let point = Path {
            course: Course {
                end,
                ..Course::default()
            },
            bend: Bend::default(),
        };
        match block.motion {
            Motion::Dwell(_) | Motion::Aux(_) => Ok(point),
            Motion::Rapid | Motion::Linear => {
                let (lin, rot) = (sq(0..3), sq(3..6));
                let (length, rotary_only) = if lin > 0.0 {
                    (libm::sqrt(lin), false)
                } else {
                    (libm::sqrt(rot), true)
                };
                if length < 0.5 {
                    return Ok(point);
                }
                // Direction per unit of the *stored* (whole-unit) length, so that
                // start + u·s reaches the target at s = length and never passes it (a
                // rotary axis turning thousands of n° per nm would overshoot its travel
                // by the rounding of the length otherwise).
                let length = libm::round(length);
                let mut unit = [0i64; AXES];
                for (u, d) in unit.iter_mut().zip(&delta) {
                    *u = unit_q44(*d, length);
                }
                Ok(Path {
                    course: Course {
                        end,
                        length: length as i64,
                        rotary_only,
                        form: Form::Line,
                        unit,
                    },
                    ..point
                })
            }
            Motion::Arc {
                center,
                plane,
                clockwise,
                turns,
            } => {
                let (i, j, k) = plane.axes();
                let (sx, sy) = ((start[i] - center[0]) as f64, (start[j] - center[1]) as f64);
                let (ex, ey) = ((end[i] - center[0]) as f64, (end[j] - center[1]) as f64);
                let (r0, r1) = (libm::sqrt(sx * sx + sy * sy), libm::sqrt(ex * ex + ey * ey));
                if r0 < 0.5 || r1 < 0.5 {
                    return Err(GeometryError::ArcWithoutRadius);
                }
                if (r1 - r0).abs() > ARC_RADIUS_SLACK_NM as f64 {
                    return Err(GeometryError::ArcEndOffCircle);
                }
                let a0 = libm::atan2(sy, sx);
                let a1 = libm::atan2(ey, ex);
                let tau = core::f64::consts::TAU;
                // Counter-clockwise sweep in (0, 2π] (a full circle when the ends meet).
                let mut ccw = wrap(a1 - a0, tau);
                let mut cw = wrap(a0 - a1, tau);
                if ccw < 1e-12 {
                    ccw = tau;
                }
                if cw < 1e-12 {
                    cw = tau;
                }
                let sweep_rad = if clockwise {
                    -(cw + tau * turns as f64)
                } else {
                    ccw + tau * turns as f64
                };
                let planar = sweep_rad.abs() * (r0 + r1) / 2.0;
                let mut lin = delta;
                lin[i] = 0;
                lin[j] = 0;
                let helix = (lin[k] as f64).abs();
                let length = libm::sqrt(planar * planar + helix * helix);
                let mut unit = [0i64; AXES];
                for (u, d) in unit.iter_mut().zip(&lin) {
                    // Per unit of the stored length, as for lines.
                    *u = unit_q44(*d, libm::round(length).max(1.0));
                }
                let turn_of = |rad: f64| rad / tau * TURN_Q64;
                let len = (libm::round(length) as i64).max(1);
                let sweep = turn_of(sweep_rad) as i128;
                let dr = libm::round(r1 - r0) as i64;
                Ok(Path {
                    course: Course {
                        end,
                        length: libm::round(length) as i64,
                        rotary_only: false,
                        form: Form::Arc,
                        unit,
                    },
                    bend: Bend::Arc(Circle {
                        plane,
                        center,
                        r0: libm::round(r0) as i64,
                        dr,
                        phi0: turn_of(wrap(a0, tau)) as u64,
                        phi_rate: (sweep << 16) / len as i128,
                        r_rate: (((dr as i128) << 40) / len as i128) as i64,
                    }),
                })
            }
            Motion::Cubic { .. } | Motion::Quadratic { .. } => {
                let a = spline::coefficients(&block.motion, start, &end)
                    .ok_or(GeometryError::SplineOutOfRange)?;
                let length = spline::host_length(&a);
                if a[..].iter().all(|c| c[..3] == [0; 3]) || length > MAX_SPLINE_SPAN as f64 {
                    return Err(GeometryError::SplineOutOfRange);
                }
                let length = (length as i64).max(MIN_SPLINE_NM);
                Ok(Path {
                    course: Course {
                        end,
                        length,
                        rotary_only: false,
                        form: Form::Spline,
                        unit: a[0],
                    },
                    bend: Bend::Spline(Curve {
                        a2: a[1],
                        a3: a[2],
                        rate: spline::rate_of(length),
                    }),
                })
            }
        }
    }

    /// The path of `block` from `start` with the length and shape the host computed
    /// ([`Path::new`] on the host), checked without `f64` and without a division:
    /// lines must have the measured length (within half a unit) and reach the target;
    /// arcs must have the block's plane, centre, direction and turns, rates that
    /// match their sweep and radius change, start on the start and reach the target
    /// (within [`PLAN_SLACK_UNITS`]), and a length matching r̄·|sweep| and the helix
    /// (to 10⁻⁵, plus the rounding of the radii to whole nanometres).
    pub fn from_plan(
        block: &Block,
        start: &[i64; AXES],
        length: i64,
        shape: Shape,
    ) -> Result<Path, GeometryError> {
        let mut p = Path::default();
        p.course
            .set_from_plan(&mut p.bend, block, start, length, &shape)?;
        Ok(p)
    }

    /// The one rule, host and controller, for a block the controller runs as it is: the
    /// path the host plans for `block` from `start` ([`Path::new`]), which the host
    /// sends, checked by the very check the controller makes on receipt
    /// ([`Course::set_from_plan`], exact integers and `f32`, the same on both). For an
    /// arc it holds when its start radius is 1 nm to [`MAX_ARC_RADIUS_NM`], its radius
    /// changes by at most [`ARC_RADIUS_SLACK_NM`], and the controller's own
    /// interpolation starts and ends within [`PLAN_SLACK_UNITS`] of its programmed
    /// points, with rates and length that match its sweep. An arc refused here is sent
    /// by the host as lines along it (`gcode::blocks` in the host tools); the
    /// controller refuses the plan of any block refused here.
    pub fn checked(block: &Block, start: &[i64; AXES]) -> Result<Path, GeometryError> {
        let host = Path::new(block, start)?;
        let controller = Path::from_plan(block, start, host.length, host.shape())?;
        if controller == host {
            Ok(host)
        } else {
            Err(GeometryError::PlanMismatch)
        }
    }

    /// The shape the host sends for this path.
    pub fn shape(&self) -> Shape {
        let b = &self.bend.circle();
        match self.form {
            Form::Point => Shape::Point,
            Form::Line => Shape::Line { unit: self.unit },
            Form::Arc => Shape::Arc {
                plane: b.plane,
                center: b.center,
                r0: b.r0,
                dr: b.dr,
                phi0: b.phi0,
                phi_rate: b.phi_rate,
                r_rate: b.r_rate,
                unit: self.unit,
            },
            Form::Spline => match self.bend {
                Bend::Spline(c) => Shape::Spline { rate: c.rate },
                Bend::Arc(_) => Shape::Point,
            },
        }
    }

    /// Pose after `s` (nm Q16) along the path from `start` ([`Course::pose_at`]).
    pub fn pose_at(&self, start: &[i64; AXES], s: i64, pose: &mut [i64; AXES]) {
        self.course.pose_at(&self.bend, start, s, pose);
    }
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
        let squares = |r: core::ops::Range<usize>| -> u128 {
            delta[r]
                .iter()
                .map(|d| d.unsigned_abs() as u128 * d.unsigned_abs() as u128)
                .sum()
        };
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
                let (lin, rot) = (squares(0..3), squares(3..6));
                let rotary_only = lin == 0;
                let sq = if rotary_only { rot } else { lin };
                // length = round(√sq): (2L − 1)² ≤ 4·sq ≤ (2L + 1)².
                let l2 = 2 * length.max(0) as u128;
                if length <= 0
                    || sq.saturating_mul(4) < (l2 - 1) * (l2 - 1)
                    || sq.saturating_mul(4) > (l2 + 1) * (l2 + 1)
                {
                    return bad;
                }
                self.length = length;
                self.rotary_only = rotary_only;
                self.form = Form::Line;
                self.unit = *unit;
                let mut at = [0; AXES];
                self.eval(bend, start, length << 16, &mut at);
                if near(&at, &end) {
                    Ok(())
                } else {
                    bad
                }
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
                // Length: √((r̄·|sweep|)² + helix²), to 10⁻⁵ (single precision). The
                // sweep is converted whole (its turns, then its fraction): cut to 2⁻³²
                // turn, a sweep of 10⁻⁵ turn (0.2 mm on a 4 m radius) was off by 3·10⁻⁵
                // and its plan refused.
                let f = crate::math::i64_to_f32;
                let sw = sweep.unsigned_abs();
                let sweep_turns = crate::math::u64_to_f32((sw >> 64) as u64)
                    + crate::math::u64_to_f32(sw as u64) * (1.0 / 18_446_744_073_709_551_616.0);
                let planar = (f(r0) + f(dr) / 2.0) * (sweep_turns * core::f32::consts::TAU);
                let helix = f(delta[k]);
                let want = planar * planar + helix * helix;
                let got = f(length) * f(length);
                // The radii are whole nanometres here (the host's are not): r̄ may
                // differ by 0.75 nm, the planar length by that times the sweep in
                // radians (2·10⁻⁵ of a 45 µm radius: more than the relative bound).
                let rounding = 2.0 + 0.75 * sweep_turns * core::f32::consts::TAU;
                if (got - want).abs() > 1e-5 * want + 2.0 * f(length) * (2.0 + rounding) {
                    return bad;
                }
                self.length = length;
                self.form = Form::Arc;
                self.unit = *unit;
                // The plane and centre are the block's (they are not sent twice).
                *bend = Bend::Arc(Circle {
                    plane,
                    center,
                    r0,
                    dr,
                    phi0,
                    phi_rate,
                    r_rate,
                });
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
            (Motion::Cubic { .. } | Motion::Quadratic { .. }, &Shape::Spline { rate }) => {
                // Written where it stays (no curve built aside and moved in).
                if !matches!(bend, Bend::Spline(_)) {
                    *bend = Bend::Spline(Curve::default());
                }
                let Bend::Spline(curve) = bend else {
                    return bad;
                };
                self.set_spline(curve, &block.motion, start, length, rate)
            }
            _ => bad,
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
                Bend::Spline(c) => self.eval_spline(c, start, s, pose),
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
                if let Bend::Spline(c) = &self.bend {
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
            Bend::Spline(c) if self.form == Form::Spline => self.course.spline_bend(c, s),
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

#[cfg(test)]
mod tests {
    use super::*;

    fn arc(target: [i64; AXES], center: [i64; 2], clockwise: bool, turns: u16) -> Block {
        Block {
            line: 1,
            motion: Motion::Arc {
                center,
                plane: Plane::Xy,
                clockwise,
                turns,
            },
            target,
            feed: 1,
            tolerance_nm: 0,
        }
    }

    #[test]
    fn a_quarter_circle_stays_on_the_circle_and_ends_exactly() {
        let r = 10_000_000;
        let b = arc([0, r, 0, 0, 0, 0], [0, 0], false, 0);
        let from = [r, 0, 0, 0, 0, 0];
        let p = Path::new(&b, &from).unwrap();
        let quarter = core::f64::consts::FRAC_PI_2 * r as f64;
        assert!((p.length as f64 - quarter).abs() < 1.0);
        let mut pose = [0; AXES];
        for k in 0..=1000 {
            let s = (p.length << 16) / 1000 * k;
            p.pose_at(&from, s, &mut pose);
            let rad = ((pose[0] as f64).powi(2) + (pose[1] as f64).powi(2)).sqrt();
            assert!(
                (rad - r as f64).abs() < 1.0,
                "off the circle by {} nm",
                rad - r as f64
            );
        }
        p.pose_at(&from, p.length << 16, &mut pose);
        assert_eq!(pose, [0, r, 0, 0, 0, 0]);
    }

    #[test]
    fn a_full_helix_with_an_extra_turn_has_the_length_of_two_turns() {
        let r = 5_000_000;
        let b = arc([r, 0, -2_000_000, 0, 0, 0], [0, 0], true, 1);
        let from = [r, 0, 0, 0, 0, 0];
        let p = Path::new(&b, &from).unwrap();
        let planar = 2.0 * core::f64::consts::TAU * r as f64;
        let want = (planar * planar + 4e12).sqrt();
        assert!((p.length as f64 - want).abs() < 1.0);
        // Halfway: one full turn done (back at angle 0), halfway down.
        let mut pose = [0; AXES];
        p.pose_at(&from, p.length << 15, &mut pose);
        assert!((pose[0] - r).abs() <= 1 && pose[1].abs() <= 1, "{pose:?}");
        assert!((pose[2] + 1_000_000).abs() <= 1);
    }

    #[test]
    fn a_straight_line_lands_within_a_nanometre_of_every_fraction() {
        let b = Block {
            line: 1,
            motion: Motion::Linear,
            target: [123_456_789, -98_765_432, 5, 0, 0, 0],
            feed: 1,
            tolerance_nm: 0,
        };
        let p = Path::new(&b, &[0; AXES]).unwrap();
        let mut pose = [0; AXES];
        p.pose_at(&[0; AXES], p.length << 15, &mut pose);
        assert!((pose[0] - 61_728_394).abs() <= 1, "{pose:?}");
        assert!((pose[1] + 49_382_716).abs() <= 1, "{pose:?}");
    }

    /// What the host computes for `block` from `start`, checked as the controller does.
    fn round_trip(block: &Block, start: &[i64; AXES]) -> Result<Path, GeometryError> {
        let host = Path::new(block, start)?;
        Path::from_plan(block, start, host.length, host.shape())
    }

    proptest::proptest! {
        #[test]
        fn the_controller_accepts_every_arc_the_host_computes(
            r_um in 10i64..5_000_000, a0 in 0.0f64..360.0, sweep in 1.0f64..359.0,
            helix in -50_000_000i64..50_000_000, cw in proptest::bool::ANY, turns in 0u16..3,
            plane in 0usize..3, dr in -2_000i64..2_000,
        ) {
            let plane = [Plane::Xy, Plane::Zx, Plane::Yz][plane];
            let (i, j, k) = plane.axes();
            let r = r_um * 1000;
            let c = [1_000_000i64, -2_000_000];
            let a1 = if cw { a0 - sweep } else { a0 + sweep };
            let mut start = [0i64; AXES];
            start[i] = c[0] + (r as f64 * a0.to_radians().cos()).round() as i64;
            start[j] = c[1] + (r as f64 * a0.to_radians().sin()).round() as i64;
            let mut target = start;
            let r1 = (r + dr).max(1) as f64;
            target[i] = c[0] + (r1 * a1.to_radians().cos()).round() as i64;
            target[j] = c[1] + (r1 * a1.to_radians().sin()).round() as i64;
            target[k] += helix;
            let b = Block {
                line: 1,
                motion: Motion::Arc { center: c, plane, clockwise: cw, turns },
                target,
                feed: 1_000_000,
                tolerance_nm: 0,
            };
            let host = Path::new(&b, &start);
            proptest::prop_assume!(host.is_ok());
            let host = host.unwrap();
            proptest::prop_assert_eq!(round_trip(&b, &start), Ok(host));
        }

        #[test]
        fn the_controller_accepts_every_line_the_host_computes(
            d in proptest::array::uniform6(-500_000_000i64..500_000_000),
            rotary_only in proptest::bool::ANY,
        ) {
            let mut target = d;
            if rotary_only {
                target[..3].copy_from_slice(&[0, 0, 0]);
            }
            let b = Block { line: 1, motion: Motion::Linear, target, feed: 1_000_000, tolerance_nm: 0 };
            let start = [0; AXES];
            proptest::prop_assert_eq!(round_trip(&b, &start), Path::new(&b, &start));
        }
    }

    #[test]
    fn an_arc_s_tangent_is_the_derivative_of_its_pose() {
        for (clockwise, turns) in [(false, 0), (true, 0), (false, 1)] {
            // A quarter (or one and a quarter) of a 10 mm circle with a 3 mm helix.
            let b = arc(
                [0, 10_000_000, 3_000_000, 0, 0, 0],
                [0, 0],
                clockwise,
                turns,
            );
            let from = [10_000_000, 0, 0, 0, 0, 0];
            let p = Path::new(&b, &from).unwrap();
            for k in 1..8 {
                let s = (p.length << 16) / 8 * k;
                let h = 1_000i64 << 16; // 1 µm
                let (mut a, mut c) = ([0; AXES], [0; AXES]);
                p.pose_at(&from, s - h, &mut a);
                p.pose_at(&from, s + h, &mut c);
                let t = p.tangent_at(s);
                for i in 0..3 {
                    let fd = (c[i] - a[i]) as f32 / 2_000.0;
                    assert!(
                        (t[i] - fd).abs() < 1e-3,
                        "{clockwise} {turns} {k} {i}: {t:?} vs {fd}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_tiny_arc_whose_radius_the_controller_rounds_is_accepted() {
        // A 45.58 µm radius, 314° (found by the property test of issue 16): the whole
        // nanometre radii move the planar length by 2.7·10⁻⁵, beyond the relative
        // bound alone.
        let b = Block {
            line: 3,
            motion: Motion::Arc {
                center: [15_400, 42_900],
                plane: Plane::Xy,
                clockwise: false,
                turns: 0,
            },
            target: [-26_200, 24_200, -30_000_000, 0, 0, 0],
            feed: 50_000_000,
            tolerance_nm: 0,
        };
        let start = [0, 0, -30_000_000, 0, 0, 0];
        assert_eq!(round_trip(&b, &start), Path::new(&b, &start));
    }

    #[test]
    fn a_plan_for_another_arc_is_refused() {
        let b = arc([0, 10_000_000, 0, 0, 0, 0], [0, 0], false, 0);
        let start = [10_000_000, 0, 0, 0, 0, 0];
        let host = Path::new(&b, &start).unwrap();
        // The other way round (three quarters), or one turn more.
        let mut other = b;
        other.motion = Motion::Arc {
            center: [0, 0],
            plane: Plane::Xy,
            clockwise: true,
            turns: 0,
        };
        assert_eq!(
            Path::from_plan(&other, &start, host.length, host.shape()),
            Err(GeometryError::PlanMismatch)
        );
        let mut more = b;
        more.motion = Motion::Arc {
            center: [0, 0],
            plane: Plane::Xy,
            clockwise: false,
            turns: 1,
        };
        assert_eq!(
            Path::from_plan(&more, &start, host.length, host.shape()),
            Err(GeometryError::PlanMismatch)
        );
        // A length that does not match the sweep.
        assert_eq!(
            Path::from_plan(&b, &start, host.length * 2, host.shape()),
            Err(GeometryError::PlanMismatch)
        );
    }
}

#[cfg(test)]
mod extreme_arcs {
    use super::*;

    /// xorshift64*: a seeded generator (the same cases every run).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Issue 34: line 5,557 of a CamBam program, `G3 X10.9764 Y15.2949 I3827.4875
    /// J1391.3692` (radius 4,072 mm, chord 0.2 mm), with the start written to four
    /// decimals at 2,000 places along its circle. The length check took the sweep to
    /// 2⁻³² turn, 3·10⁻⁵ of this one, and refused 182 of these plans as malformed.
    #[test]
    fn the_cambam_arc_of_issue_34_runs_exactly_wherever_it_starts() {
        let off = [3_827_487_500i64, 1_391_369_200];
        let r = (off[0] as f64).hypot(off[1] as f64);
        let e = [10_976_400i64, 15_294_900];
        let u = [-off[0] as f64 / r, -off[1] as f64 / r];
        let mut refused = 0;
        for k in 0..2000 {
            let d = 200_000.0 / r * (0.5 + k as f64 * 1e-3);
            let ru = [
                u[0] * d.cos() - u[1] * d.sin(),
                u[0] * d.sin() + u[1] * d.cos(),
            ];
            let ct = [e[0] as f64 - r * ru[0], e[1] as f64 - r * ru[1]];
            let at = |v: f64| (v / 100.0).round() as i64 * 100;
            let s = [at(ct[0] + r * u[0]), at(ct[1] + r * u[1])];
            let b = Block {
                line: 5557,
                motion: Motion::Arc {
                    center: [s[0] + off[0], s[1] + off[1]],
                    plane: Plane::Xy,
                    clockwise: false,
                    turns: 0,
                },
                target: [e[0], e[1], 0, 0, 0, 0],
                feed: 1_000_000,
                tolerance_nm: 0,
            };
            if Path::checked(&b, &[s[0], s[1], 0, 0, 0, 0]).is_err() {
                refused += 1;
            }
        }
        assert_eq!(refused, 0, "{refused} of 2000 refused");
    }

    /// The reach of the one rule ([`Path::checked`]): every arc of radius up to
    /// [`MAX_ARC_RADIUS_NM`], chord 2 nm to 100 mm (radius up to 10⁹ chords), minor
    /// or major (nearly full circles), every plane, helical or not, runs exactly.
    /// (Chords of 1 nm may not: the host sends those as lines.)
    #[test]
    fn every_arc_within_the_exact_range_over_two_nanometres_runs_exactly() {
        let mut rng = Rng(0x34);
        let (mut refused, mut n) = (0, 0);
        while n < 100_000 {
            let chord = 10f64.powf(0.31 + rng.next() * 7.7);
            let r = chord * 10f64.powf(rng.next() * 9.0).max(0.5);
            if r > MAX_ARC_RADIUS_NM as f64 {
                continue;
            }
            let half = (chord / 2.0 / r).min(1.0).asin();
            let major = rng.next() < 0.3;
            let sweep = if major {
                core::f64::consts::TAU - 2.0 * half
            } else {
                2.0 * half
            };
            let cw = rng.next() < 0.5;
            let plane = [Plane::Xy, Plane::Zx, Plane::Yz][(rng.next() * 3.0) as usize];
            let (i, j, k) = plane.axes();
            let a0 = rng.next() * core::f64::consts::TAU;
            let a1 = if cw { a0 - sweep } else { a0 + sweep };
            let c = [
                (rng.next() * 2e8 - 1e8) as i64,
                (rng.next() * 2e8 - 1e8) as i64,
            ];
            let mut start = [0i64; AXES];
            start[i] = c[0] + (r * a0.cos()).round() as i64;
            start[j] = c[1] + (r * a0.sin()).round() as i64;
            start[k] = 5_000_000;
            let mut target = start;
            target[i] = c[0] + (r * a1.cos()).round() as i64;
            target[j] = c[1] + (r * a1.sin()).round() as i64;
            if rng.next() < 0.5 {
                target[k] += (rng.next() * 2e7 - 1e7) as i64;
            }
            let ends = [target[i] - start[i], target[j] - start[j]];
            if (ends[0] as f64).hypot(ends[1] as f64) < 2.0 {
                continue;
            }
            let b = Block {
                line: 1,
                motion: Motion::Arc {
                    center: c,
                    plane,
                    clockwise: cw,
                    turns: 0,
                },
                target,
                feed: 1,
                tolerance_nm: 0,
            };
            n += 1;
            if let Err(e) = Path::checked(&b, &start) {
                refused += 1;
                std::eprintln!("{e:?}: radius {r} nm, chord {chord} nm: {b:?} from {start:?}");
            }
        }
        assert_eq!(refused, 0, "{refused} of {n} arcs refused");
    }
}
