//! HRTIM1: the DLL calibration, the master timer's enables, and timer A in the
//! low-resolution continuous mode the firmware's STEP train uses, with its preload
//! registers, repetition counter and output 2's set/reset sources.
//!
//! Source: RM0440, "High-resolution timer (HRTIM)":
//!
//! - "Clocks": CKPSC ≥ 5 counts at f_HRTIM / 2^(CKPSC − 5) (low resolution); finer
//!   ratios (CKPSC < 5) are not modelled and stop the board.
//! - "Counter operating modes": in continuous mode the counter rolls over to 0 when
//!   it reaches the period value PER and goes on; the roll-over generates the period
//!   event. Read here as: a period lasts PER counts (the counter is 0 … PER − 1), the
//!   reading `src/bin/firmware/steppers.rs` designs its trains for. Whether the last
//!   count PER itself lasts a clock on silicon (PER + 1 counts a period) is not settled
//!   by the manual's text; a board would tell: 5.9 ns a step at CKPSC 5.
//! - "Repetition counter": loaded from REP when the timer is enabled and at each
//!   repetition event; decremented at each roll-over; the repetition event comes at
//!   the roll-over at which it is already 0 (so every REP + 1 periods), sets REP in
//!   TIMxISR and, with TxREPU = 1, is an update event.
//! - "Registers preload and update": with PREEN = 1, PER, REP, CMP1–4 and the output
//!   set/reset registers are written into preload registers and transferred at an
//!   update event: a software update (TxSWU in HRTIM_CR2, immediate, sets UPD in
//!   TIMxISR) or the repetition event with TxREPU. With PREEN = 0 they act at once.
//! - "Waveform compare and capture" / "Outputs": output x is set by the events in
//!   SETxyR and reset by those of RSTxyR (bit 2 PER: period event; bit 3 CMP1: the
//!   counter reaching CMP1; bit 0 SST/SRT: a software set/reset acting at once, not
//!   preloaded). An output in RUN state (OENR) drives its pin.
//! - "DLL calibration": CAL starts a calibration; DLLRDY in HRTIM_ISR is set when it
//!   is done (the board takes [`DLL_CAL_US`]).

use super::Unmodelled;
use crate::periph::timer::Pulse;
use crate::time::from_us;

/// Time a DLL calibration takes here (a modelling choice; the manual requires
/// waiting for DLLRDY).
pub const DLL_CAL_US: u64 = 10;

/// Registers of timer A with a preload copy: PER, REP, CMP1–4, SETA1R, RSTA1R,
/// SETA2R, RSTA2R (offsets from the timer's base).
const PRELOADED: [u32; 10] = [0x14, 0x18, 0x1C, 0x24, 0x28, 0x2C, 0x3C, 0x40, 0x44, 0x48];

/// Timer A and the parts of HRTIM1 around it.
pub struct Hrtim {
    /// Time units per f_HRTIM cycle.
    pub clock_units: u64,
    mcr: u32,
    /// Common registers stored as written (0x380–0x3FC), indexed by word.
    common: [u32; 32],
    dll_ready_at: Option<u64>,
    cr: u32,
    isr: u32,
    dier: u32,
    preload: [u32; 10],
    active: [u32; 10],
    /// Other timer-A registers, stored as written (0x00–0x7C by word).
    other: [u32; 32],
    cnt_at: u32,
    since: u64,
    rep_left: u32,
    out2: bool,
    out2_since: u64,
    /// Pulses of output 2 completed (channel index 1).
    pub pulses: Vec<Pulse>,
    /// Output 2's edges are wanted (a STEP output); else whole periods are skipped.
    pub edges: bool,
}

