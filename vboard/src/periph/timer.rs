//! The STM32G474's timers TIM1–TIM8, TIM15–TIM17 and TIM20, in the modes the firmware
//! uses: up-counting with prescaler, auto-reload and repetition counter, their preload
//! registers and update events, one-pulse mode, output compare channels in PWM modes 1
//! and 2 (as STEP pulses), the update interrupt with UIFREMAP, and the encoder
//! interface.
//!
//! Source: RM0440, the chapters "Advanced-control timers (TIM1/TIM8/TIM20)",
//! "General-purpose timers (TIM2/TIM3/TIM4/TIM5)", "General purpose timers
//! (TIM15/TIM16/TIM17)" and "Basic timers (TIM6/TIM7)". The sections named below are
//! the advanced-control chapter's; the other chapters have the same sections for the
//! parts their timers have.
//!
//! - "Time-base unit": PSC, ARR (preloaded when ARPE = 1) and RCR are written
//!   to preload registers and copied to their shadows at an update event (UEV); CNT
//!   is read and written directly. The counter counts at f_CK_PSC / (PSC + 1).
//! - "Upcounting mode": the counter counts from 0 to the auto-reload value,
//!   restarts from 0 and generates a counter overflow. UG in EGR also generates an
//!   update event and reinitialises the counter (and the prescaler counter). With
//!   URS = 1 only the overflow sets UIF and raises the interrupt, not UG.
//! - "Repetition counter": an update event is generated only when the
//!   repetition down-counter reaches zero; it is reloaded from RCR at every UEV. So
//!   with RCR = N, overflows N + 1, 2N + 2, … are update events.
//! - "One-pulse mode": with OPM = 1 the counter stops (CEN cleared) at the
//!   next update event.
//! - "PWM mode": mode 1 is active while CNT < CCRx, mode 2 is inactive while
//!   CNT < CCRx and active otherwise; CCRx is preloaded when OCxPE = 1 and copied at
//!   each UEV. The output is OCxREF with polarity CCxP, driven only when CCxE = 1
//!   and, on timers with break, MOE = 1 (the table of output control bits for complementary channels with break).
//! - "Encoder interface mode": SMS = 001/010/011 counts on TI2, TI1, or both
//!   edges, up or down by the other input's level (table "Counting direction versus
//!   encoder signals"); the counter wraps between 0 and ARR.
//! - TIMx_CNT's description: bit 31 is a copy of UIF when UIFREMAP = 1.
//! - "Input capture mode" (general-purpose chapters; TIMx_CCMR1/2 in input capture
//!   mode, TIMx_CCER, TIMx_SR, TIMx_CCRx): with CCxS = 01 the channel's input ICx is
//!   its own TIx, with 10 the other input of its pair (TI2 for channel 1, TI1 for
//!   channel 2, TI4 for 3, TI3 for 4); TIx passes the digital filter ICxF (N
//!   consecutive equal samples at f_SAMPLING = f_CK_INT or f_DTS / 2…32, f_DTS from
//!   CKD; table of ICxF); the edge detector takes the rising edge (CCxP = 0,
//!   CCxNP = 0), the falling one (1, 0) or both (1, 1); ICxPSC captures every 1st,
//!   2nd, 4th or 8th edge (its count reset while CCxE = 0). With CCxE = 1 a capture
//!   copies the counter into CCRx and sets CCxIF; CCxOF is set if CCxIF was still
//!   set. CCRx is read-only in input mode and reading it clears CCxIF. Modelled
//!   without the input resynchroniser and the sampling clock's phase: a level passes
//!   the filter once it has held for N sampling periods from the instant it changed.
//!   The capture interrupts are not modelled (setting CCxIE stops the run).

use crate::periph::Unmodelled;

