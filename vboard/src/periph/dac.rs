//! A DAC (DAC1–DAC4), two channels, without triggers.
//!
//! Source: RM0440, "Digital-to-analog converter (DAC)": "DAC channel enable" (EN
//! turns a channel on; DACRDY in DAC_SR is set once it is ready: the board gives it
//! [`WAKEUP_US`]), "DAC data format" and "DAC conversion" (with the trigger disabled,
//! TENx = 0, DHRx is moved into DORx one APB clock after the write: at once here) and
//! the register map (DHR12Rx, DHR12Lx, DHR8Rx, the dual registers, DORx, SR, MCR).
//! The output voltage is DOR / 4095 × VREF+; the board passes the code on.

use super::Unmodelled;
use crate::time::from_us;

/// The time a channel takes to report ready after EN (tWAKEUP is a few µs in the
/// datasheet; a modelling choice).
pub const WAKEUP_US: u64 = 5;

/// One DAC.
pub struct Dac {
    /// Name, for messages.
    pub name: &'static str,
    cr: u32,
    mcr: u32,
    dor: [u16; 2],
    ready_at: [Option<u64>; 2],
    other: [u32; 8],
    /// Writes of a data register that changed a DOR, since reset.
    pub conversions: u64,
}

impl Dac {
    /// A DAC at reset.
    pub fn new(name: &'static str) -> Self {
        Self {
            name,
            cr: 0,
            mcr: 0,
            dor: [0; 2],
            ready_at: [None; 2],
            other: [0; 8],
            conversions: 0,
        }
    }

    /// Is channel `ch` enabled?
    pub fn enabled(&self, ch: usize) -> bool {
        self.cr & (1 << (16 * ch)) != 0
    }

    /// The output code of channel `ch` (DOR).
    pub fn output(&self, ch: usize) -> u16 {
        self.dor[ch]
    }

    /// Reads `offset` at `now`.
    pub fn read(&self, offset: u32, now: u64) -> Result<u32, Unmodelled> {
        Ok(match offset {
            0x00 => self.cr,
            0x2C => u32::from(self.dor[0]),
            0x30 => u32::from(self.dor[1]),
            0x34 => {
                let mut sr = 0;
                for ch in 0..2 {
                    if self.ready_at[ch].is_some_and(|t| now >= t) {
                        sr |= 1 << (11 + 16 * ch);
                    }
                }
                sr
            }
            0x3C => self.mcr,
            0x08..=0x28 => 0,
            o @ (0x38 | 0x40 | 0x44 | 0x48 | 0x4C | 0x58 | 0x5C | 0x60) => {
                self.other[Self::other(o)]
            }
            _ => return Err(Unmodelled),
        })
    }

    fn other(o: u32) -> usize {
        match o {
            0x38 => 0,
            0x40 => 1,
            0x44 => 2,
            0x48 => 3,
            0x4C => 4,
            0x58 => 5,
            0x5C => 6,
            _ => 7,
        }
    }

    fn load(&mut self, ch: usize, code: u32) {
        if self.cr & (1 << (2 + 16 * ch)) != 0 {
            return; // triggered conversions: not used, never converted here
        }
        let code = (code & 0xFFF) as u16;
        if self.dor[ch] != code {
            self.conversions += 1;
        }
        self.dor[ch] = code;
    }

    /// Writes `offset` at `now`.
    pub fn write(&mut self, offset: u32, value: u32, now: u64) -> Result<(), Unmodelled> {
        match offset {
            0x00 => {
                for ch in 0..2 {
                    let en = value & (1 << (16 * ch)) != 0;
                    if en && !self.enabled(ch) {
                        self.ready_at[ch] = Some(now + from_us(WAKEUP_US));
                    } else if !en {
                        self.ready_at[ch] = None;
                    }
                }
                self.cr = value;
            }
            0x04 => {}
            0x08 => self.load(0, value),
            0x0C => self.load(0, value >> 4),
            0x10 => self.load(0, (value & 0xFF) << 4),
            0x14 => self.load(1, value),
            0x18 => self.load(1, value >> 4),
            0x1C => self.load(1, (value & 0xFF) << 4),
            0x20 => {
                self.load(0, value);
                self.load(1, value >> 16);
            }
            0x24 => {
                self.load(0, value >> 4);
                self.load(1, value >> 20);
            }
            0x28 => {
                self.load(0, (value & 0xFF) << 4);
                self.load(1, ((value >> 8) & 0xFF) << 4);
            }
            0x34 => {}
            0x3C => self.mcr = value,
            o @ (0x38 | 0x40 | 0x44 | 0x48 | 0x4C | 0x58 | 0x5C | 0x60) => {
                self.other[Self::other(o)] = value
            }
            _ => return Err(Unmodelled),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_a_trigger_the_data_register_reaches_the_output_at_once() {
        let mut d = Dac::new("DAC1");
        d.write(0x00, 1, 0).ok();
        assert_eq!(d.read(0x34, 0).ok(), Some(0));
        assert_eq!(d.read(0x34, from_us(WAKEUP_US)).ok(), Some(1 << 11));
        d.write(0x08, 0x0ABC, 0).ok();
        assert_eq!(d.output(0), 0x0ABC);
        d.write(0x18, 0x0123_0, 0).ok(); // left-aligned into channel 2
        assert_eq!(d.output(1), 0x123);
    }
}
