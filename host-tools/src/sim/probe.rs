//! A touch probe in the simulator: spheres and planes in the workpiece frame that the
//! tool point touches.
//!
//! **Where the tool is.** Each tick the simulator takes the joints' true positions
//! (the steps the stepper drives have made, the servo plants' encoders), runs the
//! machine's forward kinematics and gets the tool point at the tick's start. Between
//! two ticks the point moves in a straight line. The kinematics are the controller's
//! own, or, with a truth seed, a "true" machine's whose geometry differs from the
//! machine file's ([`Frame`]): a probing run then measures a machine to calibrate.
//!
//! **When it triggers.** The probe touches where the point's signed distance to a
//! target (a sphere's surface, outward positive; a plane's height above it) is at most
//! a trigger offset. That offset is the trigger noise: drawn afresh, normally
//! distributed with standard deviation `noise_mm`, each time the probe changes, for
//! the next change. The instant of a change is where the straight segment between the
//! two tick samples crosses that level (found by bisection), plus a constant `delay_us`
//! (the probe's switching delay). The controller's input then reads the new level from
//! the first tick sample after that instant, with the instant as its timer capture
//! (`RawInputs::probe_edge_us`), as the board's input capture gives it.
//!
//! A sphere's radius is the artefact's plus the probe tip's: the point is the tip's
//! centre.

use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::kinematics::{Kinematics, MachineKinematics};
use pkmc::units::units_per_user;
use std::sync::Arc;

/// A true machine's tool point: from the joints (mm or degrees) and the controller's
/// pose (mm, degrees) as the first guess, the tool point in mm in the workpiece frame;
/// `None` where the true machine has no pose.
pub type TruePoint = Box<dyn FnMut(&[f64], &[f64; AXES]) -> Option<[f64; 3]> + Send>;

/// How a [`Truth`] builds its tool point for a machine file.
pub type BuildTruth = dyn Fn(&MachineConfig) -> Result<TruePoint, String> + Send + Sync;

/// A "true" machine for the simulator's probe: its seed, and how its tool point is
/// built for a machine file (the calibration model with every parameter perturbed by
/// the seed, wired by `nc-send --probe-truth-seed`).
#[derive(Clone)]
pub struct Truth {
    /// The seed it is drawn with.
    pub seed: u64,
    /// Its tool point for a machine file (an error for a machine it cannot perturb).
    pub build: Arc<BuildTruth>,
}

impl std::fmt::Debug for Truth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Truth {{ seed: {} }}", self.seed)
    }
}

/// Where the simulator finds the tool point from the joints' true positions: the
/// controller's own forward kinematics, or a "true" machine whose geometry differs
/// from the machine file's ([`Truth`]). With the true machine, a probing run measures
/// the geometry a calibration is to find.
pub enum Frame {
    /// The machine file's geometry, through the controller's kinematics.
    Nominal(MachineKinematics),
    /// A true machine.
    True {
        /// What it is.
        truth: Truth,
        /// Its tool point.
        point: TruePoint,
        /// The controller's kinematics, for a pose the true machine cannot solve.
        fallback: MachineKinematics,
    },
}

impl Frame {
    /// The frame of `machine`: the true machine `truth`, or its own geometry.
    pub(super) fn new(machine: &MachineConfig, truth: Option<&Truth>) -> Result<Frame, String> {
        let kin = MachineKinematics::new(machine);
        let Some(truth) = truth else {
            return Ok(Frame::Nominal(kin));
        };
        Ok(Frame::True {
            point: (truth.build)(machine)?,
            truth: truth.clone(),
            fallback: kin,
        })
    }

    /// Its true machine, if it has one.
    pub(super) fn truth(&self) -> Option<&Truth> {
        match self {
            Frame::Nominal(_) => None,
            Frame::True { truth, .. } => Some(truth),
        }
    }

    /// The tool point, mm in the workpiece frame, with the joints at `q` (axis units)
    /// and the controller's pose `pose` (axis units) as the first guess.
    pub(super) fn point(
        &mut self,
        machine: &MachineConfig,
        q: &[i64; MAX_JOINTS],
        pose: &[i64; AXES],
    ) -> [f64; 3] {
        let nominal = |kin: &MachineKinematics| {
            let mut p = *pose;
            let _ = kin.forward(q, pose, &mut p);
            std::array::from_fn(|i| p[i] as f64 / 1e6)
        };
        let (point, fallback) = match self {
            Frame::Nominal(kin) => return nominal(kin),
            Frame::True {
                point, fallback, ..
            } => (point, fallback),
        };
        let qf: Vec<f64> = machine
            .joints
            .iter()
            .enumerate()
            .map(|(j, jc)| q[j] as f64 / units_per_user(jc.rotary) as f64)
            .collect();
        let guess = std::array::from_fn(|i| pose[i] as f64 / units_per_user(i >= 3) as f64);
        point(&qf, &guess).unwrap_or_else(|| nominal(fallback))
    }
}