/// Register offsets (RM0440, the TIMx register map).
mod reg {
    pub const CR1: u32 = 0x00;
    pub const CR2: u32 = 0x04;
    pub const SMCR: u32 = 0x08;
    pub const DIER: u32 = 0x0C;
    pub const SR: u32 = 0x10;
    pub const EGR: u32 = 0x14;
    pub const CCMR1: u32 = 0x18;
    pub const CCMR2: u32 = 0x1C;
    pub const CCER: u32 = 0x20;
    pub const CNT: u32 = 0x24;
    pub const PSC: u32 = 0x28;
    pub const ARR: u32 = 0x2C;
    pub const RCR: u32 = 0x30;
    pub const CCR1: u32 = 0x34;
    pub const CCR4: u32 = 0x40;
    pub const BDTR: u32 = 0x44;
    pub const CCR5: u32 = 0x48;
    pub const CCR6: u32 = 0x4C;
    pub const CCMR3: u32 = 0x50;
    pub const DTR2: u32 = 0x54;
    pub const ECR: u32 = 0x58;
    pub const TISEL: u32 = 0x5C;
    pub const AF1: u32 = 0x60;
    pub const AF2: u32 = 0x64;
    pub const OR: u32 = 0x68;
    pub const DCR: u32 = 0x3DC;
}

const CR1_CEN: u32 = 1;
const CR1_URS: u32 = 1 << 2;
const CR1_OPM: u32 = 1 << 3;
const CR1_DIR: u32 = 1 << 4;
const CR1_CMS: u32 = 3 << 5;
const CR1_ARPE: u32 = 1 << 7;
const CR1_UIFREMAP: u32 = 1 << 11;
const SR_UIF: u32 = 1;
const DIER_UIE: u32 = 1;

/// What kind of timer: which registers it has.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Kind {
    /// TIM6, TIM7: basic.
    Basic,
    /// TIM2–TIM5: general purpose, four channels (TIM2/TIM5 32-bit).
    General {
        /// 32-bit counter.
        wide: bool,
    },
    /// TIM1, TIM8, TIM20: advanced, 16-bit repetition counter, six channels.
    Advanced,
    /// TIM15 (two channels), TIM16, TIM17 (one): 8-bit repetition counter, break.
    Compact {
        /// Channels.
        channels: usize,
    },
}

/// A STEP-like pulse on a channel output: rising at `rise`, falling at `fall` (time
/// units).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pulse {
    /// Channel index, 0-based.
    pub channel: usize,
    /// Time of the active edge.
    pub rise: u64,
    /// Time of the inactive edge.
    pub fall: u64,
}

/// One timer.
pub struct Timer {
    /// Name, for messages.
    pub name: &'static str,
    kind: Kind,
    /// Time units per kernel-clock cycle.
    pub clock_units: u64,
    cr1: u32,
    cr2: u32,
    smcr: u32,
    dier: u32,
    sr: u32,
    ccmr: [u32; 3],
    ccer: u32,
    psc: u32,
    psc_active: u32,
    arr: u32,
    arr_active: u32,
    rcr: u32,
    rep_left: u32,
    ccr: [u32; 6],
    ccr_active: [u32; 6],
    bdtr: u32,
    other: [u32; 8],
    /// Counter value at `since`.
    cnt_at: u32,
    /// Time the counter had `cnt_at` (counting from there while CEN = 1).
    since: u64,
    /// Output levels (OCxREF after polarity and enables) at `since`, per channel.
    high_since: [Option<u64>; 6],
    /// Pulses completed, waiting for the board to take them.
    pub pulses: Vec<Pulse>,
    /// Update interrupts raised (UIF set with UIE), waiting for the board.
    pub irq: bool,
    /// Time of the last update interrupt request.
    pub irq_at: u64,
    /// Update events generated by counter overflow, since reset.
    pub update_events: u64,
    /// Encoder inputs (TI1, TI2) as last driven.
    enc: (bool, bool),
    /// Capture inputs TI1–TI4 as driven, and after the filter (TIxF).
    ti_raw: [bool; 4],
    ti: [bool; 4],
    /// A change of TIx not yet through its filter: the level and when it passes.
    ti_pending: [Option<(bool, u64)>; 4],
    /// Edges counted by each channel's input prescaler.
    ic_events: [u32; 4],
}

impl Timer {
    /// A timer of `kind` at its reset state, clocked at `clock_units` per cycle.
    pub fn new(name: &'static str, kind: Kind, clock_units: u64) -> Self {
        Self {
            name,
            kind,
            clock_units,
            cr1: 0,
            cr2: 0,
            smcr: 0,
            dier: 0,
            sr: 0,
            ccmr: [0; 3],
            ccer: 0,
            psc: 0,
            psc_active: 0,
            arr: 0xFFFF_FFFF & Self::mask_of(kind),
            arr_active: 0xFFFF_FFFF & Self::mask_of(kind),
            rcr: 0,
            rep_left: 0,
            ccr: [0; 6],
            ccr_active: [0; 6],
            bdtr: 0,
            other: [0; 8],
            cnt_at: 0,
            since: 0,
            high_since: [None; 6],
            pulses: Vec::new(),
            irq: false,
            irq_at: 0,
            update_events: 0,
            enc: (false, false),
            ti_raw: [false; 4],
            ti: [false; 4],
            ti_pending: [None; 4],
            ic_events: [0; 4],
        }
    }

