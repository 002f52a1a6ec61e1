//! Peripherals whose registers the firmware only configures, with no behaviour the
//! board depends on: a register file with the reset values of RM0440's register maps,
//! in which every named register keeps what is written. Reads of an offset the map
//! does not name are unmodelled.

use super::Unmodelled;

/// A register file: (offset, reset value, writable mask) per register.
pub struct Plain {
    /// Name, for messages.
    pub name: &'static str,
    regs: Vec<(u32, u32, u32)>,
    values: Vec<u32>,
}

impl Plain {
    /// A peripheral with registers `regs` (offset, reset value, writable bits).
    pub fn new(name: &'static str, regs: &[(u32, u32, u32)]) -> Self {
        Self {
            name,
            regs: regs.to_vec(),
            values: regs.iter().map(|r| r.1).collect(),
        }
    }

    fn index(&self, offset: u32) -> Result<usize, Unmodelled> {
        self.regs
            .iter()
            .position(|r| r.0 == offset)
            .ok_or(Unmodelled)
    }

    /// Reads the register at `offset`.
    pub fn read(&self, offset: u32) -> Result<u32, Unmodelled> {
        Ok(self.values[self.index(offset)?])
    }

    /// Writes the register at `offset` (its writable bits).
    pub fn write(&mut self, offset: u32, value: u32) -> Result<(), Unmodelled> {
        let i = self.index(offset)?;
        let mask = self.regs[i].2;
        self.values[i] = self.values[i] & !mask | value & mask;
        Ok(())
    }

    /// Back to the reset values.
    pub fn reset(&mut self) {
        for (v, r) in self.values.iter_mut().zip(&self.regs) {
            *v = r.1;
        }
    }
}

/// SYSCFG (RM0440, SYSCFG register map): MEMRMP, CFGR1, EXTICR1–4, SCSR, CFGR2, SWPR,
/// SKR.
pub fn syscfg() -> Plain {
    Plain::new(
        "SYSCFG",
        &[
            (0x00, 0, 0x0000_0107),
            (0x04, 0x7C00_0001, 0xFFFF_FFFF),
            (0x08, 0, 0xFFFF),
            (0x0C, 0, 0xFFFF),
            (0x10, 0, 0xFFFF),
            (0x14, 0, 0xFFFF),
            (0x18, 0, 0x3),
            (0x1C, 0, 0xF),
            (0x20, 0, 0xFFFF_FFFF),
            (0x24, 0, 0xFF),
        ],
    )
}

/// EXTI (RM0440, EXTI register map): IMR1, EMR1, RTSR1, FTSR1, SWIER1, PR1 and the
/// same for lines 32–43. Reset values of IMR1 and IMR2 per their register descriptions (the
/// direct lines unmasked).
pub fn exti() -> Plain {
    Plain::new(
        "EXTI",
        &[
            (0x00, 0xFF82_0000, 0xFFFF_FFFF),
            (0x04, 0, 0xFFFF_FFFF),
            (0x08, 0, 0xFFFF_FFFF),
            (0x0C, 0, 0xFFFF_FFFF),
            (0x10, 0, 0xFFFF_FFFF),
            (0x14, 0, 0), // PR1: no edge is ever detected here (inputs are polled)
            (0x20, 0x0000_0187, 0xFFFF_FFFF),
            (0x24, 0, 0xFFFF_FFFF),
            (0x28, 0, 0xFFFF_FFFF),
            (0x2C, 0, 0xFFFF_FFFF),
            (0x30, 0, 0xFFFF_FFFF),
            (0x34, 0, 0),
        ],
    )
}

/// DBGMCU (RM0440, "DBGMCU registers"): IDCODE (DEV_ID 0x469, the STM32G47x/G48x category 3), CR,
/// APB1FZR1, APB1FZR2, APB2FZR.
pub fn dbgmcu() -> Plain {
    Plain::new(
        "DBGMCU",
        &[
            (0x00, 0x2000_6469, 0),
            (0x04, 0, 0xFFFF_FFFF),
            (0x08, 0, 0xFFFF_FFFF),
            (0x0C, 0, 0xFFFF_FFFF),
            (0x10, 0, 0xFFFF_FFFF),
        ],
    )
}

/// CRS (RM0440, CRS register map): CR, CFGR (reset 0x2022_BB7F), ISR, ICR. The HSI48 trimming is
/// not modelled: the USB host of this board does not depend on the clock's accuracy.
pub fn crs() -> Plain {
    Plain::new(
        "CRS",
        &[
            (0x00, 0x0000_4000, 0x0000_7FEF),
            (0x04, 0x2022_BB7F, 0xFFFF_FFFF),
            (0x08, 0, 0),
            (0x0C, 0, 0),
        ],
    )
}

/// The OPAMP control registers (RM0440, OPAMP register map: OPAMPx_CSR at 0x00–0x14, OPAMPx_TCMR at
/// 0x18–0x2C). An enabled follower's output is its input: the board reads the DAC
/// channel behind it.
pub fn opamp() -> Plain {
    let mut regs = Vec::new();
    for k in 0..6 {
        regs.push((4 * k, 0, 0xFFFF_FFFF));
        regs.push((0x18 + 4 * k, 0, 0xFFFF_FFFF));
    }
    Plain::new("OPAMP", &regs)
}

/// COMP1–COMP7 control registers (RM0440, COMP register map: COMPx_CSR at 0x00–0x18).
pub fn comp() -> Plain {
    let regs: Vec<(u32, u32, u32)> = (0..7).map(|k| (4 * k, 0, 0xFFFF_FFFF)).collect();
    Plain::new("COMP", &regs)
}
