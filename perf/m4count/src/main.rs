//! Cortex-M4 instruction counts of the kinematics, the servo period and whole controller
//! calls: the measured functions behind C-ABI entry points.
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
//!
//! Whole controller calls: `bench_ctrl_init` builds a real [`Controller`] in emulated
//! RAM; `bench_ctrl_receive`, `bench_ctrl_tick` and `bench_ctrl_transmit` each make one
//! whole call of the core's `receive`, `tick` or `transmit` (the counted calls);
//! `bench_ctrl_inputs` and `bench_ctrl_outputs` convert a tick's inputs and outputs
//! from and to the flat words of [`wire`] (not counted). The calls to replay come from
//! the host build run with `--record DIR`, which streams whole programs through
//! `nc-send`'s link client to the simulator and logs every call (`src/record.rs`).
#![cfg_attr(target_os = "none", no_std, no_main)]

use pkmc::config::MachineConfig;
use pkmc::contour::{PeriodInputs, ServoBank};
use pkmc::controller::{Controller, Inputs, Outputs};
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
pub const PERIOD_BYTES: usize = 96 * 1024;
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
        // Planned as the host plans them, then queued as the controller queues them.
        let blocks = period_blocks(home);
        let mut plans = [pkmc::planner::PlanBlock::default(); 2];
        let _ = pkmc::planner::plan_into(&blocks, home, &p.machine, &p.kin, 1, &mut plans);
        for (b, plan) in blocks.iter().zip(&plans) {
            let planned = pkmc::protocol::PlannedBlock {
                block: *b,
                plan: plan.plan(),
            };
            let _ = p.planner.push_planned(&planned, &p.machine, &p.kin);
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

/// Bytes the emulator reserves for one [`Controller`] (`.ci/m4count.py` checks
/// [`bench_ctrl_size`] against its own reserve).
pub const CTRL_BYTES: usize = 192 * 1024;
const _: () = assert!(core::mem::size_of::<Controller>() <= CTRL_BYTES);

/// `size_of::<Controller>()`, for the emulator's memory map.
#[no_mangle]
pub extern "C" fn bench_ctrl_size() -> u32 {
    core::mem::size_of::<Controller>() as u32
}

/// Builds the controller of machine `m` into `out` (not timed), with the link-loss
/// watch off as `nc-send --check` runs it (`pkmc_host::link::InProcess`); returns 0,
/// or −1 if the controller refuses the machine.
///
/// # Safety
/// `out` must be valid for writing [`CTRL_BYTES`] bytes, 8-aligned.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_init(m: u32, out: *mut Controller) -> i32 {
    match Controller::new(machine(m)) {
        Ok(mut c) => {
            c.set_link_watch(false);
            // SAFETY: the caller provides room and alignment.
            unsafe { out.write(c) };
            0
        }
        Err(_) => -1,
    }
}

/// One whole `Controller::receive` call: the bytes of one USB packet.
///
/// # Safety
/// `c` from [`bench_ctrl_init`]; `bytes` valid for `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_receive(c: *mut Controller, bytes: *const u8, len: usize) {
    // SAFETY: the caller passes valid pointers.
    unsafe { (*c).receive(core::slice::from_raw_parts(bytes, len)) }
}

/// One whole `Controller::tick` call; returns the controller's outputs (read by
/// [`bench_ctrl_outputs`], outside the count).
///
/// # Safety
/// `c` from [`bench_ctrl_init`]; `inputs` from [`bench_ctrl_inputs`].
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_tick(
    c: *mut Controller,
    inputs: *const Inputs,
) -> *const Outputs {
    // SAFETY: the caller passes valid pointers.
    unsafe { (*c).tick(&*inputs) }
}

/// One whole `Controller::transmit` call into `out[..len]`; returns the bytes written.
///
/// # Safety
/// `c` from [`bench_ctrl_init`]; `out` valid for `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_transmit(
    c: *mut Controller,
    out: *mut u8,
    len: usize,
) -> usize {
    // SAFETY: the caller passes valid pointers.
    unsafe { (*c).transmit(core::slice::from_raw_parts_mut(out, len)) }
}

/// Rebuilds a tick's [`Inputs`] from the log's words (not timed).
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_inputs(
    words: *const [i64; wire::INPUT_WORDS],
    out: *mut Inputs,
) {
    // SAFETY: the caller passes valid pointers.
    unsafe { out.write(wire::inputs_from(&*words)) }
}

/// Flattens a tick's [`Outputs`] into words, as the host logged its own (not timed).
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_outputs(
    outputs: *const Outputs,
    words: *mut [i64; wire::OUTPUT_WORDS],
) {
    // SAFETY: the caller passes valid pointers.
    unsafe { *words = wire::outputs_words(&*outputs) }
}

/// The controller's tick inputs and outputs as flat `i64` words: the form in which the
/// host logs them and the emulator passes and compares them. Every field is named
/// (no `..`): a field added to [`Inputs`] or [`Outputs`] stops this from compiling
/// until the harness carries it.
pub mod wire {
    use pkmc::config::{MAX_SERVOS, MAX_STEPPERS};
    use pkmc::controller::{Inputs, Outputs};
    use pkmc::servo::Trip;
    use pkmc::stepper::StepTrain;

