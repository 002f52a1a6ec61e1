//! The 10 kHz servo interrupt: every servo channel's loop, and the pacing of the tick.
//!
//! Each servo period ([`on_servo_period`], TIM7 at [`pkmc::servo::SERVO_HZ`]) reads
//! the four encoder counters (extended to 64 bits) and the shared amplifier fault
//! input, runs [`ServoBank::period`] and writes its DAC codes and the shared
//! amplifier enable (active when any channel is enabled: one line on this board).
//!
//! Every [`SERVO_PER_TICK`]th period is a tick edge. There the interrupt first takes
//! what the previous tick posted ([`post`]): a rebuilt bank if the controller asked for
//! a servo reset, then the tick's targets ([`ServoBank::load_tick`]) and the enable;
//! then it runs the period; then it leaves a [`Snapshot`] of that period (encoder
//! counts, trips, whether the fault input was active in any period since the last
//! edge) for the tick and pends the tick, which runs as soon as this interrupt returns.
//! So the targets computed by tick N are loaded at edge N + 1, the same edge at which
//! tick N + 1 starts tick N's step trains: servo and stepper joints follow the path
//! with the same one-tick delay, and the loops always ramp over exactly
//! `SERVO_PER_TICK` periods. A tick that has not posted by the next edge (only if it
//! ran longer than a tick) is counted in [`ServoStats::late_ticks`]; the loops then
//! hold their last target for that tick.
//!
//! Shared state: the servo state is touched only by this interrupt (and once at
//! start-up); the exchange with the tick is under short critical sections (copies
//! only; this interrupt, being the most urgent, holds one for its whole run, a few µs).

use core::cell::RefCell;

use critical_section::Mutex;
use pkmc::config::MAX_SERVOS;
use pkmc::contour::{PeriodInputs, ServoBank};
use pkmc::servo::{Trip, SERVO_PER_TICK, SETPOINT_FRAC_BITS};
use static_cell::StaticCell;

use crate::board::{self, ServoIo};

/// What the servo interrupt saw at the last tick edge, for the tick.
#[derive(Clone, Copy, Default)]
pub struct Snapshot {
    /// Encoder positions read in the edge period, counts.
    pub counts: [i64; MAX_SERVOS],
    /// Trip latched by each channel's loop, as of the edge period.
    pub trips: [Option<Trip>; MAX_SERVOS],
    /// The shared amplifier fault input was active in at least one period since the
    /// previous edge (edge included).
    pub fault: bool,
    /// Servo periods run since start-up (wrapping).
    pub periods: u32,
}

/// What a tick hands to the servo loops, taken at the next tick edge.
pub struct Command {
    /// A new bank to run from now on (the controller asked for a servo reset).
    pub bank: Option<ServoBank>,
    /// Each channel's target at the end of the next tick, counts × 2^16.
    pub targets: [i64; MAX_SERVOS],
    /// The controller wants the amplifiers enabled.
    pub enable: bool,
}

/// Diagnostics of the servo interrupt (wrapping counters).
#[derive(Clone, Copy, Default, defmt::Format)]
pub struct ServoStats {
    /// Servo periods run.
    pub periods: u32,
    /// Tick edges at which the previous tick had not posted its targets yet.
    pub late_ticks: u32,
    /// The shared fault input at the last edge (see [`Snapshot::fault`]).
    pub fault: bool,
}

/// The servo loops and their hardware, owned by the servo interrupt.
struct Servo {
    io: ServoIo,
    bank: ServoBank,
    /// `PeriodInputs::enable` in force (from the last command).
    enable: bool,
    /// Periods since the last tick edge: 0 at an edge.
    phase: usize,
    /// Fault input seen active since the last edge.
    fault_seen: bool,
    stats: ServoStats,
}

/// The exchange between the servo interrupt and the tick.
struct Exchange {
    snapshot: Snapshot,
    command: Option<Command>,
}

/// Where the servo state and the exchange live: in .bss (their initial values would
/// otherwise be images in flash).
static SERVO_CELL: StaticCell<Servo> = StaticCell::new();
static EXCHANGE_CELL: StaticCell<Exchange> = StaticCell::new();
/// The servo state. `None` only during start-up.
static SERVO: Mutex<RefCell<Option<&'static mut Servo>>> = Mutex::new(RefCell::new(None));
/// The exchange with the tick. `None` only during start-up.
static EXCHANGE: Mutex<RefCell<Option<&'static mut Exchange>>> = Mutex::new(RefCell::new(None));

/// Hands the servo hardware and the first bank (standing, disabled) to the servo
/// interrupt; call once before the servo timer starts.
pub fn install(io: ServoIo, bank: ServoBank) {
    let counts = io.encoders.last();
    let exchange = EXCHANGE_CELL.init(Exchange {
        snapshot: Snapshot {
            counts,
            ..Snapshot::default()
        },
        // The first edge loads the bank's own standing targets, disabled.
        command: Some(Command {
            bank: None,
            targets: counts.map(|c| c << SETPOINT_FRAC_BITS),
            enable: false,
        }),
    });
    let servo = SERVO_CELL.init(Servo {
        io,
        bank,
        enable: false,
        phase: 0,
        fault_seen: false,
        stats: ServoStats::default(),
    });
    critical_section::with(|cs| {
        EXCHANGE.borrow_ref_mut(cs).replace(exchange);
        SERVO.borrow_ref_mut(cs).replace(servo);
    });
}

/// The snapshot of the last tick edge.
pub fn snapshot() -> Snapshot {
    critical_section::with(|cs| {
        EXCHANGE
            .borrow_ref(cs)
            .as_ref()
            .map(|e| e.snapshot)
            .unwrap_or_default()
    })
}

/// Posts a tick's command, to be taken at the next tick edge (replacing one not yet
/// taken).
pub fn post(command: Command) {
    critical_section::with(|cs| {
        if let Some(e) = EXCHANGE.borrow_ref_mut(cs).as_mut() {
            e.command = Some(command);
        }
    });
}

/// Diagnostics since start-up.
pub fn stats() -> ServoStats {
    critical_section::with(|cs| {
        SERVO
            .borrow_ref(cs)
            .as_ref()
            .map(|s| s.stats)
            .unwrap_or_default()
    })
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
        let mut exchange = EXCHANGE.borrow_ref_mut(cs);
        let Some(exchange) = exchange.as_deref_mut() else {
            return;
        };
        let feedback = s.io.encoders.read();
        let fault = s.io.fault();
        s.fault_seen |= fault;
        let edge = s.phase == 0;
        if edge {
            match exchange.command.take() {
                Some(command) => {
                    if let Some(bank) = command.bank {
                        s.bank = bank;
                    }
                    s.bank.load_tick(&command.targets);
                    s.enable = command.enable;
                }
                None => s.stats.late_ticks = s.stats.late_ticks.wrapping_add(1),
            }
        }
        let out = s.bank.period(&PeriodInputs {
            feedback,
            fault: [fault; MAX_SERVOS],
            enable: s.enable,
        });
        s.io.write(&out.dac, out.enable.iter().any(|&on| on));
        s.stats.periods = s.stats.periods.wrapping_add(1);
        s.phase += 1;
        if s.phase == SERVO_PER_TICK {
            s.phase = 0;
        }
        if edge {
            s.stats.fault = s.fault_seen;
            exchange.snapshot = Snapshot {
                counts: feedback,
                trips: out.trip,
                fault: s.fault_seen,
                periods: s.stats.periods,
            };
            s.fault_seen = false;
            board::pend_tick();
        }
    });
}