    fn mask_of(kind: Kind) -> u32 {
        match kind {
            Kind::General { wide: true } => u32::MAX,
            _ => 0xFFFF,
        }
    }

    fn mask(&self) -> u32 {
        Self::mask_of(self.kind)
    }

    fn channels(&self) -> usize {
        match self.kind {
            Kind::Basic => 0,
            Kind::General { .. } => 4,
            Kind::Advanced => 6,
            Kind::Compact { channels } => channels,
        }
    }

    fn has_rcr(&self) -> bool {
        matches!(self.kind, Kind::Advanced | Kind::Compact { .. })
    }

    fn running(&self) -> bool {
        self.cr1 & CR1_CEN != 0 && !self.encoder_mode()
    }

    /// SMS selects an encoder mode (TIMx_SMCR: 001, 010, 011).
    pub fn encoder_mode(&self) -> bool {
        matches!(self.smcr & 0x7, 1..=3) && self.smcr & (1 << 16) == 0
    }

    fn units_per_count(&self) -> u64 {
        self.clock_units * (u64::from(self.psc_active) + 1)
    }

    /// Output-compare mode of channel `ch` (OCxM, 4 bits).
    fn ocm(&self, ch: usize) -> u32 {
        let r = self.ccmr[ch / 2];
        let s = (ch % 2) * 8;
        if (r >> s) & 3 != 0 {
            return 0xFF; // input capture
        }
        ((r >> (s + 4)) & 7) | ((r >> (s + 16 - 3)) & 8) // OCxM[3] at bit 16/24
    }

    /// Is channel `ch`'s output driven (CCxE and, with break, MOE)?
    fn output_enabled(&self, ch: usize) -> bool {
        let cce = self.ccer & (1 << (4 * ch)) != 0;
        let moe = match self.kind {
            Kind::Advanced | Kind::Compact { .. } => self.bdtr & (1 << 15) != 0,
            _ => true,
        };
        cce && moe
    }

    /// OCxREF of channel `ch` at counter value `cnt`, after the polarity bit.
    fn level_at(&self, ch: usize, cnt: u32) -> bool {
        let ccr = self.ccr_active[ch];
        let reference = match self.ocm(ch) {
            0b0110 => cnt < ccr,
            0b0111 => cnt >= ccr,
            0b0101 => true,
            _ => false,
        };
        let inverted = self.ccer & (1 << (4 * ch + 1)) != 0;
        self.output_enabled(ch) && (reference != inverted)
    }

    /// Counter value now (advances lazily).
    fn cnt_now(&mut self, now: u64) -> u32 {
        self.advance(now);
        self.cnt_at
    }

    /// Time of the next counter overflow, if the counter runs.
    pub fn next_overflow(&self) -> Option<u64> {
        if !self.running() || self.cr1 & (CR1_DIR | CR1_CMS) != 0 {
            return None;
        }
        let left = u64::from(self.arr_active) + 1 - u64::from(self.cnt_at.min(self.arr_active));
        Some(self.since + left * self.units_per_count())
    }

    /// The next time the board must call [`Timer::advance`] for an interrupt: the next
    /// overflow that generates an update event with UIE set.
    pub fn next_event(&self) -> Option<u64> {
        if self.dier & DIER_UIE == 0 {
            return None;
        }
        let first = self.next_overflow()?;
        Some(first + u64::from(self.rep_left) * self.period_units())
    }

    fn period_units(&self) -> u64 {
        (u64::from(self.arr_active) + 1) * self.units_per_count()
    }

