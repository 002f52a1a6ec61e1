//! The embassy-time driver: a 1 MHz time base on a basic timer, checked every ms.
//!
//! Every timer that embassy-stm32 can use as its time driver (TIM1-5, TIM8, TIM15,
//! TIM20) is taken by the pin map, so the firmware brings its own driver on the basic
//! timer [`TIME_BASE`] (TIM6): it counts at 1 MHz (embassy-time's
//! `tick-hz-1_000_000`) and overflows every millisecond. `now()` is the overflow count
//! × 1000 + the counter, read atomically through the counter's copy of the overflow
//! flag (UIFREMAP), so it is monotonic and exact to 1 µs. Timers are not given their
//! own compare interrupt: the overflow interrupt wakes every expired timer each
//! millisecond, so an `await`ed delay ends up to 1 ms late (never early). Every user in
//! this firmware waits for milliseconds (LED, link poll), which this serves exactly.

use core::cell::{Cell, RefCell};
use core::task::Waker;

use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use embassy_stm32::pac;

/// The embassy time base (basic timer TIM6, IRQ `TIM6_DAC`); `crate::board` programs
/// it (and takes its interrupt) with the other basic timer.
pub const TIME_BASE: pac::timer::TimBasic = pac::TIM6;
/// Counting rate of both basic timers (this one and the servo-period timer), Hz.
pub const BASIC_TIMER_COUNT_HZ: u32 = 1_000_000;

/// Overflow rate of the time base, Hz.
pub const PERIOD_HZ: u32 = 1_000;
/// Counter ticks per overflow period.
const TICKS_PER_PERIOD: u64 = (BASIC_TIMER_COUNT_HZ / PERIOD_HZ) as u64;
const _: () = assert!(embassy_time_driver::TICK_HZ == BASIC_TIMER_COUNT_HZ as u64);

/// The driver state: elapsed overflow periods and the timer queue.
struct TimeBase {
    /// Overflow periods counted by the interrupt.
    periods: Mutex<Cell<u64>>,
    /// Wakers waiting for a moment.
    queue: Mutex<RefCell<Queue>>,
}

impl TimeBase {
    /// Ticks since start-up.
    fn now_in(&self, cs: CriticalSection) -> u64 {
        // One read gives the counter and a not-yet-counted overflow together.
        let cnt = TIME_BASE.cnt().read();
        let periods = self.periods.borrow(cs).get() + u64::from(cnt.uifcpy());
        periods * TICKS_PER_PERIOD + u64::from(cnt.cnt())
    }

    /// Counts an overflow and wakes every expired timer.
    fn on_overflow(&self) {
        critical_section::with(|cs| {
            if TIME_BASE.sr().read().uif() {
                TIME_BASE.sr().write(|w| w.set_uif(false));
                let periods = self.periods.borrow(cs);
                periods.set(periods.get() + 1);
            }
            let now = self.now_in(cs);
            self.queue.borrow_ref_mut(cs).next_expiration(now);
        });
    }
}

impl Driver for TimeBase {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_in(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let mut queue = self.queue.borrow_ref_mut(cs);
            if queue.schedule_wake(at, waker) {
                let now = self.now_in(cs);
                if at <= now {
                    // Already due: wake now rather than at the next overflow.
                    queue.next_expiration(now);
                }
            }
        });
    }
}

embassy_time_driver::time_driver_impl!(static DRIVER: TimeBase = TimeBase {
    periods: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// The time-base overflow interrupt's work; called by [`crate::board`]'s handler.
pub fn on_overflow() {
    DRIVER.on_overflow();
}
