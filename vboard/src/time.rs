//! Virtual time.
//!
//! Time is counted in units of 1/2.72 GHz: a whole number of units per cycle of every
//! clock the board runs its core on (16 per cycle at 170 MHz, 170 per cycle at the
//! 16 MHz HSI16 the chip starts on) and per count of its timers. It advances only with
//! executed instructions (one cycle each, see `docs/vboard.md`, "Cycle model") and by
//! the fast-forward of a sleeping core to its next event, so a run is deterministic.

/// Time units per second.
pub const UNITS_PER_S: u64 = 2_720_000_000;

/// Units per nanosecond, as a ratio (2.72 = 68 / 25).
const NS_NUM: u64 = 25;
const NS_DEN: u64 = 68;

/// Units per cycle of a `hz` clock, if whole.
pub fn units_per_cycle(hz: u64) -> Option<u64> {
    (hz != 0 && UNITS_PER_S % hz == 0).then(|| UNITS_PER_S / hz)
}

/// `units` in nanoseconds, rounded down.
pub fn to_ns(units: u64) -> u64 {
    (u128::from(units) * u128::from(NS_NUM) / u128::from(NS_DEN)) as u64
}

/// `units` in seconds.
pub fn to_s(units: u64) -> f64 {
    units as f64 / UNITS_PER_S as f64
}

/// `us` microseconds in units.
pub fn from_us(us: u64) -> u64 {
    us * (UNITS_PER_S / 1_000_000)
}

/// `ms` milliseconds in units.
pub fn from_ms(ms: u64) -> u64 {
    ms * (UNITS_PER_S / 1_000)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clocks_of_the_board_are_whole_units() {
        assert_eq!(units_per_cycle(170_000_000), Some(16));
        assert_eq!(units_per_cycle(16_000_000), Some(170));
        assert_eq!(units_per_cycle(24_000_000), None);
        assert_eq!(to_ns(from_us(3)), 3000);
        assert_eq!(to_ns(16), 5);
    }
}
