//! The contour-control study of report B (`seeds-digest.md` §B): the report's helix
//! x = t·cos t, y = t·sin t, z = 3t + 260 mm, t = 0..10 s, run on a machine whose servo
//! joints carry transfer-function plants ([`crate::control::plant`]), under four controllers
//! that share the same per-axis PID gains:
//!
//! 1. **uncoupled** — PID only (feed-forward gains zeroed, contour mode uncoupled);
//! 2. **feed-forward** — uncoupled PID plus the per-axis velocity and acceleration
//!    feed-forward;
//! 3. **cross-coupled** — PID plus Koren's cross-coupled controller, no feed-forward;
//! 4. **CCPM** — PID, feed-forward (velocity pre-compensation), cross-coupled
//!    controller and reference pre-compensation.
//!
//! Coupling gains come from the machine file's `[contour]` table, PID and feed-forward
//! gains from its joints. The simulated plants differ from the models by a
//! [`Mismatch`] per axis and are disturbed by a periodic cutting force
//! ([`Disturbance`]). Each run steps the core's [`ServoBank`] at 10 kHz exactly as the
//! firmware will: the analytic path sampled at the 1 kHz interpolation tick, joint
//! targets in encoder counts, 16-bit encoder counters extended by
//! [`extend_counter`], DAC codes back to the plants' inputs. The contour error is
//! measured as the true distance from the simulated tool position to the helix (Newton
//! iteration on the curve parameter), not the controller's estimate.

pub mod five_axis;

use crate::control::plant::{DiscretePlant, Mismatch, TransferFunction};
use crate::machine_file::MachineFile;
use pkmc::config::{ContourMode, Drive, KinematicsConfig, MachineConfig, MAX_SERVOS};
use pkmc::drive::contour::{PeriodInputs, ServoBank};
use pkmc::drive::servo::{extend_counter, target_q16, DAC_MID, SERVO_HZ, SERVO_PER_TICK};
use pkmc::units::{NM_PER_MM, TICK_HZ};

/// Why the study cannot run on a machine.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The machine file's values are refused.
    #[error(transparent)]
    Machine(#[from] crate::machine_file::FieldError),
    /// Seed B's machine file does not parse.
    #[error(transparent)]
    Toml(#[from] toml::de::Error),
    /// The machine is not one the study can use, in words.
    #[error("{0}")]
    Unsuitable(String),
}

/// The four controllers compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// PID alone.
    Uncoupled,
    /// PID with per-axis velocity and acceleration feed-forward.
    FeedForward,
    /// PID with Koren's cross-coupled controller.
    CrossCoupled,
    /// Cross-coupling pre-compensation method.
    Ccpm,
}

impl Scheme {
    /// All four, in the report's order of sophistication.
    pub const ALL: [Scheme; 4] = [
        Scheme::Uncoupled,
        Scheme::FeedForward,
        Scheme::CrossCoupled,
        Scheme::Ccpm,
    ];

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::Uncoupled => "uncoupled",
            Scheme::FeedForward => "feed-forward",
            Scheme::CrossCoupled => "cross-coupled",
            Scheme::Ccpm => "CCPM",
        }
    }

    /// `machine` set up for this scheme: contour mode and, for the schemes without it,
    /// the feed-forward gains zeroed. The PID gains are left as they are.
    pub fn configure(self, machine: &MachineConfig) -> MachineConfig {
        let mut m = machine.clone();
        let (mode, ff) = match self {
            Scheme::Uncoupled => (ContourMode::Uncoupled, false),
            Scheme::FeedForward => (ContourMode::Uncoupled, true),
            Scheme::CrossCoupled => (ContourMode::CrossCoupled, false),
            Scheme::Ccpm => (ContourMode::Ccpm, true),
        };
        m.servo.contour.mode = mode;
        if !ff {
            for g in &mut m.servo.gains {
                g.kvff = 0.0;
                g.kaff = 0.0;
            }
        }
        m
    }
}

/// A periodic cutting force on every axis, referred to the plant input (the report's
/// cylinder model adds the load force through the same dynamics as the valve command,
/// eq. 5): d_i(t) = mean + amplitude·sin(2π·f·t + i·120°), c.u.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disturbance {
    /// Steady part, c.u.
    pub mean: f64,
    /// Periodic part's amplitude, c.u.
    pub amplitude: f64,
    /// Frequency, Hz (tooth passing).
    pub freq_hz: f64,
}

impl Disturbance {
    /// None.
    pub const NONE: Disturbance = Disturbance {
        mean: 0.0,
        amplitude: 0.0,
        freq_hz: 0.0,
    };

    /// Force on axis `i` at `t` seconds, c.u.
    pub fn at(&self, i: usize, t: f64) -> f64 {
        let phase = i as f64 * std::f64::consts::TAU / 3.0;
        self.mean + self.amplitude * (std::f64::consts::TAU * self.freq_hz * t + phase).sin()
    }
}

