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
//! the tangent is undefined and ε is taken as zero (coupling holds its state). The
//! curvature is bounded by [`MAX_CURVATURE`]: from one tick's velocity change it is
//! not the path's where the path leaves rest or turns a corner between pieces.
//!
//! **Resolution.** The joints' targets are whole nanometres (or n°), so each channel's
//! tick velocity is uncertain by 1e-3 mm/s and its acceleration by 2 mm/s². The
//! frame divides by |v| (tangent, tool turn) and |v|² (curvature), so as a stop's
//! last ticks shrink to a few nanometres of motion it reads that rounding, times the
//! tangential lag, as contour error. Hence: the curvature comes only from a normal
//! acceleration above what the ticks resolve ([`RESOLVED_ACCEL`]), and below
//! [`RESOLVED_SPEED`] a tick slower than the one before keeps the frame it has
//! ([`PathFrame::next`]): a path slowing to a stop does so along its last piece, whose
//! frame the faster ticks resolved.
//!
//! **Uncoupled.** Each axis runs its own PID with its velocity and acceleration
//! feed-forward ([`crate::drive::servo`]).
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
//! Arithmetic: `f32`, as in [`crate::drive::servo`]; 1/|v| by the bit-level reciprocal square
//! root with three Newton steps (no division, no library call). Capacities: the bank
//! has [`MAX_SERVOS`] channels; every loop is a fixed count.

// Vector arithmetic over channel-indexed parallel arrays reads best with an index.
#![allow(clippy::needless_range_loop)]

use crate::config::{ContourConfig, ContourMode, Drive, KinematicsConfig, MachineConfig};
use crate::config::{ServoGains, MAX_SERVOS};
use crate::drive::servo::{
    following_error, AmpIo, Coupling, ServoAxis, ServoOutput, SetpointInterpolator, Trip, DAC_MID,
    SERVO_PERIOD_S, SERVO_PER_TICK, SETPOINT_FRAC_BITS,
};
use crate::kinematics::{ContourMap, PoseVec, POSE_AXES};
use crate::math::clamp_sym;

/// Slowest path speed at which the contour error is estimated, mm/s.
pub const MIN_CONTOUR_SPEED: f32 = 0.01;

/// Largest curvature the path frame takes, 1/mm (a radius of 0.5 mm: report B's
/// helix's tightest). The frame's curvature is the tick's velocity change across the
/// path over |v|²: where the path starts from rest, stops, or turns a corner between
/// straight pieces within one tick, that estimate is not the path's and is unbounded
/// (10⁵ /mm at the first tick after a stop), and the circular correction
/// ½(e·t)²·κ would turn it into a contour error of millimetres.
pub const MAX_CURVATURE: f32 = 2.0;

/// Path speed from which one tick's motion resolves the frame, mm/s: 1 µm a tick, a
/// thousand times the quantum of the joints' targets (1 nm or 1 n°, whose rounding
/// makes each channel's velocity uncertain by 1e-3 mm/s). Below it the tangent and
/// the tool's turn per mm carry that rounding over |v|: in a stop's last tick (13 nm
/// of motion on report B's helix) a few degrees of the tangent and, on the
/// hexapod-xy, 0.02 °/mm of turn where the tool axis is held, which the tangential
/// lag e·t (µm) turned into 140–200 µ° of tool-direction error.
pub const RESOLVED_SPEED: f32 = 1.0;

/// Normal acceleration the ticks resolve, mm/s². The rounding of the joints' targets
/// makes each channel's tick acceleration uncertain by up to two quanta a tick squared
/// (2 mm/s²), 3 mm/s² seen in the pose's normal part on report B's helix. The
/// curvature is taken from the normal acceleration in full from twice this, not at all
/// below it, in proportion between; below it, it would be that rounding over |v|², at
/// the bound [`MAX_CURVATURE`] in a random direction below a few mm/s, where the
/// circular correction ½(e·t)²·κ turned a stop's tens of µm of lag into a µm of
/// contour error.
pub const RESOLVED_ACCEL: f32 = 4.0;

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

/// The dot product of the X Y Z parts.
fn dot3(a: &PoseVec, b: &PoseVec) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The path's local frame at the setpoint.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathFrame {
    /// Unit tangent of the X Y Z path (direction cosines; A B zero).
    pub tangent: PoseVec,
    /// Curvature vector κ·n of the X Y Z path, 1/mm (A B zero), |κ| at most
    /// [`MAX_CURVATURE`].
    pub curvature: PoseVec,
    /// The tool direction's rate per mm of path, degrees/mm (X Y Z zero).
    pub turn: PoseVec,
    /// |v|² of the last tick, (mm/s)² ([`PathFrame::next`]); zero while the path
    /// stands (slower than [`MIN_CONTOUR_SPEED`]), when the frame is undefined.
    pub speed2: f32,
}

