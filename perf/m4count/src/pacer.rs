//! Servo-period benchmarks of the servo interrupt's whole work: one
//! [`ServoPacer::period`] (the tick edge's command taken, the bank's period, the DAC
//! sums, the snapshot at the edge and, when the data recorder samples every servo
//! period, the staging of its signals), on the banks of [`crate::servo`]. The
//! benches, by index ([`bench_pacer_init`]'s `bench`, the `pacer P …` lines of the
//! host run):
//!
//! * 0, `pacer_ccpm_4axes`, and 1, `pacer_ccpm_4axes_rec8`: the four-channel CCPM bank
//!   (servo bench 0), the recorder off, then staging [`CCPM_SIGNALS`];
//! * 2, `pacer_hexapod_xy_8ch`, and 3, `pacer_hexapod_xy_8ch_rec8`: the hexapod-xy's
//!   bank (servo bench 1), the recorder off, then staging [`HEXAPOD_XY_SIGNALS`].
//!
//! Each bench's cases are the ten periods of one tick, on the feedback of its servo
//! bench ([`crate::servo::feedback`]). The tick's command is posted before the first
//! period, which takes it at the edge: the targets the servo bench loads outside its
//! count, and on the hexapod-xy the channel map too (a tick that carries a new map,
//! every seventh: the dearer edge), and the recorder's signals. After the tenth period
//! one more (not counted) starts the next tick, after which the staged samples of the
//! measured tick are read back and checked against the host's (the `staged P …` line).

use crate::servo::{ccpm_4axes_machine, channels, helix_targets, hexapod_xy_machine, HELIX};
use pkmc::config::MAX_SERVOS;
use pkmc::controller::pacing::{Command, CommandSlot, ServoPacer, NOT_SERVO};
use pkmc::drive::contour::{PeriodOutputs, ServoBank};
use pkmc::drive::recorder::{Row, MAX_SIGNALS, ROW_BYTES};
use pkmc::drive::servo::{SERVO_PER_TICK, SETPOINT_FRAC_BITS};
use pkmc::kinematics::{ContourMap, MachineKinematics};

/// A pacer bench: the servo interrupt's pacer and the slot its tick's command waits
/// in (the firmware's mailbox: read in place at the edge).
#[derive(Clone, Debug)]
pub struct BenchPacer {
    pub pacer: ServoPacer,
    pub slot: CommandSlot,
}

impl BenchPacer {
    /// One servo period, no fault.
    pub fn period(&mut self, feedback: &[i64; MAX_SERVOS]) -> &PeriodOutputs {
        self.slot
            .period(&mut self.pacer, feedback, &[false; MAX_SERVOS])
            .out
    }
}

/// Bytes the emulator reserves for one [`BenchPacer`].
pub const PACER_BYTES: usize = 8192;
const _: () = assert!(core::mem::size_of::<BenchPacer>() <= PACER_BYTES);

/// The benches (see the module documentation).
pub const BENCHES: u32 = 4;

/// The recorder's signals staged on the four-channel bank (servo-side ids: kind << 4
/// | channel): channel 0's commanded and measured position, following error and DAC
/// code, channel 1's following error and DAC code, the contour errors of the path and
/// of the tool's direction.
pub const CCPM_SIGNALS: [u8; MAX_SIGNALS] = [0x00, 0x10, 0x20, 0x30, 0x21, 0x31, 0x90, 0xa0];

/// The recorder's signals staged on the hexapod-xy: leg 0's commanded and measured
/// position, following error and DAC code, the table X's (channel 6) following
/// error and DAC code, the contour errors of the path and of the tool's direction
/// (what the `hexapod_xy_*_rec10k` programs arm, `programs.rs`).
pub const HEXAPOD_XY_SIGNALS: [u8; MAX_SIGNALS] = [0x00, 0x10, 0x20, 0x30, 0x26, 0x36, 0x90, 0xa0];

/// Added to the staged signals: the joint's zero taken off the two positions (any
/// values cost the same).
const RECORD_ADD: [i32; MAX_SIGNALS] = [-1234, -1234, 0, 0, 0, 0, 0, 0];