/// Conditions of a study.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conditions {
    /// Plant mismatch of the X, Y and Z joints.
    pub mismatch: [Mismatch; 3],
    /// Cutting force.
    pub disturbance: Disturbance,
    /// Path duration, s (the report: 10).
    pub duration_s: f64,
    /// Time on the same curve before t = 0, s: the machine starts at rest at
    /// helix(−lead_in) and is already on the path, settled, when the measured window
    /// t = 0..duration begins. Zero starts from rest at t = 0 with the report's velocity
    /// step of √10 mm/s.
    pub lead_in_s: f64,
}

impl Conditions {
    /// The study's conditions: X and Z plants 10 % more gain, Y 10 % less, every
    /// resonance 10 % lower; a cutting force of 2 c.u. steady plus 2 c.u. (1 % of the
    /// DAC's full scale) at 20 Hz, tooth passing of a two-flute cutter at 600 rpm.
    pub const STUDY: Conditions = Conditions {
        mismatch: [
            Mismatch {
                gain: 1.1,
                resonance: 0.9,
            },
            Mismatch {
                gain: 0.9,
                resonance: 0.9,
            },
            Mismatch {
                gain: 1.1,
                resonance: 0.9,
            },
        ],
        disturbance: Disturbance {
            mean: 2.0,
            amplitude: 2.0,
            freq_hz: 20.0,
        },
        duration_s: 10.0,
        lead_in_s: 1.0,
    };
}

/// The report's helix at `t` s, mm.
pub fn helix(t: f64) -> [f64; 3] {
    [t * t.cos(), t * t.sin(), 3.0 * t + 260.0]
}

fn helix_d1(t: f64) -> [f64; 3] {
    [t.cos() - t * t.sin(), t.sin() + t * t.cos(), 3.0]
}

