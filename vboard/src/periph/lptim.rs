//! LPTIM1 in encoder mode (the eight-servo wiring's eighth encoder).
//!
//! Source: RM0440, "Low-power timer (LPTIM)": "Encoder mode" (ENC = 1 in LPTIM_CFGR
//! with the kernel clock running: the counter counts up or down on both edges of
//! Input1 and Input2, by the table "Encoder counting scenarios", between 0 and ARR),
//! "LPTIM register map" (ISR, ICR, IER, CFGR, CR, CMP, ARR, CNT, OR, CFGR2), CR.ENABLE
//! (bit 0) and CR.CNTSTRT (bit 2, continuous start). ARR is written only with the
//! timer enabled.

use super::Unmodelled;

/// LPTIM1.
#[derive(Default)]
pub struct Lptim {
    isr: u32,
    ier: u32,
    cfgr: u32,
    cr: u32,
    cmp: u32,
    arr: u32,
    cnt: u32,
    or: u32,
    cfgr2: u32,
    inputs: (bool, bool),
}

impl Lptim {
    /// Reads `offset`.
    pub fn read(&self, offset: u32) -> Result<u32, Unmodelled> {
        Ok(match offset {
            0x00 => self.isr,
            0x04 => 0,
            0x08 => self.ier,
            0x0C => self.cfgr,
            0x10 => self.cr,
            0x14 => self.cmp,
            0x18 => self.arr,
            0x1C => self.cnt,
            0x20 => self.or,
            0x24 => self.cfgr2,
            _ => return Err(Unmodelled),
        })
    }

    /// Writes `offset`.
    pub fn write(&mut self, offset: u32, value: u32) -> Result<(), Unmodelled> {
        match offset {
            0x00 => {}
            0x04 => self.isr &= !value,
            0x08 => self.ier = value,
            0x0C => self.cfgr = value,
            0x10 => self.cr = value & 0x1F,
            0x14 => {
                self.cmp = value & 0xFFFF;
                self.isr |= 1 << 3; // CMPOK
            }
            0x18 => {
                self.arr = value & 0xFFFF;
                self.isr |= 1 << 4; // ARROK
            }
            0x1C => {}
            0x20 => self.or = value,
            0x24 => self.cfgr2 = value,
            _ => return Err(Unmodelled),
        }
        Ok(())
    }

    /// The inputs as last driven.
    pub fn inputs(&self) -> (bool, bool) {
        self.inputs
    }

    /// Drives Input1 = `a`, Input2 = `b`; counts in encoder mode while enabled and
    /// started (same direction rule as the timers' encoder mode 3).
    pub fn encoder_input(&mut self, a: bool, b: bool) {
        let (pa, pb) = self.inputs;
        self.inputs = (a, b);
        let counting = self.cfgr & (1 << 24) != 0 && self.cr & 1 != 0 && self.cr & 4 != 0;
        if !counting {
            return;
        }
        let up = if a != pa {
            a != b
        } else if b != pb {
            a == b
        } else {
            return;
        };
        let top = self.arr + 1;
        self.cnt = if up {
            (self.cnt + 1) % top
        } else {
            (self.cnt + top - 1) % top
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoder_mode_counts_both_edges_of_both_inputs_both_ways_within_arr() {
        let mut l = Lptim::default();
        l.write(0x0C, 1 << 24).ok(); // ENC
        l.write(0x10, 1).ok(); // ENABLE
        l.write(0x18, 0xFFFF).ok();
        assert_ne!(l.read(0x00).ok().unwrap_or(0) & (1 << 4), 0); // ARROK
                                                                  // Not started (CNTSTRT): nothing counts.
        l.encoder_input(true, false);
        assert_eq!(l.read(0x1C).ok(), Some(0));
        l.encoder_input(false, false);
        l.write(0x10, 1 | 4).ok();
        for (a, b) in [(true, false), (true, true), (false, true), (false, false)] {
            l.encoder_input(a, b);
        }
        assert_eq!(l.read(0x1C).ok(), Some(4));
        for _ in 0..2 {
            for (a, b) in [(false, true), (true, true), (true, false), (false, false)] {
                l.encoder_input(a, b);
            }
        }
        assert_eq!(l.read(0x1C).ok(), Some(0xFFFC));
    }
}
