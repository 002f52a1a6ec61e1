//! The independent watchdog (IWDG).
//!
//! Source: RM0440, "Independent watchdog (IWDG)": its functional description and
//! register map. Key 0xCCCC starts it (software start: the option byte IWDG_SW is
//! set at the factory), 0x5555 unlocks PR, RLR and WINR, 0xAAAA reloads the counter
//! from RLR (and locks them again). The 12-bit down-counter counts at LSI / (4 · 2^PR)
//! and resets the chip when it reaches 0. IWDG_SR's PVU/RVU/WVU are set while a new
//! value is carried into the LSI domain; the manual gives no fixed time, the board
//! takes [`UPDATE_LSI_CYCLES`]. The LSI is at its nominal 32 kHz.

use super::Unmodelled;
use crate::time::UNITS_PER_S;

/// The LSI's nominal frequency, Hz.
pub const LSI_HZ: u64 = 32_000;
/// LSI cycles a register update takes to reach the LSI domain (a modelling choice).
pub const UPDATE_LSI_CYCLES: u64 = 5;

/// The watchdog.
pub struct Iwdg {
    running: bool,
    unlocked: bool,
    pr: u32,
    rlr: u32,
    winr: u32,
    /// Time of the last reload.
    reloaded_at: u64,
    /// Prescaler divider and reload value in force since the last reload.
    active: (u32, u32),
    /// Time until which SR reads busy.
    busy_until: u64,
    busy_bits: u32,
    /// Refreshes since start.
    pub refreshes: u64,
}

impl Default for Iwdg {
    fn default() -> Self {
        Self {
            running: false,
            unlocked: false,
            pr: 0,
            rlr: 0xFFF,
            winr: 0xFFF,
            reloaded_at: 0,
            active: (0, 0xFFF),
            busy_until: 0,
            busy_bits: 0,
            refreshes: 0,
        }
    }
}

impl Iwdg {
    fn lsi_units(&self) -> u64 {
        UNITS_PER_S / LSI_HZ
    }

    /// Time the counter reaches 0 (the chip resets), if running.
    pub fn expiry(&self) -> Option<u64> {
        self.running.then(|| {
            let div = 4u64 << self.active.0;
            self.reloaded_at + u64::from(self.active.1) * div * self.lsi_units()
        })
    }

    fn reload(&mut self, now: u64) {
        self.reloaded_at = now;
        self.active = (self.pr, self.rlr);
        self.refreshes += 1;
    }

    /// Reads `offset`.
    pub fn read(&self, offset: u32, now: u64) -> Result<u32, Unmodelled> {
        Ok(match offset {
            0x00 => 0,
            0x04 => self.pr,
            0x08 => self.rlr,
            0x0C => {
                if now < self.busy_until {
                    self.busy_bits
                } else {
                    0
                }
            }
            0x10 => self.winr,
            _ => return Err(Unmodelled),
        })
    }

    fn busy(&mut self, bit: u32, now: u64) {
        self.busy_bits = if now < self.busy_until {
            self.busy_bits | bit
        } else {
            bit
        };
        self.busy_until = now + UPDATE_LSI_CYCLES * self.lsi_units();
    }

    /// Writes `offset`.
    pub fn write(&mut self, offset: u32, value: u32, now: u64) -> Result<(), Unmodelled> {
        match offset {
            0x00 => match value & 0xFFFF {
                0xCCCC => {
                    if !self.running {
                        self.running = true;
                        self.reload(now);
                    }
                }
                0x5555 => self.unlocked = true,
                0xAAAA => {
                    self.unlocked = false;
                    self.reload(now);
                }
                _ => self.unlocked = false,
            },
            0x04 if self.unlocked => {
                self.pr = value & 7;
                self.busy(1, now);
            }
            0x08 if self.unlocked => {
                self.rlr = value & 0xFFF;
                self.busy(2, now);
            }
            0x10 if self.unlocked => {
                self.winr = value & 0xFFF;
                self.busy(4, now);
            }
            0x04 | 0x08 | 0x10 => {} // locked: ignored
            _ => return Err(Unmodelled),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::from_ms;

    #[test]
    fn a_starved_watchdog_expires_after_rlr_counts_and_a_refresh_moves_it() {
        let mut w = Iwdg::default();
        w.write(0x00, 0xCCCC, 0).ok();
        w.write(0x00, 0x5555, 0).ok();
        w.write(0x04, 1, 0).ok(); // ÷8: 4 kHz
        w.write(0x08, 199, 0).ok();
        assert_ne!(w.read(0x0C, 0).ok(), Some(0));
        w.write(0x00, 0xAAAA, 0).ok();
        assert_eq!(w.expiry(), Some(from_ms(199) / 4));
        w.write(0x00, 0xAAAA, from_ms(10)).ok();
        assert_eq!(w.expiry(), Some(from_ms(10) + from_ms(199) / 4));
        // Locked again: a write to RLR is ignored.
        w.write(0x08, 10, from_ms(11)).ok();
        assert_eq!(w.read(0x08, from_ms(11)).ok(), Some(199));
    }
}
