//! Servo-period benchmarks: one 10 kHz [`ServoBank::period_into`] of a whole bank (every
//! channel's setpoint interpolator and loop and their contour coupling), with a tick's
//! targets loaded and the contour controller active. The benches, by index
//! ([`bench_servo_init`]'s `bench`, the `servo B …` lines of the host run):
//!
//! * 0, `servo_ccpm_4axes`: a Cartesian bank of four channels, X Y Z coupled by CCPM
//!   through the constant map ([`ccpm_4axes_machine`]);
//! * 1, `servo_hexapod_xy_8ch`: the hexapod-xy's bank, six legs and the table's X and Y,
//!   CCPM through the channel map the controller computes each tick at the commanded
//!   pose ([`hexapod_xy_machine`], [`hexapod_xy_bank`]).
//!
//! Each bench's cases are the ten periods of one tick, the encoder feedback lagging the
//! setpoints by a few counts so that the contour error is not zero (the host run
//! checks it: the counted periods take the coupled path).

use pkmc::config::{Drive, MachineConfig, MAX_JOINTS, MAX_SERVOS};
use pkmc::drive::contour::{PeriodOutputs, ServoBank};
use pkmc::drive::servo::target_q16;
use pkmc::kinematics::{ContourMap, POSE_AXES};
use pkmc::kinematics::{Kinematics, MachineKinematics, Pose};

/// A bank and the outputs it keeps from one period to the next, as the servo
/// interrupt keeps them ([`ServoBank::period_into`], `ServoPacer`).
#[repr(C)]
pub struct BenchBank {
    bank: ServoBank,
    out: PeriodOutputs,
}

/// Bytes the emulator reserves for one [`BenchBank`].
pub const BANK_BYTES: usize = 4096;
const _: () = assert!(core::mem::size_of::<BenchBank>() <= BANK_BYTES);

/// The benches (see the module documentation).
pub const BENCHES: u32 = 2;

/// Four servo channels: X, Y, Z coupled by CCPM with `seed-b`'s gains (docs/contour.md),
/// a fourth (rotary A) uncoupled; 1 µm per count. The bank's other channels are unused.
pub fn ccpm_4axes_machine() -> MachineConfig {
    use pkmc::config::{ContourConfig, ContourMode, KinematicsConfig, Scale, ServoGains};
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
    m.servo.gains = [ServoGains::NONE; MAX_SERVOS];
    m.servo.gains[..4].copy_from_slice(&[g; 4]);
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

/// `v` on the first channels, zero on the rest.
pub fn channels(v: &[i64]) -> [i64; MAX_SERVOS] {
    let mut out = [0; MAX_SERVOS];
    out[..v.len()].copy_from_slice(v);
    out
}

/// The four-channel bench's tick targets, counts × 2^16.
pub fn ccpm_4axes_targets() -> [i64; MAX_SERVOS] {
    channels(&[
        (10 << 16) + 123,
        (3 << 16) + 77,
        (260_003 << 16) + 5,
        2 << 16,
    ])
}

/// The four-channel bank at rest with one tick's targets loaded.
fn ccpm_4axes_bank() -> ServoBank {
    let mut bank = ServoBank::new(&ccpm_4axes_machine(), &channels(&[0, 0, 260_000, 0]));
    bank.load_tick(&ccpm_4axes_targets());
    bank
}

/// The hexapod-xy as built in: its own loops on the eight channels (`seed-b`'s PIDs
/// with velocity and acceleration feed-forward on the six legs and on the table's X
/// and Y) and its CCPM. The bench measures whatever law the machine's configuration
/// gives each channel: when [`ServoBank`] runs the LQG law for the legs, switching the
/// six legs to it is a change of this configuration only (here, or in
/// `MachineConfig::hexapod_xy()` itself); nothing else in the bench changes.
pub fn hexapod_xy_machine() -> MachineConfig {
    MachineConfig::hexapod_xy()
}

/// Three successive ticks (1 ms apart) on report B's tilting helix
/// (`examples/helix-b-tilt.ngc`) at t = 2.500, 2.501 and 2.502 s: X = t cos t,
/// Y = t sin t, Z = 3t + 260 mm, A = 10 sin(πt/5)°, B = 10 sin(πt/10)° (nm, n°). About
/// 4 mm/s along the path: the table, every leg and the tool axis move.
pub const HELIX: [Pose; 3] = [
    [
        -2_002_859,
        1_496_180,
        267_500_000,
        10_000_000_000,
        7_071_067_812,
        0,
    ],
    [
        -2_005_156,
        1_494_774,
        267_503_000,
        9_999_998_026,
        7_073_288_904,
        0,
    ],
    [
        -2_007_452,
        1_493_365,
        267_506_000,
        9_999_992_104,
        7_075_509_299,
        0,
    ],
];

/// Each servo channel's target at each pose of [`HELIX`], counts × 2^16, as the
/// controller sends them (`Controller::update_servo_targets`; no homing offsets).
pub fn helix_targets(m: &MachineConfig, kin: &MachineKinematics) -> [[i64; MAX_SERVOS]; 3] {
    HELIX.map(|pose| {
        let mut q = [0; MAX_JOINTS];
        if kin.inverse(&pose, &mut q).is_err() {
            panic!("the helix is reachable");
        }
        let mut t = [0; MAX_SERVOS];
        for (j, jc) in m.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                t[channel as usize] = target_q16(&jc.scale, q[j]);
            }
        }
        t
    })
}

