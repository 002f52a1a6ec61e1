//! Cortex-M4 instruction counts of the kinematics: the measured functions behind C-ABI
//! entry points.
//!
//! For `thumbv7em-none-eabihf` this is a `no_std`, `no_main` image with no start-up
//! code: `.ci/m4count.py` loads it into the unicorn emulator and calls the `bench_*`
//! functions with pointers into emulated RAM, counting executed instructions. Built for
//! the host, `main` prints the benchmark cases with the host's results, one per line,
//! so the script can check that every counted run computed exactly the host's answer.
//!
//! Line formats (integers separated by spaces):
//! `ik M p0..p5 rc q0..q10`, `fk M q0..q10 g0..g5 rc p0..p5`, `sincos a s c`,
//! `isqrt n r`, `servo k f0..f3 d0..d3`; M = 0 for the H-4 with rolling table, 1 for
//! the hexapod; rc = 0 or the iteration count, negative for an `Unreachable` reason;
//! servo: period k of a tick, encoder feedback f, DAC codes d.
#![cfg_attr(target_os = "none", no_std, no_main)]

use pkmc::config::MachineConfig;
use pkmc::contour::{PeriodInputs, ServoBank};
use pkmc::kinematics::fixed::{isqrt, sincos};
use pkmc::kinematics::{Joints, Kinematics, MachineKinematics, Pose, Unreachable};

/// Bytes the emulator reserves for one [`MachineKinematics`].
pub const KIN_BYTES: usize = 1024;
const _: () = assert!(core::mem::size_of::<MachineKinematics>() <= KIN_BYTES);

fn code(e: Unreachable) -> i32 {
    match e {
        Unreachable::OutOfReach => -1,
        Unreachable::JointLimit { .. } => -2,
        Unreachable::Singular => -3,
        Unreachable::NoConvergence => -4,
        _ => -5,
    }
}

fn machine(m: u32) -> MachineConfig {
    if m == 0 {
        MachineConfig::h4_table()
    } else {
        MachineConfig::hexapod()
    }
}

/// Builds machine `m`'s kinematics into `out` (not timed).
///
/// # Safety
/// `out` must be valid for writing [`KIN_BYTES`] bytes, 8-aligned.
#[no_mangle]
pub unsafe extern "C" fn bench_init(m: u32, out: *mut MachineKinematics) {
    // SAFETY: the caller provides room and alignment.
    unsafe { out.write(MachineKinematics::new(&machine(m))) }
}

/// Inverse kinematics, as the controller calls it every period.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_ik(
    kin: *const MachineKinematics,
    pose: *const Pose,
    joints: *mut Joints,
) -> i32 {
    // SAFETY: the caller passes valid pointers.
    let (kin, pose, joints) = unsafe { (&*kin, &*pose, &mut *joints) };
    match kin.inverse(pose, joints) {
        Ok(()) => 0,
        Err(e) => code(e),
    }
}

/// Forward kinematics from a guess; returns the iterations.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_fk(
    kin: *const MachineKinematics,
    joints: *const Joints,
    guess: *const Pose,
    pose: *mut Pose,
) -> i32 {
    // SAFETY: the caller passes valid pointers.
    let (kin, joints, guess, pose) = unsafe { (&*kin, &*joints, &*guess, &mut *pose) };
    match kin.forward_counted(joints, guess, pose) {
        Ok(n) => n as i32,
        Err(e) => code(e),
    }
}

/// Q30 sine and cosine of `*angle` (n°) into `out[0..2]`.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_sincos(angle: *const i64, out: *mut [i32; 2]) {
    // SAFETY: the caller passes valid pointers.
    unsafe {
        let (s, c) = sincos(*angle);
        *out = [s, c];
    }
}

/// Correctly rounded square root of `*n` into `*out`.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_isqrt(n: *const u64, out: *mut u64) {
    // SAFETY: the caller passes valid pointers.
    unsafe { *out = isqrt(*n) }
}

/// Bytes the emulator reserves for one [`ServoBank`].
pub const BANK_BYTES: usize = 2048;
const _: () = assert!(core::mem::size_of::<ServoBank>() <= BANK_BYTES);

