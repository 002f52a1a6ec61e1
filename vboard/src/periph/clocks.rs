//! RCC and PWR: oscillators that become ready when switched on, the system-clock
//! switch, the PLL, the peripheral clock enables and the reset flags.
//!
//! Source: RM0440, "Reset and clock control (RCC)" (RCC register map and the
//! descriptions of RCC_CR, RCC_CFGR, RCC_PLLCFGR, RCC_CSR, RCC_CRRCR) and "Power
//! control (PWR)" (PWR_CR1, PWR_SR2, PWR_CR5). Modelled:
//!
//! - every oscillator's ready flag follows its ON bit at once (HSIRDY, HSERDY,
//!   PLLRDY, LSERDY, LSIRDY, HSI48RDY): the board's crystals always start;
//! - RCC_CFGR.SWS follows SW; SYSCLK is HSI16 (16 MHz), HSE (the NUCLEO's 24 MHz
//!   crystal X3) or PLL R = f_src / (PLLM + 1) × PLLN / (2 × (PLLR + 1));
//! - HCLK, the core's clock, is SYSCLK through the AHB prescaler (HPRE); the APB
//!   prescalers must be ÷1 (a timer kernel clock is then HCLK): anything else is
//!   refused, as the timers' timing would be wrong;
//! - RCC_CSR's reset flags: PINRSTF on every reset, plus IWDGRSTF or SFTRSTF by
//!   cause; RMVF clears them;
//! - PWR_SR2.VOSF reads 0 (the regulator is always at its voltage).

use super::Unmodelled;
use crate::time::units_per_cycle;

/// The HSE crystal of the NUCLEO-G474RE (X3), Hz.
pub const HSE_HZ: u64 = 24_000_000;
/// HSI16, Hz.
pub const HSI16_HZ: u64 = 16_000_000;

/// What reset the chip.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum ResetCause {
    /// Power-on.
    PowerOn,
    /// The independent watchdog.
    Watchdog,
    /// A software reset (AIRCR.SYSRESETREQ).
    Software,
    /// The NRST pin (the NUCLEO's reset button).
    Pin,
}

/// RCC register offsets that only keep their value, with reset values.
const STORED: &[(u32, u32)] = &[
    (0x04, 0x4080_0000), // ICSCR
    (0x0C, 0x0000_1000), // PLLCFGR
    (0x18, 0),           // CIER
    (0x1C, 0),           // CIFR
    (0x20, 0),           // CICR
    (0x28, 0),           // AHB1RSTR
    (0x2C, 0),           // AHB2RSTR
    (0x30, 0),           // AHB3RSTR
    (0x38, 0),           // APB1RSTR1
    (0x3C, 0),           // APB1RSTR2
    (0x40, 0),           // APB2RSTR
    (0x48, 0x0000_0100), // AHB1ENR (FLASHEN)
    (0x4C, 0),           // AHB2ENR
    (0x50, 0),           // AHB3ENR
    (0x58, 0x0000_0400), // APB1ENR1 (RTCAPBEN)
    (0x5C, 0),           // APB1ENR2
    (0x60, 0),           // APB2ENR
    (0x68, 0x0000_130F), // AHB1SMENR
    (0x6C, 0x050F_667F), // AHB2SMENR
    (0x70, 0x0000_0101), // AHB3SMENR
    (0x78, 0xD2FE_C13F), // APB1SMENR1
    (0x7C, 0x0000_0103), // APB1SMENR2
    (0x80, 0x0437_F801), // APB2SMENR
    (0x88, 0),           // CCIPR
    (0x9C, 0),           // CCIPR2
];

/// The RCC.
pub struct Rcc {
    cr: u32,
    cfgr: u32,
    bdcr: u32,
    csr: u32,
    crrcr: u32,
    stored: Vec<u32>,
}

impl Rcc {
    /// The RCC after a reset by `cause`, reset flags from `previous_csr`.
    pub fn new(cause: ResetCause, previous_csr: u32) -> Self {
        let flags = match cause {
            ResetCause::PowerOn => 0x0C00_0000, // PINRSTF, BORRSTF
            ResetCause::Watchdog => previous_csr & 0xFE00_0000 | 1 << 26 | 1 << 29,
            ResetCause::Software => previous_csr & 0xFE00_0000 | 1 << 26 | 1 << 28,
            ResetCause::Pin => previous_csr & 0xFE00_0000 | 1 << 26,
        };
        Self {
            cr: 0x0000_0500, // HSION, HSIRDY
            cfgr: 0x0000_0005,
            bdcr: 0,
            csr: flags,
            crrcr: 0,
            stored: STORED.iter().map(|r| r.1).collect(),
        }
    }

    /// RCC_CSR, for the next reset's flags.
    pub fn csr(&self) -> u32 {
        self.csr
    }

    fn stored(&self, offset: u32) -> Option<usize> {
        STORED.iter().position(|r| r.0 == offset)
    }

    /// Reads `offset`.
    pub fn read(&self, offset: u32) -> Result<u32, Unmodelled> {
        if let Some(i) = self.stored(offset) {
            return Ok(self.stored[i]);
        }
        Ok(match offset {
            0x00 => self.cr,
            0x08 => self.cfgr,
            0x90 => self.bdcr,
            0x94 => self.csr,
            0x98 => self.crrcr,
            _ => return Err(Unmodelled),
        })
    }