impl PathFrame {
    /// The frame of a path with velocity `v` (mm/s, degrees/s) and acceleration `a`
    /// (mm/s², degrees/s²).
    pub fn new(v: &PoseVec, a: &PoseVec) -> Self {
        let v2 = dot3(v, v);
        if v2.partial_cmp(&(MIN_CONTOUR_SPEED * MIN_CONTOUR_SPEED))
            != Some(core::cmp::Ordering::Greater)
        {
            return Self::default();
        }
        let inv = rsqrt(v2);
        // (Arrays written element by element: an all-zero one first would be a
        // `memclr` call on the M4.)
        let tangent = [v[0] * inv, v[1] * inv, v[2] * inv, 0.0, 0.0];
        let at = dot3(a, &tangent);
        let mut curvature = [
            a[0] - at * tangent[0],
            a[1] - at * tangent[1],
            a[2] - at * tangent[2],
            0.0,
            0.0,
        ];
        // The normal acceleration a_n, weighted by how far the ticks resolve it: 0 up to
        // RESOLVED_ACCEL, 1 from twice that; then κ = w·a_n/|v|², at most MAX_CURVATURE.
        let an2 = dot3(&curvature, &curvature);
        let mut scale = 0.0;
        if an2 > RESOLVED_ACCEL * RESOLVED_ACCEL {
            let w = an2 * rsqrt(an2) * (1.0 / RESOLVED_ACCEL) - 1.0;
            // (A compare, not `f32::min`: that may be a library call on the M4.)
            scale = if w < 1.0 { w } else { 1.0 } * inv * inv;
            let k2 = scale * scale * an2;
            if k2 > MAX_CURVATURE * MAX_CURVATURE {
                scale *= MAX_CURVATURE * rsqrt(k2);
            }
        }
        for k in &mut curvature[..3] {
            *k *= scale;
        }
        let turn = [0.0, 0.0, 0.0, v[3] * inv, v[4] * inv];
        Self {
            tangent,
            curvature,
            turn,
            speed2: v2,
        }
    }

    /// The frame of the tick after this one's, with velocity `v` and acceleration `a`:
    /// its own ([`PathFrame::new`]), except that a tick below [`RESOLVED_SPEED`] slower
    /// than the one before, on a moving path, keeps this frame (taken from a tick that
    /// resolved the path better: the path slowing to a stop does so along its last
    /// piece). A path starting from rest, or keeping a speed below [`RESOLVED_SPEED`],
    /// takes each tick's own frame.
    pub fn next(&self, v: &PoseVec, a: &PoseVec) -> Self {
        let v2 = dot3(v, v);
        if self.moving()
            && v2 < self.speed2
            && v2 < RESOLVED_SPEED * RESOLVED_SPEED
            && v2 > MIN_CONTOUR_SPEED * MIN_CONTOUR_SPEED
        {
            return Self {
                speed2: v2,
                ..*self
            };
        }
        Self::new(v, a)
    }

    /// The path is moving (faster than [`MIN_CONTOUR_SPEED`]): the frame is defined.
    pub fn moving(&self) -> bool {
        self.speed2 > 0.0
    }

    /// Removes the tangential part of `x`'s X Y Z in place.
    pub fn project(&self, x: &mut PoseVec) {
        let along = dot3(x, &self.tangent);
        for i in 0..3 {
            x[i] -= along * self.tangent[i];
        }
    }

    /// The contour error ε of the tracking error `e` (mm, degrees); zero when standing.
    /// Path: the normal-plane part of e with the circular correction. Tool direction:
    /// its error less what the tangential lag e·t explains (the reference direction
    /// where the tool actually is on the path), `e_o − (e·t)·turn`.
    pub fn contour_error(&self, e: &PoseVec) -> PoseVec {
        let mut eps = [0.0; POSE_AXES];
        self.contour_error_into(e, &mut eps);
        eps
    }

    /// [`PathFrame::contour_error`] into `eps`, every element written.
    pub fn contour_error_into(&self, e: &PoseVec, eps: &mut PoseVec) {
        if !self.moving() {
            *eps = [0.0; POSE_AXES];
            return;
        }
        let et = dot3(e, &self.tangent);
        let bend = 0.5 * et * et;
        for i in 0..3 {
            eps[i] = e[i] - et * self.tangent[i] + bend * self.curvature[i];
        }
        for i in 3..POSE_AXES {
            eps[i] = e[i] - et * self.turn[i];
        }
    }
}

