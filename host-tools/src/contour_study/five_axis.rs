//! Report B's test on its own machine, the hexapod-xy (`examples/machines/hexapod-xy.toml`):
//! the helix x = t·cos t, y = t·sin t, z = 3t + 260 mm, t = 0..10 s, in workpiece
//! coordinates, with the tool axis held vertical or tilting ±10° along the path
//! (A = 10°·sin(πt/5), B = 10°·sin(πt/10)); eight servo joints (six legs, the table's
//! X and Y) with the report's identified plants, 10 % off; a periodic cutting force
//! on the tool, carried to the legs through the statics ([`joint_forces`]) and into
//! each leg by the cylinder's load-force term; the four schemes of [`Scheme`] with PID
//! or LQG axis loops.
//!
//! Each run steps the core's [`ServoBank`] at 10 kHz as the firmware does: per 1 kHz
//! tick the pose on the path, its joints by the fixed-point inverse kinematics, the
//! targets in counts × 2^16 and, when coupled, the channel map as the controller
//! sends it: one phase a tick ([`MapBuilder`]), a map every
//! [`pkmc::kinematics::hexapod_xy_map::MAP_PHASES`] ticks at the pose of its first
//! phase (the bank starts with the map at the start pose); 16-bit encoder counters
//! extended by [`extend_counter`]; DAC codes to the plants. Errors are measured from
//! the simulated joints: the pose by the forward kinematics, the path error as the
//! distance from the tool point to the helix, the direction error as the angle between
//! the tool axis and the reference tool axis at the nearest point of the path.
//!
//! **Load-force term** (report B, the position response of the valve-controlled
//! cylinder): x = [K_q/A·x_s − K_ce/A²·(1 + V_t/(4β_e K_ce)·s)·F_L] / [s(s²/ω_h² +
//! 2δ_h s/ω_h + 1)]. With the identified L(s) for the command path, the load force
//! enters through the same denominator: x_F = −c_F·(1 + τ_F s)/D(s)·F_L, with
//! c_F = K_ce/A² and τ_F = V_t/(4β_e K_ce) from [`LegLoad`].

use super::{helix, nearest_on_helix, Scheme, StudyError};
use crate::analysis::direction::{angle_deg, tool_axis};
use crate::analysis::statics::joint_forces;
use crate::control::plant::{DiscretePlant, Mismatch, TransferFunction};
use crate::machine_file::MachineFile;
use pkmc::config::{Drive, KinematicsConfig, MachineConfig, AXES, MAX_JOINTS, MAX_SERVOS};
use pkmc::drive::contour::{PeriodInputs, ServoBank};
use pkmc::drive::servo::{extend_counter, target_q16, DAC_MID, SERVO_HZ, SERVO_PER_TICK};
use pkmc::kinematics::hexapod_xy_map::MapBuilder;
use pkmc::kinematics::ContourMap;
use pkmc::kinematics::{hexapod_xy::HexapodXy, Kinematics, MachineKinematics};
use pkmc::units::{NM_PER_MM, TICK_HZ};

/// The load-force term of a hydraulic leg.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegLoad {
    /// c_F = K_ce/A², mm/s per N.
    pub gain: f64,
    /// τ_F = V_t/(4β_e·K_ce), s.
    pub lead_s: f64,
}

/// The cutting force on the tool: `steady` N (machine frame) times
/// (1 + `ripple`·sin(2π·`freq_hz`·t)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CuttingForce {
    /// Mean force, N.
    pub steady: [f64; 3],
    /// Relative amplitude of the periodic part.
    pub ripple: f64,
    /// Tooth-passing frequency, Hz.
    pub freq_hz: f64,
}

impl CuttingForce {
    /// The wrench at `t` s (no moment).
    pub fn at(&self, t: f64) -> [f64; 6] {
        let k = 1.0 + self.ripple * (std::f64::consts::TAU * self.freq_hz * t).sin();
        [
            self.steady[0] * k,
            self.steady[1] * k,
            self.steady[2] * k,
            0.0,
            0.0,
            0.0,
        ]
    }
}

/// Conditions of a five-axis run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conditions {
    /// Plant mismatch per joint (legs 1..6, table X, Y).
    pub mismatch: [Mismatch; 8],
    /// The cutting force.
    pub force: CuttingForce,
    /// The legs' load-force term.
    pub leg_load: LegLoad,
    /// The table's drives: command units of input disturbance per N along their axis.
    pub table_input_per_newton: f64,
    /// Tool-axis tilt amplitude, degrees (0: held vertical).
    pub tilt_deg: f64,
    /// Path duration, s.
    pub duration_s: f64,
    /// Time on the same path before t = 0, s (the window starts on the path).
    pub lead_in_s: f64,
}

