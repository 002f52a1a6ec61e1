//! The block vocabulary: what a block asks for (`Motion`, `Plane`, `Aux`, `Block`),
//! the host's plan for it (`Plan`, with the path's `Shape`), and the two together
//! (`PlannedBlock`). The motion rooms compute with these; the wire carries them
//! (serde derives; `Shape`'s random-bit fields go as fixed-width bytes).

use crate::config::AXES;
use serde::{Deserialize, Serialize};

/// Shape of a path, as the wire carries it: computed by the host
/// ([`crate::motion::geometry::Path::new`]) and sent with each block; the controller checks it
/// against the block ([`crate::motion::geometry::Path::from_plan`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Shape {
    /// Straight line; `unit[i]` = Δᵢ/S in Q20.44.
    Line {
        /// Direction per axis, Q20.44.
        unit: [i64; AXES],
    },
    /// Arc or helix.
    Arc {
        /// Plane. Not sent: the block has it ([`crate::motion::geometry::Path::from_plan`] takes
        /// it from there).
        #[serde(skip)]
        plane: Plane,
        /// Centre (first, second in-plane axis), nm. Not sent, as `plane`.
        #[serde(skip)]
        center: [i64; 2],
        /// Start radius, nm.
        r0: i64,
        /// End radius minus start radius, nm.
        dr: i64,
        /// Start angle, turns Q64 (wrapping). Sent as 8 bytes (its varint would be 10,
        /// and slower to read).
        #[serde(with = "fixed_width::u64_le")]
        phi0: u64,
        /// Angle per path distance: sweep·2¹⁶ / length (sweep: the signed angle, turns
        /// Q64, more than one turn for multi-turn arcs), so that φ(s) = φ₀ + (k·s) ≫ 32
        /// for s in nm Q16 (no division per tick). The sweep itself is not stored: it
        /// is (k·length) ≫ 16 to within length/2¹⁶ + 1 units of 2⁻⁶⁴ turn.
        #[serde(with = "fixed_width::i128_le")]
        phi_rate: i128,
        /// Radius change per path distance: (dr·2⁴⁰) / length, used as (k·s) ≫ 56 (fine
        /// enough that the radius lands within a nanometre of the end on any arc).
        r_rate: i64,
        /// Per-axis direction of the linear part (helix axis and A B C), Q20.44;
        /// in-plane entries are 0.
        unit: [i64; AXES],
    },
    /// No motion (dwell, auxiliary function, zero-length move).
    Point,
    /// Cubic or quadratic spline ([`Motion::Cubic`], [`Motion::Quadratic`]): the
    /// curve itself follows from the block; the parameter advances linearly with path
    /// distance, u = s / length, where `length` is the largest |dP/du| over X Y Z (so
    /// the tool never moves faster than the path speed).
    Spline {
        /// ⌊2⁶⁴ / length⌋, so that u (Q32) = (s·rate) ≫ 48 for s in nm Q16 (no
        /// division per tick). Sent as 8 bytes.
        #[serde(with = "fixed_width::u64_le")]
        rate: u64,
        /// Where the curve's bend allows least and how fast it may pass there (the
        /// plan's, not the curve's: a path the host derives has none; its plan,
        /// [`crate::motion::planner::PlanBlock::dip`], may). Only a curve has one, so
        /// only a curve's block carries its byte.
        dip: Option<Dip>,
    },
}

/// Little-endian fixed-width encodings for fields whose varint is long (random bits):
/// cheaper for the controller to read than their varints.
mod fixed_width {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub mod u64_le {
        use super::*;
        pub fn serialize<S: Serializer>(v: &u64, s: S) -> Result<S::Ok, S::Error> {
            v.to_le_bytes().serialize(s)
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
            <[u8; 8]>::deserialize(d).map(u64::from_le_bytes)
        }
    }

    pub mod i128_le {
        use super::*;
        pub fn serialize<S: Serializer>(v: &i128, s: S) -> Result<S::Ok, S::Error> {
            v.to_le_bytes().serialize(s)
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<i128, D::Error> {
            <[u8; 16]>::deserialize(d).map(i128::from_le_bytes)
        }
    }
}

/// Arc plane: the in-plane axes are XY, ZX or YZ and the helix axis Z, Y or X.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Plane {
    /// G17.
    #[default]
    Xy,
    /// G18.
    Zx,
    /// G19.
    Yz,
}

