//! Tests of the servo loop and the setpoint interpolator.

use super::*;

fn gains() -> ServoGains {
    ServoGains {
        kp: 0.5,
        ki: 10.0,
        kd: 0.0,
        kvff: 0.01,
        kaff: 0.0,
        max_output: 100.0,
        max_integral: 50.0,
        dac_per_unit: 10.0,
        dac_offset: 0,
        ferror: 1000,
        min_ferror: 100,
    }
}

const ON: AmpIo = AmpIo {
    enable: true,
    fault: false,
};

fn at(counts: i64) -> Setpoint {
    Setpoint {
        position_q16: counts << 16,
        ..Setpoint::default()
    }
}

#[test]
fn the_counter_extends_across_wraps_in_both_directions() {
    let mut p: i64 = 65_530;
    for raw in [65_535u16, 4, 100, 65_500, 65_000] {
        p = extend_counter(p, raw);
    }
    assert_eq!(p, 65_000);
    // Forward through 2^16 and 2^17 in steps of 30 000, then back down below zero.
    let mut p = 0i64;
    let mut truth = 0i64;
    for _ in 0..10 {
        truth += 30_000;
        p = extend_counter(p, truth as u16);
    }
    assert_eq!(p, 300_000);
    for _ in 0..20 {
        truth -= 32_000;
        p = extend_counter(p, truth as u16);
    }
    assert_eq!(p, truth);
    assert_eq!(p, -340_000);
}

#[test]
fn a_tick_is_cut_into_ten_even_setpoints_ending_on_the_target() {
    let mut s = SetpointInterpolator::new(1000 << 16);
    s.load(1100 << 16);
    let pts: Vec<i64> = (0..SERVO_PER_TICK)
        .map(|_| s.advance().position_q16 >> 16)
        .collect();
    assert_eq!(
        pts,
        [1010, 1020, 1030, 1040, 1050, 1060, 1070, 1080, 1090, 1100]
    );
    assert_eq!(s.advance().position_q16, 1100 << 16, "holds after the tick");
    s.load((1103 << 16) + 5);
    let sp = s.advance();
    assert!((sp.velocity - 3.0 * TICK_HZ as f32).abs() < 0.1);
    let last = (1..SERVO_PER_TICK).map(|_| s.advance()).last().unwrap();
    assert_eq!(last.position_q16, (1103 << 16) + 5, "exactly on the target");
}

#[test]
fn the_setpoint_velocity_and_acceleration_follow_the_ticks() {
    let mut s = SetpointInterpolator::new(0);
    s.load(5 << 16);
    assert_eq!(s.advance().velocity, 5_000.0);
    s.load(15 << 16);
    let sp = s.advance();
    assert_eq!(sp.velocity, 10_000.0);
    assert_eq!(sp.accel, 5_000_000.0);
}

#[test]
fn sub_count_targets_are_kept_in_the_following_error() {
    assert_eq!(following_error((10 << 16) + 32_768, 4), (6, 6.5));
    assert_eq!(following_error(-(3 << 16) - 16_384, 0), (-4, -3.25));
    assert_eq!(following_error(i64::MAX, 0).0, i32::MAX);
    let s = crate::config::Scale::new(1000, 1_000_000); // 1 µm per count
    assert_eq!(target_q16(&s, 1_500), (1 << 16) + 32_768);
    assert_eq!(target_q16(&s, -1), -66);
}

#[test]
fn the_output_pushes_toward_the_target_around_mid_scale() {
    let mut a = ServoAxis::new(&gains(), 10_000.0);
    let out = a.update(&at(20), 0, ON, Coupling::NONE, None);
    assert!(out.enable);
    assert!(out.command > 10.0 && out.command < 11.0, "{out:?}");
    assert!(out.dac >= DAC_MID as u16 + 100);
    let out = a.update(&at(-20), 0, ON, Coupling::NONE, None);
    assert!(out.dac < DAC_MID as u16);
}

#[test]
fn a_disabled_loop_outputs_mid_scale_plus_trim_and_clears_its_integrator() {
    let mut g = gains();
    g.dac_offset = -7;
    let mut a = ServoAxis::new(&g, 10_000.0);
    for _ in 0..100 {
        a.update(&at(50), 0, ON, Coupling::NONE, None);
    }
    assert!(a.integral() > 0.0);
    let out = a.update(&at(50), 0, AmpIo::default(), Coupling::NONE, None);
    assert_eq!(out.dac, (DAC_MID - 7) as u16);
    assert!(!out.enable);
    assert_eq!(a.integral(), 0.0);
    assert_eq!(out.trip, None);
}

