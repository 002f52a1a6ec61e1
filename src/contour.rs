//! Contour control: coordinates the servo loops of the X, Y and Z axes so that the tool
//! stays on the path, rather than each axis on its own schedule, and runs one servo
//! period of every servo channel ([`ServoBank::period`]).
//!
//! Source: report B of `seeds-digest.md` (NSC 92-2212-E-009-036, §3.5 and Fig. 6),
//! after Koren (1980), "Cross-coupled biaxial computer control for manufacturing
//! systems", and Koren and Lo (1991), "Variable-gain cross-coupling control for
//! contouring".
//!
//! **Contour error** (3-D, from the axis errors and the path's direction and
//! curvature). With the path velocity v and acceleration a at the setpoint (from the
//! interpolator, mm/s and mm/s²), the unit tangent t = v/|v| and the curvature vector
//! k = (a − (a·t)t)/|v|² (= κ·n, n the principal normal). The path near the setpoint r is
//! r + s·t + (s²/2)·k. For the tracking error e = r − y (y the measured position), the
//! contour error vector — from y to the nearest path point, to second order — is
//!
//! ```text
//! ε = e − (e·t)·t + ((e·t)²/2)·k
//! ```
//!
//! (the normal-plane part of e, corrected for the path bending away over the tangential
//! lag e·t: Koren and Lo's circular correction, in 3-D). Below [`MIN_CONTOUR_SPEED`]
//! the tangent is undefined and ε is taken as zero (coupling holds its state).
//!
//! **Uncoupled.** Each axis runs its own PID with its velocity and acceleration
//! feed-forward ([`crate::servo`]).
//!
//! **Cross-coupled** (Koren): the contour error goes through a PI controller
//! W = kp + ki/s whose output is distributed to the axes' commands by the direction
//! cosines of ε (its components): c = kp·ε + P(I), I = ∫ki·ε dt, P the projection onto
//! the normal plane (the integral stays a path-normal correction while the path turns).
//!
//! **CCPM** (cross-coupling pre-compensation, report B §3.5, steps 1–4): (1) the
//! interpolator's joint targets; (2) the contour error computed from the fed-back
//! positions and decoupled into per-axis errors (for this X-Y table + Z leg machine the
//! decoupling is the identity; for a parallel mechanism it is the inverse Jacobian);
//! (3) the velocity pre-compensation — each joint's velocity (and acceleration) from
//! the path by the inverse kinematics, applied as feed-forward by every axis loop; (4)
//! the path offset fed back into the interpolator iteratively: each period the
//! reference of every axis is shifted by o, o ← P(o + kr·ε·T), so the path the loops
//! follow is pre-compensated by the contour error they will otherwise leave. The
//! cross-coupled command c is applied as well. The report gives the structure, not the
//! equations; the form here is this project's reading of it.
//!
//! Arithmetic: `f32`, as in [`crate::servo`]; 1/|v| by the bit-level reciprocal square
//! root with three Newton steps (no division, no library call). Capacities: the bank
//! has [`MAX_SERVOS`] channels; every loop is a fixed count.

// Vector arithmetic over channel-indexed parallel arrays reads best with an index.
#![allow(clippy::needless_range_loop)]

use crate::config::{ContourConfig, ContourMode, Drive, KinematicsConfig, MachineConfig};
use crate::config::{ServoGains, MAX_SERVOS};
use crate::servo::{
    clamp_sym, following_error, AmpIo, Coupling, ServoAxis, ServoOutput, Setpoint,
    SetpointInterpolator, Trip, DAC_MID, SERVO_PERIOD_S, SETPOINT_FRAC_BITS,
};

/// Slowest path speed at which the contour error is estimated, mm/s.
pub const MIN_CONTOUR_SPEED: f32 = 0.01;

/// A vector over the servo channels (uncoupled channels hold zero).
pub type ChannelVec = [f32; MAX_SERVOS];

/// 1/√x for x > 0, relative error below 1e-7: bit-level first guess and three Newton
/// steps (multiplies only).
pub fn rsqrt(x: f32) -> f32 {
    let mut y = f32::from_bits(0x5f37_5a86u32.wrapping_sub(x.to_bits() >> 1));
    let half = 0.5 * x;
    y *= 1.5 - half * y * y;
    y *= 1.5 - half * y * y;
    y *= 1.5 - half * y * y;
    y
}

fn dot(a: &ChannelVec, b: &ChannelVec) -> f32 {
    let mut s = 0.0;
    for i in 0..MAX_SERVOS {
        s += a[i] * b[i];
    }
    s
}

/// The path's local frame at the setpoint.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathFrame {
    /// Unit tangent (direction cosines).
    pub tangent: ChannelVec,
    /// Curvature vector κ·n, 1/mm.
    pub curvature: ChannelVec,
    /// The path is moving (faster than [`MIN_CONTOUR_SPEED`]): the frame is defined.
    pub moving: bool,
}

