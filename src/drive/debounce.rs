//! Debouncing of the switch inputs, sampled once per interpolation tick (1 kHz): the
//! one implementation the firmware and the simulator both run, so the simulator sees
//! an injected limit, home or e-stop with the board's delay.
//!
//! One rule covers every input: a [`Debouncer`] holds a debounced state and counts the
//! consecutive samples that disagree with it; a sample that agrees resets the count,
//! and when the count reaches the number of samples required for that direction of
//! change (`to_active` to become active, `to_inactive` to become inactive) the state
//! takes the sample's value. So a change needs that many *consecutive* equal samples,
//! and a run that is broken by one sample of the present state starts again from zero.
//!
//! - Limit/home switches ([`SWITCH`]): 3 consecutive equal samples (3 ms) in either
//!   direction. A contact bouncing for less than that is not seen to change at all; a
//!   clean change is seen at the third sample, two ticks after the tick that first
//!   read it.
//! - E-stop ([`ESTOP`]): fail-safe asymmetric rule. The first active sample makes it
//!   active (`to_active` = 1: no added latency), and it is released only after 20
//!   consecutive inactive samples (20 ms); any active sample in between restarts that
//!   count.
//!
//! Every debouncer starts inactive; an input already active at power-up is seen on the
//! first tick (e-stop) or the third (switches). [`SwitchFilter`] applies these rules to
//! the e-stop and to every joint's limit and home switch at once.
//!
//! Invariants: pure logic, no time source: one call is one sample; the state of one
//! input never depends on another's.

use crate::config::MAX_JOINTS;

/// One debounced input. See the module documentation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Debouncer {
    /// Debounced state: true = active.
    active: bool,
    /// Consecutive samples that disagreed with `active`.
    run: u8,
    /// Disagreeing samples needed to become active (≥ 1).
    to_active: u8,
    /// Disagreeing samples needed to become inactive (≥ 1).
    to_inactive: u8,
}

/// The limit/home switch rule: 3 consecutive equal samples to change either way.
pub const SWITCH: Debouncer = Debouncer::new(3, 3);
/// The e-stop rule: active at once, released after 20 consecutive inactive samples.
pub const ESTOP: Debouncer = Debouncer::new(1, 20);

impl Debouncer {
    /// An inactive input that changes after `to_active` / `to_inactive` consecutive
    /// samples (each at least 1).
    pub const fn new(to_active: u8, to_inactive: u8) -> Self {
        assert!(to_active >= 1 && to_inactive >= 1);
        Self {
            active: false,
            run: 0,
            to_active,
            to_inactive,
        }
    }

    /// Takes one raw sample (true = active) and returns the debounced state.
    pub const fn sample(&mut self, raw: bool) -> bool {
        if raw == self.active {
            self.run = 0;
        } else {
            self.run += 1;
            let needed = if raw {
                self.to_active
            } else {
                self.to_inactive
            };
            if self.run >= needed {
                self.active = raw;
                self.run = 0;
            }
        }
        self.active
    }

    /// The debounced state after the last sample.
    pub const fn active(&self) -> bool {
        self.active
    }
}

/// Debounces `N` (at most 16) inputs with one rule and packs the states into a bit
/// mask.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Debounced<const N: usize> {
    inputs: [Debouncer; N],
}

impl<const N: usize> Debounced<N> {
    /// `N` inputs following `rule`, all inactive.
    pub const fn new(rule: Debouncer) -> Self {
        assert!(N <= 16);
        Self { inputs: [rule; N] }
    }

    /// Takes one raw sample of every input (bit k = input k active; bits from `N` up
    /// are ignored) and returns the debounced states the same way.
    pub fn sample(&mut self, raw: u16) -> u16 {
        let mut states = 0;
        for (k, d) in self.inputs.iter_mut().enumerate() {
            if d.sample(raw & (1 << k) != 0) {
                states |= 1 << k;
            }
        }
        states
    }
}

/// The e-stop and the joints' limit and home switches, one sample of each: raw as
/// read, or debounced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Switches {
    /// E-stop input active.
    pub estop: bool,
    /// Limit switch of each joint (bit j), active.
    pub limit: u16,
    /// Home switch of each joint (bit j), active.
    pub home: u16,
}

/// The switch filters of a controller: [`ESTOP`] for the e-stop, [`SWITCH`] for every
/// joint's limit and home switch (one filter per input: on a board where one contact
/// serves both roles, both filters see the same samples and agree).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwitchFilter {
    estop: Debouncer,
    limit: Debounced<MAX_JOINTS>,
    home: Debounced<MAX_JOINTS>,
    state: Switches,
}