impl Conditions {
    /// The study's conditions: legs 1–3 10 % more gain and legs 4–6 10 % less (legs
    /// alternately more and less, each adjacent pair one of each, would turn the
    /// platform about the vertical, which the tool direction does not see), the table's X
    /// 10 % more and Y 10 % less, every resonance 10 % lower; a cutting force of
    /// (120, −80, −400) N with a 50 % ripple at 20 Hz (a two-flute cutter at 600 rpm);
    /// the legs' load term c_F = 6.3e-3 mm/s per N and τ_F = 4.5 ms (K_ce ≈ 1e-11 m³/(s·Pa),
    /// a 40 mm bore, V_t = 0.25 l, β_e = 1.4 GPa: textbook magnitudes, assumed, not
    /// from the report); the table 0.01 c.u. per N; the orientation held.
    pub fn study() -> Self {
        let m = |gain| Mismatch {
            gain,
            resonance: 0.9,
        };
        Conditions {
            mismatch: [
                m(1.1),
                m(1.1),
                m(1.1),
                m(0.9),
                m(0.9),
                m(0.9),
                m(1.1),
                m(0.9),
            ],
            force: CuttingForce {
                steady: [120.0, -80.0, -400.0],
                ripple: 0.5,
                freq_hz: 20.0,
            },
            leg_load: LegLoad {
                gain: 6.3e-3,
                lead_s: 4.5e-3,
            },
            table_input_per_newton: 0.01,
            tilt_deg: 0.0,
            duration_s: 10.0,
            lead_in_s: 1.0,
        }
    }

    /// The programmed pose at `t` s: mm and degrees.
    pub fn pose(&self, t: f64) -> [f64; 5] {
        let p = helix(t);
        let a = self.tilt_deg * (std::f64::consts::PI * t / 5.0).sin();
        let b = self.tilt_deg * (std::f64::consts::PI * t / 10.0).sin();
        [p[0], p[1], p[2], a, b]
    }
}

/// The axis loops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Law {
    /// The machine file's PID gains on every joint.
    Pid,
    /// The machine file's LQG designs (`lqg_gains`) on every joint.
    Lqg,
}

impl Law {
    /// Both.
    pub const ALL: [Law; 2] = [Law::Pid, Law::Lqg];

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Law::Pid => "PID",
            Law::Lqg => "LQG",
        }
    }
}

/// One run's result.
#[derive(Clone, Debug)]
pub struct Run {
    /// Contour scheme.
    pub scheme: Scheme,
    /// Axis loops.
    pub law: Law,
    /// Largest path contour error, mm.
    pub max_path_mm: f64,
    /// RMS path contour error, mm.
    pub rms_path_mm: f64,
    /// Largest tool-direction error, degrees.
    pub max_dir_deg: f64,
    /// RMS tool-direction error, degrees.
    pub rms_dir_deg: f64,
    /// Largest following error of any joint, mm.
    pub max_following_mm: f64,
    /// Path and direction error at the end of every tick: (t s, mm, degrees).
    pub trace: Vec<(f64, f64, f64)>,
    /// Periods in which some joint's command was at its clamp.
    pub saturated_periods: u64,
    /// A servo trip that stopped the run: (channel, description).
    pub trip: Option<(usize, String)>,
}

impl Run {
    fn new(scheme: Scheme, law: Law, ticks: usize) -> Self {
        Run {
            scheme,
            law,
            max_path_mm: 0.0,
            rms_path_mm: 0.0,
            max_dir_deg: 0.0,
            rms_dir_deg: 0.0,
            max_following_mm: 0.0,
            trace: Vec::with_capacity(ticks),
            saturated_periods: 0,
            trip: None,
        }
    }
}

/// One servo joint of the machine.
#[derive(Clone, Debug)]
struct Joint {
    channel: usize,
    counts_per_mm: f64,
    input_per_count: f64,
    model: TransferFunction,
}

/// The hexapod-xy with a plant on every joint.
#[derive(Clone, Debug)]
pub struct FiveAxisMachine {
    /// Core configuration, every joint on its PID.
    pub config: MachineConfig,
    /// The same, every joint on its LQG design.
    pub lqg: MachineConfig,
    kin: HexapodXy,
    joints: Vec<Joint>,
}