impl PathFrame {
    /// The frame of a path with velocity `v` (mm/s) and acceleration `a` (mm/s²).
    pub fn new(v: &ChannelVec, a: &ChannelVec) -> Self {
        let v2 = dot(v, v);
        if v2.partial_cmp(&(MIN_CONTOUR_SPEED * MIN_CONTOUR_SPEED))
            != Some(core::cmp::Ordering::Greater)
        {
            return Self::default();
        }
        let inv = rsqrt(v2);
        let mut tangent = [0.0; MAX_SERVOS];
        for i in 0..MAX_SERVOS {
            tangent[i] = v[i] * inv;
        }
        let at = dot(a, &tangent);
        let inv2 = inv * inv;
        let mut curvature = [0.0; MAX_SERVOS];
        for i in 0..MAX_SERVOS {
            curvature[i] = (a[i] - at * tangent[i]) * inv2;
        }
        Self {
            tangent,
            curvature,
            moving: true,
        }
    }

    /// Removes the tangential part of `x` in place.
    pub fn project(&self, x: &mut ChannelVec) {
        let along = dot(x, &self.tangent);
        for i in 0..MAX_SERVOS {
            x[i] -= along * self.tangent[i];
        }
    }

    /// The contour error vector ε of the tracking error `e` (mm); zero when standing.
    pub fn contour_error(&self, e: &ChannelVec) -> ChannelVec {
        if !self.moving {
            return [0.0; MAX_SERVOS];
        }
        let et = dot(e, &self.tangent);
        let bend = 0.5 * et * et;
        let mut eps = [0.0; MAX_SERVOS];
        for i in 0..MAX_SERVOS {
            eps[i] = e[i] - et * self.tangent[i] + bend * self.curvature[i];
        }
        eps
    }
}

/// The coupling state of the contour controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContourLoop {
    config: ContourConfig,
    ki_t: f32,
    kr_t: f32,
    integral: ChannelVec,
    offset: ChannelVec,
}

/// What the contour controller asks of each channel this period.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContourCorrection {
    /// Reference offset, mm (CCPM).
    pub reference: ChannelVec,
    /// Command correction, c.u. (cross-coupled and CCPM).
    pub command: ChannelVec,
}

impl ContourLoop {
    /// A controller with no accumulated correction.
    pub fn new(config: &ContourConfig) -> Self {
        Self {
            config: *config,
            ki_t: config.ki * SERVO_PERIOD_S,
            kr_t: config.kr * SERVO_PERIOD_S,
            integral: [0.0; MAX_SERVOS],
            offset: [0.0; MAX_SERVOS],
        }
    }

    /// Clears the integrator and the reference offset.
    pub fn reset(&mut self) {
        self.integral = [0.0; MAX_SERVOS];
        self.offset = [0.0; MAX_SERVOS];
    }

    /// One period given the frame and the contour error `eps` (mm).
    pub fn update(&mut self, frame: &PathFrame, eps: &ChannelVec) -> ContourCorrection {
        let mut out = ContourCorrection::default();
        let c = &self.config;
        if c.mode == ContourMode::Uncoupled || !frame.moving {
            out.reference = self.offset;
            return out;
        }
        for i in 0..MAX_SERVOS {
            self.integral[i] = clamp_sym(self.integral[i] + self.ki_t * eps[i], c.max_integral);
        }
        frame.project(&mut self.integral);
        for i in 0..MAX_SERVOS {
            out.command[i] = c.kp * eps[i] + self.integral[i];
        }
        if c.mode == ContourMode::Ccpm {
            for i in 0..MAX_SERVOS {
                self.offset[i] = clamp_sym(self.offset[i] + self.kr_t * eps[i], c.max_offset);
            }
            frame.project(&mut self.offset);
            out.reference = self.offset;
        }
        out
    }
}

/// What the hardware reports each servo period.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PeriodInputs {
    /// Extended encoder position of each channel, counts ([`crate::servo::extend_counter`]).
    pub feedback: [i64; MAX_SERVOS],
    /// Amplifier fault input of each channel.
    pub fault: [bool; MAX_SERVOS],
    /// The controller wants the drives enabled (not in alarm or e-stop).
    pub enable: bool,
}

/// What the hardware must do this servo period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeriodOutputs {
    /// DAC code of each channel.
    pub dac: [u16; MAX_SERVOS],
    /// Amplifier enable of each channel.
    pub enable: [bool; MAX_SERVOS],
    /// Latched trip of each channel.
    pub trip: [Option<Trip>; MAX_SERVOS],
    /// Estimated contour error vector, mm, per channel (zero for uncoupled channels).
    pub contour_error: ChannelVec,
    /// Command of each channel after its clamp, c.u.
    pub command: ChannelVec,
}

