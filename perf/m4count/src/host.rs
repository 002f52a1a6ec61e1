//! The host run without arguments: the benchmark cases with the host's results, one
//! per line (the formats are in the crate's documentation).

use super::*;
use pkmc::config::{MAX_JOINTS, MAX_SERVOS};
use pkmc::drive::contour::PeriodInputs;
use pkmc::kinematics::POSE_AXES;

struct Lcg(u64);
impl Lcg {
    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        lo + (hi - lo) * ((self.0 >> 11) as f64 / (1u64 << 53) as f64)
    }
}

fn line(parts: &[&[i64]]) -> String {
    let v: Vec<String> = parts
        .iter()
        .flat_map(|p| p.iter().map(|x| x.to_string()))
        .collect();
    v.join(" ")
}

/// H-4 pose from the head point E (mm), θ and A (degrees): the workpiece tool tip
/// whose machine position is E − 80 mm, through the inverse table rotation.
fn h4_pose(e: [f64; 3], theta: f64, a: f64) -> Pose {
    let (r, tool) = ([0.0, 0.0, -130.0], 80.0);
    let t = [e[0], e[1], e[2] - tool];
    let (s, c) = (-a.to_radians()).sin_cos();
    let (dy, dz) = (t[1] - r[1], t[2] - r[2]);
    let p = [t[0], r[1] + c * dy - s * dz, r[2] + s * dy + c * dz];
    let nm = |v: f64| (v * 1e6).round() as i64;
    let nd = |v: f64| (v * 1e9).round() as i64;
    [nm(p[0]), nm(p[1]), nm(p[2]), nd(a), 0, nd(theta)]
}

/// Cases of machine `m`'s kinematics: `n` poses covering its usable workspace, the
/// corners first (H-4: E within ±100 mm, ±50 mm of the home plane, θ ±45°, A 0–90°;
/// hexapod: ±50 mm around (0, 0, 450 mm), A B C ±10°; hexapod-xy: X Y ±40 mm around
/// its home (0, 0, 275 mm), Z ±20 mm, A B ±10°, within every joint's travel).
fn poses(m: u32, rng: &mut Lcg, n: usize) -> Vec<Pose> {
    let mut out = Vec::new();
    if m == 0 {
        out.push(h4_pose([0.0; 3], 0.0, 0.0));
        out.push(h4_pose([100.0, 100.0, 50.0], 45.0, 90.0));
        out.push(h4_pose([-100.0, 100.0, -50.0], -45.0, 45.0));
        out.push(h4_pose([100.0, -100.0, -50.0], 45.0, 0.0));
        while out.len() < n {
            let e = [
                rng.uniform(-100.0, 100.0),
                rng.uniform(-100.0, 100.0),
                rng.uniform(-50.0, 50.0),
            ];
            out.push(h4_pose(e, rng.uniform(-45.0, 45.0), rng.uniform(0.0, 90.0)));
        }
    } else if m == 1 {
        out.push([0, 0, 450_000_000, 0, 0, 0]);
        out.push([
            50_000_000,
            -50_000_000,
            500_000_000,
            10_000_000_000,
            -10_000_000_000,
            10_000_000_000,
        ]);
        while out.len() < n {
            let mut u = |h: f64, s: f64| (rng.uniform(-h, h) * s).round() as i64;
            out.push([
                u(50.0, 1e6),
                u(50.0, 1e6),
                450_000_000 + u(50.0, 1e6),
                u(10.0, 1e9),
                u(10.0, 1e9),
                u(10.0, 1e9),
            ]);
        }
    } else {
        let config = machine(m);
        let kin = MachineKinematics::new(&config);
        let reachable = |p: &Pose| {
            let mut q = [0; MAX_JOINTS];
            kin.inverse_checked(p, &config.joints, &mut q).is_ok()
        };
        out.push([0, 0, 275_000_000, 0, 0, 0]);
        out.push([
            40_000_000,
            -40_000_000,
            290_000_000,
            10_000_000_000,
            -10_000_000_000,
            0,
        ]);
        while out.len() < n {
            let mut u = |h: f64, s: f64| (rng.uniform(-h, h) * s).round() as i64;
            let p = [
                u(40.0, 1e6),
                u(40.0, 1e6),
                275_000_000 + u(20.0, 1e6),
                u(10.0, 1e9),
                u(10.0, 1e9),
                0,
            ];
            if reachable(&p) {
                out.push(p);
            }
        }
        assert!(out.iter().all(reachable), "the hexapod-xy's corners");
    }
    out
}

/// Prints every case: the wire's word counts, then kinematics, `sincos` and `isqrt`,
/// the servo benches and the interpolation periods.
pub fn print_cases() {
    println!(
        "wire {} {} {MAX_SERVOS} {POSE_AXES}",
        wire::INPUT_WORDS,
        wire::OUTPUT_WORDS
    );
    let mut rng = Lcg(2026);
    for m in 0..MACHINES {
        // The hexapod-xy draws from its own sequence: the other machines' cases, and
        // the `sincos` and `isqrt` ones below, stay those of the two-machine harness.
        let mut own = Lcg(2026 + u64::from(m));
        kinematics_cases(m, if m < 2 { &mut rng } else { &mut own });
    }
    let deg = 1_000_000_000i64;
    let mut angles = vec![0, 30 * deg, -100 * deg, 170 * deg, 400 * deg];
    for _ in 0..20 {
        angles.push((rng.uniform(-180.0, 180.0) * 1e9) as i64);
    }
    for a in angles {
        let (s, c) = sincos(a);
        println!("sincos {a} {s} {c}");
    }
    let mut values = vec![0u64, 1, 226_400_000_000_000_000 * 16, 1 << 40];
    for _ in 0..20 {
        values.push(rng.uniform(1e16, 4.8e18) as u64);
    }
    for n in values {
        println!("isqrt {n} {}", isqrt(n));
    }
    servo_cases();
    pacer_cases();
    period_cases();
}