impl Hrtim {
    /// HRTIM1 at reset, f_HRTIM at `clock_units` per cycle.
    pub fn new(clock_units: u64) -> Self {
        Self {
            clock_units,
            mcr: 0,
            common: [0; 32],
            dll_ready_at: None,
            cr: 0,
            isr: 0,
            dier: 0,
            preload: [0; 10],
            active: [0; 10],
            other: [0; 32],
            cnt_at: 0,
            since: 0,
            rep_left: 0,
            out2: false,
            out2_since: 0,
            pulses: Vec::new(),
            edges: true,
        }
    }

    fn idx(offset: u32) -> Option<usize> {
        PRELOADED.iter().position(|&o| o == offset)
    }

    fn act(&self, offset: u32) -> u32 {
        Self::idx(offset).map_or(0, |i| self.active[i])
    }

    fn running(&self) -> bool {
        self.mcr & (1 << 17) != 0
    }

    /// Time units per count: f_HRCK = f_HRTIM × 32 / 2^CKPSC ("Clocks"); CKPSC 0
    /// (0.18 ns) is finer than the board's time unit and not modelled.
    fn units_per_count(&self) -> Result<u64, Unmodelled> {
        let ckpsc = self.cr & 7;
        let scaled = self.clock_units << ckpsc;
        if scaled % 32 != 0 {
            return Err(Unmodelled);
        }
        Ok(scaled / 32)
    }

    /// The duty of output 2 as a 12-bit command code, for a PWM set by the period
    /// event and reset by CMP1 (high from the period start to CMP1): CMP1 × 4096 / PER
    /// of the active registers; None unless the timer runs with output 2 enabled in
    /// that configuration.
    pub fn duty_code(&self) -> Option<u16> {
        let oen = self.common[(0x394 - 0x380) / 4] & 2 != 0;
        let pwm = self.act(0x44) == 1 << 2 && self.act(0x48) == 1 << 3;
        let per = self.act(0x14);
        (self.running() && oen && pwm && per > 0)
            .then(|| (u64::from(self.act(0x1C)) * 4096 / u64::from(per)).min(4095) as u16)
    }

    fn set_out2(&mut self, high: bool, t: u64) {
        if high && !self.out2 {
            self.out2 = true;
            self.out2_since = t;
        } else if !high && self.out2 {
            self.out2 = false;
            if self.common[(0x394 - 0x380) / 4] & 2 != 0 {
                self.pulses.push(Pulse {
                    channel: 1,
                    rise: self.out2_since,
                    fall: t,
                });
            }
        }
    }

    fn update(&mut self) {
        self.active = self.preload;
        self.isr |= 1 << 6;
    }

    /// Runs timer A up to `now`.
    pub fn advance(&mut self, now: u64) {
        if !self.running() {
            self.since = self.since.max(now);
            return;
        }
        let Ok(upc) = self.units_per_count() else {
            return;
        };
        if !self.edges {
            self.skip_to(now, upc);
            return;
        }
        loop {
            let per = self.act(0x14).max(1);
            let cmp1 = self.act(0x1C);
            let cnt = self.cnt_at.min(per);
            // The CMP1 event of this period, if still ahead.
            if cmp1 > cnt && cmp1 < per {
                let t = self.since + u64::from(cmp1 - cnt) * upc;
                if t > now {
                    break;
                }
                if self.act(0x44) & (1 << 3) != 0 {
                    self.set_out2(true, t);
                }
                if self.act(0x48) & (1 << 3) != 0 {
                    self.set_out2(false, t);
                }
                self.cnt_at = cmp1;
                self.since = t;
                continue;
            }
            let t = self.since + u64::from(per - cnt) * upc;
            if t > now {
                break;
            }
            // Roll-over: period event, repetition counter.
            if self.act(0x44) & (1 << 2) != 0 {
                self.set_out2(true, t);
            }
            if self.act(0x48) & (1 << 2) != 0 {
                self.set_out2(false, t);
            }
            self.cnt_at = 0;
            self.since = t;
            if self.rep_left == 0 {
                self.isr |= 1 << 4;
                if self.cr & (1 << 17) != 0 {
                    self.update();
                }
                self.rep_left = self.act(0x18) & 0xFF;
            } else {
                self.rep_left -= 1;
            }
        }
        let elapsed = (now - self.since) / upc;
        self.cnt_at += elapsed as u32;
        self.since += elapsed * upc;
    }