impl Default for SwitchFilter {
    fn default() -> Self {
        Self::new()
    }
}

impl SwitchFilter {
    /// Every input inactive.
    pub const fn new() -> Self {
        Self {
            estop: ESTOP,
            limit: Debounced::new(SWITCH),
            home: Debounced::new(SWITCH),
            state: Switches {
                estop: false,
                limit: 0,
                home: 0,
            },
        }
    }

    /// Takes one tick's raw samples and returns the debounced states.
    pub fn sample(&mut self, raw: &Switches) -> Switches {
        self.state = Switches {
            estop: self.estop.sample(raw.estop),
            limit: self.limit.sample(raw.limit),
            home: self.home.sample(raw.home),
        };
        self.state
    }

    /// The debounced states after the last sample.
    pub fn state(&self) -> Switches {
        self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `samples` through `d` and returns the state after each (1 = active), as the
    /// bits of the result, sample 0 in bit 0.
    fn trace(mut d: Debouncer, samples: u64, n: u32) -> u64 {
        let mut out = 0;
        for i in 0..n {
            if d.sample(samples & (1 << i) != 0) {
                out |= 1 << i;
            }
        }
        out
    }

    #[test]
    fn switch_pulses_of_one_and_two_samples_are_ignored() {
        assert_eq!(trace(SWITCH, 0b0_0110_0010, 9), 0);
    }

    #[test]
    fn a_switch_turns_on_at_its_third_active_sample_and_stays_on() {
        // Active from sample 3: seen at 5.
        assert_eq!(trace(SWITCH, 0b1_1111_1000, 9), 0b1_1110_0000);
    }

    #[test]
    fn a_three_sample_pulse_is_seen_and_released_at_the_third_inactive_sample() {
        // Pulse at 4..=6: on at 6, off at 9.
        assert_eq!(trace(SWITCH, 0b00_0111_0000, 10), 0b01_1100_0000);
        // On at 2, off at the third inactive sample (8).
        assert_eq!(trace(SWITCH, 0b00_0011_1111, 10), 0b00_1111_1100);
    }

    #[test]
    fn a_short_dropout_of_an_active_switch_is_ignored() {
        // On at 2; a 2-sample dropout (5, 6) is ignored.
        assert_eq!(trace(SWITCH, 0b11_1001_1111, 10), 0b11_1111_1100);
    }

    #[test]
    fn a_run_broken_by_one_sample_starts_again_from_zero() {
        // Active at 0, 1, then 3, 4, 5: the run restarts at 3 and completes at 5.
        assert_eq!(trace(SWITCH, 0b11_1011, 6), 0b10_0000);
    }

    #[test]
    fn the_estop_acts_at_its_first_active_sample() {
        // A single active sample (1) makes it active at once; the 20th inactive
        // sample after it (21) releases it.
        assert_eq!(trace(ESTOP, 0b10, 40), ((1 << 21) - 1) & !1);
        // Active at 0, released at 20.
        assert_eq!(trace(ESTOP, 0b1, 25), (1 << 20) - 1);
    }

    #[test]
    fn an_active_sample_restarts_the_estop_release_count() {
        // Active at 0 and 10: released at 30.
        assert_eq!(trace(ESTOP, 0b100_0000_0001, 35), (1 << 30) - 1);
    }

    #[test]
    fn a_bank_debounces_each_input_on_its_own_and_ignores_bits_beyond_it() {
        let mut bank = Debounced::<3>::new(SWITCH);
        // Input 0 steady, input 1 bouncing, bit 3 outside the bank.
        let samples = [0b1011, 0b1001, 0b1011, 0b1001, 0b1011];
        let states: Vec<u16> = samples.iter().map(|&s| bank.sample(s)).collect();
        assert_eq!(states, [0, 0, 0b1, 0b1, 0b1]);
    }

    #[test]
    fn the_switch_filter_applies_each_inputs_rule() {
        let mut f = SwitchFilter::new();
        let raw = Switches {
            estop: true,
            limit: 1 << 2,
            home: 1 << 10,
        };
        let seen: Vec<Switches> = (0..3).map(|_| f.sample(&raw)).collect();
        // The e-stop at the first sample, the switches at the third.
        assert_eq!(
            seen[0],
            Switches {
                estop: true,
                limit: 0,
                home: 0
            }
        );
        assert_eq!(seen[1], seen[0]);
        assert_eq!(seen[2], raw);
        assert_eq!(f.state(), raw);
    }
}