fn helix_d2(t: f64) -> [f64; 3] {
    [
        -2.0 * t.sin() - t * t.cos(),
        2.0 * t.cos() - t * t.sin(),
        0.0,
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Distance from `y` (mm) to the helix over t ∈ [`start`, `end`], searched near `guess`.
pub fn distance_to_helix(y: [f64; 3], guess: f64, start: f64, end: f64) -> f64 {
    nearest_on_helix(y, guess, start, end).1
}

/// The nearest point of the helix to `y` (mm) over t ∈ [`start`, `end`], searched near
/// `guess` by Newton's method on the curve parameter: (t, distance).
pub fn nearest_on_helix(y: [f64; 3], guess: f64, start: f64, end: f64) -> (f64, f64) {
    let mut t = guess.clamp(start, end);
    for _ in 0..8 {
        let p = helix(t);
        let d = [p[0] - y[0], p[1] - y[1], p[2] - y[2]];
        let d1 = helix_d1(t);
        let f = dot(d, d1);
        let fp = dot(d1, d1) + dot(d, helix_d2(t));
        if fp <= 0.0 {
            break;
        }
        let next = (t - f / fp).clamp(start, end);
        if (next - t).abs() < 1e-13 {
            t = next;
            break;
        }
        t = next;
    }
    let p = helix(t);
    let d = [p[0] - y[0], p[1] - y[1], p[2] - y[2]];
    (t, dot(d, d).sqrt())
}

/// One servo channel of the study machine.
#[derive(Clone, Debug)]
struct Channel {
    channel: usize,
    axis: usize,
    joint: usize,
    counts_per_mm: f64,
    input_per_count: f64,
    plant: DiscretePlant,
}

/// The result of one run.
#[derive(Clone, Debug)]
pub struct RunResult {
    /// Which controller.
    pub scheme: Scheme,
    /// Largest contour error, mm.
    pub max_mm: f64,
    /// RMS contour error over the run, mm.
    pub rms_mm: f64,
    /// Time of the largest contour error, s.
    pub max_at_s: f64,
    /// Largest tracking error of any axis, mm.
    pub max_tracking_mm: f64,
    /// Contour error at the end of every interpolation tick: (t s, mm).
    pub trace: Vec<(f64, f64)>,
    /// Tracking error (setpoint − position) of X, Y, Z at the end of every tick, mm.
    pub axis_trace: Vec<[f64; 3]>,
    /// Periods in which some axis's command was at its clamp.
    pub saturated_periods: u64,
    /// A servo trip, if one stopped the run: (channel, description).
    pub trip: Option<(usize, String)>,
}

/// The study's machine: the converted configuration plus the X, Y, Z servo channels'
/// plant models.
#[derive(Clone, Debug)]
pub struct StudyMachine {
    /// Core configuration.
    pub config: MachineConfig,
    models: Vec<(usize, usize, usize, f64, f64, TransferFunction)>,
}

impl StudyMachine {
    /// From a machine file whose X, Y and Z joints are Cartesian servo joints with a
    /// `plant` table each.
    pub fn new(file: &MachineFile) -> Result<Self, StudyError> {
        let config = file.to_config()?;
        let KinematicsConfig::Cartesian { axis_of_joint } = config.kinematics else {
            return Err(StudyError::Unsuitable(
                "contour study: the machine must be Cartesian".into(),
            ));
        };
        let mut models = Vec::new();
        for (j, (jc, jf)) in config.joints.iter().zip(&file.joints).enumerate() {
            let Drive::Servo { channel, .. } = jc.drive else {
                continue;
            };
            let axis = axis_of_joint[j] as usize;
            if axis >= 3 {
                continue;
            }
            let p = jf.plant.as_ref().ok_or_else(|| {
                StudyError::Unsuitable(format!("joints[{j}] ({}): no plant table", jf.name))
            })?;
            let tf = TransferFunction::new(&p.num, &p.den)
                .map_err(|e| StudyError::Unsuitable(format!("joints[{j}] ({}).{e}", jf.name)))?;
            let counts_per_mm =
                jc.scale.steps as f64 / jc.scale.per_units as f64 * NM_PER_MM as f64;
            models.push((
                channel as usize,
                axis,
                j,
                counts_per_mm,
                p.input_per_count,
                tf,
            ));
        }
        let mut axes: Vec<usize> = models.iter().map(|m| m.1).collect();
        axes.sort();
        if axes != [0, 1, 2] {
            return Err(StudyError::Unsuitable(
                "contour study: X, Y and Z must each be a servo joint with a plant".into(),
            ));
        }
        Ok(Self { config, models })
    }

    /// The plant model of pose axis `axis` (0 = X).
    pub fn model(&self, axis: usize) -> Option<&TransferFunction> {
        self.models.iter().find(|m| m.1 == axis).map(|m| &m.5)
    }

    /// Runs `scheme` under `conditions`.
    pub fn run(&self, scheme: Scheme, conditions: &Conditions) -> RunResult {
        let config = scheme.configure(&self.config);
        let h = 1.0 / SERVO_HZ as f64;
        let t0 = -conditions.lead_in_s;
        let start = helix(t0);
        let mut channels: Vec<Channel> = self
            .models
            .iter()
            .map(|(c, axis, j, cpm, ipc, tf)| Channel {
                channel: *c,
                axis: *axis,
                joint: *j,
                counts_per_mm: *cpm,
                input_per_count: *ipc,
                plant: tf.perturbed(conditions.mismatch[*axis]).discretize(h),
            })
            .collect();
        // The interpolator's pose in nm, as the joint's target in counts × 2^16.
        let target = |t: f64, ch: &Channel| -> i64 {
            let nm = (helix(t)[ch.axis] * NM_PER_MM as f64).round() as i64;
            target_q16(&config.joints[ch.joint].scale, nm)
        };
        let mut counts = [0i64; MAX_SERVOS];
        for ch in &channels {
            counts[ch.channel] = (start[ch.axis] * ch.counts_per_mm).round() as i64;
        }
        let mut bank = ServoBank::new(&config, &counts);
        let mut feedback = counts;
        let mut targets = counts.map(|c| c << 16);
        let mut commands = [0.0f64; MAX_SERVOS];
        let ticks =
            ((conditions.duration_s + conditions.lead_in_s) * TICK_HZ as f64).round() as u64;
        let mut result = RunResult {
            scheme,
            max_mm: 0.0,
            rms_mm: 0.0,
            max_at_s: 0.0,
            max_tracking_mm: 0.0,
            trace: Vec::with_capacity(ticks as usize),
            axis_trace: Vec::with_capacity(ticks as usize),
            saturated_periods: 0,
            trip: None,
        };
        let mut sum_sq = 0.0;
        let mut samples = 0u64;
        'run: for n in 1..=ticks {
            let t_tick = t0 + n as f64 / TICK_HZ as f64;
            for ch in &channels {
                targets[ch.channel] = target(t_tick, ch);
            }
            bank.load_tick(&targets);
            let mut err = 0.0;
            let mut tracking = [0.0; 3];
            for k in 0..SERVO_PER_TICK {
                // Time at the start of this period; the setpoint it ends on is the
                // path at t − 1 tick + (k + 1)/10 tick.
                let period = (n - 1) * SERVO_PER_TICK as u64 + k as u64;
                let t = t0 + period as f64 * h;
                let mut pos = start;
                for ch in &channels {
                    let y = start[ch.axis] + ch.plant.output(commands[ch.channel]);
                    pos[ch.axis] = y;
                    let raw = (y * ch.counts_per_mm).round() as i64 as u16;
                    feedback[ch.channel] = extend_counter(feedback[ch.channel], raw);
                }
                let out = bank.period(&PeriodInputs {
                    feedback,
                    fault: [false; MAX_SERVOS],
                    enable: true,
                });
                if let Some((c, trip)) = bank
                    .trips()
                    .iter()
                    .enumerate()
                    .find_map(|(c, t)| t.map(|t| (c, t)))
                {
                    result.trip = Some((c, format!("{trip:?} at t = {t:.4} s")));
                    break 'run;
                }
                let mut saturated = false;
                for ch in &mut channels {
                    let c = ch.channel;
                    let u = (out.dac[c] as i32 - DAC_MID) as f64 * ch.input_per_count;
                    saturated |= out.command[c].abs() >= config.servo.gains[c].max_output;
                    let u = u + conditions.disturbance.at(ch.axis, t - t0);
                    commands[c] = u;
                    ch.plant.step(u);
                }
                result.saturated_periods += saturated as u64;
                if t < 0.0 {
                    continue;
                }
                // Measure on the position the loop just saw.
                let reference_t = t - 1.0 / TICK_HZ as f64;
                err = distance_to_helix(pos, reference_t, t0, conditions.duration_s);
                sum_sq += err * err;
                samples += 1;
                if err > result.max_mm {
                    result.max_mm = err;
                    result.max_at_s = t;
                }
                for ch in &channels {
                    let sp_t = t - 1.0 / TICK_HZ as f64;
                    tracking[ch.axis] = helix(sp_t)[ch.axis] - pos[ch.axis];
                    result.max_tracking_mm = result.max_tracking_mm.max(tracking[ch.axis].abs());
                }
            }
            if t_tick >= 0.0 {
                result.trace.push((t_tick, err));
                result.axis_trace.push(tracking);
            }
        }
        result.rms_mm = (sum_sq / samples.max(1) as f64).sqrt();
        result
    }
}

/// Loop figures of one axis's PID on a plant, from its frequency response with the
/// servo's 1.5-period delay (hold plus computation): the peak sensitivity max|1/(1+L)|
/// and the highest gain crossover, rad/s.
pub fn loop_figures(tf: &TransferFunction, kp: f64, ki: f64, kd: f64) -> (f64, f64) {
    let delay = 1.5 / SERVO_HZ as f64;
    let (mut peak, mut crossover) = (0.0f64, 0.0f64);
    let mut above = false;
    for i in 0..=4000 {
        let w = 10f64.powf(-1.0 + 5.3 * i as f64 / 4000.0);
        let g = tf.at(w);
        let (cr, ci) = (kp, kd * w - ki / w);
        let (lr, li) = (cr * g.re - ci * g.im, cr * g.im + ci * g.re);
        let (dc, ds) = ((w * delay).cos(), -(w * delay).sin());
        let (lr, li) = (lr * dc - li * ds, lr * ds + li * dc);
        let one_plus = ((1.0 + lr).powi(2) + li * li).sqrt();
        peak = peak.max(1.0 / one_plus);
        let over = (lr * lr + li * li).sqrt() > 1.0;
        if above && !over {
            crossover = w;
        }
        above = over;
    }
    (peak, crossover)
}

impl StudyMachine {
    /// [`loop_figures`] of pose axis `axis` on its model and on its mismatched plant.
    pub fn axis_figures(&self, axis: usize, m: Mismatch) -> [(f64, f64); 2] {
        let (c, _, _, cpm, _, tf) = self.models.iter().find(|x| x.1 == axis).unwrap();
        let g = &self.config.servo.gains[*c];
        let k = |v: f32| v as f64 * cpm;
        let f = |t: &TransferFunction| loop_figures(t, k(g.kp), k(g.ki), k(g.kd));
        [f(tf), f(&tf.perturbed(m))]
    }
}

/// The bundled study machine file.
pub const SEED_B: &str = include_str!("../../../examples/machines/seed-b.toml");

/// Runs all four schemes on the bundled `seed-b` machine under [`Conditions::STUDY`].
pub fn run_study() -> Result<Vec<RunResult>, StudyError> {
    let file: MachineFile = toml::from_str(SEED_B)?;
    let m = StudyMachine::new(&file)?;
    Ok(Scheme::ALL
        .iter()
        .map(|s| m.run(*s, &Conditions::STUDY))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_on_the_helix_is_at_distance_zero_and_one_beside_it_at_its_offset() {
        let p = helix(4.0);
        assert!(distance_to_helix(p, 3.99, 0.0, 10.0) < 1e-9);
        let n = [p[0] + 0.0, p[1], p[2] + 0.01];
        let d = distance_to_helix(n, 4.0, 0.0, 10.0);
        assert!(d > 0.0 && d <= 0.01 + 1e-12);
    }
}