impl Default for PeriodOutputs {
    fn default() -> Self {
        Self {
            dac: [DAC_MID as u16; MAX_SERVOS],
            enable: [false; MAX_SERVOS],
            trip: [None; MAX_SERVOS],
            contour_error: [0.0; MAX_SERVOS],
            command: [0.0; MAX_SERVOS],
        }
    }
}

/// Every servo channel's setpoint interpolator and loop, and their contour coupling:
/// the whole 10 kHz servo work of the board, as plain state and two calls.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoBank {
    setpoints: [SetpointInterpolator; MAX_SERVOS],
    axes: [ServoAxis; MAX_SERVOS],
    contour: ContourLoop,
    used: [bool; MAX_SERVOS],
    mm_per_count: ChannelVec,
    counts_per_mm: ChannelVec,
}

impl ServoBank {
    /// The bank of `machine`, standing at `positions` (encoder counts, per channel).
    ///
    /// A channel is coupled when the machine is Cartesian and its joint follows X, Y
    /// or Z (linear); its counts convert to mm by the joint's scale.
    pub fn new(machine: &MachineConfig, positions: &[i64; MAX_SERVOS]) -> Self {
        let mut used = [false; MAX_SERVOS];
        let mut mm_per_count = [0.0f32; MAX_SERVOS];
        let mut counts_per_mm = [0.0f32; MAX_SERVOS];
        let mut axes = [ServoAxis::new(&ServoGains::NONE, 0.0); MAX_SERVOS];
        for (j, jc) in machine.joints.iter().enumerate() {
            let Drive::Servo { channel, .. } = jc.drive else {
                continue;
            };
            let c = channel as usize;
            if c >= MAX_SERVOS {
                continue;
            }
            used[c] = true;
            // counts per axis unit (nm or n°), from the scale ratio.
            let per_unit = jc.scale.steps as f64 / jc.scale.per_units as f64;
            let vmax = (jc.limits.max_velocity as f64 * per_unit) as f32;
            axes[c] = ServoAxis::new(&machine.servo.gains[c], vmax);
            let linear_xyz = match machine.kinematics {
                KinematicsConfig::Cartesian { axis_of_joint } => axis_of_joint[j] < 3,
                _ => false,
            };
            if linear_xyz && !jc.rotary {
                let nm_per_mm = crate::units::NM_PER_MM as f64;
                counts_per_mm[c] = (per_unit * nm_per_mm) as f32;
                mm_per_count[c] = (1.0 / (per_unit * nm_per_mm)) as f32;
            }
        }
        Self {
            setpoints: positions.map(|p| SetpointInterpolator::new(p << SETPOINT_FRAC_BITS)),
            axes,
            contour: ContourLoop::new(&machine.servo.contour),
            used,
            mm_per_count,
            counts_per_mm,
        }
    }

    /// At each interpolation tick: the channels' next targets, counts × 2^16
    /// ([`crate::servo::target_q16`]).
    pub fn load_tick(&mut self, targets: &[i64; MAX_SERVOS]) {
        for (s, t) in self.setpoints.iter_mut().zip(targets) {
            s.load(*t);
        }
    }

    /// Clears every latched trip and the contour state.
    pub fn reset(&mut self) {
        for a in &mut self.axes {
            a.reset();
        }
        self.contour.reset();
    }