/// The coupling state of the contour controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContourLoop {
    config: ContourConfig,
    ki_t: f32,
    kr_t: f32,
    integral: PoseVec,
    offset: PoseVec,
}

/// What the contour controller asks, in pose coordinates, this period.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContourCorrection {
    /// Reference offset, mm and degrees (CCPM).
    pub reference: PoseVec,
    /// Command correction, c.u. per mm (or degree) of pose, distributed to the
    /// channels by ∂q/∂pose (cross-coupled and CCPM).
    pub command: PoseVec,
}

impl ContourLoop {
    /// A controller with no accumulated correction.
    pub fn new(config: &ContourConfig) -> Self {
        Self {
            config: *config,
            ki_t: config.ki * SERVO_PERIOD_S,
            kr_t: config.kr * SERVO_PERIOD_S,
            integral: [0.0; POSE_AXES],
            offset: [0.0; POSE_AXES],
        }
    }

    /// Clears the integrator and the reference offset.
    pub fn reset(&mut self) {
        self.integral = [0.0; POSE_AXES];
        self.offset = [0.0; POSE_AXES];
    }

    /// One period given the frame and the contour error `eps` (mm).
    pub fn update(&mut self, frame: &PathFrame, eps: &PoseVec) -> ContourCorrection {
        let mut out = ContourCorrection::default();
        self.update_into(frame, eps, &mut out);
        out
    }

    /// [`ContourLoop::update`] into `out`, every field written.
    pub fn update_into(&mut self, frame: &PathFrame, eps: &PoseVec, out: &mut ContourCorrection) {
        out.reference = self.offset;
        let c = &self.config;
        if c.mode == ContourMode::Uncoupled || !frame.moving() {
            out.command = [0.0; POSE_AXES];
            return;
        }
        for i in 0..POSE_AXES {
            self.integral[i] = clamp_sym(self.integral[i] + self.ki_t * eps[i], c.max_integral);
        }
        frame.project(&mut self.integral);
        for i in 0..POSE_AXES {
            out.command[i] = c.kp * eps[i] + self.integral[i];
        }
        if c.mode == ContourMode::Ccpm {
            for i in 0..POSE_AXES {
                self.offset[i] = clamp_sym(self.offset[i] + self.kr_t * eps[i], c.max_offset);
            }
            frame.project(&mut self.offset);
            out.reference = self.offset;
        }
    }
}

/// What the hardware reports each servo period.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PeriodInputs {
    /// Extended encoder position of each channel, counts ([`crate::drive::servo::extend_counter`]).
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
    /// Amplifier enable of each channel (a channel whose loop tripped is disabled:
    /// [`ServoBank::trips`] says why).
    pub enable: [bool; MAX_SERVOS],
    /// Estimated contour error, X Y Z in mm and the tool direction's A B in degrees
    /// (zero when uncoupled or standing).
    pub contour_error: PoseVec,
    /// Command of each channel after its clamp, c.u.
    pub command: ChannelVec,
}

impl PeriodOutputs {
    /// Every channel idle: DAC at mid-scale, disabled, no contour error.
    pub const IDLE: Self = Self {
        dac: [DAC_MID as u16; MAX_SERVOS],
        enable: [false; MAX_SERVOS],
        contour_error: [0.0; POSE_AXES],
        command: [0.0; MAX_SERVOS],
    };
}

impl Default for PeriodOutputs {
    fn default() -> Self {
        Self::IDLE
    }
}

/// Every servo channel's setpoint interpolator and loop, and their contour coupling:
/// the whole 10 kHz servo work of the board, as plain state and two calls.
#[derive(Clone, Debug, PartialEq)]
pub struct ServoBank {
    setpoints: [SetpointInterpolator; MAX_SERVOS],
    axes: [ServoAxis; MAX_SERVOS],
    contour: ContourLoop,
    /// The contour controller runs (a coupling mode other than uncoupled).
    coupled: bool,
    /// ∂pose/∂q of each channel (the map's `to_pose`, by channel: one 5-vector each).
    to_pose: [PoseVec; MAX_SERVOS],
    /// ∂q/∂pose of each channel (the map's `to_joint`).
    to_joint: [PoseVec; MAX_SERVOS],
    /// Each channel's feedback law and the LQG designs (as [`crate::config::ServoConfig`]).
    law: [u8; MAX_SERVOS],
    lqg: heapless::Vec<crate::config::LqgGains, { crate::config::MAX_LQG }>,
    /// The channels in use, `active[..n_active]`: the period loops over these only.
    active: [u8; MAX_SERVOS],
    n_active: usize,
    /// The path frame of the current tick (velocity and acceleration are constant
    /// over a tick: computed in its first period, and again when the setpoints run out).
    frame: PathFrame,
    /// Periods since the last `load_tick`.
    since_load: usize,
    /// The contour controller's correction, from the last period's errors: this
    /// period's loops apply it.
    correction: ContourCorrection,
    /// Joint units (mm or degrees) per count, and counts per joint unit.
    unit_per_count: ChannelVec,
    counts_per_unit: ChannelVec,
}

