//! The paths' tests: arcs, helices and lines end exactly; plans for another path
//! are refused; the extreme arcs run exactly.

use super::*;

fn arc(target: [i64; AXES], center: [i64; 2], clockwise: bool, turns: u16) -> Block {
    Block {
        line: 1,
        motion: Motion::Arc {
            center,
            plane: Plane::Xy,
            clockwise,
            turns,
        },
        target,
        feed: 1,
        tolerance_nm: 0,
    }
}

#[test]
fn a_quarter_circle_stays_on_the_circle_and_ends_exactly() {
    let r = 10_000_000;
    let b = arc([0, r, 0, 0, 0, 0], [0, 0], false, 0);
    let from = [r, 0, 0, 0, 0, 0];
    let p = Path::new(&b, &from).unwrap();
    let quarter = core::f64::consts::FRAC_PI_2 * r as f64;
    assert!((p.length as f64 - quarter).abs() < 1.0);
    let mut pose = [0; AXES];
    for k in 0..=1000 {
        let s = (p.length << 16) / 1000 * k;
        p.pose_at(&from, s, &mut pose);
        let rad = ((pose[0] as f64).powi(2) + (pose[1] as f64).powi(2)).sqrt();
        assert!(
            (rad - r as f64).abs() < 1.0,
            "off the circle by {} nm",
            rad - r as f64
        );
    }
    p.pose_at(&from, p.length << 16, &mut pose);
    assert_eq!(pose, [0, r, 0, 0, 0, 0]);
}

#[test]
fn a_full_helix_with_an_extra_turn_has_the_length_of_two_turns() {
    let r = 5_000_000;
    let b = arc([r, 0, -2_000_000, 0, 0, 0], [0, 0], true, 1);
    let from = [r, 0, 0, 0, 0, 0];
    let p = Path::new(&b, &from).unwrap();
    let planar = 2.0 * core::f64::consts::TAU * r as f64;
    let want = (planar * planar + 4e12).sqrt();
    assert!((p.length as f64 - want).abs() < 1.0);
    // Halfway: one full turn done (back at angle 0), halfway down.
    let mut pose = [0; AXES];
    p.pose_at(&from, p.length << 15, &mut pose);
    assert!((pose[0] - r).abs() <= 1 && pose[1].abs() <= 1, "{pose:?}");
    assert!((pose[2] + 1_000_000).abs() <= 1);
}

#[test]
fn a_straight_line_lands_within_a_nanometre_of_every_fraction() {
    let b = Block {
        line: 1,
        motion: Motion::Linear,
        target: [123_456_789, -98_765_432, 5, 0, 0, 0],
        feed: 1,
        tolerance_nm: 0,
    };
    let p = Path::new(&b, &[0; AXES]).unwrap();
    let mut pose = [0; AXES];
    p.pose_at(&[0; AXES], p.length << 15, &mut pose);
    assert!((pose[0] - 61_728_394).abs() <= 1, "{pose:?}");
    assert!((pose[1] + 49_382_716).abs() <= 1, "{pose:?}");
}

/// What the host computes for `block` from `start`, checked as the controller does.
fn round_trip(block: &Block, start: &[i64; AXES]) -> Result<Path, GeometryError> {
    let host = Path::new(block, start)?;
    Path::from_plan(block, start, host.length, host.shape())
}

proptest::proptest! {
    #[test]
    fn the_controller_accepts_every_arc_the_host_computes(
        r_um in 10i64..5_000_000, a0 in 0.0f64..360.0, sweep in 1.0f64..359.0,
        helix in -50_000_000i64..50_000_000, cw in proptest::bool::ANY, turns in 0u16..3,
        plane in 0usize..3, dr in -2_000i64..2_000,
    ) {
        let plane = [Plane::Xy, Plane::Zx, Plane::Yz][plane];
        let (i, j, k) = plane.axes();
        let r = r_um * 1000;
        let c = [1_000_000i64, -2_000_000];
        let a1 = if cw { a0 - sweep } else { a0 + sweep };
        let mut start = [0i64; AXES];
        start[i] = c[0] + (r as f64 * a0.to_radians().cos()).round() as i64;
        start[j] = c[1] + (r as f64 * a0.to_radians().sin()).round() as i64;
        let mut target = start;
        let r1 = (r + dr).max(1) as f64;
        target[i] = c[0] + (r1 * a1.to_radians().cos()).round() as i64;
        target[j] = c[1] + (r1 * a1.to_radians().sin()).round() as i64;
        target[k] += helix;
        let b = Block {
            line: 1,
            motion: Motion::Arc { center: c, plane, clockwise: cw, turns },
            target,
            feed: 1_000_000,
            tolerance_nm: 0,
        };
        let host = Path::new(&b, &start);
        proptest::prop_assume!(host.is_ok());
        let host = host.unwrap();
        proptest::prop_assert_eq!(round_trip(&b, &start), Ok(host));
    }

    #[test]
    fn the_controller_accepts_every_line_the_host_computes(
        d in proptest::array::uniform6(-500_000_000i64..500_000_000),
        rotary_only in proptest::bool::ANY,
    ) {
        let mut target = d;
        if rotary_only {
            target[..3].copy_from_slice(&[0, 0, 0]);
        }
        let b = Block { line: 1, motion: Motion::Linear, target, feed: 1_000_000, tolerance_nm: 0 };
        let start = [0; AXES];
        proptest::prop_assert_eq!(round_trip(&b, &start), Path::new(&b, &start));
    }
}