    /// One servo period of every channel.
    pub fn period(&mut self, inputs: &PeriodInputs) -> PeriodOutputs {
        let mut sp = [Setpoint::default(); MAX_SERVOS];
        let mut v = [0.0f32; MAX_SERVOS];
        let mut a = [0.0f32; MAX_SERVOS];
        let mut e = [0.0f32; MAX_SERVOS];
        for c in 0..MAX_SERVOS {
            sp[c] = self.setpoints[c].advance();
            let s = self.mm_per_count[c];
            v[c] = sp[c].velocity * s;
            a[c] = sp[c].accel * s;
            e[c] = following_error(sp[c].position_q16, inputs.feedback[c]).1 * s;
        }
        let frame = PathFrame::new(&v, &a);
        let eps = frame.contour_error(&e);
        let corr = self.contour.update(&frame, &eps);
        let mut out = PeriodOutputs {
            contour_error: eps,
            ..PeriodOutputs::default()
        };
        for c in 0..MAX_SERVOS {
            if !self.used[c] {
                continue;
            }
            let amp = AmpIo {
                enable: inputs.enable,
                fault: inputs.fault[c],
            };
            let coupling = Coupling {
                reference: corr.reference[c] * self.counts_per_mm[c],
                command: corr.command[c],
            };
            let o: ServoOutput = self.axes[c].update(&sp[c], inputs.feedback[c], amp, coupling);
            out.dac[c] = o.dac;
            out.enable[c] = o.enable;
            out.trip[c] = o.trip;
            out.command[c] = o.command;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v3(x: f32, y: f32, z: f32) -> ChannelVec {
        let mut v = [0.0; MAX_SERVOS];
        v[..3].copy_from_slice(&[x, y, z]);
        v
    }

    #[test]
    fn the_reciprocal_square_root_is_within_a_ten_millionth() {
        for &x in &[1e-6f32, 0.01, 0.5, 1.0, 2.0, 3.0, 100.0, 12_345.0, 1e8] {
            let want = 1.0 / (x as f64).sqrt();
            let got = rsqrt(x) as f64;
            assert!(
                (got / want - 1.0).abs() < 1e-7 * 2.0,
                "{x}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn a_lag_along_a_straight_path_is_no_contour_error() {
        let f = PathFrame::new(&v3(3.0, 4.0, 0.0), &[0.0; MAX_SERVOS]);
        let eps = f.contour_error(&v3(0.3, 0.4, 0.0));
        assert!(eps.iter().all(|c| c.abs() < 1e-6), "{eps:?}");
        // A sideways error is all contour error, along the normal.
        let eps = f.contour_error(&v3(-0.4, 0.3, 0.2));
        assert!((eps[0] + 0.4).abs() < 1e-6 && (eps[1] - 0.3).abs() < 1e-6);
        assert!((eps[2] - 0.2).abs() < 1e-6);
    }

    #[test]
    fn a_lag_along_a_circle_is_no_contour_error_to_second_order() {
        // Circle of radius 10 mm at 10 mm/s, setpoint at (10, 0) moving +Y; the actual
        // position lags 0.1 rad on the circle.
        let f = PathFrame::new(&v3(0.0, 10.0, 0.0), &v3(-10.0, 0.0, 0.0));
        assert!((f.curvature[0] + 0.1).abs() < 1e-6, "{:?}", f.curvature);
        let y = (10.0 * 0.1f32.cos(), -10.0 * 0.1f32.sin());
        let e = v3(10.0 - y.0, -y.1, 0.0);
        let eps = f.contour_error(&e);
        let plain = e[0]; // the normal part alone: 0.05 mm
        assert!(plain > 0.04);
        assert!(eps[0].abs() < 1e-3 * plain * 10.0, "{eps:?}");
    }

    #[test]
    fn standing_still_there_is_no_contour_error_and_no_coupling() {
        let f = PathFrame::new(&[0.0; MAX_SERVOS], &[0.0; MAX_SERVOS]);
        assert!(!f.moving);
        assert_eq!(f.contour_error(&v3(1.0, 1.0, 1.0)), [0.0; MAX_SERVOS]);
    }

    fn config(mode: ContourMode) -> ContourConfig {
        ContourConfig {
            mode,
            kp: 10.0,
            ki: 100.0,
            max_integral: 5.0,
            kr: 20.0,
            max_offset: 0.5,
        }
    }

    #[test]
    fn cross_coupling_pushes_each_axis_by_its_direction_cosine() {
        let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &[0.0; MAX_SERVOS]);
        let mut l = ContourLoop::new(&config(ContourMode::CrossCoupled));
        let c = l.update(&f, &v3(0.0, 0.01, 0.0));
        assert!(c.command[0].abs() < 1e-9 && c.command[2].abs() < 1e-9);
        assert!(
            (c.command[1] - (0.1 + 100.0 * 0.01 * 1e-4)).abs() < 1e-6,
            "{c:?}"
        );
        assert_eq!(c.reference, [0.0; MAX_SERVOS]);
    }

    #[test]
    fn ccpm_shifts_the_reference_along_the_normal_and_integrates_it() {
        let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &[0.0; MAX_SERVOS]);
        let mut l = ContourLoop::new(&config(ContourMode::Ccpm));
        let mut c = ContourCorrection::default();
        for _ in 0..100 {
            c = l.update(&f, &v3(0.0, 0.01, 0.0));
        }
        assert!(
            (c.reference[1] - 100.0 * 20.0 * 0.01 * 1e-4).abs() < 1e-6,
            "{c:?}"
        );
        assert_eq!(c.reference[0], 0.0);
        // The offset is clamped.
        for _ in 0..1_000_000 {
            c = l.update(&f, &v3(0.0, 1.0, 0.0));
        }
        assert_eq!(c.reference[1], 0.5);
    }

    #[test]
    fn uncoupled_asks_for_nothing() {
        let f = PathFrame::new(&v3(10.0, 0.0, 0.0), &[0.0; MAX_SERVOS]);
        let mut l = ContourLoop::new(&config(ContourMode::Uncoupled));
        assert_eq!(
            l.update(&f, &v3(0.0, 1.0, 0.0)),
            ContourCorrection::default()
        );
    }
}
