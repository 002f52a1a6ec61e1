//! The Cortex-M4 system control space that the core executes against: the NVIC
//! (enable, pending, active, priority of 102 interrupt lines), the SCB registers the
//! firmware touches, SysTick, the FPU's control registers and DWT's cycle counter.
//!
//! Source: the ARMv7-M Architecture Reference Manual (ARM DDI 0403E), "System
//! Control Space" and "Nested Vectored Interrupt Controller", and ST's Cortex-M4
//! programming manual PM0214, "Core peripherals" (the registers as STM32 implements them:
//! four priority bits, bits 7:4 of each priority byte).
//!
//! Priorities here are the raw priority bytes with the unimplemented low nibble
//! cleared; a lower number is more urgent. PRIGROUP is honoured (group priority =
//! the bits above the sub-priority field).

/// Interrupt lines of the STM32G474 (RM0440 table "STM32G4 vector table": positions
/// 0–101).
pub const IRQ_LINES: usize = 102;
/// Exception number of interrupt line 0.
pub const IRQ0: u32 = 16;
/// Implemented priority bits mask (four bits: PM0214, the NVIC's priority registers).
pub const PRIO_MASK: u8 = 0xF0;

/// Exception numbers of the system exceptions used here.
pub mod exc {
    /// HardFault.
    pub const HARD_FAULT: u32 = 3;
    /// PendSV.
    pub const PENDSV: u32 = 14;
    /// SysTick.
    pub const SYSTICK: u32 = 15;
}

/// Why an access to the system control space failed.
pub struct Unknown;

/// The system control space's state.
pub struct Scs {
    /// Interrupt line enabled (ISER/ICER).
    pub enabled: [bool; IRQ_LINES],
    /// Exception pending, by exception number (0..16+IRQ_LINES).
    pub pending: Vec<bool>,
    /// When each exception became pending, time units (for latency figures).
    pub pending_since: Vec<u64>,
    /// Priority byte of each exception (system handlers from SHPR, lines from IPR).
    pub priority: Vec<u8>,
    /// Active exceptions, innermost last.
    pub active: Vec<u32>,
    /// AIRCR.PRIGROUP.
    pub prigroup: u8,
    /// VTOR.
    pub vtor: u32,
    /// SCR.
    pub scr: u32,
    /// CCR.
    pub ccr: u32,
    /// CPACR.
    pub cpacr: u32,
    /// FPCCR (PM0214 4.6.2): ASPEN bit 31, LSPEN bit 30, and the lazy-stacking state
    /// LSPACT bit 0, USER bit 1, THREAD bit 3, HFRDY bit 4.
    pub fpccr: u32,
    /// FPCAR (PM0214 4.6.3): the address of the deferred S0–S15 slot of the frame
    /// whose FP state is still in the registers.
    pub fpcar: u32,
    /// FPDSCR.
    pub fpdscr: u32,
    /// SHCSR.
    pub shcsr: u32,
    /// DEMCR.
    pub demcr: u32,
    /// DWT_CTRL.
    pub dwt_ctrl: u32,
    /// SysTick CSR, RVR.
    pub systick_csr: u32,
    /// SysTick reload value.
    pub systick_rvr: u32,
    /// A system reset was requested (AIRCR.SYSRESETREQ).
    pub reset_request: bool,
    /// The core's event register (WFE), set by SEV, exception entry and return.
    pub event: bool,
    /// Something that may change which exception is taken happened (a pend, an enable,
    /// a priority write): the run loop should look before running on.
    pub changed: bool,
}

impl Default for Scs {
    fn default() -> Self {
        let n = IRQ0 as usize + IRQ_LINES;
        Self {
            enabled: [false; IRQ_LINES],
            pending: vec![false; n],
            pending_since: vec![0; n],
            priority: vec![0; n],
            active: Vec::new(),
            prigroup: 0,
            vtor: 0,
            scr: 0,
            ccr: 0x0000_0200, // STKALIGN (PM0214, CCR: reset value 0x0000 0200)
            cpacr: 0,
            fpccr: 0xC000_0000, // ASPEN, LSPEN (PM0214, FPCCR)
            fpcar: 0,
            fpdscr: 0,
            shcsr: 0,
            demcr: 0,
            dwt_ctrl: 0x4000_0000,
            systick_csr: 0,
            systick_rvr: 0,
            reset_request: false,
            event: false,
            changed: false,
        }
    }
}

