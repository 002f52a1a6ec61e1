//! The flash interface (FLASH registers) and the flash pages the firmware keeps its
//! machine configuration in.
//!
//! Source: RM0440, "Embedded flash memory (FLASH)": "Flash program and erase
//! operations" (unlock with KEYR 0x4567 0123 then 0xCDEF 89AB; LOCK set again locks;
//! page erase: PER, PNB, BKER in dual-bank mode, then STRT, with BSY set until the
//! erase is done; programming: PG set, then one double word written as two words to
//! an aligned address, BSY while it is programmed; programming a double word that is
//! not erased sets PROGERR; a page number outside the bank, a write with PG clear or
//! a second operation while busy set PGSERR/PGAERR), and the register map (ACR,
//! PDKEYR, KEYR, OPTKEYR, SR, CR, ECCR, OPTR). OPTR reads the factory value
//! 0xFFEF F8AA (DBANK = 1: two banks of 256 KB, 2 KB pages). Erase and program times
//! are modelling choices: a page erase takes 22 ms (the typical figure the firmware's
//! `board.rs` designs its watchdog for, from the STM32G474 datasheet) and a double
//! word 82 µs (of the order of the datasheet's programming time; not checked here).
//!
//! Only the configuration pages (bank 2, pages 126 and 127: the last 4 KB) may be
//! erased or written; an erase or a write anywhere else would change the program
//! under the board's feet and is refused as unmodelled.

use super::Unmodelled;
use crate::time::{from_ms, from_us};

/// Flash base address.
pub const BASE: u32 = 0x0800_0000;
/// Flash size.
pub const SIZE: u32 = 512 * 1024;
/// First byte of the configuration pages.
pub const CONFIG: u32 = BASE + 508 * 1024;
/// Their size.
pub const CONFIG_SIZE: u32 = 4 * 1024;
/// Page size in dual-bank mode.
pub const PAGE: u32 = 2048;

const ERASE_MS: u64 = 22;
const PROGRAM_US: u64 = 82;

const SR_EOP: u32 = 1;
const SR_PROGERR: u32 = 1 << 3;
const SR_PGAERR: u32 = 1 << 5;
const SR_PGSERR: u32 = 1 << 7;
const SR_BSY: u32 = 1 << 16;
const CR_PG: u32 = 1;
const CR_PER: u32 = 1 << 1;
const CR_BKER: u32 = 1 << 11;
const CR_STRT: u32 = 1 << 16;
const CR_EOPIE: u32 = 1 << 24;
const CR_LOCK: u32 = 1 << 31;

/// The flash interface and the configuration pages' contents.
pub struct Flash {
    acr: u32,
    sr: u32,
    cr: u32,
    key_step: u8,
    busy_until: u64,
    /// What happens when the busy time ends.
    pending: Option<(u32, Vec<u8>)>,
    /// A first word of a double word, waiting for its second.
    half: Option<(u32, u32)>,
    /// The configuration pages (erased: 0xFF).
    pub config: Vec<u8>,
    /// Pages erased and double words programmed, since the board started.
    pub erases: u64,
    /// Double words programmed.
    pub programs: u64,
}

impl Flash {
    /// The interface at reset, keeping `config` (the pages survive a reset).
    pub fn new(config: Vec<u8>) -> Self {
        Self {
            acr: 0x0000_0600,
            sr: 0,
            cr: 0xC000_0000,
            key_step: 0,
            busy_until: 0,
            pending: None,
            half: None,
            config,
            erases: 0,
            programs: 0,
        }
    }

    /// Completes an operation whose time is up.
    pub fn advance(&mut self, now: u64) {
        if self.sr & SR_BSY != 0 && now >= self.busy_until {
            self.sr &= !SR_BSY;
            if let Some((at, bytes)) = self.pending.take() {
                let o = (at - CONFIG) as usize;
                self.config[o..o + bytes.len()].copy_from_slice(&bytes);
            }
            if self.cr & CR_EOPIE != 0 {
                self.sr |= SR_EOP;
            }
        }
    }

    /// Is the FLASH interrupt asserted: EOP with EOPIE, OPERR with ERRIE (RM0440,
    /// "Flash interrupts")?
    pub fn irq(&self) -> bool {
        (self.sr & SR_EOP != 0 && self.cr & CR_EOPIE != 0)
            || (self.sr & 2 != 0 && self.cr & (1 << 25) != 0)
    }

    /// When the running operation ends.
    pub fn next_event(&self) -> Option<u64> {
        (self.sr & SR_BSY != 0).then_some(self.busy_until)
    }

    /// Reads register `offset`.
    pub fn read(&mut self, offset: u32, now: u64) -> Result<u32, Unmodelled> {
        self.advance(now);
        Ok(match offset {
            0x00 => self.acr,
            0x04 | 0x08 | 0x0C => 0,
            0x10 => self.sr,
            0x14 => self.cr,
            0x18 => 0,
            0x20 => 0xFFEF_F8AA,
            _ => return Err(Unmodelled),
        })
    }