/// Machine `m`'s inverse kinematics at 200 poses, and forward kinematics at 40.
fn kinematics_cases(m: u32, rng: &mut Lcg) {
    let kin = MachineKinematics::new(&machine(m));
    for p in poses(m, rng, 200) {
        let mut q = [0; MAX_JOINTS];
        let rc = match kin.inverse(&p, &mut q) {
            Ok(()) => 0,
            Err(e) => code(e),
        };
        println!("ik {m} {} {rc} {}", line(&[&p]), line(&[&q]));
    }
    // Forward from the previous 1 ms period: 200 mm/s along a random direction,
    // 90 °/s on each angle the machine moves (H-4: C; hexapod: A B C; hexapod-xy: A B).
    for p in poses(m, rng, 40) {
        let mut q = [0; MAX_JOINTS];
        kin.inverse(&p, &mut q).expect("the cases are reachable");
        let d = [
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
        ];
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let mut g = p;
        for k in 0..3 {
            g[k] -= (200_000.0 * d[k] / norm).round() as i64;
        }
        let turning: &[usize] = match m {
            0 => &[5],
            1 => &[3, 4, 5],
            _ => &[3, 4],
        };
        for &k in turning {
            g[k] -= 90_000_000;
        }
        let mut out = [0; 6];
        let rc = match kin.forward_counted(&q, &g, &mut out) {
            Ok(n) => n as i32,
            Err(e) => code(e),
        };
        println!("fk {m} {} {rc} {}", line(&[&q, &g]), line(&[&out]));
    }
}

/// The ten periods of each servo bench's tick. Every one must take the coupled path:
/// a contour error that is not zero.
fn servo_cases() {
    for b in 0..servo::BENCHES {
        let mut bank = servo::bank(b);
        for k in 0..10i64 {
            let f = servo::feedback(b, k);
            let o = bank.period(&PeriodInputs {
                feedback: f,
                fault: [false; MAX_SERVOS],
                enable: true,
            });
            assert!(
                o.contour_error.iter().any(|e| *e != 0.0),
                "servo bench {b}, period {k}: no contour error (the coupled path is not taken)"
            );
            let d = o.dac.map(i64::from);
            let e = o.contour_error.map(|e| i64::from(e.to_bits()));
            println!("servo {b} {k} {}", line(&[&f, &d, &e]));
        }
    }
}

/// The ten periods of each pacer bench's tick, then the samples it staged.
fn pacer_cases() {
    for b in 0..pacer::BENCHES {
        let mut p = pacer::pacer(b);
        let bench = pacer::servo_bench(b);
        let mut f = [0; MAX_SERVOS];
        for k in 0..10i64 {
            f = servo::feedback(bench, k);
            let o = p.period(&f);
            let d = o.dac.map(i64::from);
            let e = o.contour_error.map(|e| i64::from(e.to_bits()));
            println!("pacer {b} {k} {}", line(&[&f, &d, &e]));
        }
        let staged = pacer::finish(&mut p, &f);
        let ids = staged.ids.map(i64::from);
        // The packed samples as the script reads the emulated memory: words.
        let rows: Vec<i64> = staged
            .rows
            .iter()
            .flat_map(|r| r.chunks_exact(4))
            .map(|w| i64::from(i32::from_le_bytes([w[0], w[1], w[2], w[3]])))
            .collect();
        assert!(
            b % 2 == 0 || rows.iter().any(|&v| v != 0),
            "pacer bench {b}: nothing staged"
        );
        println!("staged {b} {}", line(&[&ids, &rows]));
    }
}

/// Interpolation periods on the arc, after the warm-up.
fn period_cases() {
    let machine = MachineConfig::h4_table();
    let kin = MachineKinematics::new(&machine);
    let mut planner = pkmc::motion::planner::Planner::new(machine.home);
    let mut exec = pkmc::motion::interp::Executor::new(machine.home);
    let blocks = period_blocks(machine.home);
    let mut plans = [pkmc::motion::planner::PlanBlock::default(); 2];
    let _ = pkmc::motion::planner::plan_into(&blocks, machine.home, &machine, &kin, 1, &mut plans);
    for (b, plan) in blocks.iter().zip(&plans) {
        let planned = pkmc::motion::block::PlannedBlock {
            block: *b,
            plan: plan.plan(),
        };
        let _ = planner.push_planned(&planned, &machine, &kin);
    }
    for _ in 0..PERIOD_WARMUP {
        exec.tick(&mut planner);
    }
    for k in 0..20i64 {
        exec.tick(&mut planner);
        let mut q: Joints = [0; MAX_JOINTS];
        let rc = match kin.inverse(&exec.pose, &mut q) {
            Ok(()) => 0,
            Err(e) => code(e) as i64,
        };
        println!("period {k} {rc} {}", line(&[&q]));
    }
}
