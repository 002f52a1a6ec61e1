//! A GPIO port (GPIOA–GPIOG).
//!
//! Source: RM0440, "General-purpose I/Os (GPIO)": the register map and reset values
//! (GPIOA_MODER 0xABFF FFFF, GPIOB_MODER 0xFFFF FEBF, the others 0xFFFF FFFF; the
//! pull-ups and speeds of PA13–PA15 and PB4 as reset), "I/O pin functional
//! description" (an output pin's IDR reads its ODR level; an input reads the pin; an
//! analog pin's Schmitt trigger is off and IDR reads 0) and "GPIO port bit set/reset
//! register" (BSRR: set bits 0–15, reset bits 16–31, set wins; BRR resets).
//!
//! The board drives each input it has wired ([`Gpio::drive`]); an input nothing drives
//! reads its pull (up: 1, down or none: 0). A pin in alternate-function mode has its
//! Schmitt trigger on, so IDR reads the pin ("Alternate function configuration"): the
//! board's drive when the pin is an input of its function, else the level of the
//! function's output, which the board does not feed back: 0 (no firmware reads an
//! alternate-function output through IDR).

use super::Unmodelled;

/// One port.
pub struct Gpio {
    /// Port letter, for messages.
    pub port: char,
    moder: u32,
    otyper: u32,
    ospeedr: u32,
    pupdr: u32,
    odr: u32,
    lckr: u32,
    afr: [u32; 2],
    /// Levels driven from outside, and which pins are driven.
    external: u32,
    driven: u32,
    /// Levels of the alternate functions' outputs.
    af_level: u32,
}

impl Gpio {
    /// Port `port` at reset.
    pub fn new(port: char) -> Self {
        let (moder, ospeedr, pupdr) = match port {
            'A' => (0xABFF_FFFF, 0x0C00_0000, 0x6400_0000),
            'B' => (0xFFFF_FEBF, 0, 0x0000_0100),
            _ => (0xFFFF_FFFF, 0, 0),
        };
        Self {
            port,
            moder,
            otyper: 0,
            ospeedr,
            pupdr,
            odr: 0,
            lckr: 0,
            afr: [0; 2],
            external: 0,
            driven: 0,
            af_level: 0,
        }
    }

    /// The mode of `pin`: 0 input, 1 output, 2 alternate function, 3 analog.
    pub fn mode(&self, pin: usize) -> u32 {
        (self.moder >> (2 * pin)) & 3
    }

    /// The alternate function number selected for `pin`.
    pub fn af(&self, pin: usize) -> u32 {
        (self.afr[pin / 8] >> (4 * (pin % 8))) & 0xF
    }

    /// The level of `pin` as the outside sees it if the chip drives it: Some(level)
    /// for an output or alternate-function pin, None for an input or analog pin.
    pub fn output(&self, pin: usize) -> Option<bool> {
        match self.mode(pin) {
            1 => Some(self.odr & (1 << pin) != 0),
            2 => Some(self.af_level & (1 << pin) != 0),
            _ => None,
        }
    }

    /// The level of `pin` read through IDR.
    pub fn level(&self, pin: usize) -> bool {
        let bit = 1 << pin;
        match self.mode(pin) {
            1 => self.odr & bit != 0,
            2 if self.driven & bit != 0 => self.external & bit != 0,
            2 => self.af_level & bit != 0,
            3 => false,
            _ => {
                if self.driven & bit != 0 {
                    self.external & bit != 0
                } else {
                    (self.pupdr >> (2 * pin)) & 3 == 1
                }
            }
        }
    }

    /// The outside drives `pin` to `high` (None: lets it float).
    pub fn drive(&mut self, pin: usize, high: Option<bool>) {
        let bit = 1 << pin;
        match high {
            Some(h) => {
                self.driven |= bit;
                self.external = self.external & !bit | if h { bit } else { 0 };
            }
            None => self.driven &= !bit,
        }
    }

    /// Reads `offset`.
    pub fn read(&self, offset: u32) -> Result<u32, Unmodelled> {
        Ok(match offset {
            0x00 => self.moder,
            0x04 => self.otyper,
            0x08 => self.ospeedr,
            0x0C => self.pupdr,
            0x10 => (0..16)
                .filter(|&p| self.level(p))
                .fold(0, |w, p| w | 1 << p),
            0x14 => self.odr,
            0x18 | 0x28 => 0, // write-only: read as 0
            0x1C => self.lckr,
            0x20 => self.afr[0],
            0x24 => self.afr[1],
            _ => return Err(Unmodelled),
        })
    }

    /// Writes `offset`; returns the ODR bits that changed.
    pub fn write(&mut self, offset: u32, value: u32) -> Result<u32, Unmodelled> {
        let before = self.odr;
        match offset {
            0x00 => self.moder = value,
            0x04 => self.otyper = value & 0xFFFF,
            0x08 => self.ospeedr = value,
            0x0C => self.pupdr = value,
            0x10 => {}
            0x14 => self.odr = value & 0xFFFF,
            0x18 => {
                let set = value & 0xFFFF;
                let reset = value >> 16;
                self.odr = (self.odr & !reset) | set;
            }
            0x1C => self.lckr = value,
            0x20 => self.afr[0] = value,
            0x24 => self.afr[1] = value,
            0x28 => self.odr &= !(value & 0xFFFF),
            _ => return Err(Unmodelled),
        }
        Ok(before ^ self.odr)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bsrr_sets_and_resets_with_set_winning() {
        let mut g = Gpio::new('C');
        g.write(0x00, 0x5555_5555).ok();
        assert_eq!(g.write(0x18, 0x0001_0003).ok(), Some(0b11));
        assert_eq!(g.read(0x10).ok(), Some(0b11));
        assert_eq!(g.write(0x18, 0x0002_0000).ok(), Some(0b10));
        assert_eq!(g.read(0x10).ok(), Some(0b01));
    }

    #[test]
    fn inputs_read_the_driver_or_the_pull_and_analog_reads_zero() {
        let mut g = Gpio::new('B');
        g.write(0x00, 0).ok();
        g.write(0x0C, 1 << 4).ok(); // PB2 pull-up
        assert!(g.level(2));
        g.drive(2, Some(false));
        assert!(!g.level(2));
        g.write(0x00, 3 << 4).ok();
        assert!(!g.level(2));
    }
}