    /// Writes register `offset`.
    pub fn write(&mut self, offset: u32, value: u32, now: u64) -> Result<(), Unmodelled> {
        self.advance(now);
        match offset {
            0x00 => self.acr = value & 0x0000_7F0F,
            0x04 | 0x0C => {}
            0x08 => {
                self.key_step = match (self.key_step, value) {
                    (0, 0x4567_0123) => 1,
                    (1, 0xCDEF_89AB) => {
                        self.cr &= !CR_LOCK;
                        0
                    }
                    _ => 0,
                };
            }
            0x10 => self.sr &= !(value & 0xC3FB), // write-one-to-clear flags
            0x14 => {
                if self.cr & CR_LOCK != 0 {
                    return Ok(()); // locked: CR cannot be written (but LOCK stays)
                }
                self.cr = value & !CR_STRT;
                if value & CR_STRT != 0 {
                    self.start_erase(value, now)?;
                }
            }
            _ => return Err(Unmodelled),
        }
        Ok(())
    }

    fn start_erase(&mut self, cr: u32, now: u64) -> Result<(), Unmodelled> {
        if cr & CR_PER == 0 || self.sr & SR_BSY != 0 {
            self.sr |= SR_PGSERR;
            return Ok(());
        }
        let bank = u32::from(cr & CR_BKER != 0);
        let page = (cr >> 3) & 0x7F;
        let at = BASE + bank * (SIZE / 2) + page * PAGE;
        if !(CONFIG..CONFIG + CONFIG_SIZE).contains(&at) {
            return Err(Unmodelled);
        }
        self.sr |= SR_BSY;
        self.busy_until = now + from_ms(ERASE_MS);
        self.pending = Some((at, vec![0xFF; PAGE as usize]));
        self.erases += 1;
        Ok(())
    }

    /// Reads configuration-page memory at `addr`.
    pub fn read_memory(&self, addr: u32, size: usize) -> u32 {
        let o = (addr - CONFIG) as usize;
        let mut v = 0u32;
        for k in 0..size {
            v |= u32::from(self.config[o + k]) << (8 * k);
        }
        v
    }

    /// A write of `value` (`size` bytes) to configuration-page memory at `addr`.
    pub fn write_memory(&mut self, addr: u32, size: usize, value: u32, now: u64) {
        self.advance(now);
        if self.cr & CR_PG == 0 || self.cr & CR_LOCK != 0 || self.sr & SR_BSY != 0 {
            self.sr |= SR_PGSERR;
            return;
        }
        if size != 4 || addr % 4 != 0 {
            self.sr |= SR_PGAERR;
            return;
        }
        match self.half.take() {
            None if addr % 8 == 0 => self.half = Some((addr, value)),
            Some((first, lo)) if addr == first + 4 => {
                let o = (first - CONFIG) as usize;
                if self.config[o..o + 8].iter().any(|&b| b != 0xFF) {
                    self.sr |= SR_PROGERR;
                    return;
                }
                let mut bytes = lo.to_le_bytes().to_vec();
                bytes.extend_from_slice(&value.to_le_bytes());
                self.sr |= SR_BSY;
                self.busy_until = now + from_us(PROGRAM_US);
                self.pending = Some((first, bytes));
                self.programs += 1;
            }
            _ => self.sr |= SR_PGAERR,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unlocked() -> Flash {
        let mut f = Flash::new(vec![0xFF; CONFIG_SIZE as usize]);
        f.write(0x08, 0x4567_0123, 0).ok();
        f.write(0x08, 0xCDEF_89AB, 0).ok();
        f
    }

    #[test]
    fn a_page_erase_is_busy_then_leaves_the_page_erased() {
        let mut f = unlocked();
        f.config[0] = 0;
        // Bank 2, page 126 = the first configuration page.
        f.write(0x14, CR_PER | CR_BKER | 126 << 3 | CR_STRT, 0).ok();
        assert_ne!(f.read(0x10, 0).ok().unwrap_or(0) & SR_BSY, 0);
        assert_eq!(f.read(0x10, from_ms(ERASE_MS)).ok(), Some(0));
        assert_eq!(f.config[0], 0xFF);
    }

    #[test]
    fn a_double_word_is_programmed_only_when_erased_and_the_lock_holds() {
        let mut f = Flash::new(vec![0xFF; CONFIG_SIZE as usize]);
        f.write(0x14, CR_PG, 0).ok();
        assert_eq!(f.read(0x14, 0).ok(), Some(0xC000_0000));
        let mut f = unlocked();
        f.write(0x14, CR_PG, 0).ok();
        f.write_memory(CONFIG, 4, 0x1234_5678, 0);
        f.write_memory(CONFIG + 4, 4, 0x9ABC_DEF0, 0);
        f.advance(from_us(PROGRAM_US));
        assert_eq!(f.read_memory(CONFIG, 4), 0x1234_5678);
        assert_eq!(f.read_memory(CONFIG + 4, 4), 0x9ABC_DEF0);
        f.write_memory(CONFIG, 4, 0, from_us(PROGRAM_US));
        f.write_memory(CONFIG + 4, 4, 0, from_us(PROGRAM_US));
        assert_ne!(
            f.read(0x10, from_us(PROGRAM_US)).ok().unwrap_or(0) & SR_PROGERR,
            0
        );
    }
}
