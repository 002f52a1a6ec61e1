//! Servo position loops: encoder extension, setpoint interpolation from the 1 kHz
//! interpolator to the 10 kHz servo period, and one axis's PID loop with feed-forward,
//! anti-windup, a 12-bit DAC output stage, amplifier enable/fault handling and a
//! velocity-scaled following-error trip.
//!
//! **Period.** The loops run at [`SERVO_HZ`] = 10 kHz, [`SERVO_PER_TICK`] periods per
//! interpolation tick ([`crate::units::TICK_HZ`]). At each tick the caller
//! [`SetpointInterpolator::load`]s the joint's next target ([`target_q16`]: encoder
//! counts with 16 fraction bits, so that the velocity and acceleration feed-forward see
//! the path and not the encoder's quantisation: at 1 µm per count and 1 kHz a whole
//! count per tick is 1 mm/s); each servo period [`SetpointInterpolator::advance`] steps
//! linearly from the previous target to it, so the loop sees the 1 kHz path one tick
//! late, as a continuous ramp with constant velocity inside the tick.
//!
//! **Loop** ([`ServoAxis::update`], LinuxCNC `pid` component form), with the following
//! error e = target − feedback + r (counts, fractional; r is a reference pre-compensation from
//! [`crate::drive::contour`], zero when uncoupled):
//!
//! ```text
//! u = kp·e + I + kd·ė + kvff·v + kaff·a + c        (c.u., c = coupling command)
//! I ← clamp(I + ki·e·T, ±max_integral)             only if u is not saturated, or
//!                                                  e drives it back (conditional
//!                                                  integration: no wind-up)
//! out = clamp(u, ±max_output)
//! dac = clamp(2048 + dac_offset + round(dac_per_unit·out), 0, 4095)
//! ```
//!
//! **Following error** (LinuxCNC `FERROR` / `MIN_FERROR`): the loop trips when
//! |target − feedback| > MIN_FERROR + (FERROR − MIN_FERROR)·|v|/v_max, v the commanded
//! joint velocity. A trip ([`Trip`]), like an amplifier fault, latches: the output goes
//! to zero (mid-scale plus trim), the amplifier is disabled, the integrator cleared,
//! until [`ServoAxis::reset`].
//!
//! **Arithmetic.** Positions are `i64` counts and errors exact integers; the loop
//! arithmetic is `f32` because the STM32G474's Cortex-M4F has a single-precision FPU
//! (one-cycle multiply-accumulate, no library calls), gains span six decades (a Q16
//! acceleration feed-forward would keep two significant digits), and errors below
//! 2^24 counts convert exactly. No `f64`, no division (reciprocals are formed once in
//! [`ServoAxis::new`]), no loops, no panics per period; IEEE single-precision
//! operations give the same bits on the MCU and the host, so the simulator runs the
//! firmware's arithmetic.

use crate::config::ServoGains;
use crate::math::clamp_sym;
use crate::units::TICK_HZ;

/// Servo loop frequency, Hz.
pub const SERVO_HZ: u32 = 10_000;
/// Servo periods per interpolation tick.
pub const SERVO_PER_TICK: usize = (SERVO_HZ / TICK_HZ) as usize;
/// Servo period, s.
pub const SERVO_PERIOD_S: f32 = 1.0 / SERVO_HZ as f32;
const _: () = assert!(SERVO_HZ.is_multiple_of(TICK_HZ) && SERVO_PER_TICK >= 1);

/// DAC resolution, bits.
pub const DAC_BITS: u32 = 12;
/// Highest DAC code.
pub const DAC_MAX: i32 = (1 << DAC_BITS) - 1;
/// DAC code of a zero command (mid-scale).
pub const DAC_MID: i32 = 1 << (DAC_BITS - 1);

/// Extends a free-running 16-bit hardware counter to 64 bits: the position whose low
/// 16 bits are `raw` nearest to `previous`. Exact as long as the counter moves by less
/// than 2^15 counts between two calls (at 10 kHz: 327 million counts/s).
pub fn extend_counter(previous: i64, raw: u16) -> i64 {
    let step = raw.wrapping_sub(previous as u16) as i16;
    previous.wrapping_add(step as i64)
}

/// Fraction bits of setpoint positions.
pub const SETPOINT_FRAC_BITS: u32 = 16;