/// Four servo channels: X, Y, Z coupled by CCPM with `seed-b`'s gains (docs/contour.md),
/// a fourth (rotary A) uncoupled; 1 µm per count.
fn servo_machine() -> MachineConfig {
    use pkmc::config::{ContourConfig, ContourMode, Drive, KinematicsConfig, Scale, ServoGains};
    let mut m = MachineConfig::cartesian_xyz();
    let g = ServoGains {
        kp: 0.1,
        ki: 1.6,
        kd: 3.0e-4,
        kvff: 5.4632e-3,
        kaff: -8.6924e-5,
        max_output: 200.0,
        max_integral: 200.0,
        dac_per_unit: 10.0,
        dac_offset: 0,
        ferror: 2000,
        min_ferror: 1000,
    };
    for (c, j) in m.joints.iter_mut().enumerate() {
        j.drive = Drive::Servo { channel: c as u8 };
        j.scale = Scale::new(1000, 1_000_000);
    }
    let mut a = m.joints[0];
    a.rotary = true;
    a.drive = Drive::Servo { channel: 3 };
    let _ = m.joints.push(a);
    if let KinematicsConfig::Cartesian { axis_of_joint } = &mut m.kinematics {
        axis_of_joint[3] = 3;
    }
    m.servo.gains = [g; 4];
    m.servo.contour = ContourConfig {
        mode: ContourMode::Ccpm,
        kp: 200.0,
        ki: 1000.0,
        max_integral: 50.0,
        kr: 20.0,
        max_offset: 0.5,
    };
    m
}

/// A servo bank at rest with one tick's targets loaded (not timed).
fn servo_bank() -> ServoBank {
    let mut bank = ServoBank::new(&servo_machine(), &[0, 0, 260_000, 0]);
    bank.load_tick(&[
        (10 << 16) + 123,
        (3 << 16) + 77,
        (260_003 << 16) + 5,
        2 << 16,
    ]);
    bank
}

/// Builds the servo bank into `out` (not timed).
///
/// # Safety
/// `out` must be valid for writing [`BANK_BYTES`] bytes, 8-aligned.
#[no_mangle]
pub unsafe extern "C" fn bench_servo_init(out: *mut ServoBank) {
    // SAFETY: the caller provides room and alignment.
    unsafe { out.write(servo_bank()) }
}

/// One 10 kHz servo period of the four channels with CCPM, given the encoder
/// feedback; the DAC codes into `dac`.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_servo_ccpm_4axes(
    bank: *mut ServoBank,
    feedback: *const [i64; 4],
    dac: *mut [u16; 4],
) {
    // SAFETY: the caller passes valid pointers.
    unsafe {
        let inputs = PeriodInputs {
            feedback: *feedback,
            fault: [false; 4],
            enable: true,
        };
        *dac = (*bank).period(&inputs).dac;
    }
}

/// One whole interpolation period on the H-4 with rolling table: the look-ahead
/// executor (profile and exact arc), then the table transform and inverse kinematics
/// of the new pose.
pub struct Period {
    machine: MachineConfig,
    kin: MachineKinematics,
    planner: pkmc::planner::Planner,
    exec: pkmc::interp::Executor,
}

/// Bytes the emulator reserves for one [`Period`].
pub const PERIOD_BYTES: usize = 64 * 1024;
const _: () = assert!(core::mem::size_of::<Period>() <= PERIOD_BYTES);
/// Ticks run before the measured ones: the head is then on the arc, at its feed.
pub const PERIOD_WARMUP: u32 = 1600;
/// Ticks per warm-up call (keeps each emulated call short).
pub const PERIOD_CHUNK: u32 = 200;

/// A helical arc at a 30° table angle: a line from home to the arc start (turning the
/// table), then a full clockwise circle of 30 mm radius, both at 40 mm/s.
fn period_blocks(home: Pose) -> [pkmc::protocol::Block; 2] {
    use pkmc::protocol::{Block, Motion, Plane};
    let mut start = home;
    start[0] += 30_000_000;
    start[3] = 30_000_000_000;
    let line = Block {
        line: 1,
        motion: Motion::Linear,
        target: start,
        feed: 40_000_000,
        tolerance_nm: u32::MAX,
    };
    let mut end = start;
    end[2] -= 2_000_000;
    let arc = Block {
        line: 2,
        motion: Motion::Arc {
            center: [home[0], home[1]],
            plane: Plane::Xy,
            clockwise: true,
            turns: 0,
        },
        target: end,
        feed: 40_000_000,
        tolerance_nm: u32::MAX,
    };
    [line, arc]
}