    /// Channel levels' edges from `from_cnt` up to (not including) count `to_cnt`
    /// within one period starting at time `t0` with counter `from_cnt`.
    fn edges_in_period(&mut self, t0: u64, from_cnt: u32, to_cnt: u32) {
        let upc = self.units_per_count();
        for ch in 0..self.channels() {
            let at_start = self.level_at(ch, from_cnt);
            // With PWM modes the level changes at most once inside a period: at CCR.
            let ccr = self.ccr_active[ch];
            let switch =
                (ccr > from_cnt && ccr < to_cnt).then(|| t0 + u64::from(ccr - from_cnt) * upc);
            let mut level = at_start;
            self.set_level(ch, level, t0);
            if let Some(t) = switch {
                level = self.level_at(ch, ccr);
                self.set_level(ch, level, t);
            }
        }
    }

    fn set_level(&mut self, ch: usize, high: bool, t: u64) {
        match (self.high_since[ch], high) {
            (None, true) => self.high_since[ch] = Some(t),
            (Some(rise), false) => {
                // A level that comes and goes at one instant is no edge at the pin.
                if t > rise {
                    self.pulses.push(Pulse {
                        channel: ch,
                        rise,
                        fall: t,
                    });
                }
                self.high_since[ch] = None;
            }
            _ => {}
        }
    }

    /// Update event ("Time-base unit"): shadows from preloads, repetition counter reloaded.
    fn update_event(&mut self) {
        self.psc_active = self.psc;
        self.arr_active = self.arr;
        self.rep_left = self.rcr;
        self.ccr_active = self.ccr;
    }

    /// Runs the timer up to `now`: the input changes that pass their filters by then
    /// (each captured at its own instant), then the counter.
    pub fn advance(&mut self, now: u64) {
        while let Some((n, level, t)) = self.next_filtered(now) {
            self.ti_pending[n] = None;
            self.advance_counter(t);
            self.filtered_edge(n, level);
        }
        self.advance_counter(now);
    }

    /// The earliest pending input change that passes its filter by `now`.
    fn next_filtered(&self, now: u64) -> Option<(usize, bool, u64)> {
        (0..4)
            .filter_map(|n| self.ti_pending[n].map(|(l, t)| (n, l, t)))
            .filter(|&(_, _, t)| t <= now)
            .min_by_key(|&(_, _, t)| t)
    }

    /// CCxS of channel `ch`: 0 output, 1 input TIx, 2 the pair's other input, 3 TRC.
    fn ccs(&self, ch: usize) -> u32 {
        (self.ccmr[ch / 2] >> ((ch % 2) * 8)) & 3
    }

    /// The delay of TIn's digital filter (ICnF of channel n in input mode; none in
    /// output mode), time units: N sampling periods (table of ICxF).
    fn filter_delay(&self, n: usize) -> u64 {
        if n >= self.channels() || self.ccs(n) == 0 {
            return 0;
        }
        let icf = (self.ccmr[n / 2] >> ((n % 2) * 8 + 4)) & 0xF;
        let dts = self.clock_units << ((self.cr1 >> 8) & 3).min(2);
        let (period, samples) = match icf {
            0 => (0, 0),
            1 => (self.clock_units, 2),
            2 => (self.clock_units, 4),
            3 => (self.clock_units, 8),
            4 => (dts * 2, 6),
            5 => (dts * 2, 8),
            6 => (dts * 4, 6),
            7 => (dts * 4, 8),
            8 => (dts * 8, 6),
            9 => (dts * 8, 8),
            10 => (dts * 16, 5),
            11 => (dts * 16, 6),
            12 => (dts * 16, 8),
            13 => (dts * 32, 5),
            14 => (dts * 32, 6),
            _ => (dts * 32, 8),
        };
        period * samples
    }

    /// Drives capture input TIn (0-based) to `level` at time `t`: a change starts
    /// through TIn's filter; a change back before it passed is a pulse the filter
    /// removes.
    pub fn capture_input(&mut self, n: usize, level: bool, t: u64) {
        self.advance(t);
        if self.ti_raw[n] == level {
            return;
        }
        self.ti_raw[n] = level;
        if self.ti_pending[n].take().is_some() {
            return;
        }
        self.ti_pending[n] = Some((level, t + self.filter_delay(n)));
        self.advance(t);
    }

