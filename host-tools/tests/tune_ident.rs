//! Servo tuning that identifies the plant (issue 35), checked on every distinct servo
//! plant of the example machines: closed-loop data are generated with the machine
//! file's TRUE plant under the core's own loop (`ServoAxis`, the file's present
//! gains), the plant is identified from the recorded input and position alone, and
//! the gains designed on the identified model are judged on the true plant.
//!
//! * **Excitation.** The position command is offset by a PRBS of ±50 µm (±0.05 mm;
//!   PRBS15, each value held 5 ms), no velocity or acceleration feed-forward;
//!   1 s at 10 kHz. The amplitude keeps the following error below the smallest
//!   `min_ferror` of the files (0.2 mm).
//! * **Measurement.** The encoder reads round(true position in counts + n), n
//!   Gaussian with σ = 0.3 count (seeded), so quantisation to whole counts plus a
//!   small noise. The record holds u = (DAC − mid-scale − offset)/dac_per_unit c.u.
//!   and y = counts/counts per unit.
//! * **Step criterion.** Every plant here integrates (or has a pole below 1 rad/s),
//!   so its open-loop step never settles: the comparison is the closed loop's unit
//!   step with the file's present PID gains (`tune::closed_loop_step`, 2 s) on the
//!   identified and on the true plant, by `tune::step_error`:
//!   ∫₀^{t₉₀}|ŷ − y|dt / ∫₀^{t₉₀}|y_∞ − y|dt < 0.10, t₉₀ the true response's
//!   first 90 % crossing.
//! * **Margin criterion.** The PID designed on the identified model for the stated
//!   crossover (`PidSpec::new`, 60° aimed at on the model) keeps ≥ 45° of phase
//!   margin and a stable closed loop on the true plant (`tune::margins`, the
//!   discrete loop with its hold and sampling).
//!
//! Run with `--nocapture` to see the figures.

use pkmc::config::{LqgGains, ServoGains};
use pkmc::drive::servo::{AmpIo, Coupling, ServoAxis, Setpoint, DAC_MID};
use pkmc_host::control::ident::{self, IdentOptions, Record};
use pkmc_host::control::lqg::{self, LqgWeights};
use pkmc_host::control::plant::TransferFunction;
use pkmc_host::control::tune::{self, PidSpec};
use pkmc_host::machine_file::lqg::LawKind;
use pkmc_host::machine_file::{read_file, DriveKind};

const H: f64 = 1e-4;
const SAMPLES: usize = 10_000;
const AMPLITUDE_MM: f64 = 0.2;
const NOISE_COUNTS: f64 = 0.3;

/// One servo joint of a machine file.
struct Joint {
    names: Vec<String>,
    truth: TransferFunction,
    input_per_count: f64,
    cpu: f64,
    max_velocity: f64,
    gains: ServoGains,
    lqg_gains: Option<LqgGains>,
    weights: Option<LqgWeights>,
}

/// Every distinct servo joint (plant, scale and law) of the example machines.
fn joints() -> Vec<Joint> {
    let mut out: Vec<Joint> = Vec::new();
    for file in ["cartesian-servo", "h4-table", "seed-b", "hexapod-xy"] {
        let path = format!(
            "{}/../examples/machines/{file}.toml",
            env!("CARGO_MANIFEST_DIR")
        );
        let text = std::fs::read_to_string(&path).unwrap();
        let mf = read_file(&text, &path).unwrap();
        let config = mf.to_config().unwrap();
        for jf in &mf.joints {
            if jf.drive != DriveKind::Servo {
                continue;
            }
            let cpu = jf.steps_per_unit;
            let (truth, input_per_count) = match &jf.plant {
                Some(p) => (
                    TransferFunction::new(&p.num, &p.den).unwrap(),
                    p.input_per_count,
                ),
                None => (
                    TransferFunction::new(
                        &[pkmc_host::sim::DEFAULT_PLANT_GAIN / cpu],
                        &[pkmc_host::sim::DEFAULT_PLANT_TAU_S, 1.0, 0.0],
                    )
                    .unwrap(),
                    1.0,
                ),
            };
            let law = jf.servo.as_ref().unwrap().law;
            let name = format!("{file} {}", jf.name);
            let same = |j: &Joint| {
                j.truth == truth && j.cpu == cpu && j.lqg_gains.is_some() == (law == LawKind::Lqg)
            };
            if let Some(j) = out.iter_mut().find(|j| same(j)) {
                j.names.push(name);
                continue;
            }
            out.push(Joint {
                names: vec![name],
                truth,
                input_per_count,
                cpu,
                max_velocity: jf.max_velocity * cpu,
                gains: config.servo.gains[jf.channel as usize],
                lqg_gains: (law == LawKind::Lqg).then(|| jf.lqg_gains.unwrap()),
                weights: jf.lqg,
            });
        }
    }
    out
}

/// SplitMix64 with a Box–Muller normal deviate.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * self.uniform()).cos()
    }
}