fn word_bit(base: u32, offset: u32) -> Option<usize> {
    (offset >= base && offset < base + 16).then(|| ((offset - base) / 4) as usize * 32)
}

impl Scs {
    /// Group priority of exception `e` (HardFault: -1, NMI -2 as i16).
    pub fn group_priority(&self, e: u32) -> i16 {
        match e {
            2 => -2,
            exc::HARD_FAULT => -1,
            _ => {
                let sub_bits = u32::from(self.prigroup) + 1;
                let mask = if sub_bits >= 8 { 0 } else { 0xFFu8 << sub_bits };
                i16::from(self.priority[e as usize] & PRIO_MASK & mask)
            }
        }
    }

    /// The priority the core executes at: the most urgent active exception, BASEPRI
    /// and PRIMASK (ARMv7-M ARM, "Execution priority").
    pub fn execution_priority(&self, basepri: u32, primask: u32) -> i16 {
        let mut p: i16 = 256;
        for &e in &self.active {
            p = p.min(self.group_priority(e));
        }
        let bp = (basepri as u8) & PRIO_MASK;
        if bp != 0 {
            let sub_bits = u32::from(self.prigroup) + 1;
            let mask = if sub_bits >= 8 { 0 } else { 0xFFu8 << sub_bits };
            p = p.min(i16::from(bp & mask));
        }
        if primask & 1 != 0 {
            p = p.min(0);
        }
        p
    }

    /// The pending exception that would be taken now: the most urgent enabled one,
    /// lowest number first among equals, if it is more urgent than `exec_priority`.
    pub fn next_exception(&self, exec_priority: i16) -> Option<u32> {
        let mut best: Option<(i16, u8, u32)> = None;
        for (e, &p) in self.pending.iter().enumerate() {
            if !p {
                continue;
            }
            let e = e as u32;
            if e >= IRQ0 && !self.enabled[(e - IRQ0) as usize] {
                continue;
            }
            let key = (
                self.group_priority(e),
                self.priority[e as usize] & PRIO_MASK,
                e,
            );
            if best.is_none_or(|b| key < b) {
                best = Some(key);
            }
        }
        best.filter(|b| b.0 < exec_priority).map(|b| b.2)
    }

    /// Sets exception `e` pending at time `now`.
    pub fn pend(&mut self, e: u32, now: u64) {
        let i = e as usize;
        if !self.pending[i] {
            self.pending[i] = true;
            self.pending_since[i] = now;
        }
        self.changed = true;
        // SEVONPEND: a pend wakes WFE even if it is not taken (PM0214, SCR).
        if self.scr & 0x10 != 0 {
            self.event = true;
        }
    }

    /// Sets interrupt line `irq` pending at `now`.
    pub fn pend_irq(&mut self, irq: usize, now: u64) {
        self.pend(IRQ0 + irq as u32, now);
    }

    fn bits(&self, base: usize, f: impl Fn(usize) -> bool) -> u32 {
        (0..32)
            .filter(|k| base + k < IRQ_LINES && f(base + k))
            .fold(0, |w, k| w | 1 << k)
    }