/// Builds the period benchmark in place (not timed).
///
/// # Safety
/// `out` must be valid for writing [`PERIOD_BYTES`] bytes, 8-aligned.
#[no_mangle]
pub unsafe extern "C" fn bench_period_init(out: *mut Period) {
    let machine = MachineConfig::h4_table();
    let home = machine.home;
    // SAFETY: the caller provides room; fields are written one at a time so that no
    // whole `Period` is ever built on the stack.
    unsafe {
        core::ptr::addr_of_mut!((*out).kin).write(MachineKinematics::new(&machine));
        core::ptr::addr_of_mut!((*out).planner).write(pkmc::planner::Planner::new(home));
        core::ptr::addr_of_mut!((*out).exec).write(pkmc::interp::Executor::new(home));
        core::ptr::addr_of_mut!((*out).machine).write(machine);
        let p = &mut *out;
        for b in period_blocks(home) {
            let _ = p.planner.push(&b, &p.machine, &p.kin);
        }
    }
}

/// Runs `n` periods without measuring them (warm-up).
///
/// # Safety
/// `p` from [`bench_period_init`].
#[no_mangle]
pub unsafe extern "C" fn bench_period_advance(p: *mut Period, n: u32) {
    // SAFETY: the caller passes a built benchmark.
    let p = unsafe { &mut *p };
    for _ in 0..n {
        p.exec.tick(&mut p.planner);
    }
}

/// One interpolation period: profile, arc, table and inverse kinematics; the joints
/// into `joints`.
///
/// # Safety
/// `p` from [`bench_period_init`]; `joints` valid.
#[no_mangle]
pub unsafe extern "C" fn bench_period(p: *mut Period, joints: *mut Joints) -> i32 {
    // SAFETY: the caller passes valid pointers.
    let (p, joints) = unsafe { (&mut *p, &mut *joints) };
    p.exec.tick(&mut p.planner);
    match p.kin.inverse(&p.exec.pose, joints) {
        Ok(()) => 0,
        Err(e) => code(e),
    }
}

#[cfg(target_os = "none")]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    // An undefined instruction stops the emulator with an error.
    // SAFETY: `udf` only traps.
    unsafe { core::arch::asm!("udf #0", options(noreturn)) }
}

#[cfg(not(target_os = "none"))]
fn main() {
    host::print_cases();
}

#[cfg(not(target_os = "none"))]
mod host {
    use super::*;
    use pkmc::config::MAX_JOINTS;

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
        } else {
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
        }
        out
    }

    pub fn print_cases() {
        let mut rng = Lcg(2026);
        for m in 0..2u32 {
            let kin = MachineKinematics::new(&machine(m));
            for p in poses(m, &mut rng, 200) {
                let mut q = [0; MAX_JOINTS];
                let rc = match kin.inverse(&p, &mut q) {
                    Ok(()) => 0,
                    Err(e) => code(e),
                };
                println!("ik {m} {} {rc} {}", line(&[&p]), line(&[&q]));
            }
            // Forward from the previous 1 ms period: 200 mm/s along a random direction,
            // 90 °/s on each angle the machine moves (H-4: C; hexapod: A B C).
            for p in poses(m, &mut rng, 40) {
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
                let turning: &[usize] = if m == 0 { &[5] } else { &[3, 4, 5] };
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
        let mut bank = servo_bank();
        for k in 0..10i64 {
            let f = [k, -k / 2, 260_000 + k / 3, 0];
            let d = bank
                .period(&PeriodInputs {
                    feedback: f,
                    fault: [false; 4],
                    enable: true,
                })
                .dac;
            let d = d.map(i64::from);
            println!("servo {k} {} {}", line(&[&f]), line(&[&d]));
        }
        // Interpolation periods on the arc, after the warm-up.
        let machine = MachineConfig::h4_table();
        let kin = MachineKinematics::new(&machine);
        let mut planner = pkmc::planner::Planner::new(machine.home);
        let mut exec = pkmc::interp::Executor::new(machine.home);
        for b in period_blocks(machine.home) {
            let _ = planner.push(&b, &machine, &kin);
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
}