impl Truth {
    /// The true machine of `seed`, built for a machine file by `build` (e.g.
    /// `calibrate::truth::tool_point`).
    pub fn new(seed: u64, build: fn(&MachineConfig, u64) -> Result<TruePoint, String>) -> Self {
        Truth {
            seed,
            build: Arc::new(move |m| build(m, seed)),
        }
    }
}

/// A surface the probe touches, mm in the workpiece frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// A sphere: touching inside `radius` of `centre`.
    Sphere {
        /// Centre, mm.
        centre: [f64; 3],
        /// Radius (artefact plus tip), mm.
        radius: f64,
    },
    /// A horizontal plane: touching at or below `z` mm.
    Plane {
        /// Height, mm.
        z: f64,
    },
}

impl Target {
    /// Signed distance of `p` (mm) from the surface: negative inside.
    fn distance(&self, p: &[f64; 3]) -> f64 {
        match self {
            Target::Sphere { centre, radius } => {
                let d: f64 = (0..3).map(|i| (p[i] - centre[i]).powi(2)).sum();
                d.sqrt() - radius
            }
            Target::Plane { z } => p[2] - z,
        }
    }
}

/// The probe's model: its targets, noise and delay (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeModel {
    /// What it touches.
    pub targets: Vec<Target>,
    /// Standard deviation of the trigger level, mm.
    pub noise_mm: f64,
    /// Switching delay, µs.
    pub delay_us: f64,
    /// Seed of the trigger noise.
    pub seed: u64,
}

/// The simulated probe on nc-send's command line (`--sim` and `--check` only).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ProbeArgs {
    /// Simulator only: a touch probe that touches a sphere, `X,Y,Z,R` mm in the
    /// workpiece frame (R: the artefact's radius plus the tip's). May be given more
    /// than once.
    #[arg(
        long,
        global = true,
        value_name = "X,Y,Z,R",
        allow_hyphen_values = true
    )]
    pub probe_sphere: Vec<String>,
    /// Simulator only: a touch probe that touches at or below this height, mm.
    #[arg(long, global = true, value_name = "Z", allow_hyphen_values = true)]
    pub probe_plane: Vec<f64>,
    /// The simulated probe's trigger noise (standard deviation along the surface
    /// normal), µm.
    #[arg(long, global = true, value_name = "UM", default_value_t = 0.5)]
    pub probe_noise_um: f64,
    /// The simulated probe's switching delay, µs.
    #[arg(long, global = true, value_name = "US", default_value_t = 20.0)]
    pub probe_delay_us: f64,
    /// Simulator only: the probe sees a "true" machine, the machine file's geometry
    /// with every parameter moved at random by seed N (up to ±0.5 mm, ±0.3° for a
    /// rotary joint's zero), as `calibrate simulate` draws it. Parallel machines only.
    #[arg(long, global = true, value_name = "N")]
    pub probe_truth_seed: Option<u64>,
}

impl ProbeArgs {
    /// The true machine of `--probe-truth-seed`, if given, built by `build`.
    pub fn truth(
        &self,
        build: fn(&MachineConfig, u64) -> Result<TruePoint, String>,
    ) -> Option<Truth> {
        self.probe_truth_seed.map(|seed| Truth::new(seed, build))
    }

    /// The model these options describe (`None` without a sphere or a plane); `seed`
    /// seeds its noise. Errors name the option.
    pub fn model(&self, seed: u64) -> Result<Option<ProbeModel>, String> {
        let mut targets = Vec::new();
        for s in &self.probe_sphere {
            let v: Vec<f64> = s
                .split(',')
                .map(|f| f.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|e| format!("--probe-sphere {s}: {e}"))?;
            match v[..] {
                [x, y, z, r] if v.iter().all(|f| f.is_finite()) && r > 0.0 => {
                    targets.push(Target::Sphere {
                        centre: [x, y, z],
                        radius: r,
                    })
                }
                _ => return Err(format!("--probe-sphere {s}: give X,Y,Z,R in mm, R above 0")),
            }
        }
        for &z in &self.probe_plane {
            if !z.is_finite() {
                return Err(format!("--probe-plane {z}: give a height in mm"));
            }
            targets.push(Target::Plane { z });
        }
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        if !ok(self.probe_noise_um) || !ok(self.probe_delay_us) {
            return Err("--probe-noise-um and --probe-delay-us: give 0 or more".into());
        }
        Ok((!targets.is_empty()).then(|| ProbeModel {
            targets,
            noise_mm: self.probe_noise_um / 1000.0,
            delay_us: self.probe_delay_us,
            seed,
        }))
    }
}