/// Closed-loop data of `j`'s true plant under the core's loop (module documentation).
fn record(j: &Joint, seed: u16) -> Record {
    let mut plant = j.truth.discretize(H);
    let mut axis = ServoAxis::new(&j.gains, j.max_velocity as f32);
    let offset = ident::prbs(SAMPLES, 100, seed);
    let mut rng = Rng(seed as u64);
    let mut rec = Record {
        h: H,
        u: Vec::with_capacity(SAMPLES),
        y: Vec::with_capacity(SAMPLES),
    };
    let on = AmpIo {
        enable: true,
        fault: false,
    };
    for r in offset {
        let exact = std::env::var("TUNE_EXACT").is_ok();
        let truep = plant.output(0.0) * j.cpu;
        let noisy = truep + NOISE_COUNTS * rng.normal();
        let counts = noisy.round() as i64;
        let sp = Setpoint {
            position_q16: (r * amplitude(j) * j.cpu * 65_536.0).round() as i64,
            velocity: 0.0,
            accel: 0.0,
        };
        let out = axis.update(&sp, counts, on, Coupling::NONE, j.lqg_gains.as_ref());
        assert_eq!(out.trip, None, "{}", j.names[0]);
        let code = out.dac as i32 - DAC_MID;
        let u = (code - j.gains.dac_offset as i32) as f64 / j.gains.dac_per_unit as f64;
        rec.u.push(u);
        rec.y.push(if exact {
            truep / j.cpu
        } else {
            counts as f64 / j.cpu
        });
        plant.step(code as f64 * j.input_per_count);
    }
    rec
}

/// The excitation's amplitude, mm: a quarter of the standstill following-error limit,
/// at most 0.2 mm.
fn amplitude(j: &Joint) -> f64 {
    (0.25 * j.gains.min_ferror as f64 / j.cpu).min(AMPLITUDE_MM)
}

fn present(g: &ServoGains) -> [f64; 3] {
    [g.kp as f64, g.ki as f64, g.kd as f64]
}

/// The stated crossover of the design, rad/s: near the present loop's.
fn crossover(j: &Joint) -> f64 {
    let f = lqg::pid_loop_figures(&j.truth, j.cpu, H, present(&j.gains)).unwrap();
    f.crossover_rad_s
}

#[test]
fn identified_plants_predict_the_closed_loop_and_their_gains_keep_45_degrees() {
    for (i, j) in joints().iter().enumerate() {
        let rec = record(j, 0x1234 + i as u16);
        let o = IdentOptions {
            min_fit: -1e9,
            ..IdentOptions::default()
        };
        let id = ident::identify(&rec, &o).unwrap();
        println!("amplitude {}", amplitude(j));
        for c in &id.candidates {
            println!("    {c:?}");
        }
        let steps = 2 * SAMPLES;
        let truth = tune::closed_loop_step(&j.truth, j.cpu, H, present(&j.gains), steps);
        let model = tune::closed_loop_step(&id.plant, j.cpu, H, present(&j.gains), steps);
        let err = tune::step_error(&truth, &model, H);
        println!("{}", j.names.join(", "));
        println!(
            "  identified: na {} nb {} nk {}, validation fit {:.1} %, num {:?} den {:?}",
            id.arx.a.len() - 1,
            id.arx.b.len(),
            id.arx.nk,
            id.fit_percent,
            id.plant.num,
            id.plant.den
        );
        println!(
            "  closed-loop step with the present gains: error {:.2} % over the rise (t90 {:.3} s)",
            100.0 * err.ratio,
            err.rise_s
        );
        if err.ratio > 0.10 {
            println!("FAIL step");
        }
        let spec = PidSpec::new(crossover(j));
        let tuned = tune::design_pid(&id.plant, j.cpu, H, &spec).unwrap();
        let on_truth = tune::margins(&j.truth, j.cpu, H, tuned.pid()).unwrap();
        println!(
            "  PID for {:.1} rad/s: kp {:.4e} ki {:.4e} kd {:.4e} kvff {:.4e} kaff {:.4e}",
            spec.crossover_rad_s, tuned.kp, tuned.ki, tuned.kd, tuned.kvff, tuned.kaff
        );
        println!(
            "  margins on the model: PM {:.1}° at {:.1} rad/s, GM {:.1} dB; on the true plant: PM {:.1}° at {:.1} rad/s, GM {:.1} dB, stable {}",
            tuned.margins.phase_margin_deg,
            tuned.margins.phase_margin_at_rad_s,
            tuned.margins.gain_margin_db(),
            on_truth.phase_margin_deg,
            on_truth.phase_margin_at_rad_s,
            on_truth.gain_margin_db(),
            on_truth.stable
        );
        if !(on_truth.stable && on_truth.phase_margin_deg >= 45.0) {
            println!("FAIL PM");
        }
        if let Some(w) = &j.weights {
            let d = lqg::design(&id.plant, j.cpu, H, w).unwrap();
            let f = d.loop_figures(&j.truth, j.cpu).unwrap();
            let reference = lqg::design(&j.truth, j.cpu, H, w).unwrap();
            let g = reference.loop_figures(&j.truth, j.cpu).unwrap();
            println!(
                "  LQG on the identified model, judged on the true plant: |S|max {:.2}, crossover {:.1} rad/s, largest pole {:.6} (designed on the true plant: {:.2}, {:.1} rad/s)",
                f.peak_sensitivity, f.crossover_rad_s, f.max_pole, g.peak_sensitivity, g.crossover_rad_s
            );
            assert!(f.max_pole < 1.0, "{}: {f:?}", j.names[0]);
        }
    }
}