/// A joint position (axis units, nm or n°) as encoder counts with
/// [`SETPOINT_FRAC_BITS`] fraction bits, rounded to nearest. Once per joint and tick.
pub fn target_q16(scale: &crate::config::Scale, position: i64) -> i64 {
    crate::units::div_round(
        ((position as i128) << SETPOINT_FRAC_BITS) * scale.steps as i128,
        scale.per_units as i128,
    ) as i64
}

/// The target of one servo period.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Setpoint {
    /// Position, counts × 2^[`SETPOINT_FRAC_BITS`].
    pub position_q16: i64,
    /// Velocity, counts/s (constant over a tick).
    pub velocity: f32,
    /// Acceleration, counts/s² (the change of velocity from the previous tick).
    pub accel: f32,
}

/// Fractions (k+1)/SERVO_PER_TICK of a tick in Q32, for k = 0..SERVO_PER_TICK−1.
const STEP_Q32: [u64; SERVO_PER_TICK] = {
    let mut t = [0u64; SERVO_PER_TICK];
    let mut k = 0;
    while k < SERVO_PER_TICK {
        t[k] = (((k as u64 + 1) << 32) + SERVO_PER_TICK as u64 / 2) / SERVO_PER_TICK as u64;
        k += 1;
    }
    t
};

/// Largest move of one tick, counts × 2^16, that the interpolator steps exactly; larger
/// jumps are clamped: 32 767 counts per tick, 32.7 m/s at 1 µm per count.
pub const MAX_TICK_MOVE: i64 = i32::MAX as i64;

/// Linear interpolation of one joint's 1 kHz targets into 10 kHz setpoints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SetpointInterpolator {
    start: i64,
    delta: i64,
    step: usize,
    velocity: f32,
    accel: f32,
}

impl SetpointInterpolator {
    /// At rest at `position` (counts × 2^16).
    pub const fn new(position: i64) -> Self {
        Self {
            start: position,
            delta: 0,
            step: SERVO_PER_TICK,
            velocity: 0.0,
            accel: 0.0,
        }
    }

    /// Starts a new tick towards `target` (counts × 2^16, from [`target_q16`]) from the
    /// previous target.
    pub fn load(&mut self, target: i64) {
        let end = self.start + self.delta;
        self.start = end;
        self.delta = target
            .wrapping_sub(end)
            .clamp(-MAX_TICK_MOVE, MAX_TICK_MOVE);
        let velocity = self.delta as i32 as f32 * (TICK_HZ as f32 / 65_536.0);
        self.accel = (velocity - self.velocity) * TICK_HZ as f32;
        self.velocity = velocity;
        self.step = 0;
    }

    /// The setpoint of the next servo period; after [`SERVO_PER_TICK`] calls it stays on
    /// the loaded target with zero velocity until the next [`load`](Self::load).
    pub fn advance(&mut self) -> Setpoint {
        if self.step >= SERVO_PER_TICK {
            self.velocity = 0.0;
            self.accel = 0.0;
            return Setpoint {
                position_q16: self.start + self.delta,
                velocity: 0.0,
                accel: 0.0,
            };
        }
        let position = if self.step + 1 == SERVO_PER_TICK {
            self.start + self.delta
        } else {
            self.start + self.part(self.step)
        };
        self.step += 1;
        Setpoint {
            position_q16: position,
            velocity: self.velocity,
            accel: self.accel,
        }
    }

    /// The velocity (counts/s) and acceleration (counts/s²) of the last setpoint
    /// [`advance`](Self::advance) gave.
    pub fn rates(&self) -> (f32, f32) {
        (self.velocity, self.accel)
    }

    /// The setpoint [`advance`](Self::advance) gave last (the previous target before
    /// the first advance of a tick), counts × 2^16.
    pub fn position(&self) -> i64 {
        match self.step {
            0 => self.start,
            s if s >= SERVO_PER_TICK => self.start + self.delta,
            s => self.start + self.part(s - 1),
        }
    }

    /// `delta` × (`k` + 1) / [`SERVO_PER_TICK`], rounded (`k` below
    /// `SERVO_PER_TICK - 1`): `delta` is within `i32` ([`MAX_TICK_MOVE`]) and the
    /// fraction `STEP_Q32[k]` within `u32`, so the product is one 32 × 32-bit multiply
    /// (the fraction taken as signed, and `delta` added back to the high word when its
    /// top bit is set), not a 64 × 64-bit one.
    #[inline(always)]
    fn part(&self, k: usize) -> i64 {
        let q = STEP_Q32[k % SERVO_PER_TICK];
        let d = self.delta as i32;
        let mut p = d as i64 * (q as u32 as i32) as i64;
        if q >= 1 << 31 {
            p = p.wrapping_add((d as i64) << 32);
        }
        (p + (1 << 31)) >> 32
    }