impl FiveAxisMachine {
    /// From a hexapod-xy machine file whose eight joints are servo joints with a
    /// `plant` table each.
    pub fn new(file: &MachineFile) -> Result<Self, StudyError> {
        let config = file.to_config()?;
        let MachineKinematics::HexapodXy(kin) = MachineKinematics::new(&config) else {
            return Err(StudyError::Unsuitable(
                "five-axis study: the machine must be a hexapod-xy".into(),
            ));
        };
        let mut joints = Vec::new();
        for (j, (jc, jf)) in config.joints.iter().zip(&file.joints).enumerate() {
            let Drive::Servo { channel } = jc.drive else {
                return Err(StudyError::Unsuitable(format!(
                    "joints[{j}] ({}): every joint must be a servo joint",
                    jf.name
                )));
            };
            let p = jf.plant.as_ref().ok_or_else(|| {
                StudyError::Unsuitable(format!("joints[{j}] ({}): no plant table", jf.name))
            })?;
            let model = TransferFunction::new(&p.num, &p.den)
                .map_err(|e| StudyError::Unsuitable(format!("joints[{j}] ({}).{e}", jf.name)))?;
            joints.push(Joint {
                channel: channel as usize,
                counts_per_mm: jc.scale.steps as f64 / jc.scale.per_units as f64 * NM_PER_MM as f64,
                input_per_count: p.input_per_count,
                model,
            });
        }
        debug_assert!(matches!(config.kinematics, KinematicsConfig::HexapodXy(_)));
        let mut config = config;
        config.servo.law = [0; MAX_SERVOS];
        config.servo.lqg.clear();
        let mut lqg = config.clone();
        file.apply_lqg(&mut lqg, true)?;
        Ok(Self {
            config,
            lqg,
            kin,
            joints,
        })
    }

    /// The pose (nm, n°) of `p` (mm, degrees).
    fn units(p: &[f64; 5]) -> [i64; AXES] {
        [
            (p[0] * 1e6).round() as i64,
            (p[1] * 1e6).round() as i64,
            (p[2] * 1e6).round() as i64,
            (p[3] * 1e9).round() as i64,
            (p[4] * 1e9).round() as i64,
            0,
        ]
    }

    /// Each joint's plant, `c`'s mismatch applied, at period `h`: the command path and,
    /// on the legs, the load-force path.
    fn plants(&self, c: &Conditions, h: f64) -> Vec<(DiscretePlant, Option<DiscretePlant>)> {
        self.joints
            .iter()
            .enumerate()
            .map(|(j, jt)| {
                let tf = jt.model.perturbed(c.mismatch[j]);
                let load = (j < 6).then(|| {
                    let l = c.leg_load;
                    TransferFunction::new(&[-l.gain * l.lead_s, -l.gain], &tf.den)
                        .expect("a proper load path")
                        .discretize(h)
                });
                (tf.discretize(h), load)
            })
            .collect()
    }

    /// The servo bank of `config` standing at `counts` with the channel map at `start`
    /// (the controller builds it at rest before a job), and the builder of the maps the
    /// controller sends along the path.
    fn bank(
        &self,
        config: &MachineConfig,
        counts: &[i64; MAX_SERVOS],
        start: &pkmc::kinematics::Pose,
    ) -> (ServoBank, MapBuilder) {
        let mut bank = ServoBank::new(config, counts);
        let map = self
            .kin
            .contour_map(start)
            .expect("the start is not singular");
        bank.load_map(&ContourMap::of_joints(config, &map));
        (bank, MapBuilder::new(config))
    }