    /// Reads the word at `offset` from 0xE000_0000 (ITM/DWT/SCS/debug space).
    pub fn read(&self, offset: u32, cycles: u64) -> Result<u32, Unknown> {
        if let Some(b) = word_bit(0xE100, offset) {
            return Ok(self.bits(b, |i| self.enabled[i]));
        }
        if let Some(b) = word_bit(0xE180, offset) {
            return Ok(self.bits(b, |i| self.enabled[i]));
        }
        if let Some(b) = word_bit(0xE200, offset).or(word_bit(0xE280, offset)) {
            return Ok(self.bits(b, |i| self.pending[IRQ0 as usize + i]));
        }
        if let Some(b) = word_bit(0xE300, offset) {
            return Ok(self.bits(b, |i| self.active.contains(&(IRQ0 + i as u32))));
        }
        if (0xE400..0xE400 + IRQ_LINES as u32).contains(&offset) {
            let i = IRQ0 as usize + (offset - 0xE400) as usize;
            let b = |k: usize| u32::from(*self.priority.get(i + k).unwrap_or(&0));
            return Ok(b(0) | b(1) << 8 | b(2) << 16 | b(3) << 24);
        }
        if (0xED18..0xED24).contains(&offset) {
            let i = 4 + (offset - 0xED18) as usize;
            let b = |k: usize| u32::from(self.priority[i + k]);
            return Ok(b(0) | b(1) << 8 | b(2) << 16 | b(3) << 24);
        }
        Ok(match offset {
            0x1000 => self.dwt_ctrl,
            0x1004 => cycles as u32, // DWT_CYCCNT
            0xE004 => 0x3,           // ICTR: 4 × 32 interrupt lines
            0xE010 => self.systick_csr,
            0xE014 => self.systick_rvr,
            0xE018 => 0,
            0xED00 => 0x410F_C241, // CPUID: Cortex-M4 r0p1 (PM0214, CPUID)
            0xED04 => self.icsr(),
            0xED08 => self.vtor,
            0xED0C => 0xFA05_0000 | u32::from(self.prigroup) << 8,
            0xED10 => self.scr,
            0xED14 => self.ccr,
            0xED24 => self.shcsr,
            0xED28 | 0xED2C | 0xED30 | 0xED34 | 0xED38 | 0xED3C => 0, // fault status
            0xED88 => self.cpacr,
            0xEDFC => self.demcr,
            0xEF34 => self.fpccr,
            0xEF38 => self.fpcar,
            0xEF3C => self.fpdscr,
            _ => return Err(Unknown),
        })
    }

    fn icsr(&self) -> u32 {
        let active = self.active.last().copied().unwrap_or(0);
        let pending = (0..self.pending.len() as u32)
            .filter(|&e| self.pending[e as usize])
            .max_by_key(|&e| -self.group_priority(e))
            .unwrap_or(0);
        let mut v = active & 0x1FF | (pending & 0x1FF) << 12;
        if self.pending.iter().skip(IRQ0 as usize).any(|&p| p) {
            v |= 1 << 22; // ISRPENDING
        }
        if self.pending[exc::PENDSV as usize] {
            v |= 1 << 28;
        }
        if self.pending[exc::SYSTICK as usize] {
            v |= 1 << 26;
        }
        if self.active.len() <= 1 {
            v |= 1 << 11; // RETTOBASE
        }
        v
    }

    /// Writes `value` (`size` bytes) at `offset` from 0xE000_0000.
    pub fn write(&mut self, offset: u32, size: u32, value: u32, now: u64) -> Result<(), Unknown> {
        if (0xE400..0xE400 + IRQ_LINES as u32).contains(&offset) {
            let i = IRQ0 as usize + (offset - 0xE400) as usize;
            for k in 0..size as usize {
                if let Some(p) = self.priority.get_mut(i + k) {
                    *p = (value >> (8 * k)) as u8 & PRIO_MASK;
                }
            }
            self.changed = true;
            return Ok(());
        }
        if (0xED18..0xED24).contains(&offset) {
            let i = 4 + (offset - 0xED18) as usize;
            for k in 0..size as usize {
                self.priority[i + k] = (value >> (8 * k)) as u8 & PRIO_MASK;
            }
            self.changed = true;
            return Ok(());
        }
        let lines = |base: u32| word_bit(base, offset);
        if let Some(b) = lines(0xE100) {
            self.set_lines(b, value, |s, i| s.enabled[i] = true);
        } else if let Some(b) = lines(0xE180) {
            self.set_lines(b, value, |s, i| s.enabled[i] = false);
        } else if let Some(b) = lines(0xE200) {
            self.set_lines(b, value, |s, i| s.pend_irq(i, now));
        } else if let Some(b) = lines(0xE280) {
            self.set_lines(b, value, |s, i| s.pending[IRQ0 as usize + i] = false);
        } else {
            match offset {
                0x1000 => self.dwt_ctrl = value,
                0x1004 => {} // DWT_CYCCNT: the count is the board's
                0xE010 => {
                    if value & 1 != 0 {
                        return Err(Unknown); // SysTick counting: not modelled (unused)
                    }
                    self.systick_csr = value;
                }
                0xE014 => self.systick_rvr = value & 0x00FF_FFFF,
                0xE018 => {}
                0xED04 => {
                    if value & (1 << 28) != 0 {
                        self.pend(exc::PENDSV, now);
                    }
                    if value & (1 << 27) != 0 {
                        self.pending[exc::PENDSV as usize] = false;
                    }
                    if value & (1 << 26) != 0 {
                        self.pend(exc::SYSTICK, now);
                    }
                    if value & (1 << 25) != 0 {
                        self.pending[exc::SYSTICK as usize] = false;
                    }
                }
                0xED08 => self.vtor = value & 0xFFFF_FF80,
                0xED0C => {
                    if value >> 16 != 0x05FA {
                        return Ok(()); // writes without VECTKEY are ignored
                    }
                    self.prigroup = ((value >> 8) & 7) as u8;
                    if value & 4 != 0 {
                        self.reset_request = true;
                    }
                    self.changed = true;
                }
                0xED10 => self.scr = value & 0x16,
                0xED14 => self.ccr = value,
                0xED24 => self.shcsr = value,
                0xED28..=0xED3C => {} // fault status: write-one-to-clear, nothing set
                0xED88 => self.cpacr = value,
                0xEDFC => self.demcr = value,
                0xEF00 => self.pend_irq((value & 0x1FF) as usize % IRQ_LINES, now),
                // LSPEN is modelled both ways. Clearing ASPEN (QEMU keeps its own copy,
                // which sets CONTROL.FPCA) or writing the state bits is not modelled.
                0xEF34
                    if value & 0x8000_0000 != 0
                        && value & 0x3FFF_FFFF == self.fpccr & 0x3FFF_FFFF =>
                {
                    self.fpccr = value
                }
                0xEF38 => self.fpcar = value & !7,
                0xEF3C => self.fpdscr = value,
                _ => return Err(Unknown),
            }
        }
        Ok(())
    }

