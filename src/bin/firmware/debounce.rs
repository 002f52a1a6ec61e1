//! Debouncing of the switch inputs, sampled once per interpolation tick (1 kHz).
//!
//! One rule covers every input: a [`Debouncer`] holds a debounced state and counts the
//! consecutive samples that disagree with it; a sample that agrees resets the count,
//! and when the count reaches the number of samples required for that direction of
//! change (`to_active` to become active, `to_inactive` to become inactive) the state
//! takes the sample's value. So a change needs that many *consecutive* equal samples,
//! and a run that is broken by one sample of the present state starts again from zero.
//!
//! - Limit/home switches ([`SWITCH`]): 3 consecutive equal samples (3 ms) in either
//!   direction. A contact bouncing for less than that is not seen to change at all.
//! - E-stop ([`ESTOP`]): fail-safe asymmetric rule. The first active sample makes it
//!   active (`to_active` = 1: no added latency), and it is released only after 20
//!   consecutive inactive samples (20 ms); any active sample in between restarts that
//!   count.
//!
//! Every debouncer starts inactive; an input already active at power-up is seen on the
//! first tick (e-stop) or the third (switches).
//!
//! The firmware binary has no host test harness, so the rules are checked at compile
//! time instead: [`Debouncer::sample`] is a `const fn` and the `const` block at the end
//! of this file runs sample sequences through it (a wrong answer fails the build).

/// One debounced input. See the module documentation.
#[derive(Clone, Copy)]
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
}

/// Debounces `N` inputs with one rule and packs the states into a bit mask.
pub struct Debounced<const N: usize> {
    inputs: [Debouncer; N],
}

impl<const N: usize> Debounced<N> {
    /// `N` inputs following `rule`, all inactive.
    pub const fn new(rule: Debouncer) -> Self {
        Self { inputs: [rule; N] }
    }

    /// Takes one raw sample of every input (bit k = input k active) and returns the
    /// debounced states the same way.
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

/// Runs `samples` through `d` and returns the state after each (1 = active), as the
/// bits of the result, sample 0 in bit 0.
const fn trace(mut d: Debouncer, samples: u64, n: u32) -> u64 {
    let mut out = 0;
    let mut i = 0;
    while i < n {
        if d.sample(samples & (1 << i) != 0) {
            out |= 1 << i;
        }
        i += 1;
    }
    out
}

// Compile-time checks of the rules. Sample i is bit i of the input; state i is bit i of
// the result.
const _: () = {
    // Switch: pulses of 1 and 2 samples are ignored.
    assert!(trace(SWITCH, 0b0_0110_0010, 9) == 0);
    // 3 active samples (3..=5) switch it on at the third (5); it stays on.
    assert!(trace(SWITCH, 0b1_1111_1000, 9) == 0b1_1110_0000);
    // A 3-sample pulse (4..=6) is seen at 6 and released at the third inactive sample (9).
    assert!(trace(SWITCH, 0b00_0111_0000, 10) == 0b01_1100_0000);
    // On at 2; a 2-sample dropout (5, 6) is ignored.
    assert!(trace(SWITCH, 0b11_1001_1111, 10) == 0b11_1111_1100);
    // On at 2, off at the third inactive sample (8).
    assert!(trace(SWITCH, 0b00_0011_1111, 10) == 0b00_1111_1100);
    // E-stop: a single active sample (1) makes it active at once; the 20th inactive
    // sample after it (21) releases it.
    assert!(trace(ESTOP, 0b10, 40) == ((1 << 21) - 1) & !1);
    // Active at 0, released at 20.
    assert!(trace(ESTOP, 0b1, 25) == (1 << 20) - 1);
    // An active sample at 10 restarts the count: released at 30.
    assert!(trace(ESTOP, 0b100_0000_0001, 35) == (1 << 30) - 1);
};