    /// The last loaded target, counts × 2^16.
    pub fn target(&self) -> i64 {
        self.start + self.delta
    }
}

/// The amplifier's lines as the loop sees them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AmpIo {
    /// The controller wants the axis enabled.
    pub enable: bool,
    /// The amplifier reports a fault (active).
    pub fault: bool,
}

/// Corrections from contour control ([`crate::drive::contour`]); zero when uncoupled.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Coupling {
    /// Added to the reference, counts (CCPM pre-compensation).
    pub reference: f32,
    /// Added to the command, c.u. (cross-coupled control).
    pub command: f32,
}

impl Coupling {
    /// No correction.
    pub const NONE: Coupling = Coupling {
        reference: 0.0,
        command: 0.0,
    };
}

/// Why a loop stopped driving its axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Trip {
    /// |target − feedback| exceeded the velocity-scaled limit.
    FollowingError {
        /// Following error, counts (saturated to `i32`).
        error: i32,
        /// Limit in force, counts.
        limit: i32,
    },
    /// The amplifier's fault input was active while enabled.
    AmplifierFault,
}

/// What one loop update drives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoOutput {
    /// DAC code to write, 0..=[`DAC_MAX`].
    pub dac: u16,
    /// Command after the clamp, c.u.
    pub command: f32,
    /// Amplifier enable line.
    pub enable: bool,
    /// The command hit `max_output` this period.
    pub saturated: bool,
    /// The latched trip, if any (the loop is then disabled).
    pub trip: Option<Trip>,
}

/// Per-period constants of a loop, formed once from [`ServoGains`].
#[derive(Clone, Copy, Debug, PartialEq)]
struct Coefs {
    kp: f32,
    ki_t: f32,
    kd_hz: f32,
    kvff: f32,
    kaff: f32,
    max_output: f32,
    max_integral: f32,
    dac_per_unit: f32,
    dac_zero: i32,
    min_ferror: f32,
    ferror: f32,
    ferror_per_velocity: f32,
    ferror_on: bool,
}

/// One axis's position loop. See the module documentation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoAxis {
    c: Coefs,
    /// The LQG law's estimate and integral (unused under PID).
    lqg: crate::drive::lqg::LqgState,
    integral: f32,
    previous_error: f32,
    enabled: bool,
    trip: Option<Trip>,
}

/// Saturating `i64` → `i32`.
fn to_i32(v: i64) -> i32 {
    let low = v as i32;
    if low as i64 == v {
        low
    } else if v < 0 {
        i32::MIN
    } else {
        i32::MAX
    }
}

/// `target − feedback` in counts: the whole part saturated to `i32`, and the exact
/// value as `f32` (no 64-bit float conversion, which is a library call on the M4).
pub fn following_error(target_q16: i64, feedback: i64) -> (i32, f32) {
    let diff = target_q16.wrapping_sub(feedback << SETPOINT_FRAC_BITS);
    let whole = to_i32(diff >> SETPOINT_FRAC_BITS);
    let frac = (diff & 0xFFFF) as i32 as f32 * (1.0 / 65_536.0);
    (whole, whole as f32 + frac)
}

/// Rounds to nearest, ties away from zero, saturating (one VCVT on the M4F).
fn round_i32(v: f32) -> i32 {
    if v >= 0.0 {
        (v + 0.5) as i32
    } else {
        (v - 0.5) as i32
    }
}

impl ServoAxis {
    /// A disabled loop with `gains`, for a joint whose top speed is `max_velocity`
    /// counts/s (scales the following-error limit).
    pub fn new(gains: &ServoGains, max_velocity: f32) -> Self {
        let (min_fe, fe) = (gains.min_ferror as f32, gains.ferror as f32);
        let per_v = if max_velocity > 0.0 {
            (fe - min_fe) / max_velocity
        } else {
            0.0
        };
        Self {
            c: Coefs {
                kp: gains.kp,
                ki_t: gains.ki * SERVO_PERIOD_S,
                kd_hz: gains.kd * SERVO_HZ as f32,
                kvff: gains.kvff,
                kaff: gains.kaff,
                max_output: gains.max_output,
                max_integral: gains.max_integral,
                dac_per_unit: gains.dac_per_unit,
                dac_zero: DAC_MID + gains.dac_offset as i32,
                min_ferror: min_fe,
                ferror: fe,
                ferror_per_velocity: per_v,
                ferror_on: gains.ferror > 0,
            },
            lqg: crate::drive::lqg::LqgState::new(),
            integral: 0.0,
            previous_error: 0.0,
            enabled: false,
            trip: None,
        }
    }

