//! Servo encoder positions: 16-bit hardware counters extended to `i64` counts.
//!
//! Each servo channel's timer runs in quadrature-encoder mode (x4, all edges) with a
//! 16-bit wrap (set up by [`crate::board`]). Every tick [`Encoders::read`] adds the
//! wrapping difference since the previous read to a 64-bit position, so a position is
//! exact as long as an encoder moves less than 32 767 counts per tick (32 M counts/s
//! at 1 kHz). Counts start at zero at power-up; homing is the core's business.

use embassy_stm32::pac::timer::TimGp16;
use pkmc::config::MAX_SERVOS;

/// The encoder counters of all servo channels.
pub struct Encoders {
    /// Counter registers, servo channel order.
    regs: [TimGp16; MAX_SERVOS],
    /// Raw counter values at the previous read.
    last: [u16; MAX_SERVOS],
    /// Extended positions, counts.
    counts: [i64; MAX_SERVOS],
}

impl Encoders {
    /// Encoders counting from their current counter values, which become position 0.
    pub fn new(regs: [TimGp16; MAX_SERVOS]) -> Self {
        Self {
            last: regs.map(|r| r.cnt().read().cnt()),
            regs,
            counts: [0; MAX_SERVOS],
        }
    }

    /// Reads every counter and returns the extended positions, counts.
    pub fn read(&mut self) -> [i64; MAX_SERVOS] {
        for ((r, last), count) in self.regs.iter().zip(&mut self.last).zip(&mut self.counts) {
            let raw = r.cnt().read().cnt();
            *count += i64::from(raw.wrapping_sub(*last) as i16);
            *last = raw;
        }
        self.counts
    }
}