    /// Runs `scheme` with `law` under `c`.
    pub fn run(&self, scheme: Scheme, law: Law, c: &Conditions) -> Run {
        let config = scheme.configure(match law {
            Law::Pid => &self.config,
            Law::Lqg => &self.lqg,
        });
        let kin = MachineKinematics::HexapodXy(self.kin);
        let coupled = config.servo.contour.mode != pkmc::config::ContourMode::Uncoupled;
        let h = 1.0 / SERVO_HZ as f64;
        let t0 = -c.lead_in_s;
        let mut start_q = [0i64; MAX_JOINTS];
        kin.inverse(&Self::units(&c.pose(t0)), &mut start_q)
            .expect("the path's start is reachable");
        let mut plants = self.plants(c, h);
        let mut counts = [0i64; MAX_SERVOS];
        for (j, jt) in self.joints.iter().enumerate() {
            counts[jt.channel] = (start_q[j] as f64 * 1e-6 * jt.counts_per_mm).round() as i64;
        }
        let (mut bank, mut builder) = self.bank(&config, &counts, &Self::units(&c.pose(t0)));
        let mut feedback = counts;
        let mut targets = counts.map(|v| v << 16);
        let mut inputs = [0.0f64; 8];
        let mut load = [0.0f64; 8];
        let ticks = ((c.duration_s + c.lead_in_s) * TICK_HZ as f64).round() as u64;
        let mut run = Run::new(scheme, law, ticks as usize);
        let (mut sum_path, mut sum_dir, mut samples) = (0.0, 0.0, 0u64);
        let mut q_nm = start_q;
        let mut measured_pose = Self::units(&c.pose(t0));
        'run: for n in 1..=ticks {
            let t_tick = t0 + n as f64 / TICK_HZ as f64;
            let pose = Self::units(&c.pose(t_tick));
            let mut q = [0i64; MAX_JOINTS];
            kin.inverse(&pose, &mut q).expect("the path is reachable");
            for (j, jt) in self.joints.iter().enumerate() {
                targets[jt.channel] = target_q16(&config.joints[j].scale, q[j]);
            }
            bank.load_tick(&targets);
            if coupled {
                if let Some(map) = builder.step(&self.kin, &pose) {
                    bank.load_map(map);
                }
            }
            // The cutting force at this tick, carried to the joints.
            let w = c.force.at(t_tick);
            let f = joint_forces(&pose, &w, &config, &kin, &[0, 1, 2, 3, 4])
                .unwrap_or([0.0; MAX_JOINTS]);
            load.copy_from_slice(&f[..8]);
            let (mut path_err, mut dir_err) = (0.0, 0.0);
            for k in 0..SERVO_PER_TICK {
                let period = (n - 1) * SERVO_PER_TICK as u64 + k as u64;
                let t = t0 + period as f64 * h;
                for (j, jt) in self.joints.iter().enumerate() {
                    let (plant, lp) = &plants[j];
                    let mut y = plant.output(inputs[j]);
                    if let Some(lp) = lp {
                        y += lp.output(load[j]);
                    }
                    let mm = start_q[j] as f64 * 1e-6 + y;
                    q_nm[j] = (mm * 1e6).round() as i64;
                    let raw = (mm * jt.counts_per_mm).round() as i64 as u16;
                    feedback[jt.channel] = extend_counter(feedback[jt.channel], raw);
                    let want = targets[jt.channel] as f64 / 65536.0 / jt.counts_per_mm;
                    run.max_following_mm = run.max_following_mm.max((want - mm).abs());
                }
                let out = bank.period(&PeriodInputs {
                    feedback,
                    fault: [false; MAX_SERVOS],
                    enable: true,
                });
                if let Some((ch, trip)) = bank
                    .trips()
                    .iter()
                    .enumerate()
                    .find_map(|(i, t)| t.map(|t| (i, t)))
                {
                    run.trip = Some((ch, format!("{trip:?} at t = {t:.4} s")));
                    break 'run;
                }
                let mut saturated = false;
                for (j, jt) in self.joints.iter().enumerate() {
                    let ch = jt.channel;
                    saturated |= out.command[ch].abs() >= config.servo.gains[ch].max_output;
                    let mut u = (out.dac[ch] as i32 - DAC_MID) as f64 * jt.input_per_count;
                    if j >= 6 {
                        // The table's drives feel the force along their own axis.
                        u -= c.table_input_per_newton * w[j - 6];
                    }
                    inputs[j] = u;
                    let (plant, lp) = &mut plants[j];
                    plant.step(u);
                    if let Some(lp) = lp {
                        lp.step(load[j]);
                    }
                }
                run.saturated_periods += saturated as u64;
                if t < 0.0 {
                    continue;
                }
                let Some((d, dir)) = measure(&kin, &q_nm, &mut measured_pose, t, c) else {
                    continue;
                };
                (path_err, dir_err) = (d, dir);
                sum_path += d * d;
                sum_dir += dir * dir;
                samples += 1;
                run.max_path_mm = run.max_path_mm.max(d);
                run.max_dir_deg = run.max_dir_deg.max(dir);
            }
            if t_tick >= 0.0 {
                run.trace.push((t_tick, path_err, dir_err));
            }
        }
        run.rms_path_mm = (sum_path / samples.max(1) as f64).sqrt();
        run.rms_dir_deg = (sum_dir / samples.max(1) as f64).sqrt();
        run
    }
}

/// The errors at joints `q` (nm) at `t` s: the pose by forward kinematics from `guess`
/// (updated), the distance to the helix and the tool-direction error at the nearest
/// point, mm and degrees.
fn measure(
    kin: &MachineKinematics,
    q: &[i64; MAX_JOINTS],
    guess: &mut [i64; AXES],
    t: f64,
    c: &Conditions,
) -> Option<(f64, f64)> {
    let mut at = [0i64; AXES];
    kin.forward(q, guess, &mut at).ok()?;
    *guess = at;
    let y = [
        at[0] as f64 * 1e-6,
        at[1] as f64 * 1e-6,
        at[2] as f64 * 1e-6,
    ];
    let (ts, d) = nearest_on_helix(y, t - 1.0 / TICK_HZ as f64, -c.lead_in_s, c.duration_s);
    let want = c.pose(ts);
    let dir = angle_deg(
        tool_axis(at[3] as f64 * 1e-9, at[4] as f64 * 1e-9),
        tool_axis(want[3], want[4]),
    );
    Some((d, dir))
}

/// The bundled machine file.
pub const HEXAPOD_XY: &str = include_str!("../../../examples/machines/hexapod-xy.toml");