impl ServoBank {
    /// The bank of `machine`, standing at `positions` (encoder counts, per channel).
    ///
    /// On a Cartesian machine the channels whose joints follow X, Y or Z (linear) are
    /// coupled, through a constant [`ContourMap`]; on the hexapod-xy every channel is,
    /// through the map the controller sends each tick ([`ServoBank::load_map`]).
    pub fn new(machine: &MachineConfig, positions: &[i64; MAX_SERVOS]) -> Self {
        let mut used = [false; MAX_SERVOS];
        let mut unit_per_count = [0.0f32; MAX_SERVOS];
        let mut counts_per_unit = [0.0f32; MAX_SERVOS];
        let mut map = ContourMap::NONE;
        let mut axes = [ServoAxis::new(&ServoGains::NONE, 0.0); MAX_SERVOS];
        for (j, jc) in machine.joints.iter().enumerate() {
            let Drive::Servo { channel } = jc.drive else {
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
            // nm per mm and n° per degree are both 10^6 and 10^9; the joint's unit.
            let per_user = crate::units::units_per_user(jc.rotary) as f64;
            counts_per_unit[c] = (per_unit * per_user) as f32;
            unit_per_count[c] = (1.0 / (per_unit * per_user)) as f32;
            if let KinematicsConfig::Cartesian { axis_of_joint } = machine.kinematics {
                let a = axis_of_joint[j] as usize;
                if a < 3 && !jc.rotary {
                    map.to_pose[a][c] = 1.0;
                    map.to_joint[c][a] = 1.0;
                }
            }
        }
        let mut active = [0u8; MAX_SERVOS];
        let mut n_active = 0;
        for (c, &u) in used.iter().enumerate() {
            if u {
                active[n_active] = c as u8;
                n_active += 1;
            }
        }
        Self {
            setpoints: positions.map(|p| SetpointInterpolator::new(p << SETPOINT_FRAC_BITS)),
            axes,
            contour: ContourLoop::new(&machine.servo.contour),
            coupled: machine.servo.contour.mode != ContourMode::Uncoupled,
            to_pose: core::array::from_fn(|c| core::array::from_fn(|k| map.to_pose[k][c])),
            to_joint: map.to_joint,
            law: machine.servo.law,
            lqg: machine.servo.lqg.clone(),
            active,
            n_active,
            frame: PathFrame::default(),
            since_load: SERVO_PER_TICK,
            correction: ContourCorrection::default(),
            unit_per_count,
            counts_per_unit,
        }
    }

    /// At each interpolation tick: the channels' next targets, counts × 2^16
    /// ([`crate::drive::servo::target_q16`]).
    pub fn load_tick(&mut self, targets: &[i64; MAX_SERVOS]) {
        // The channels in use only: no other one's setpoint is ever read.
        for &c in &self.active[..self.n_active.min(MAX_SERVOS)] {
            let c = c as usize % MAX_SERVOS;
            self.setpoints[c].load(targets[c]);
        }
        self.since_load = 0;
    }

    /// At a tick: the channels' map to the pose at the tick's commanded pose (a
    /// machine whose map changes along the path).
    pub fn load_map(&mut self, map: &ContourMap) {
        for c in 0..MAX_SERVOS {
            for k in 0..POSE_AXES {
                self.to_pose[c][k] = map.to_pose[k][c];
            }
        }
        self.to_joint = map.to_joint;
    }

    /// The trip latched by each channel's loop.
    pub fn trips(&self) -> [Option<Trip>; MAX_SERVOS] {
        let mut trips = [None; MAX_SERVOS];
        self.trips_into(&mut trips);
        trips
    }

    /// [`ServoBank::trips`] into `out`.
    pub fn trips_into(&self, out: &mut [Option<Trip>; MAX_SERVOS]) {
        for (t, axis) in out.iter_mut().zip(&self.axes) {
            *t = axis.trip();
        }
    }

    /// Clears every latched trip and the contour state.
    pub fn reset(&mut self) {
        for a in &mut self.axes {
            a.reset();
        }
        self.contour.reset();
        self.correction = ContourCorrection::default();
    }

    /// Channel `c`'s setpoint of the last period, whole counts (for the data recorder);
    /// a channel not in use keeps the position the bank was built at.
    pub fn setpoint_counts(&self, c: usize) -> i32 {
        (self.setpoints[c % MAX_SERVOS].position() >> SETPOINT_FRAC_BITS) as i32
    }

    /// One servo period of every channel in use, in one pass over the channels: each
    /// channel's loop takes the contour correction formed from the previous period's
    /// errors (a delay of one period, 100 µs, against the contour loop's bandwidth of
    /// tens of hertz), and its tracking error joins this period's estimate.
    pub fn period(&mut self, inputs: &PeriodInputs) -> PeriodOutputs {
        let mut out = PeriodOutputs::IDLE;
        self.period_into(&inputs.feedback, &inputs.fault, inputs.enable, &mut out);
        out
    }

    /// [`ServoBank::period`] into the caller's `out`, which it writes in part: every
    /// channel in use, and the contour error of a coupled bank; the rest keeps what
    /// `out` held, which must be [`PeriodOutputs::IDLE`] (or the outputs of this
    /// bank's earlier periods). For the servo interrupt, which keeps its outputs from
    /// one period to the next: no outputs are built and copied each period, nor its
    /// inputs ([`PeriodInputs`]'s fields, by reference).
    pub fn period_into(
        &mut self,
        feedback: &[i64; MAX_SERVOS],
        fault: &[bool; MAX_SERVOS],
        enable: bool,
        out: &mut PeriodOutputs,
    ) {
        let active = self.active;
        let active = &active[..self.n_active.min(MAX_SERVOS)];
        // The tracking error in pose coordinates, to_pose · e. (Sums start from −0,
        // the additive identity: an all-zero array costs a `memclr` call on the M4 at
        // opt-level "s".)
        let mut pe = [-0.0f32; POSE_AXES];
        let corr = &self.correction;
        for &c in active {
            // (`% MAX_SERVOS`: a channel is below it; this spares the bounds checks.)
            let c = c as usize % MAX_SERVOS;
            let s = self.setpoints[c].advance();
            let f = following_error(s.position_q16, feedback[c]);
            let coupling = if self.coupled {
                let (col, u) = (&self.to_pose[c], self.unit_per_count[c]);
                axpy5(&mut pe, col, f.1 * u);
                let row = &self.to_joint[c];
                Coupling {
                    reference: dot5(row, &corr.reference) * self.counts_per_unit[c],
                    command: dot5(row, &corr.command),
                }
            } else {
                Coupling::NONE
            };
            let amp = AmpIo {
                enable,
                fault: fault[c],
            };
            let law = self.law[c] as usize;
            let lqg = if law == 0 {
                None
            } else {
                self.lqg.get(law - 1)
            };
            let o: ServoOutput = self.axes[c].update_on(&s, f, amp, coupling, lqg);
            out.dac[c] = o.dac;
            out.enable[c] = o.enable;
            out.command[c] = o.command;
        }
        if self.coupled {
            if self.since_load == 0 || self.since_load == SERVO_PER_TICK {
                // A new tick, or the setpoints just ran out (a late tick): the
                // channels' velocity and acceleration, hence the frame, changed.
                let (mut pv, mut pa) = ([-0.0f32; POSE_AXES], [-0.0; POSE_AXES]);
                for &c in active {
                    let c = c as usize % MAX_SERVOS;
                    let (col, u) = (&self.to_pose[c], self.unit_per_count[c]);
                    let (v, a) = self.setpoints[c].rates();
                    axpy5(&mut pv, col, v * u);
                    axpy5(&mut pa, col, a * u);
                }
                self.frame = self.frame.next(&pv, &pa);
            }
            self.frame.contour_error_into(&pe, &mut out.contour_error);
            self.contour
                .update_into(&self.frame, &out.contour_error, &mut self.correction);
        }
        self.since_load = self.since_load.saturating_add(1);
    }
}

/// `acc += col · x` over the five pose axes.
#[inline(always)]
fn axpy5(acc: &mut PoseVec, col: &PoseVec, x: f32) {
    acc[0] += col[0] * x;
    acc[1] += col[1] * x;
    acc[2] += col[2] * x;
    acc[3] += col[3] * x;
    acc[4] += col[4] * x;
}

/// `a · b` over the five pose axes.
#[inline(always)]
fn dot5(a: &PoseVec, b: &PoseVec) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4]
}

#[cfg(test)]
#[path = "contour_tests.rs"]
mod tests;