    /// TIn's filtered level changed to `level` (the counter is at that instant): every
    /// enabled input channel on TIn whose edge detector takes the edge captures.
    fn filtered_edge(&mut self, n: usize, level: bool) {
        self.ti[n] = level;
        for ch in 0..self.channels().min(4) {
            let source = match self.ccs(ch) {
                1 => ch,
                2 => ch ^ 1,
                _ => continue,
            };
            if source != n || self.ccer & (1 << (4 * ch)) == 0 {
                continue;
            }
            let p = self.ccer & (1 << (4 * ch + 1)) != 0;
            let np = self.ccer & (1 << (4 * ch + 3)) != 0;
            let taken = match (p, np) {
                (false, false) => level,
                (true, false) => !level,
                (true, true) => true,
                (false, true) => false, // reserved
            };
            if !taken {
                continue;
            }
            let psc = (self.ccmr[ch / 2] >> ((ch % 2) * 8 + 2)) & 3;
            self.ic_events[ch] += 1;
            if self.ic_events[ch] < 1 << psc {
                continue;
            }
            self.ic_events[ch] = 0;
            let ccif = 1 << (1 + ch);
            if self.sr & ccif != 0 {
                self.sr |= 1 << (9 + ch); // CCxOF
            }
            self.sr |= ccif;
            self.ccr[ch] = self.cnt_at;
            self.ccr_active[ch] = self.cnt_at;
        }
    }

    /// Runs the counter up to `now`: overflows, update events, one-pulse stops and the
    /// channels' output edges.
    fn advance_counter(&mut self, now: u64) {
        if now < self.since {
            return; // already past (an input change applied late: see `capture_input`)
        }
        if !self.running() || self.cr1 & (CR1_DIR | CR1_CMS) != 0 {
            if self.since < now {
                self.since = now;
            }
            return;
        }
        let upc = self.units_per_count();
        loop {
            let Some(wrap) = self.next_overflow() else {
                return;
            };
            if wrap > now {
                // Edges inside the current, unfinished period.
                let elapsed = ((now - self.since) / upc) as u32;
                let cnt = self.cnt_at + elapsed;
                self.edges_in_period(self.since, self.cnt_at, cnt + 1);
                let t = self.since + u64::from(elapsed) * upc;
                self.cnt_at = cnt;
                self.since = t;
                return;
            }
            self.edges_in_period(self.since, self.cnt_at, self.arr_active + 1);
            // Overflow at `wrap`: counter to 0.
            self.since = wrap;
            self.cnt_at = 0;
            if self.has_rcr() && self.rep_left > 0 {
                self.rep_left -= 1;
            } else {
                self.update_events += 1;
                self.update_event();
                self.sr |= SR_UIF;
                if self.dier & DIER_UIE != 0 {
                    self.irq = true;
                    self.irq_at = wrap;
                }
                if self.cr1 & CR1_OPM != 0 {
                    self.cr1 &= !CR1_CEN;
                    self.edges_in_period(wrap, 0, 1);
                    return;
                }
            }
        }
    }

    /// Reads register `offset` at time `now`.
    pub fn read(&mut self, offset: u32, now: u64) -> Result<u32, Unmodelled> {
        self.advance(now);
        Ok(match offset {
            reg::CR1 => self.cr1,
            reg::CR2 => self.cr2,
            reg::SMCR => self.smcr,
            reg::DIER => self.dier,
            reg::SR => self.sr,
            reg::EGR => 0,
            reg::CCMR1 => self.ccmr[0],
            reg::CCMR2 => self.ccmr[1],
            reg::CCMR3 if self.kind == Kind::Advanced => self.ccmr[2],
            reg::CCER => self.ccer,
            reg::CNT => {
                let remap = if self.cr1 & CR1_UIFREMAP != 0 && self.sr & SR_UIF != 0 {
                    1 << 31
                } else {
                    0
                };
                self.cnt_now(now) | remap
            }
            reg::PSC => self.psc,
            reg::ARR => self.arr,
            reg::RCR if self.has_rcr() => self.rcr,
            o @ reg::CCR1..=reg::CCR4 => {
                let ch = ((o - reg::CCR1) / 4) as usize;
                if ch < self.channels() && self.ccs(ch) != 0 {
                    self.sr &= !(1 << (1 + ch)); // reading CCRx clears CCxIF
                }
                self.ccr[ch]
            }
            reg::BDTR if self.has_rcr() => self.bdtr,
            reg::CCR5 | reg::CCR6 if self.kind == Kind::Advanced => {
                self.ccr[4 + ((offset - reg::CCR5) / 4) as usize]
            }
            o @ (reg::DTR2 | reg::ECR | reg::TISEL | reg::AF1 | reg::AF2 | reg::OR | reg::DCR) => {
                self.other[Self::other_index(o)]
            }
            _ => return Err(Unmodelled),
        })
    }