impl Plane {
    /// Pose indices of the first and second in-plane axes and of the helix axis.
    pub const fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Zx => (2, 0, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
}

/// Auxiliary functions executed in program order (they wait for motion before them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Aux {
    /// Spindle off (M5).
    SpindleOff,
    /// Spindle clockwise at rpm (M3).
    SpindleCw(u32),
    /// Spindle counter-clockwise at rpm (M4).
    SpindleCcw(u32),
    /// Mist coolant (M7).
    Mist,
    /// Flood coolant (M8).
    Flood,
    /// Coolant off (M9).
    CoolantOff,
    /// Tool change to tool n (M6); the controller holds until resumed.
    ToolChange(u32),
    /// Program pause (M0, or M1 when `true`); the controller holds until resumed.
    Pause(bool),
}

/// What a block does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Motion {
    /// Rapid positioning at the machine's limits (G0).
    Rapid,
    /// Straight feed move (G1).
    Linear,
    /// Circular or helical feed move (G2/G3) about `center` in `plane`.
    Arc {
        /// Centre, in-plane coordinates (first, second axis of the plane), nm.
        center: [i64; 2],
        /// Plane.
        plane: Plane,
        /// G2 (clockwise seen from the positive helix axis).
        clockwise: bool,
        /// Extra full turns (P − 1).
        turns: u16,
    },
    /// Dwell (G4), ms; `target` must equal the current pose.
    Dwell(u32),
    /// Auxiliary function; `target` must equal the current pose.
    Aux(Aux),
    /// Cubic Bézier feed move (G5, and runs of short moves the host merged into one
    /// curve): from the start through the control points start + `c1` and `target` +
    /// `c2` to `target` (axis units; offsets, so that they are short on the wire).
    Cubic {
        /// First control point minus the start.
        c1: [i64; AXES],
        /// Second control point minus the target.
        c2: [i64; AXES],
    },
    /// Quadratic (parabolic) Bézier feed move (G5.1): from the start through the
    /// control point start + `c` to `target`.
    Quadratic {
        /// Control point minus the start.
        c: [i64; AXES],
    },
}

impl Motion {
    /// Does the controller keep a bend for this motion (arcs and splines: their
    /// curved part is held apart from the queue's line-sized slots)?
    pub const fn curved(&self) -> bool {
        matches!(
            self,
            Motion::Arc { .. } | Motion::Cubic { .. } | Motion::Quadratic { .. }
        )
    }
}

/// One canonical block, in absolute workpiece pose (axis units, see
/// [`crate::units`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Block {
    /// NC program line the block came from (1-based; 0 for none).
    pub line: u32,
    /// Motion kind.
    pub motion: Motion,
    /// End pose X Y Z (nm) A B C (n°).
    pub target: [i64; AXES],
    /// Path feed, nm/s along XYZ (or µ°/s when only rotary axes move); ignored for
    /// rapids, dwells and auxiliary functions.
    pub feed: i64,
    /// Largest deviation allowed when blending into the next block, nm (G64 P);
    /// 0 stops exactly at the block's end (G61), `u32::MAX` blends as the limits allow.
    pub tolerance_nm: u32,
}

/// The host's plan of a motion block, made with the whole program in view by the
/// core's own planner ([`crate::motion::planner::plan_into`]) on the host: the geometry, the
/// speed and acceleration limits sampled along the block through the kinematics, and
/// the entry speed of unlimited look-ahead. The controller checks the geometry against
/// the block ([`crate::motion::geometry::Path::from_plan`]) and the target against the joint
/// travel, and never runs faster than the plan nor than it can stop within what it has
/// buffered ([`crate::motion::planner`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Path length, nm (n° for a move of rotary axes only).
    pub length: i64,
    /// Geometry.
    pub shape: Shape,
    /// Hard speed limit along the block, nm/tick.
    pub v_limit: f32,
    /// Acceleration of the block's profile, nm/tick².
    pub accel: f32,
    /// Planned entry speed, nm/tick.
    pub entry: f32,
    /// The block must be entered at rest (exact stop, or a corner not blended).
    pub stop: bool,
}

