//! Servo encoder positions: 16-bit hardware counters extended to `i64` counts.
//!
//! Each servo channel's timer runs in quadrature-encoder mode (x4, all edges) with a
//! 16-bit wrap (set up by [`crate::board`]). Every servo period (10 kHz)
//! [`Encoders::read`] extends each counter with [`pkmc::servo::extend_counter`], so a
//! position is exact as long as an encoder moves less than 32 767 counts per period
//! (327 M counts/s). Positions start at the counters' power-up value (0); homing is the
//! core's business. Only the servo interrupt reads them.

use embassy_stm32::pac::timer::TimGp16;
use pkmc::config::MAX_SERVOS;
use pkmc::servo::extend_counter;

/// The encoder counters of all servo channels.
pub struct Encoders {
    /// Counter registers, servo channel order.
    regs: [TimGp16; MAX_SERVOS],
    /// Extended positions at the last read, counts.
    counts: [i64; MAX_SERVOS],
}

impl Encoders {
    /// Encoders counting from their current counter values.
    pub fn new(regs: [TimGp16; MAX_SERVOS]) -> Self {
        Self {
            counts: regs.map(|r| i64::from(r.cnt().read().cnt())),
            regs,
        }
    }

    /// Reads every counter and returns the extended positions, counts.
    pub fn read(&mut self) -> [i64; MAX_SERVOS] {
        for (r, count) in self.regs.iter().zip(&mut self.counts) {
            *count = extend_counter(*count, r.cnt().read().cnt());
        }
        self.counts
    }

    /// The positions of the last [`read`](Self::read), counts.
    pub fn last(&self) -> [i64; MAX_SERVOS] {
        self.counts
    }
}
