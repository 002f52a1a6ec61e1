//! Servo encoder positions: 16-bit hardware counters extended to `i64` counts.
//!
//! Each servo channel's counter runs in quadrature-encoder mode (x4, all edges) with a
//! 16-bit wrap (set up by [`crate::board`]): a timer's encoder interface, or LPTIM1's
//! encoder mode. Every servo period (10 kHz)
//! [`Encoders::read`] extends each counter with [`pkmc::drive::servo::extend_counter`], so a
//! position is exact as long as an encoder moves less than 32 767 counts per period
//! (327 M counts/s). Positions start at the counters' power-up value (0); homing is the
//! core's business. Channels the wiring lacks stay at 0. Only the servo interrupt
//! reads them.

use embassy_stm32::pac::timer::TimGp16;
use pkmc::config::MAX_SERVOS;
use pkmc::drive::servo::extend_counter;

use crate::board::SERVO_CHANNELS;

/// A 16-bit position counter in quadrature-encoder mode.
#[derive(Clone, Copy)]
pub enum Counter {
    /// A timer's encoder interface (TIM1-5, TIM8, TIM20): its CNT register.
    Timer(TimGp16),
    /// LPTIM1 in encoder mode (servo channel 0 of the default wiring, 7 of the
    /// eight-servo one).
    LowPower(embassy_stm32::pac::lptim::Lptim),
}

impl Counter {
    /// The counter's value. LPTIM_CNT is read twice, and a third time if the two differ:
    /// RM0440 (LPTIM, counter register) trusts a read only when two in a row agree if
    /// the kernel clock is asynchronous to the bus. Here it is PCLK1 itself, so two
    /// reads differ only when the encoder counted between them, and the third is taken
    /// as it is: three reads at most.
    #[inline]
    fn read(&self) -> u16 {
        match self {
            Self::Timer(t) => t.cnt().read().cnt(),
            Self::LowPower(l) => {
                let first = l.cnt().read().cnt();
                let second = l.cnt().read().cnt();
                if first == second {
                    second
                } else {
                    l.cnt().read().cnt()
                }
            }
        }
    }
}

/// The encoder counters of all servo channels.
pub struct Encoders {
    /// Counters, servo channel order.
    regs: [Counter; SERVO_CHANNELS],
    /// Extended positions at the last read, counts (channels beyond the wiring: 0).
    counts: [i64; MAX_SERVOS],
}

impl Encoders {
    /// Encoders counting from their current counter values.
    pub fn new(regs: [Counter; SERVO_CHANNELS]) -> Self {
        let mut counts = [0; MAX_SERVOS];
        for (r, count) in regs.iter().zip(&mut counts) {
            *count = i64::from(r.read());
        }
        Self { regs, counts }
    }

    /// Reads every counter and returns the extended positions, counts.
    pub fn read(&mut self) -> [i64; MAX_SERVOS] {
        for (r, count) in self.regs.iter().zip(&mut self.counts) {
            *count = extend_counter(*count, r.read());
        }
        self.counts
    }

    /// The positions of the last [`read`](Self::read), counts.
    pub fn last(&self) -> [i64; MAX_SERVOS] {
        self.counts
    }
}

const _: () = assert!(SERVO_CHANNELS <= MAX_SERVOS);
