//! Units and fixed-point formats: every quantity's representation is fixed here, once.
//!
//! All motion quantities are integers so that the firmware, the simulator and the tests
//! compute bit-identical results and so that decimal G-code values convert exactly:
//!
//! | quantity            | type  | unit                          | range used          |
//! |---------------------|-------|-------------------------------|---------------------|
//! | linear position     | `i64` | nanometre (nm)                | ±9.2e9 mm           |
//! | angular position    | `i64` | nanodegree (n°, 1e-9 degree)  | ±9.2e9 degrees      |
//! | linear speed        | `i64` | nm/s                          |                     |
//! | linear acceleration | `i64` | nm/s²                         |                     |
//! | time inside a tick  | `u32` | nanosecond                    | 0..[`TICK_NS`]      |
//! | time                | `u64` | interpolation ticks           | 1 tick = [`TICK_NS`]|
//! | joint scale         | ratio | steps (or encoder counts) per N axis units |       |
//!
//! A pose is X Y Z in nm and A B C in n°; "axis unit" means nm for a linear axis and n°
//! for a rotary one. Products that could overflow `i64` are formed in `i128`. G-code
//! decimals convert to these units exactly (to the nearest unit for inch input).

/// Interpolation frequency, Hz. 1 kHz: a step train is re-planned every millisecond,
/// which keeps a 50 µs DIR-setup window at 5 % of the period and the per-tick work far
/// inside the 170 MHz budget.
pub const TICK_HZ: u32 = 1_000;
/// Interpolation period, ns.
pub const TICK_NS: u32 = 1_000_000_000 / TICK_HZ;

/// Nanometres per millimetre.
pub const NM_PER_MM: i64 = 1_000_000;
/// Nanodegrees per degree.
pub const NDEG_PER_DEG: i64 = 1_000_000_000;

/// Converts axis units (nm or n°) to user units (mm or degrees), for display only.
pub fn to_user(value: i64, rotary: bool) -> f64 {
    if rotary {
        value as f64 / NDEG_PER_DEG as f64
    } else {
        value as f64 / NM_PER_MM as f64
    }
}

/// Divides rounding to nearest, ties away from zero; `den > 0`.
pub const fn div_round(num: i128, den: i128) -> i128 {
    if num >= 0 {
        (num + den / 2) / den
    } else {
        -((-num + den / 2) / den)
    }
}

/// Axis units (nm or n°) per user unit (mm or degree).
pub const fn units_per_user(rotary: bool) -> i64 {
    if rotary {
        NDEG_PER_DEG
    } else {
        NM_PER_MM
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_division_is_symmetric_about_zero() {
        assert_eq!(div_round(5, 2), 3);
        assert_eq!(div_round(-5, 2), -3);
        assert_eq!(div_round(4, 3), 1);
        assert_eq!(div_round(-4, 3), -1);
    }

    #[test]
    fn tick_period_is_whole_nanoseconds() {
        assert_eq!(TICK_NS as u64 * TICK_HZ as u64, 1_000_000_000);
    }
}
