//! Cortex-M4 instruction counts of the kinematics, the servo period and whole controller
//! calls: the measured functions behind C-ABI entry points.
//!
//! For `thumbv7em-none-eabihf` this is a `no_std`, `no_main` image with no start-up
//! code: `.ci/m4count.py` loads it into the unicorn emulator and calls the `bench_*`
//! functions with pointers into emulated RAM, counting executed instructions. Built for
//! the host, `main` prints the benchmark cases with the host's results, one per line,
//! so the script can check that every counted run computed exactly the host's answer
//! ([`host`]).
//!
//! Line formats (integers separated by spaces): first `wire I O S P`, the word counts
//! of [`wire`] (I inputs, O outputs), `MAX_SERVOS` and `POSE_AXES`; then
//! `ik M p0..p5 rc q0..q10`, `fk M q0..q10 g0..g5 rc p0..p5`, `sincos a s c`,
//! `isqrt n r`, `servo B k f0..f(S-1) d0..d(S-1) e0..e(P-1)`,
//! `pacer P k f0..f(S-1) d0..d(S-1) e0..e(P-1)`, `staged P i0..i7 v0..v79`,
//! `period k rc q0..q10`.
//! M is the machine ([`machine`]: 0 the H-4 with rolling table, 1 the hexapod, 2 the
//! hexapod-xy); rc = 0 or the iteration count, negative for an `Unreachable` reason;
//! servo: bench B ([`servo`]), period k of its tick, encoder feedback f, DAC codes d,
//! contour error e (`f32` bits); pacer: bench P ([`pacer`]), as servo, then the
//! tick's staged samples: the recorder's servo-side ids i and ten periods' values v.
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
use pkmc::controller::{Controller, Inputs, Outputs};
use pkmc::drive::recorder::MAX_SIGNALS;
use pkmc::kinematics::fixed::{isqrt, sincos};
use pkmc::kinematics::{Joints, Kinematics, MachineKinematics, Pose, Unreachable};

pub mod pacer;
pub mod servo;
pub mod wire;

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

/// The measured machines, by index: 0 the H-4 with rolling table, 1 the hexapod, 2
/// the hexapod-xy (each checked equal to its file in `examples/machines`, see
/// [`record`]).
pub const MACHINES: u32 = 3;

/// Machine `m` (below [`MACHINES`]).
fn machine(m: u32) -> MachineConfig {
    match m {
        0 => MachineConfig::h4_table(),
        1 => MachineConfig::hexapod(),
        2 => MachineConfig::hexapod_xy(),
        _ => panic!("no such machine"),
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

/// `*a / *b` in `u128` into `*out`: the canary of the script's detector of LLVM's
/// inline 128-bit division loop (never counted; the script checks it is seen).
///
/// # Safety
/// Valid, aligned pointers; `*b` not zero.
#[no_mangle]
pub unsafe extern "C" fn bench_wide_division(a: *const u128, b: *const u128, out: *mut u128) {
    // SAFETY: the caller passes valid pointers.
    unsafe { *out = core::hint::black_box(*a) / core::hint::black_box(*b) }
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

/// One whole interpolation period on the H-4 with rolling table: the look-ahead
/// executor (profile and exact arc), then the table transform and inverse kinematics
/// of the new pose.
pub struct Period {
    machine: MachineConfig,
    kin: MachineKinematics,
    planner: pkmc::motion::planner::Planner,
    exec: pkmc::motion::interp::Executor,
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
fn period_blocks(home: Pose) -> [pkmc::motion::block::Block; 2] {
    use pkmc::motion::block::{Block, Motion, Plane};
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
        core::ptr::addr_of_mut!((*out).planner).write(pkmc::motion::planner::Planner::new(home));
        core::ptr::addr_of_mut!((*out).exec).write(pkmc::motion::interp::Executor::new(home));
        core::ptr::addr_of_mut!((*out).machine).write(machine);
        let p = &mut *out;
        // Planned as the host plans them, then queued as the controller queues them.
        let blocks = period_blocks(home);
        let mut plans = [pkmc::motion::planner::PlanBlock::default(); 2];
        let _ = pkmc::motion::planner::plan_into(&blocks, home, &p.machine, &p.kin, 1, &mut plans);
        for (b, plan) in blocks.iter().zip(&plans) {
            let planned = pkmc::motion::block::PlannedBlock {
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

/// Bytes the emulator reserves for one tick's [`Inputs`].
pub const INPUTS_BYTES: usize = 2048;
const _: () = assert!(core::mem::size_of::<Inputs>() <= INPUTS_BYTES);

/// The image's [`wire`] word counts, inputs in the low half, outputs in the high half
/// (`.ci/m4count.py` checks them against the host's `wire` line).
#[no_mangle]
pub extern "C" fn bench_wire_words() -> u32 {
    (wire::INPUT_WORDS | wire::OUTPUT_WORDS << 16) as u32
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

/// One whole `Controller::record_servo` call: the servo side's samples of `n`
/// periods (`rows`) of the signals `ids`, as the firmware hands them over after a
/// tick, under the same lock (`src/bin/firmware/main.rs`, `on_tick`).
///
/// # Safety
/// `c` from [`bench_ctrl_init`]; `ids` valid; `rows` valid for `n` rows.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_record_servo(
    c: *mut Controller,
    ids: *const [u8; MAX_SIGNALS],
    rows: *const pkmc::drive::recorder::Row,
    n: usize,
) {
    // SAFETY: the caller passes valid pointers.
    unsafe { (*c).record_servo(&*ids, core::slice::from_raw_parts(rows, n)) }
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

/// Flattens a tick's [`Outputs`] and the contour map it completed (if any) into
/// words, as the host logged its own (not timed).
///
/// # Safety
/// Valid, aligned pointers: `outputs` as [`bench_ctrl_tick`] returned it, `c` its
/// controller.
#[no_mangle]
pub unsafe extern "C" fn bench_ctrl_outputs(
    outputs: *const Outputs,
    c: *const Controller,
    words: *mut [i64; wire::OUTPUT_WORDS],
) {
    // SAFETY: the caller passes valid pointers.
    unsafe { *words = wire::outputs_words(&*outputs, (*c).contour_map()) }
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
mod host;
#[cfg(not(target_os = "none"))]
mod programs;