    /// Words of one [`Inputs`]: encoder counts, index (flag, count) per servo channel,
    /// e-stop, limit, home and drive-fault bits, trip (code, error, limit) per channel.
    pub const INPUT_WORDS: usize = MAX_SERVOS + 2 * MAX_SERVOS + 4 + 3 * MAX_SERVOS;
    /// Words of one [`Outputs`]: five per step train, the servo targets, three flags.
    pub const OUTPUT_WORDS: usize = 5 * MAX_STEPPERS + MAX_SERVOS + 3;

    /// `inputs` as words.
    pub fn inputs_words(inputs: &Inputs) -> [i64; INPUT_WORDS] {
        let Inputs {
            encoder_counts,
            index,
            estop,
            limit,
            home,
            drive_fault,
            servo_trip,
        } = *inputs;
        let mut w = [0; INPUT_WORDS];
        let mut k = 0;
        let mut put = |v: i64| {
            w[k] = v;
            k += 1;
        };
        for c in encoder_counts {
            put(c);
        }
        for i in index {
            put(i.is_some() as i64);
            put(i.unwrap_or(0));
        }
        put(estop as i64);
        put(limit as i64);
        put(home as i64);
        put(drive_fault as i64);
        for t in servo_trip {
            let (code, error, limit) = match t {
                None => (0, 0, 0),
                Some(Trip::FollowingError { error, limit }) => (1, error, limit),
                Some(Trip::AmplifierFault) => (2, 0, 0),
                // A kind this harness does not know: no rebuilt input equals it, so the
                // recording's round-trip check fails and names it.
                Some(_) => (-1, 0, 0),
            };
            put(code);
            put(error as i64);
            put(limit as i64);
        }
        w
    }

    /// The [`Inputs`] that [`inputs_words`] flattened.
    pub fn inputs_from(w: &[i64; INPUT_WORDS]) -> Inputs {
        let s = MAX_SERVOS;
        Inputs {
            encoder_counts: core::array::from_fn(|c| w[c]),
            index: core::array::from_fn(|c| (w[s + 2 * c] != 0).then_some(w[s + 2 * c + 1])),
            estop: w[3 * s] != 0,
            limit: w[3 * s + 1] as u16,
            home: w[3 * s + 2] as u16,
            drive_fault: w[3 * s + 3] as u16,
            servo_trip: core::array::from_fn(|c| {
                let t = 3 * s + 4 + 3 * c;
                match w[t] {
                    1 => Some(Trip::FollowingError {
                        error: w[t + 1] as i32,
                        limit: w[t + 2] as i32,
                    }),
                    2 => Some(Trip::AmplifierFault),
                    _ => None,
                }
            }),
        }
    }

    /// `outputs` as words.
    pub fn outputs_words(outputs: &Outputs) -> [i64; OUTPUT_WORDS] {
        let Outputs {
            steps,
            servo_target,
            enable,
            servo_enable,
            servo_reset,
        } = *outputs;
        let mut w = [0; OUTPUT_WORDS];
        for (c, t) in steps.iter().enumerate() {
            let StepTrain {
                count,
                forward,
                first_edge_ns,
                interval_ns,
                pulse_ns,
            } = *t;
            w[5 * c..5 * c + 5].copy_from_slice(&[
                count as i64,
                forward as i64,
                first_edge_ns as i64,
                interval_ns as i64,
                pulse_ns as i64,
            ]);
        }
        let s = 5 * MAX_STEPPERS;
        w[s..s + MAX_SERVOS].copy_from_slice(&servo_target);
        w[s + MAX_SERVOS] = enable as i64;
        w[s + MAX_SERVOS + 1] = servo_enable as i64;
        w[s + MAX_SERVOS + 2] = servo_reset as i64;
        w
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
mod record;

/// Without arguments: prints the benchmark cases with the host's results. With
/// `--record DIR`: runs the whole programs through `nc-send`'s link client against the
/// simulated controller, writes one call log per program into DIR and prints one line
/// per program (see [`record`]).
#[cfg(not(target_os = "none"))]
fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.as_slice() {
        [] => host::print_cases(),
        [flag, dir] if flag == "--record" => {
            if let Err(e) = record::record_all(std::path::Path::new(dir)) {
                eprintln!("pkmc-m4count: {e}");
                std::process::exit(1);
            }
        }
        _ => {
            eprintln!("usage: pkmc-m4count [--record DIR]");
            std::process::exit(2);
        }
    }
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
        let blocks = period_blocks(machine.home);
        let mut plans = [pkmc::planner::PlanBlock::default(); 2];
        let _ = pkmc::planner::plan_into(&blocks, machine.home, &machine, &kin, 1, &mut plans);
        for (b, plan) in blocks.iter().zip(&plans) {
            let planned = pkmc::protocol::PlannedBlock {
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
}