    fn other_index(o: u32) -> usize {
        match o {
            reg::DTR2 => 0,
            reg::ECR => 1,
            reg::TISEL => 2,
            reg::AF1 => 3,
            reg::AF2 => 4,
            reg::OR => 5,
            _ => 6,
        }
    }

    /// Writes register `offset` at time `now`.
    pub fn write(&mut self, offset: u32, value: u32, now: u64) -> Result<(), Unmodelled> {
        self.advance(now);
        match offset {
            reg::CR1 => {
                let was = self.cr1 & CR1_CEN != 0;
                self.cr1 = value & 0xFFF;
                let is = self.cr1 & CR1_CEN != 0;
                if is && self.cr1 & (CR1_DIR | CR1_CMS) != 0 && !self.encoder_mode() {
                    return Err(Unmodelled); // down/centre-aligned counting: unused
                }
                if is && !was {
                    self.since = now;
                    for ch in 0..self.channels() {
                        let high = self.level_at(ch, self.cnt_at);
                        self.set_level(ch, high, now);
                    }
                } else if was && !is {
                    self.freeze_outputs(now);
                }
            }
            reg::CR2 => self.cr2 = value,
            reg::SMCR => self.smcr = value,
            reg::DIER => {
                if value & 0x1E != 0 {
                    return Err(Unmodelled); // capture/compare interrupts: unused
                }
                self.dier = value
            }
            reg::SR => self.sr &= value, // rc_w0
            reg::EGR => {
                if value & 1 != 0 {
                    // UG: reinitialise the counter and the shadows ("Upcounting mode").
                    self.update_event();
                    self.cnt_at = 0;
                    self.since = now;
                    if self.cr1 & CR1_URS == 0 {
                        self.sr |= SR_UIF;
                        if self.dier & DIER_UIE != 0 {
                            self.irq = true;
                            self.irq_at = now;
                        }
                    }
                    self.freeze_outputs(now);
                }
                if value & !1 & !(0x1F << 1) != 0 {
                    return Err(Unmodelled);
                }
            }
            reg::CCMR1 => self.ccmr[0] = value,
            reg::CCMR2 => self.ccmr[1] = value,
            reg::CCMR3 if self.kind == Kind::Advanced => self.ccmr[2] = value,
            reg::CCER => {
                for ch in 0..4 {
                    if value & (1 << (4 * ch)) == 0 {
                        self.ic_events[ch] = 0; // ICxPSC's count reset while CCxE = 0
                    }
                }
                self.ccer = value;
                self.freeze_outputs(now);
            }
            reg::CNT => {
                self.cnt_at = value & self.mask();
                self.since = now;
                self.freeze_outputs(now);
            }
            reg::PSC => self.psc = value & 0xFFFF,
            reg::ARR => {
                self.arr = value & self.mask();
                if self.cr1 & CR1_ARPE == 0 {
                    self.arr_active = self.arr;
                }
            }
            reg::RCR if self.has_rcr() => {
                self.rcr = value
                    & if self.kind == Kind::Advanced {
                        0xFFFF
                    } else {
                        0xFF
                    }
            }
            o @ reg::CCR1..=reg::CCR4 => {
                let ch = ((o - reg::CCR1) / 4) as usize;
                self.write_ccr(ch, value);
            }
            reg::BDTR if self.has_rcr() => {
                self.bdtr = value;
                self.freeze_outputs(now);
            }
            reg::CCR5 | reg::CCR6 if self.kind == Kind::Advanced => {
                self.write_ccr(4 + ((offset - reg::CCR5) / 4) as usize, value)
            }
            o @ (reg::DTR2 | reg::ECR | reg::TISEL | reg::AF1 | reg::AF2 | reg::OR | reg::DCR) => {
                self.other[Self::other_index(o)] = value
            }
            _ => return Err(Unmodelled),
        }
        Ok(())
    }

    fn write_ccr(&mut self, ch: usize, value: u32) {
        if ch < 4 && ch < self.channels() && self.ccs(ch) != 0 {
            return; // read-only in input mode
        }
        self.ccr[ch] = value & self.mask();
        let preload = self.ccmr[ch / 2] & (1 << ((ch % 2) * 8 + 3)) != 0;
        if !preload {
            self.ccr_active[ch] = self.ccr[ch];
        }
    }