/// The probe as the simulator runs it.
#[derive(Clone, Debug)]
pub(super) struct SimProbe {
    model: ProbeModel,
    rng: u64,
    /// The trigger level for the next change, mm.
    level: f64,
    /// The tool point at the last tick's start.
    last: Option<[f64; 3]>,
    /// The input as the controller reads it.
    touching: bool,
    /// A change under way: the new level and its instant, µs after the last tick's
    /// start (at or past 1000: it shows at a later sample).
    pending: Option<(bool, f64)>,
}

const TICK_US: f64 = 1e6 / pkmc::units::TICK_HZ as f64;

impl SimProbe {
    pub(super) fn new(model: ProbeModel) -> Self {
        let mut p = Self {
            rng: model.seed ^ 0x9e37_79b9_7f4a_7c15,
            model,
            level: 0.0,
            last: None,
            touching: false,
            pending: None,
        };
        p.level = p.draw();
        p
    }

    /// A normal deviate × the noise (Box–Muller on a xorshift generator).
    fn draw(&mut self) -> f64 {
        let mut u = || {
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 7;
            self.rng ^= self.rng << 17;
            ((self.rng >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos() * self.model.noise_mm
    }

    fn touches(&self, p: &[f64; 3]) -> bool {
        self.model
            .targets
            .iter()
            .any(|t| t.distance(p) <= self.level)
    }

    /// The tool point `now` (mm) at this tick's start: the input to read at this
    /// tick's sample, and when it last changed since the last sample (µs after it).
    pub(super) fn sample(&mut self, now: [f64; 3]) -> (bool, Option<u16>) {
        let last = self.last.replace(now).unwrap_or(now);
        if self.pending.is_none() {
            let sought = !self.touching;
            if self.touches(&now) == sought {
                // Bisect the crossing along the segment.
                let (mut lo, mut hi) = (0.0, 1.0);
                for _ in 0..40 {
                    let mid = 0.5 * (lo + hi);
                    let p: [f64; 3] = std::array::from_fn(|i| last[i] + (now[i] - last[i]) * mid);
                    if self.touches(&p) == sought {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                self.pending = Some((sought, hi * TICK_US + self.model.delay_us));
            }
        }
        let mut edge = None;
        if let Some((level, at)) = self.pending {
            if at < TICK_US {
                self.touching = level;
                self.pending = None;
                self.level = self.draw();
                edge = Some(at.round().clamp(0.0, TICK_US - 1.0) as u16);
            } else {
                self.pending = Some((level, at - TICK_US));
            }
        }
        (self.touching, edge)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(noise: f64, delay: f64) -> ProbeModel {
        ProbeModel {
            targets: vec![Target::Plane { z: -1.0 }],
            noise_mm: noise,
            delay_us: delay,
            seed: 3,
        }
    }

    #[test]
    fn a_crossing_is_timed_within_its_tick_and_delayed() {
        let mut p = SimProbe::new(model(0.0, 0.0));
        assert_eq!(p.sample([0.0, 0.0, 0.0]), (false, None));
        assert_eq!(p.sample([0.0, 0.0, -0.5]), (false, None));
        // From -0.5 to -1.5: the plane a half way.
        assert_eq!(p.sample([0.0, 0.0, -1.5]), (true, Some(500)));
        let mut p = SimProbe::new(model(0.0, 700.0));
        p.sample([0.0, 0.0, -0.5]);
        assert_eq!(p.sample([0.0, 0.0, -1.5]), (false, None), "not yet");
        assert_eq!(p.sample([0.0, 0.0, -2.5]), (true, Some(200)));
        // Going back up from -2.5 to -0.5: contact lost three quarters of the way,
        // 700 µs later.
        assert_eq!(p.sample([0.0, 0.0, -0.5]), (true, None));
        assert_eq!(p.sample([0.0, 0.0, -0.5]), (false, Some(450)));
    }

    #[test]
    fn the_trigger_noise_has_the_stated_spread() {
        let mut p = SimProbe::new(model(0.001, 0.0));
        let n = 4000;
        let levels: Vec<f64> = (0..n).map(|_| p.draw()).collect();
        let rms = (levels.iter().map(|l| l * l).sum::<f64>() / n as f64).sqrt();
        assert!((rms - 0.001).abs() < 0.0001, "{rms}");
    }

    #[test]
    fn a_sphere_touches_inside_its_radius() {
        let t = Target::Sphere {
            centre: [1.0, 2.0, 3.0],
            radius: 2.0,
        };
        assert!((t.distance(&[1.0, 2.0, 6.0]) - 1.0).abs() < 1e-12);
        assert!(t.distance(&[1.0, 2.0, 4.0]) < 0.0);
    }
}