    /// Advances whole periods at once when nobody takes output 2's edges (a PWM
    /// command): the roll-overs' repetition events and their preload transfers only.
    fn skip_to(&mut self, now: u64, upc: u64) {
        let per = u64::from(self.act(0x14).max(1));
        let cnt = u64::from(self.cnt_at.min(self.act(0x14)));
        let to_first = (per - cnt) * upc;
        if self.since + to_first > now {
            let elapsed = (now - self.since) / upc;
            self.cnt_at += elapsed as u32;
            self.since += elapsed * upc;
            return;
        }
        let rollovers = 1 + (now - self.since - to_first) / (per * upc);
        let last = self.since + to_first + (rollovers - 1) * per * upc;
        if rollovers > u64::from(self.rep_left) {
            // At least one repetition event: the last one's transfer stands.
            self.isr |= 1 << 4;
            if self.cr & (1 << 17) != 0 {
                self.update();
            }
            let rep = u64::from(self.act(0x18) & 0xFF) + 1;
            let after = (rollovers - u64::from(self.rep_left) - 1) % rep;
            self.rep_left = (rep - 1 - after) as u32;
        } else {
            self.rep_left -= rollovers as u32;
        }
        self.cnt_at = 0;
        self.since = last;
        let elapsed = (now - last) / upc;
        self.cnt_at = elapsed as u32;
        self.since = last + elapsed * upc;
    }

    /// Reads `offset` (from HRTIM1's base) at `now`.
    pub fn read(&mut self, offset: u32, now: u64) -> Result<u32, Unmodelled> {
        self.advance(now);
        Ok(match offset {
            0x000 => self.mcr,
            0x004..=0x07C => 0,
            0x080..=0x0FC => {
                let o = offset - 0x80;
                match o {
                    0x00 => self.cr,
                    0x04 => self.isr | u32::from(self.out2) << 18,
                    0x08 => 0,
                    0x0C => self.dier,
                    0x10 => self.cnt_at,
                    _ => match Self::idx(o) {
                        Some(i) => self.preload[i],
                        None => self.other[(o / 4) as usize],
                    },
                }
            }
            0x388 => {
                let ready = self.dll_ready_at.is_some_and(|t| now >= t);
                u32::from(ready) << 16
            }
            0x380..=0x3FC => self.common[((offset - 0x380) / 4) as usize],
            _ => return Err(Unmodelled),
        })
    }

    /// Writes `offset` (from HRTIM1's base) at `now`.
    pub fn write(&mut self, offset: u32, value: u32, now: u64) -> Result<(), Unmodelled> {
        self.advance(now);
        match offset {
            0x000 => {
                let was = self.running();
                self.mcr = value;
                if self.running() && !was {
                    self.units_per_count()?;
                    self.since = now;
                    self.rep_left = self.act(0x18) & 0xFF;
                }
                if value & !(1 << 17) & 0x007E_0000 != 0 || value & (1 << 16) != 0 {
                    return Err(Unmodelled); // other timers or the master: unused
                }
            }
            0x080..=0x0FC => self.write_timer(offset - 0x80, value, now)?,
            0x384 => {
                // CR2: TASWU (bit 1) is a software update of timer A.
                if value & 2 != 0 {
                    self.update();
                }
                if value & !2 != 0 {
                    return Err(Unmodelled);
                }
            }
            0x3CC => {
                if value & 1 != 0 {
                    self.dll_ready_at = Some(now + from_us(DLL_CAL_US));
                }
                self.common[(0x3CC - 0x380) / 4] = value & !1;
            }
            0x394 => {
                // OENR: write one to enable (set-only).
                self.common[(0x394 - 0x380) / 4] |= value;
            }
            0x398 => self.common[(0x394 - 0x380) / 4] &= !value, // ODISR
            0x380..=0x3FC => self.common[((offset - 0x380) / 4) as usize] = value,
            _ => return Err(Unmodelled),
        }
        Ok(())
    }

