//! The touch probe's input: its level read through the GPIO input register for the
//! core's debounce, and the instant of its last edge latched by a timer's input
//! capture (`docs/probing.md`, "The board"; the pin and timer per wiring are in
//! `crate::board`).
//!
//! **The clock.** The capture timer counts at [`COUNT_HZ`] (10 MHz, 0.1 µs) from the
//! same 170 MHz kernel clock as the servo timer TIM7, which counts at 1 MHz; both are
//! started together, the capture timer first (`board::ServoTimer::start`), so every
//! update event of TIM7 falls on a multiple of [`COUNTS_PER_SERVO`] of the capture
//! counter, whose period [`PERIOD`] (6 ms) is a whole number of servo periods and of
//! ticks. The servo interrupt at a tick edge ([`tick_edge`]) therefore finds the edge's
//! count by rounding its own reading down to that multiple: exact, whatever its
//! latency (below a servo period).
//!
//! **The capture.** The channel maps its own input (CCxS = 01), captures both edges
//! (CCxP = CCxNP = 1) after a digital filter of eight samples at the 170 MHz kernel
//! clock (ICxF = 0011: pulses under 47 ns are ignored, every edge is delayed by 8 to
//! 10 kernel cycles with the resynchronisation, under 0.06 µs), RM0440,
//! general-purpose timers, "Input capture mode" and TIMx_CCMR1/TIMx_CCER. No
//! interrupt: the tick polls CCxIF. CCRx holds the *last* edge before the tick's read
//! (a later capture overwrites it and sets the overcapture flag CCxOF): after a bounce
//! inside a tick, the edge that settled.
//!
//! **The tick's read** ([`Probe::read`]): the flag and CCRx first, then the level. The
//! instant goes to the core as µs after the previous tick's start, rounded: within
//! ±0.55 µs of the count plus the filter's 0.06 µs. An edge after this tick's start
//! but before the read comes out past 1000 µs, which the core takes as this tick's
//! start; one between the two reads comes without an instant, which the core also
//! takes as this tick's start: either is late by at most the read's delay after the
//! tick edge. (The other order would lose that edge's instant to the next tick, whose
//! level then changes without a capture: a whole tick late.)

use core::sync::atomic::{AtomicU16, Ordering};

use embassy_stm32::gpio::Flex;
use embassy_stm32::pac;
use pkmc::drive::servo::SERVO_HZ;
use pkmc::units::TICK_HZ;

use crate::board::{PROBE_CHANNEL as CH, PROBE_TIMER as REGS};

/// The capture counter's rate: 10 MHz (the 170 MHz kernel ÷ 17).
pub const COUNT_HZ: u32 = 10_000_000;
/// Counts per µs.
const COUNTS_PER_US: u32 = COUNT_HZ / 1_000_000;
/// Counts per servo period (100 µs).
const COUNTS_PER_SERVO: u32 = COUNT_HZ / SERVO_HZ;
/// The counter's period: 60 000 counts, 6 ms, six ticks (ARR = PERIOD − 1).
pub const PERIOD: u32 = 60_000;
const _: () = assert!(PERIOD.is_multiple_of(COUNT_HZ / TICK_HZ) && PERIOD <= 1 << 16);
const _: () = assert!(COUNT_HZ.is_multiple_of(SERVO_HZ) && COUNT_HZ.is_multiple_of(1_000_000));

/// ICxF = 0011: fSAMPLING = fCK_INT, N = 8 (RM0440, TIMx_CCMR1, input capture mode).
const FILTER: u32 = 0b0011;

/// The capture count of the last tick edge, written by the servo interrupt.
static TICK_START: AtomicU16 = AtomicU16::new(0);

/// The probe's capture channel ([`REGS`], channel [`CH`]) and its pin.
pub struct Probe {
    /// The pin, in its timer's alternate function; IDR still reads its level.
    pin: Flex<'static>,
    /// The capture count of the previous tick's start.
    prev: u16,
}

impl Probe {
    /// Takes channel [`CH`] of the clocked, stopped timer [`REGS`] (general-purpose
    /// register layout: TIM2 or TIM15) as the probe's capture, counting at
    /// [`COUNT_HZ`] from its `clock_hz` kernel, and `pin`, already in the channel's
    /// alternate function. The counter starts with [`start`].
    pub fn new(clock_hz: u32, pin: Flex<'static>) -> Self {
        let (regs, ch) = (REGS, CH);
        let prescale = clock_hz / COUNT_HZ;
        defmt::assert!(
            prescale * COUNT_HZ == clock_hz,
            "probe timer clock {}",
            clock_hz
        );
        regs.psc().write_value((prescale - 1) as u16);
        regs.arr().write(|w| w.set_arr((PERIOD - 1) as u16));
        // CCxS = 01 (ICx = TIx), ICxF = FILTER; CCMR1 holds channels 0 and 1, CCMR2
        // channels 2 and 3, each in a byte.
        let shift = 8 * (ch % 2);
        regs.ccmr_input(ch / 2).modify(|w| {
            w.0 = w.0 & !(0xFF << shift) | (0b01 | FILTER << 4) << shift;
        });
        // Both edges (CCxP = CCxNP = 1), capture enabled (CCxE).
        regs.ccer().modify(|w| w.0 |= 0b1011 << (4 * ch));
        // PSC and ARR take effect; the counter and prescaler restart from 0.
        regs.egr().write(|w| w.set_ug(true));
        regs.sr().write_value(pac::timer::regs::SrGp16(0));
        Self { pin, prev: 0 }
    }

    /// The tick's sample: the level (true: touching, `active_high` says which level
    /// that is) and the instant of the last edge since the last read, µs after the
    /// previous tick's start.
    pub fn read(&mut self, active_high: bool) -> (bool, Option<u16>) {
        let start = TICK_START.load(Ordering::Relaxed);
        let prev = core::mem::replace(&mut self.prev, start);
        let sr = REGS.sr().read().0;
        let edge = if sr & (1 << (1 + CH)) != 0 {
            // Reading CCRx clears CCxIF; CCxOF (rc_w0) is cleared by writing 0.
            let at = REGS.ccr(CH).read().0 as u16;
            REGS.sr()
                .write_value(pac::timer::regs::SrGp16(!(1 << (9 + CH))));
            let d = (u32::from(at) + PERIOD - u32::from(prev)) % PERIOD;
            Some(((d + COUNTS_PER_US / 2) / COUNTS_PER_US) as u16)
        } else {
            None
        };
        (self.pin.is_high() == active_high, edge)
    }
}

/// At a tick edge, in the servo interrupt: records the capture count of the edge
/// (the servo timer's update event), the last multiple of a servo period.
#[inline(always)]
pub fn tick_edge() {
    let now = REGS.cnt().read().0 & 0xFFFF;
    TICK_START.store((now - now % COUNTS_PER_SERVO) as u16, Ordering::Relaxed);
}
