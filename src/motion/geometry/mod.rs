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
use crate::motion::block::{Block, Dip, Motion, Plane};

mod course;
mod spline;
#[cfg(test)]
mod tests;
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
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bend {
    /// An arc's in-plane part.
    Arc(Circle),
    /// A spline's a₂, a₃ and rate, and the plan's [`Dip`] along it. The dip is the
    /// controller's, written where its queue keeps the curve (a slot of the ring of
    /// bends has room for it beside the curve, where a struct of both would take 8
    /// bytes more); a path the host derives has [`Dip::NONE`] there, its plan's dip is
    /// [`crate::motion::planner::PlanBlock::dip`].
    Spline(Curve, Dip),
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
            Bend::Spline(..) => Circle::default(),
        }
    }
}

/// A block's geometry: its [`Course`] and, for an arc or a spline, its [`Bend`]
/// (ignored otherwise). Its start is not kept: it is the previous block's end, which every user
/// has at hand. Reads of the course's fields go through (`path.end`, `path.length`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
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

/// The arc case of [`Path::new`] (host side, `f64`): its radius, sweep and helix
/// from the block's centre, plane, direction and turns.
fn arc_path(
    start: &[i64; AXES],
    end: [i64; AXES],
    delta: &[i64; AXES],
    center: [i64; 2],
    plane: Plane,
    clockwise: bool,
    turns: u16,
) -> Result<Path, GeometryError> {
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
    let mut lin = *delta;
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
            } => arc_path(start, end, &delta, center, plane, clockwise, turns),
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
                    bend: Bend::Spline(
                        Curve {
                            a2: a[1],
                            a3: a[2],
                            rate: spline::rate_of(length),
                        },
                        Dip::NONE,
                    ),
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
                Bend::Spline(c, _) => Shape::Spline {
                    rate: c.rate,
                    dip: None,
                },
                Bend::Arc(_) => Shape::Point,
            },
        }
    }

    /// Pose after `s` (nm Q16) along the path from `start` ([`Course::pose_at`]).
    pub fn pose_at(&self, start: &[i64; AXES], s: i64, pose: &mut [i64; AXES]) {
        self.course.pose_at(&self.bend, start, s, pose);
    }
}