#[test]
fn an_arc_s_tangent_is_the_derivative_of_its_pose() {
    for (clockwise, turns) in [(false, 0), (true, 0), (false, 1)] {
        // A quarter (or one and a quarter) of a 10 mm circle with a 3 mm helix.
        let b = arc(
            [0, 10_000_000, 3_000_000, 0, 0, 0],
            [0, 0],
            clockwise,
            turns,
        );
        let from = [10_000_000, 0, 0, 0, 0, 0];
        let p = Path::new(&b, &from).unwrap();
        for k in 1..8 {
            let s = (p.length << 16) / 8 * k;
            let h = 1_000i64 << 16; // 1 µm
            let (mut a, mut c) = ([0; AXES], [0; AXES]);
            p.pose_at(&from, s - h, &mut a);
            p.pose_at(&from, s + h, &mut c);
            let t = p.tangent_at(s);
            for i in 0..3 {
                let fd = (c[i] - a[i]) as f32 / 2_000.0;
                assert!(
                    (t[i] - fd).abs() < 1e-3,
                    "{clockwise} {turns} {k} {i}: {t:?} vs {fd}"
                );
            }
        }
    }
}

#[test]
fn a_tiny_arc_whose_radius_the_controller_rounds_is_accepted() {
    // A 45.58 µm radius, 314° (found by the property test of issue 16): the whole
    // nanometre radii move the planar length by 2.7·10⁻⁵, beyond the relative
    // bound alone.
    let b = Block {
        line: 3,
        motion: Motion::Arc {
            center: [15_400, 42_900],
            plane: Plane::Xy,
            clockwise: false,
            turns: 0,
        },
        target: [-26_200, 24_200, -30_000_000, 0, 0, 0],
        feed: 50_000_000,
        tolerance_nm: 0,
    };
    let start = [0, 0, -30_000_000, 0, 0, 0];
    assert_eq!(round_trip(&b, &start), Path::new(&b, &start));
}

#[test]
fn a_plan_for_another_arc_is_refused() {
    let b = arc([0, 10_000_000, 0, 0, 0, 0], [0, 0], false, 0);
    let start = [10_000_000, 0, 0, 0, 0, 0];
    let host = Path::new(&b, &start).unwrap();
    // The other way round (three quarters), or one turn more.
    let mut other = b;
    other.motion = Motion::Arc {
        center: [0, 0],
        plane: Plane::Xy,
        clockwise: true,
        turns: 0,
    };
    assert_eq!(
        Path::from_plan(&other, &start, host.length, host.shape()),
        Err(GeometryError::PlanMismatch)
    );
    let mut more = b;
    more.motion = Motion::Arc {
        center: [0, 0],
        plane: Plane::Xy,
        clockwise: false,
        turns: 1,
    };
    assert_eq!(
        Path::from_plan(&more, &start, host.length, host.shape()),
        Err(GeometryError::PlanMismatch)
    );
    // A length that does not match the sweep.
    assert_eq!(
        Path::from_plan(&b, &start, host.length * 2, host.shape()),
        Err(GeometryError::PlanMismatch)
    );
}

mod extreme_arcs {
    use super::*;