#[test]
fn the_integrator_does_not_wind_up_while_the_output_is_saturated() {
    let mut a = ServoAxis::new(&gains(), 10_000.0);
    // 90 counts: P alone gives 45 c.u.; the integral would pass 55 and saturate.
    for _ in 0..100_000 {
        let out = a.update(&at(90), 0, ON, Coupling::NONE, None);
        assert!(out.command <= 100.0);
    }
    let i = a.integral();
    assert!((50.0 - 1e-3..=55.0 + 1e-3).contains(&i), "integral {i}");
    // The moment the error reverses, the output leaves saturation at once.
    let out = a.update(&at(-90), 0, ON, Coupling::NONE, None);
    assert!(!out.saturated && out.command < 10.0, "{out:?}");
}

#[test]
fn the_dac_code_is_clamped_to_twelve_bits() {
    let mut g = gains();
    g.dac_per_unit = 100.0; // 100 c.u. would be 10 000 counts
    (g.ferror, g.min_ferror) = (0, 0); // no following-error check
    let mut a = ServoAxis::new(&g, 10_000.0);
    assert_eq!(
        a.update(&at(900), 0, ON, Coupling::NONE, None).dac,
        DAC_MAX as u16
    );
    assert_eq!(a.update(&at(-900), 0, ON, Coupling::NONE, None).dac, 0);
}

#[test]
fn the_following_error_limit_grows_with_speed_from_min_ferror_to_ferror() {
    let a = ServoAxis::new(&gains(), 10_000.0);
    assert_eq!(a.ferror_limit(0.0), 100.0);
    assert_eq!(a.ferror_limit(-5_000.0), 550.0);
    assert_eq!(a.ferror_limit(10_000.0), 1000.0);
    assert_eq!(a.ferror_limit(50_000.0), 1000.0);
}

#[test]
fn a_following_error_trip_latches_names_the_error_and_disables_the_axis() {
    let mut a = ServoAxis::new(&gains(), 10_000.0);
    let moving = Setpoint {
        position_q16: 400 << 16,
        velocity: 5_000.0,
        accel: 0.0,
    };
    assert_eq!(a.update(&moving, 0, ON, Coupling::NONE, None).trip, None);
    let out = a.update(&at(400), 0, ON, Coupling::NONE, None);
    assert_eq!(
        out.trip,
        Some(Trip::FollowingError {
            error: 400,
            limit: 100
        })
    );
    assert!(!out.enable);
    assert_eq!(out.dac, DAC_MID as u16);
    // Still tripped with the error gone, until reset.
    assert!(!a.update(&at(0), 0, ON, Coupling::NONE, None).enable);
    a.reset();
    assert!(a.update(&at(0), 0, ON, Coupling::NONE, None).enable);
}

#[test]
fn an_amplifier_fault_trips_the_loop_only_while_enabled() {
    let mut a = ServoAxis::new(&gains(), 10_000.0);
    let fault_off = AmpIo {
        enable: false,
        fault: true,
    };
    assert_eq!(
        a.update(&at(0), 0, fault_off, Coupling::NONE, None).trip,
        None
    );
    let fault_on = AmpIo {
        enable: true,
        fault: true,
    };
    let out = a.update(&at(0), 0, fault_on, Coupling::NONE, None);
    assert_eq!(out.trip, Some(Trip::AmplifierFault));
    assert!(!out.enable);
}

#[test]
fn feed_forward_and_coupling_add_to_the_command() {
    let mut a = ServoAxis::new(&gains(), 10_000.0);
    let sp = Setpoint {
        position_q16: 0,
        velocity: 1_000.0,
        accel: 0.0,
    };
    let out = a.update(&sp, 0, ON, Coupling::NONE, None);
    assert!((out.command - 10.0).abs() < 1e-4, "{out:?}");
    let c = Coupling {
        reference: 4.0,
        command: 1.0,
    };
    let out = a.update(&sp, 0, ON, c, None);
    // 10 (ff) + 1 (command) + 0.5·4 (P) + 10·4·1e-4 (I) + the earlier I (0).
    assert!((out.command - 13.004).abs() < 1e-3, "{out:?}");
}

#[test]
fn a_setpoint_part_is_the_64_bit_product_rounded() {
    let mut x = 0x2468_ace1u32;
    for n in 0..20_000 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let delta = match n {
            0 => MAX_TICK_MOVE,
            1 => -MAX_TICK_MOVE,
            2 => 0,
            _ => (x as i32 as i64) >> (n % 31),
        };
        let mut s = SetpointInterpolator::new(0);
        s.load(delta);
        for (k, &q) in STEP_Q32.iter().enumerate().take(SERVO_PER_TICK - 1) {
            let want = (delta * q as i64 + (1 << 31)) >> 32;
            assert_eq!(s.part(k), want, "delta {delta}, step {k}");
        }
    }
}