/// Bench `bench`'s pacer, its tick's command posted (not timed).
pub fn pacer(bench: u32) -> BenchPacer {
    let record = |signals: [u8; MAX_SIGNALS]| {
        if bench % 2 == 1 {
            signals
        } else {
            [NOT_SERVO; MAX_SIGNALS]
        }
    };
    match bench / 2 {
        0 => {
            let counts = channels(&[0, 0, 260_000, 0]);
            let bank = ServoBank::new(&ccpm_4axes_machine(), &counts);
            let mut slot = CommandSlot::new();
            slot.post(Command {
                reset: false,
                targets: crate::servo::ccpm_4axes_targets(),
                enable: true,
                map: None,
                record: record(CCPM_SIGNALS),
                record_add: RECORD_ADD,
            });
            BenchPacer {
                pacer: ServoPacer::new(bank, &counts),
                slot,
            }
        }
        1 => {
            let m = hexapod_xy_machine();
            let kin = MachineKinematics::new(&m);
            let t = helix_targets(&m, &kin);
            let counts = t[0].map(|q| q >> SETPOINT_FRAC_BITS);
            let mut bank = ServoBank::new(&m, &counts);
            bank.load_tick(&t[1]);
            let MachineKinematics::HexapodXy(k) = &kin else {
                panic!("the hexapod-xy's kinematics");
            };
            let Ok(jm) = k.contour_map(&HELIX[2]) else {
                panic!("the helix is not singular");
            };
            let mut slot = CommandSlot::new();
            slot.post(Command {
                reset: false,
                targets: t[2],
                enable: true,
                map: Some(ContourMap::of_joints(&m, &jm)),
                record: record(HEXAPOD_XY_SIGNALS),
                record_add: RECORD_ADD,
            });
            BenchPacer {
                pacer: ServoPacer::new(bank, &counts),
                slot,
            }
        }
        _ => panic!("no such pacer bench"),
    }
}

/// The servo bench (`crate::servo`) whose bank and feedback pacer bench `bench` runs.
pub fn servo_bench(bench: u32) -> u32 {
    bench / 2
}

/// The staged samples of a tick, read back after it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Staged {
    /// The signals' servo-side ids.
    pub ids: [u8; MAX_SIGNALS],
    /// Each period's packed sample, in time order.
    pub rows: [Row; SERVO_PER_TICK],
}

/// One period more (the next tick's edge, nothing posted), then the last complete
/// tick's staged samples (not timed).
pub fn finish(p: &mut BenchPacer, feedback: &[i64; MAX_SERVOS]) -> Staged {
    p.period(feedback);
    let mut out = Staged {
        ids: [NOT_SERVO; MAX_SIGNALS],
        rows: [[0; ROW_BYTES]; SERVO_PER_TICK],
    };
    let mut k = 0;
    for half in 0..2 {
        let (ids, rows) = p.pacer.staged(half);
        out.ids = *ids;
        for r in rows {
            out.rows[k] = *r;
            k += 1;
        }
    }
    out
}

/// Builds pacer bench `bench` into `out` (not timed).
///
/// # Safety
/// `out` must be valid for writing [`PACER_BYTES`] bytes, 8-aligned.
#[no_mangle]
pub unsafe extern "C" fn bench_pacer_init(bench: u32, out: *mut BenchPacer) {
    // SAFETY: the caller provides room and alignment.
    unsafe { out.write(pacer(bench)) }
}

/// One 10 kHz period of the servo interrupt's pacer, given the encoder feedback, no
/// fault; the DAC codes and the contour error into `out`.
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_pacer_period(
    p: *mut BenchPacer,
    feedback: *const [i64; MAX_SERVOS],
    out: *mut crate::servo::PeriodResult,
) {
    // SAFETY: the caller passes valid pointers.
    unsafe {
        let o = (*p).period(&*feedback);
        *out = crate::servo::PeriodResult {
            dac: o.dac,
            contour_error: o.contour_error.map(f32::to_bits),
        };
    }
}

/// [`finish`] into `out` (not timed).
///
/// # Safety
/// Valid, aligned pointers.
#[no_mangle]
pub unsafe extern "C" fn bench_pacer_staged(
    p: *mut BenchPacer,
    feedback: *const [i64; MAX_SERVOS],
    out: *mut Staged,
) {
    // SAFETY: the caller passes valid pointers.
    unsafe { *out = finish(&mut *p, &*feedback) }
}