    /// xorshift64*: a seeded generator (the same cases every run).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Issue 34: line 5,557 of a CamBam program, `G3 X10.9764 Y15.2949 I3827.4875
    /// J1391.3692` (radius 4,072 mm, chord 0.2 mm), with the start written to four
    /// decimals at 2,000 places along its circle. The length check took the sweep to
    /// 2⁻³² turn, 3·10⁻⁵ of this one, and refused 182 of these plans as malformed.
    #[test]
    fn the_cambam_arc_of_issue_34_runs_exactly_wherever_it_starts() {
        let off = [3_827_487_500i64, 1_391_369_200];
        let r = (off[0] as f64).hypot(off[1] as f64);
        let e = [10_976_400i64, 15_294_900];
        let u = [-off[0] as f64 / r, -off[1] as f64 / r];
        let mut refused = 0;
        for k in 0..2000 {
            let d = 200_000.0 / r * (0.5 + k as f64 * 1e-3);
            let ru = [
                u[0] * d.cos() - u[1] * d.sin(),
                u[0] * d.sin() + u[1] * d.cos(),
            ];
            let ct = [e[0] as f64 - r * ru[0], e[1] as f64 - r * ru[1]];
            let at = |v: f64| (v / 100.0).round() as i64 * 100;
            let s = [at(ct[0] + r * u[0]), at(ct[1] + r * u[1])];
            let b = Block {
                line: 5557,
                motion: Motion::Arc {
                    center: [s[0] + off[0], s[1] + off[1]],
                    plane: Plane::Xy,
                    clockwise: false,
                    turns: 0,
                },
                target: [e[0], e[1], 0, 0, 0, 0],
                feed: 1_000_000,
                tolerance_nm: 0,
            };
            if Path::checked(&b, &[s[0], s[1], 0, 0, 0, 0]).is_err() {
                refused += 1;
            }
        }
        assert_eq!(refused, 0, "{refused} of 2000 refused");
    }

    /// The reach of the one rule ([`Path::checked`]): every arc of radius up to
    /// [`MAX_ARC_RADIUS_NM`], chord 2 nm to 100 mm (radius up to 10⁹ chords), minor
    /// or major (nearly full circles), every plane, helical or not, runs exactly.
    /// (Chords of 1 nm may not: the host sends those as lines.)
    #[test]
    fn every_arc_within_the_exact_range_over_two_nanometres_runs_exactly() {
        let mut rng = Rng(0x34);
        let (mut refused, mut n) = (0, 0);
        while n < 100_000 {
            let chord = 10f64.powf(0.31 + rng.next() * 7.7);
            let r = chord * 10f64.powf(rng.next() * 9.0).max(0.5);
            if r > MAX_ARC_RADIUS_NM as f64 {
                continue;
            }
            let half = (chord / 2.0 / r).min(1.0).asin();
            let major = rng.next() < 0.3;
            let sweep = if major {
                core::f64::consts::TAU - 2.0 * half
            } else {
                2.0 * half
            };
            let cw = rng.next() < 0.5;
            let plane = [Plane::Xy, Plane::Zx, Plane::Yz][(rng.next() * 3.0) as usize];
            let (i, j, k) = plane.axes();
            let a0 = rng.next() * core::f64::consts::TAU;
            let a1 = if cw { a0 - sweep } else { a0 + sweep };
            let c = [
                (rng.next() * 2e8 - 1e8) as i64,
                (rng.next() * 2e8 - 1e8) as i64,
            ];
            let mut start = [0i64; AXES];
            start[i] = c[0] + (r * a0.cos()).round() as i64;
            start[j] = c[1] + (r * a0.sin()).round() as i64;
            start[k] = 5_000_000;
            let mut target = start;
            target[i] = c[0] + (r * a1.cos()).round() as i64;
            target[j] = c[1] + (r * a1.sin()).round() as i64;
            if rng.next() < 0.5 {
                target[k] += (rng.next() * 2e7 - 1e7) as i64;
            }
            let ends = [target[i] - start[i], target[j] - start[j]];
            if (ends[0] as f64).hypot(ends[1] as f64) < 2.0 {
                continue;
            }
            let b = Block {
                line: 1,
                motion: Motion::Arc {
                    center: c,
                    plane,
                    clockwise: cw,
                    turns: 0,
                },
                target,
                feed: 1,
                tolerance_nm: 0,
            };
            n += 1;
            if let Err(e) = Path::checked(&b, &start) {
                refused += 1;
                std::eprintln!("{e:?}: radius {r} nm, chord {chord} nm: {b:?} from {start:?}");
            }
        }
        assert_eq!(refused, 0, "{refused} of {n} arcs refused");
    }
}