    fn set_lines(&mut self, base: usize, value: u32, f: impl Fn(&mut Self, usize)) {
        for k in 0..32 {
            if value & (1 << k) != 0 && base + k < IRQ_LINES {
                f(self, base + k);
            }
        }
        self.changed = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scs_with(lines: &[(usize, u8)]) -> Scs {
        let mut s = Scs::default();
        for &(irq, prio) in lines {
            s.write(0xE400 + irq as u32, 1, u32::from(prio), 0).ok();
            s.write(0xE100 + (irq as u32 / 32) * 4, 4, 1 << (irq % 32), 0)
                .ok();
        }
        s
    }

    #[test]
    fn the_most_urgent_pending_line_preempts_only_a_less_urgent_context() {
        let mut s = scs_with(&[(55, 0x00), (63, 0x10), (20, 0x20)]);
        s.pend_irq(20, 1);
        s.pend_irq(63, 2);
        // Thread mode: the most urgent of the two.
        assert_eq!(
            s.next_exception(s.execution_priority(0, 0)),
            Some(IRQ0 + 63)
        );
        // BASEPRI at 0x10 masks 0x10 and below in urgency.
        assert_eq!(s.next_exception(s.execution_priority(0x10, 0)), None);
        // PRIMASK masks all configurable ones.
        assert_eq!(s.next_exception(s.execution_priority(0, 1)), None);
        // Inside the tick (0x10), the servo line (0x00) preempts, USB (0x20) does not.
        s.active.push(IRQ0 + 63);
        s.pending[(IRQ0 + 63) as usize] = false;
        assert_eq!(s.next_exception(s.execution_priority(0, 0)), None);
        s.pend_irq(55, 3);
        assert_eq!(
            s.next_exception(s.execution_priority(0, 0)),
            Some(IRQ0 + 55)
        );
    }

    #[test]
    fn a_disabled_line_stays_pending_and_is_not_taken() {
        let mut s = scs_with(&[(54, 0x30)]);
        s.write(0xE180 + 4, 4, 1 << (54 - 32), 0).ok();
        s.pend_irq(54, 0);
        assert_eq!(s.next_exception(256), None);
        assert_eq!(s.read(0xE204, 0).ok(), Some(1 << (54 - 32)));
    }

    #[test]
    fn equal_priorities_do_not_preempt_and_the_lower_number_wins() {
        let mut s = scs_with(&[(20, 0x20), (19, 0x20)]);
        s.pend_irq(20, 0);
        s.pend_irq(19, 0);
        assert_eq!(s.next_exception(256), Some(IRQ0 + 19));
        s.active.push(IRQ0 + 19);
        s.pending[(IRQ0 + 19) as usize] = false;
        assert_eq!(s.next_exception(s.execution_priority(0, 0)), None);
    }
}