    /// Writes `offset`.
    pub fn write(&mut self, offset: u32, value: u32) -> Result<(), Unmodelled> {
        if let Some(i) = self.stored(offset) {
            self.stored[i] = value;
            return Ok(());
        }
        match offset {
            0x00 => {
                // ON bits 8 (HSI), 16 (HSE), 24 (PLL); their ready bits 10, 17, 25.
                let mut cr = value & !(1 << 10 | 1 << 17 | 1 << 25);
                for (on, rdy) in [(8, 10), (16, 17), (24, 25)] {
                    if value & (1 << on) != 0 {
                        cr |= 1 << rdy;
                    }
                }
                self.cr = cr;
            }
            0x08 => {
                if value & 0x0000_3F00 != 0 {
                    return Err(Unmodelled); // APB prescalers other than ÷1
                }
                self.cfgr = value & !0xC | (value & 3) << 2;
            }
            0x90 => {
                // LSEON (0) → LSERDY (1).
                self.bdcr = value & !2 | (value & 1) << 1;
            }
            0x94 => {
                let keep = self.csr & 0xFE00_0000;
                self.csr = value & 0x0000_0001 | (value & 1) << 1 | keep;
                if value & (1 << 23) != 0 {
                    self.csr &= 0x00FF_FFFF; // RMVF clears the reset flags
                }
            }
            0x98 => self.crrcr = value & 1 | (value & 1) << 1,
            _ => return Err(Unmodelled),
        }
        Ok(())
    }

    /// SYSCLK, Hz.
    pub fn sysclk_hz(&self) -> u64 {
        match self.cfgr & 3 {
            2 => HSE_HZ,
            3 => {
                let p = self.stored[self.stored(0x0C).unwrap_or(0)];
                let src = match p & 3 {
                    2 => HSI16_HZ,
                    3 => HSE_HZ,
                    _ => 0,
                };
                let m = u64::from((p >> 4) & 0xF) + 1;
                let n = u64::from((p >> 8) & 0x7F);
                let r = 2 * (u64::from((p >> 25) & 3) + 1);
                src / m * n / r
            }
            _ => HSI16_HZ,
        }
    }

    /// HCLK (the core's clock): SYSCLK through the AHB prescaler HPRE.
    pub fn hclk_hz(&self) -> u64 {
        let hpre = (self.cfgr >> 4) & 0xF;
        let div = match hpre {
            0..=7 => 1,
            8..=11 => 2 << (hpre - 8),
            n => 64 << (n - 12),
        };
        self.sysclk_hz() / div
    }

    /// Time units per core clock cycle, if HCLK is a whole number of units.
    pub fn cycle_units(&self) -> Option<u64> {
        units_per_cycle(self.hclk_hz())
    }
}

/// PWR register file (RM0440 PWR register map), VOSF never set.
pub fn pwr() -> super::plain::Plain {
    let mut regs = vec![
        (0x00, 0x0000_0200, 0xFFFF_FFFF), // CR1: VOS range 1
        (0x04, 0, 0xFFFF_FFFF),
        (0x08, 0x0000_8000, 0xFFFF_FFFF),
        (0x0C, 0, 0xFFFF_FFFF),
        (0x10, 0, 0),
        (0x14, 0, 0), // SR2: VOSF = 0, REGLPF = 0
        (0x18, 0, 0),
        (0x80, 0x0000_0100, 0xFFFF_FFFF), // CR5: R1MODE
    ];
    for k in 0..7 {
        regs.push((0x20 + 8 * k, 0, 0xFFFF_FFFF));
        regs.push((0x24 + 8 * k, 0, 0xFFFF_FFFF));
    }
    super::plain::Plain::new("PWR", &regs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pll_of_the_firmware_gives_170_mhz_and_its_ready_flags_follow() {
        let mut r = Rcc::new(ResetCause::PowerOn, 0);
        assert_eq!(r.sysclk_hz(), 16_000_000);
        r.write(0x00, 1 << 8 | 1 << 16).ok();
        assert_eq!(r.read(0x00).ok().map(|v| v & (1 << 17)), Some(1 << 17));
        // HSE ÷ 6 × 85 ÷ 2: PLLSRC = 3, PLLM = 5, PLLN = 85, PLLR = 0, PLLREN.
        r.write(0x0C, 3 | 5 << 4 | 85 << 8 | 1 << 24).ok();
        r.write(0x00, 1 << 8 | 1 << 16 | 1 << 24).ok();
        assert_ne!(r.read(0x00).ok().unwrap_or(0) & (1 << 25), 0);
        r.write(0x08, 3).ok();
        assert_eq!(r.read(0x08).ok().map(|v| v & 0xF), Some(0xF));
        assert_eq!(r.sysclk_hz(), 170_000_000);
        assert_eq!(r.cycle_units(), Some(16));
    }

    #[test]
    fn reset_flags_name_the_watchdog_and_rmvf_clears_them() {
        let r = Rcc::new(ResetCause::Watchdog, 0);
        assert_ne!(r.csr() & (1 << 29), 0);
        let mut r = r;
        r.write(0x94, 1 << 23).ok();
        assert_eq!(r.csr() & 0xFF00_0000, 0);
    }
}