    fn write_timer(&mut self, o: u32, value: u32, now: u64) -> Result<(), Unmodelled> {
        match o {
            0x00 => self.cr = value,
            0x04 => {}
            0x08 => self.isr &= !value,
            0x0C => self.dier = value,
            0x10 => {
                if self.running() {
                    return Err(Unmodelled); // CNT is written only while stopped
                }
                self.cnt_at = value & 0xFFFF;
                self.since = now;
            }
            _ => {
                if let Some(i) = Self::idx(o) {
                    // SST/SRT act at once and are not stored.
                    if o == 0x44 && value & 1 != 0 {
                        self.set_out2(true, now);
                    }
                    if o == 0x48 && value & 1 != 0 {
                        self.set_out2(false, now);
                    }
                    let v = if o >= 0x3C { value & !1 } else { value };
                    self.preload[i] = v;
                    if self.cr & (1 << 27) == 0 {
                        self.active[i] = v;
                    }
                } else {
                    self.other[(o / 4) as usize] = value;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Timer A at CKPSC 5, preloaded, a train of `count` pulses of `per` counts rising
    /// at `cmp1`, started as the firmware's step output starts it.
    fn train(per: u32, cmp1: u32, count: u32) -> Hrtim {
        let mut h = Hrtim::new(16);
        h.write(0x3CC, 1, 0).ok();
        h.write(0x394, 2, 0).ok();
        h.write(0x80, 5 | 1 << 3 | 1 << 27 | 1 << 17, 0).ok();
        h.write(0x80 + 0x14, per, 0).ok();
        h.write(0x80 + 0x1C, cmp1, 0).ok();
        h.write(0x80 + 0x18, count - 1, 0).ok();
        h.write(0x80 + 0x44, 1 << 3, 0).ok();
        h.write(0x80 + 0x48, 1 << 2, 0).ok();
        h.write(0x384, 2, 0).ok();
        h.write(0x80 + 0x44, 0, 0).ok();
        h.write(0x80 + 0x10, cmp1 - 1, 0).ok();
        h.write(0x000, 1 << 17, 0).ok();
        h
    }

    #[test]
    fn the_dll_reports_ready_after_calibration() {
        let mut h = Hrtim::new(16);
        h.write(0x3CC, 1, 0).ok();
        assert_eq!(h.read(0x388, 0).ok(), Some(0));
        assert_eq!(h.read(0x388, from_us(DLL_CAL_US)).ok(), Some(1 << 16));
    }

    #[test]
    fn the_repetition_event_ends_a_train_of_rep_plus_one_pulses() {
        let mut h = train(100, 90, 4);
        h.advance(16 * 10_000);
        assert_eq!(h.pulses.len(), 4);
        // Each pulse: CMP1 to the roll-over, 10 counts of 16 units; periods of 100.
        let first = h.pulses[0];
        assert_eq!((first.rise, first.fall), (16, 16 * 11));
        assert_eq!(h.pulses[3].rise - h.pulses[2].rise, 1600);
        assert_ne!(h.read(0x84, 16 * 10_000).ok().unwrap_or(0) & (1 << 4), 0);
    }

    #[test]
    fn without_preload_a_set_source_acts_at_once() {
        let mut h = Hrtim::new(16);
        h.write(0x394, 2, 0).ok();
        h.write(0x80 + 0x44, 1, 5).ok();
        h.write(0x80 + 0x48, 1, 50).ok();
        assert_eq!(
            h.pulses,
            vec![Pulse {
                channel: 1,
                rise: 5,
                fall: 50
            }]
        );
    }
}