    /// Re-evaluates every output at `now` with the counter where it is (after a
    /// register write that changes levels without counting).
    fn freeze_outputs(&mut self, now: u64) {
        for ch in 0..self.channels() {
            let high = self.level_at(ch, self.cnt_at);
            self.set_level(ch, high, now);
        }
    }

    /// Drives the encoder inputs TI1 = `a`, TI2 = `b` (a change of one of them is one
    /// edge), counting as "Encoder interface mode" says when in encoder mode with CEN set.
    pub fn encoder_input(&mut self, a: bool, b: bool) {
        let (pa, pb) = self.enc;
        self.enc = (a, b);
        if self.cr1 & CR1_CEN == 0 || !self.encoder_mode() {
            return;
        }
        let sms = self.smcr & 7;
        // Table "Counting direction versus encoder signals": on a TI1 edge the count
        // goes down if TI1 and TI2 are equal after the edge... (TI1FP1 rising with
        // TI2 low: up), i.e. up when the edge leaves them different.
        let up = if a != pa && (sms == 2 || sms == 3) {
            Some(a != b)
        } else if b != pb && (sms == 1 || sms == 3) {
            Some(a == b)
        } else {
            None
        };
        let top = u64::from(self.arr_active) + 1;
        match up {
            Some(true) => self.cnt_at = ((u64::from(self.cnt_at) + 1) % top) as u32,
            Some(false) => self.cnt_at = ((u64::from(self.cnt_at) + top - 1) % top) as u32,
            None => {}
        }
    }