/// The hexapod-xy's bank standing at the helix's first pose, with the next two ticks'
/// targets loaded (the interpolators' velocity and acceleration from successive
/// targets, as in a run) and the channel map at the second tick's commanded pose, as
/// the controller computes it (`Controller::update_contour_map`).
fn hexapod_xy_bank() -> ServoBank {
    let m = hexapod_xy_machine();
    let kin = MachineKinematics::new(&m);
    let t = helix_targets(&m, &kin);
    let mut bank = ServoBank::new(
        &m,
        &t[0].map(|q| q >> pkmc::drive::servo::SETPOINT_FRAC_BITS),
    );
    bank.load_tick(&t[1]);
    bank.load_tick(&t[2]);
    let MachineKinematics::HexapodXy(k) = &kin else {
        panic!("the hexapod-xy's kinematics");
    };
    let Ok(jm) = k.contour_map(&HELIX[2]) else {
        panic!("the helix is not singular");
    };
    bank.load_map(&ContourMap::of_joints(&m, &jm));
    bank
}

/// Bench `bench`'s bank (not timed).
pub fn bank(bench: u32) -> ServoBank {
    match bench {
        0 => ccpm_4axes_bank(),
        1 => hexapod_xy_bank(),
        _ => panic!("no such servo bench"),
    }
}

/// The encoder feedback of period `k` (0..10) of bench `bench`'s tick: the setpoint
/// lagging, or leading, by a few counts per channel.
#[cfg(not(target_os = "none"))]
pub fn feedback(bench: u32, k: i64) -> [i64; MAX_SERVOS] {
    if bench == 0 {
        return channels(&[k, -k / 2, 260_000 + k / 3, 0]);
    }
    let m = hexapod_xy_machine();
    let t = helix_targets(&m, &MachineKinematics::new(&m));
    let lag = [3, -2, 4, -1, 2, -3, 5, -4];
    core::array::from_fn(|c| {
        let at = t[1][c] + (t[2][c] - t[1][c]) * (k + 1) / 10;
        (at >> pkmc::drive::servo::SETPOINT_FRAC_BITS) - lag[c]
    })
}

/// What a counted period returns: the DAC codes and the contour error's bits.
#[repr(C)]
pub struct PeriodResult {
    /// DAC code of each channel.
    pub dac: [u16; MAX_SERVOS],
    /// `PeriodOutputs::contour_error`, `f32` bits.
    pub contour_error: [u32; POSE_AXES],
}

/// Builds bench `bench`'s bank, its outputs idle, into `out` (not timed).
///
/// # Safety
/// `out` must be valid for writing [`BANK_BYTES`] bytes, 8-aligned.
#[no_mangle]
pub unsafe extern "C" fn bench_servo_init(bench: u32, out: *mut BenchBank) {
    // SAFETY: the caller provides room and alignment.
    unsafe {
        out.write(BenchBank {
            bank: bank(bench),
            out: PeriodOutputs::IDLE,
        })
    }
}

/// One 10 kHz servo period of the bank, given the encoder feedback, drives enabled,
/// no fault; the DAC codes and the contour error into `out`.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_servo_period(
    bank: *mut BenchBank,
    feedback: *const [i64; MAX_SERVOS],
    out: *mut PeriodResult,
) {
    // SAFETY: the caller passes valid pointers.
    unsafe {
        let b = &mut *bank;
        b.bank
            .period_into(&*feedback, &[false; MAX_SERVOS], true, &mut b.out);
        let o = &b.out;
        *out = PeriodResult {
            dac: o.dac,
            contour_error: o.contour_error.map(f32::to_bits),
        };
    }
}