    /// Clears a latched trip; the loop restarts from a clear integrator when next
    /// enabled.
    pub fn reset(&mut self) {
        self.trip = None;
        self.enabled = false;
    }

    /// The latched trip, if any.
    pub fn trip(&self) -> Option<Trip> {
        self.trip
    }

    /// Integrator state, c.u.
    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Following-error limit at commanded velocity `v` counts/s, counts.
    pub fn ferror_limit(&self, v: f32) -> f32 {
        let speed = if v < 0.0 { -v } else { v };
        let limit = self.c.min_ferror + self.c.ferror_per_velocity * speed;
        if limit > self.c.ferror {
            self.c.ferror
        } else {
            limit
        }
    }

    fn idle(&mut self, error: f32) -> ServoOutput {
        self.integral = 0.0;
        self.lqg.reset();
        self.previous_error = error;
        self.enabled = false;
        ServoOutput {
            dac: self.c.dac_zero.clamp(0, DAC_MAX) as u16,
            command: 0.0,
            enable: false,
            saturated: false,
            trip: self.trip,
        }
    }

    /// One servo period: drives towards `target` given the encoder `feedback` (counts),
    /// the amplifier lines and the contour `coupling`; by the PID, or by the LQG design
    /// `lqg` in its place (the feed-forward, coupling, limits, trips and output stage
    /// are the same).
    pub fn update(
        &mut self,
        target: &Setpoint,
        feedback: i64,
        amp: AmpIo,
        coupling: Coupling,
        lqg: Option<&crate::config::LqgGains>,
    ) -> ServoOutput {
        let fe = following_error(target.position_q16, feedback);
        self.update_on(target, fe, amp, coupling, lqg)
    }

    /// [`ServoAxis::update`] given the period's following error
    /// `following_error(target.position_q16, feedback)` (the bank has it already).
    pub fn update_on(
        &mut self,
        target: &Setpoint,
        (raw, exact): (i32, f32),
        amp: AmpIo,
        coupling: Coupling,
        lqg: Option<&crate::config::LqgGains>,
    ) -> ServoOutput {
        let error = exact + coupling.reference;
        if self.trip.is_none() && amp.enable && amp.fault {
            self.trip = Some(Trip::AmplifierFault);
        }
        if self.trip.is_none() && amp.enable && self.c.ferror_on {
            let limit = self.ferror_limit(target.velocity);
            let magnitude = if exact < 0.0 { -exact } else { exact };
            if magnitude > limit {
                self.trip = Some(Trip::FollowingError {
                    error: raw,
                    limit: round_i32(limit),
                });
            }
        }
        if self.trip.is_some() || !amp.enable {
            return self.idle(error);
        }
        if !self.enabled {
            // First enabled period: no derivative kick from a stale error.
            self.enabled = true;
            self.previous_error = error;
        }
        let c = &self.c;
        if let Some(g) = lqg {
            let ff = c.kvff * target.velocity + c.kaff * target.accel + coupling.command;
            let command = self.lqg.update(g, -error, ff, c.max_output, c.max_integral);
            let dac = (c.dac_zero + round_i32(command * c.dac_per_unit)).clamp(0, DAC_MAX);
            return ServoOutput {
                dac: dac as u16,
                command,
                enable: true,
                saturated: command >= c.max_output || command <= -c.max_output,
                trip: None,
            };
        }
        let derivative = c.kd_hz * (error - self.previous_error);
        self.previous_error = error;
        let base = c.kp * error
            + derivative
            + c.kvff * target.velocity
            + c.kaff * target.accel
            + coupling.command;
        let candidate = clamp_sym(self.integral + c.ki_t * error, c.max_integral);
        let u = base + candidate;
        let winding = (u > c.max_output && error > 0.0) || (u < -c.max_output && error < 0.0);
        if !winding {
            self.integral = candidate;
        }
        let u = base + self.integral;
        let command = clamp_sym(u, c.max_output);
        let dac = (c.dac_zero + round_i32(command * c.dac_per_unit)).clamp(0, DAC_MAX);
        ServoOutput {
            dac: dac as u16,
            command,
            enable: true,
            saturated: command != u,
            trip: None,
        }
    }
}

#[cfg(test)]
#[path = "servo_tests.rs"]
mod tests;
