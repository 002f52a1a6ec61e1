//! The 10 kHz servo interrupt: the hardware side of [`ServoPacer`], which runs every
//! servo channel's loop and paces the tick (`pkmc::controller::pacing` has the rules: the command
//! a tick posts is taken at the next tick edge, where the snapshot for the next tick
//! is left, and late ticks are counted).
//!
//! Each servo period ([`on_servo_period`], TIM7 at [`pkmc::drive::servo::SERVO_HZ`]) reads
//! the wiring's encoder counters (extended to 64 bits) and amplifier fault inputs (a
//! line per group of channels: each channel gets its group's), runs
//! [`ServoPacer::period`], writes its command codes and the amplifier enables (a line
//! per group, active when any channel of the group is enabled), and at a tick edge
//! pends the tick, which runs as soon as this interrupt returns. A fixed amount of
//! work: one pass over the channels for each step, no allocation.
//!
//! Shared state: the pacer and the servo hardware are touched only by this interrupt
//! (and once at start-up), except the tick's [`snapshot`], [`restart`] and
//! [`stats`], which run under short critical sections (copies only; this interrupt,
//! being the most urgent, holds one for its whole run, a few µs), and [`post`], which
//! hands the command over through a mailbox without one.

use core::cell::{RefCell, UnsafeCell};
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

use critical_section::Mutex;
use pkmc::controller::pacing::{Command, ServoPacer, ServoStats, Snapshot};
use pkmc::drive::contour::ServoBank;
use pkmc::drive::recorder::{Row, MAX_SIGNALS, ROW_BYTES};
use pkmc::drive::servo::SERVO_PER_TICK;
use static_cell::StaticCell;

use crate::board::{self, ServoIo};

/// The servo loops and their hardware, owned by the servo interrupt.
struct Servo {
    io: ServoIo,
    pacer: ServoPacer,
}

/// Where the servo state lives: in .bss (its initial value would otherwise be an image
/// in flash).
static SERVO_CELL: StaticCell<Servo> = StaticCell::new();
/// The servo state. `None` only during start-up.
static SERVO: Mutex<RefCell<Option<&'static mut Servo>>> = Mutex::new(RefCell::new(None));

/// Hands the servo hardware and the first bank (standing, disabled) to the servo
/// interrupt; call once before the servo timer starts.
pub fn install(io: ServoIo, bank: ServoBank) {
    let counts = io.encoders.last();
    let servo = SERVO_CELL.init(Servo {
        io,
        pacer: ServoPacer::new(bank, &counts),
    });
    critical_section::with(|cs| {
        SERVO.borrow_ref_mut(cs).replace(servo);
    });
}

/// Runs `f` on the pacer in a critical section; `None` during start-up.
fn with_pacer<R>(f: impl FnOnce(&mut ServoPacer) -> R) -> Option<R> {
    critical_section::with(|cs| {
        SERVO
            .borrow_ref_mut(cs)
            .as_deref_mut()
            .map(|s| f(&mut s.pacer))
    })
}

/// The snapshot of the last tick edge.
pub fn snapshot() -> Snapshot {
    with_pacer(|p| p.snapshot()).unwrap_or_default()
}

/// Half `half` of the data recorder's servo-period samples of the last complete
/// tick, and their signals ([`ServoPacer::staged`]), copied in a short critical
/// section (168 bytes, about half of what a whole tick's would hold it).
pub fn staged(half: usize) -> Option<([u8; MAX_SIGNALS], [Row; SERVO_PER_TICK / 2])> {
    with_pacer(|p| {
        let (ids, rows) = p.staged(half);
        let mut out = [[0; ROW_BYTES]; SERVO_PER_TICK / 2];
        out.copy_from_slice(rows);
        (*ids, out)
    })
}

/// The tick's command on its way to the servo interrupt, handed over without a
/// critical section: the tick writes the slot while it is not published and then
/// publishes it; the servo interrupt, which the tick can never preempt, reads it in
/// place at the next tick edge, copying only the channel map into the bank. (Copying
/// the command, with the hexapod-xy's channel map some 460 bytes, inside a critical
/// section held the servo interrupt off for up to 1.9 µs: the virtual board,
/// docs/vboard.md.) Should a command still be published when the next one comes (a
/// tick edge missed), the slot is rewritten inside a critical section.
struct Mailbox {
    slot: UnsafeCell<MaybeUninit<Command>>,
    ready: AtomicBool,
}

// SAFETY: the slot is written by the tick only while it is not published, or inside
// a critical section, and read by the servo interrupt only while it is published
// (see `Mailbox`); the interrupt runs to completion before the tick resumes.
unsafe impl Sync for Mailbox {}

static MAILBOX: Mailbox = Mailbox {
    slot: UnsafeCell::new(MaybeUninit::uninit()),
    ready: AtomicBool::new(false),
};

/// Posts a tick's command, to be taken at the next tick edge (replacing one not yet
/// taken). Called by the tick only.
pub fn post(command: Command) {
    if MAILBOX.ready.load(Ordering::Acquire) {
        critical_section::with(|_| {
            // SAFETY: the servo interrupt cannot run inside the critical section.
            unsafe { (*MAILBOX.slot.get()).write(command) };
        });
        return;
    }
    // SAFETY: not published: the servo interrupt does not read the slot, and only the
    // tick writes it.
    unsafe { (*MAILBOX.slot.get()).write(command) };
    MAILBOX.ready.store(true, Ordering::Release);
}

/// The command the tick published since the last tick edge, if any, read in place and
/// unpublished. Servo interrupt only, at a tick edge; the reference must not outlive
/// the interrupt's run.
fn take_posted() -> Option<&'static Command> {
    if !MAILBOX.ready.swap(false, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: published, so written in full. The tick writes the slot outside a
    // critical section only while it is not published, and it cannot run before this
    // interrupt, which holds the reference, returns.
    Some(unsafe { (*MAILBOX.slot.get()).assume_init_ref() })
}

/// Replaces the loops' bank at once (a servo reset; see [`ServoPacer::restart`]).
pub fn restart(bank: ServoBank) {
    with_pacer(|p| p.restart(bank));
}

/// Diagnostics since start-up.
pub fn stats() -> ServoStats {
    with_pacer(|p| p.stats()).unwrap_or_default()
}

/// One servo period; called by the servo timer's interrupt handler.
pub fn on_servo_period() {
    critical_section::with(|cs| {
        let Ok(mut servo) = SERVO.borrow(cs).try_borrow_mut() else {
            return;
        };
        let Some(s) = servo.as_deref_mut() else {
            return;
        };
        // The command stays in the mailbox until the edge, which reads it in place.
        let posted = if s.pacer.at_edge() {
            take_posted()
        } else {
            None
        };
        let feedback = s.io.encoders.read();
        let faults = s.io.faults();
        let period = s.pacer.period(&feedback, &faults, posted);
        s.io.write(&period.out.dac, &period.out.enable);
        if period.tick {
            crate::probe::tick_edge();
            board::pend_tick();
        }
    });
}