/// A spline's dip (the host's plan, [`crate::motion::planner::refine_splines`]): a
/// curve whose bend is tightest inside it slows for that stretch alone, and runs
/// faster on either side, where a single speed limit for the whole block would hold
/// it to the tightest stretch's. The controller profiles such a block in two pieces,
/// to the dip and beyond it ([`crate::motion::interp`]).
///
/// Kept small, as the controller keeps it: beside its curve in the queue's ring of
/// bends, in the bytes the curve's slot leaves free (five of them). Its speeds are
/// rounded down to 11 bits of mantissa ([`Dip::new`]), so that host and controller
/// plan with the same values; a limit rounded down is still a limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Dip {
    /// Where, in 256ths of the block's length from its start (1 to 255; 0: no dip).
    pub at: u8,
    /// The most the block may pass there at ([`Dip::speed`]).
    pub speed: u16,
    /// Hard speed limit beyond it ([`Dip::after`]; [`Plan::v_limit`] holds before
    /// it). Carried in the curve's [`Shape::Spline`].
    pub after: u16,
}

/// Speeds a [`Dip`] holds: from 2⁻⁸ nm/tick (4 µm/s) up, 2⁵ binades of 11 bits.
const DIP_EXP_BIAS: u32 = 127 - 8;

impl Dip {
    /// No dip (a placeholder in the controller's ring of bends).
    pub const NONE: Dip = Dip {
        at: 0,
        speed: 0,
        after: 0,
    };

    /// A dip at `at` 256ths of the length passed at `speed` at most, `after` (nm/tick)
    /// beyond it, its speeds rounded down.
    pub fn new(at: u8, speed: f32, after: f32) -> Dip {
        Dip {
            at,
            speed: Self::pack(speed),
            after: Self::pack(after),
        }
    }

    /// `v` (nm/tick) rounded down to what 16 bits hold: 5 bits of exponent, 11 of
    /// mantissa (below 2⁻⁸ nm/tick: 0; above 2²⁴: the largest).
    fn pack(v: f32) -> u16 {
        // (NaN too.)
        if v.is_nan() || v < 1.0 / 256.0 {
            return 0;
        }
        let bits = v.to_bits();
        let exp = (bits >> 23) - DIP_EXP_BIAS;
        if exp > 31 {
            return u16::MAX;
        }
        ((exp << 11) | ((bits >> 12) & 0x7FF)) as u16
    }

    /// The speed (nm/tick) `p` holds.
    fn unpack(p: u16) -> f32 {
        if p == 0 {
            return 0.0;
        }
        let (exp, mantissa) = ((p >> 11) as u32, (p & 0x7FF) as u32);
        f32::from_bits(((exp + DIP_EXP_BIAS) << 23) | (mantissa << 12))
    }

    /// The most the block may pass the dip at, nm/tick.
    pub fn speed(&self) -> f32 {
        Self::unpack(self.speed)
    }

    /// The block's speed limit beyond the dip, nm/tick.
    pub fn after(&self) -> f32 {
        Self::unpack(self.after)
    }

    /// Where the dip is on a block `length` nm long, nm Q16 (exactly).
    pub fn at_q16(&self, length: i64) -> i64 {
        (length << 8) * self.at as i64
    }

    /// The speed (nm/tick) to pass the dip at on a block `length` nm long profiled at
    /// `accel` and left at `exit`: the dip's, and no faster than the rest of the block
    /// can still slow down to `exit` from (so that a stop within what is buffered holds
    /// across the dip).
    pub fn through(&self, length: i64, accel: f32, exit: f32) -> f32 {
        let beyond = crate::math::i64_to_f32((length << 16) - self.at_q16(length)) / 65_536.0;
        crate::math::fmin(
            self.speed(),
            crate::math::sqrtf(exit * exit + 2.0 * accel * beyond),
        )
    }
}

/// A block with its plan: what the host streams.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlannedBlock {
    /// The block.
    pub block: Block,
    /// Its plan.
    pub plan: Plan,
}