    /// The encoder inputs as last driven.
    pub fn encoder_inputs(&self) -> (bool, bool) {
        self.enc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step_timer() -> Timer {
        let mut t = Timer::new("TIM1", Kind::Advanced, 16);
        // PWM mode 2 on CH1 with preload, output enabled, MOE.
        t.write(reg::CCMR1, 0b0111 << 4 | 1 << 3, 0).ok();
        t.write(reg::CCER, 1, 0).ok();
        t.write(reg::BDTR, 1 << 15, 0).ok();
        t
    }

    #[test]
    fn one_pulse_mode_with_rcr_3_gives_four_pulses_then_stops() {
        let mut t = step_timer();
        t.write(reg::CR1, CR1_OPM | CR1_URS | CR1_ARPE, 0).ok();
        t.write(reg::ARR, 99, 0).ok();
        t.write(reg::CCR1, 90, 0).ok();
        t.write(reg::RCR, 3, 0).ok();
        t.write(reg::EGR, 1, 0).ok();
        t.write(reg::CR1, CR1_OPM | CR1_URS | CR1_ARPE | CR1_CEN, 0)
            .ok();
        t.advance(16 * 1000);
        assert_eq!(t.pulses.len(), 4, "{:?}", t.pulses);
        assert_eq!(
            t.read(reg::CR1, 16 * 1000).ok().map(|v| v & CR1_CEN),
            Some(0)
        );
        // URS: no UIF from UG, one from the last overflow's update event.
        assert_eq!(t.update_events, 1);
    }

    #[test]
    fn pwm_mode_2_rises_at_ccr_and_falls_at_the_wrap() {
        let mut t = step_timer();
        t.write(reg::CR1, CR1_OPM | CR1_ARPE, 0).ok();
        t.write(reg::ARR, 99, 0).ok();
        t.write(reg::CCR1, 90, 0).ok();
        t.write(reg::RCR, 1, 0).ok();
        t.write(reg::EGR, 1, 0).ok();
        t.write(reg::CR1, CR1_OPM | CR1_ARPE | CR1_CEN, 160).ok();
        t.advance(16 * 10_000);
        let p: Vec<(u64, u64)> = t.pulses.iter().map(|p| (p.rise, p.fall)).collect();
        // Counts at 16 units each from 160: CCR 90 → rise, ARR 99 → wrap at 100.
        assert_eq!(
            p,
            vec![
                (160 + 90 * 16, 160 + 100 * 16),
                (160 + 190 * 16, 160 + 200 * 16)
            ]
        );
    }

    #[test]
    fn encoder_mode_x4_counts_a_quadrature_sequence_both_ways() {
        let mut t = Timer::new("TIM2", Kind::General { wide: true }, 16);
        t.write(reg::SMCR, 3, 0).ok();
        t.write(reg::ARR, 0xFFFF, 0).ok();
        t.write(reg::CR1, CR1_CEN, 0).ok();
        // A leads B: 00 → 10 → 11 → 01 → 00, four edges, forward.
        for (a, b) in [(true, false), (true, true), (false, true), (false, false)] {
            t.encoder_input(a, b);
        }
        assert_eq!(t.read(reg::CNT, 0).ok(), Some(4));
        // B leads A: backwards over eight edges, through zero to the wrap.
        for _ in 0..2 {
            for (a, b) in [(false, true), (true, true), (true, false), (false, false)] {
                t.encoder_input(a, b);
            }
        }
        assert_eq!(t.read(reg::CNT, 0).ok(), Some(0xFFFC));
    }

    /// TIM2 counting at 1 unit per count (PSC 0), CH3 capturing both edges of TI3
    /// through the filter `icf`.
    fn capture_timer(icf: u32) -> Timer {
        let mut t = Timer::new("TIM2", Kind::General { wide: true }, 1);
        t.write(reg::ARR, 59_999, 0).ok();
        t.write(reg::CCMR2, 0b01 | icf << 4, 0).ok();
        t.write(reg::CCER, 0b1011 << 8, 0).ok();
        t.write(reg::CR1, CR1_CEN, 0).ok();
        t
    }

    #[test]
    fn input_capture_latches_the_counter_at_each_edge_through_the_filter() {
        // ICxF = 0011: eight samples at f_CK_INT, 8 units here.
        let mut t = capture_timer(0b0011);
        t.capture_input(2, true, 1000);
        assert_eq!(
            t.read(reg::SR, 1005).ok(),
            Some(0),
            "not through the filter yet"
        );
        assert_eq!(t.read(reg::SR, 1008).ok(), Some(1 << 3));
        // Reading CCR3 gives the count at the filtered edge and clears CC3IF.
        assert_eq!(t.read(reg::CCR1 + 8, 2000).ok(), Some(1008));
        assert_eq!(t.read(reg::SR, 2000).ok(), Some(0));
        // Two edges before a read: the last one stays, with the overcapture flag.
        t.capture_input(2, false, 3000);
        t.capture_input(2, true, 3500);
        assert_eq!(t.read(reg::SR, 4000).ok(), Some(1 << 3 | 1 << 11));
        assert_eq!(t.read(reg::CCR1 + 8, 4000).ok(), Some(3508));
        // A pulse shorter than the filter is no edge.
        t.capture_input(2, false, 5000);
        t.capture_input(2, true, 5005);
        assert_eq!(t.read(reg::SR, 6000).ok(), Some(1 << 11));
    }

    #[test]
    fn input_capture_takes_only_the_selected_edge_and_wraps_with_arr() {
        let mut t = capture_timer(0);
        // Rising edges only (CC3P = CC3NP = 0).
        t.write(reg::CCER, 1 << 8, 0).ok();
        t.capture_input(2, true, 70_000);
        t.capture_input(2, false, 70_100);
        assert_eq!(t.read(reg::CCR1 + 8, 70_200).ok(), Some(10_000));
        assert_eq!(t.read(reg::SR, 70_200).ok(), Some(1 << 0));
        // CCR3 is read-only in input mode.
        t.write(reg::CCR1 + 8, 5, 70_300).ok();
        assert_eq!(t.read(reg::CCR1 + 8, 70_300).ok(), Some(10_000));
    }

    #[test]
    fn uifremap_copies_the_update_flag_into_cnt_bit_31() {
        let mut t = Timer::new("TIM6", Kind::Basic, 16);
        t.write(reg::CR1, CR1_UIFREMAP | CR1_URS, 0).ok();
        t.write(reg::ARR, 9, 0).ok();
        t.write(reg::DIER, 1, 0).ok();
        t.write(reg::CR1, CR1_UIFREMAP | CR1_URS | CR1_CEN, 0).ok();
        assert_eq!(t.next_event(), Some(160));
        t.advance(165);
        assert!(t.irq);
        assert_eq!(t.read(reg::CNT, 165).ok(), Some(1 << 31));
        t.write(reg::SR, 0, 165).ok();
        assert_eq!(t.read(reg::CNT, 16 * 13).ok(), Some(3));
    }
}
