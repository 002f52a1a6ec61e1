//! The test suite every kinematics passes, run once per machine kind.
//!
//! A machine kind is described by a [`Machine`]: its configuration, a sampler of
//! reachable poses over its usable box, poses it must refuse (with the reason), the
//! pose axes its forward kinematics solves, and its error budgets. Its `f64` model is
//! [`reference::inverse`]. The table at the end ([`every_machine!`]) lists the kinds;
//! each entry expands to a test module running every check of the suite:
//!
//! * the joints at home;
//! * the inverse against the `f64` reference over random poses and a property test;
//! * forward kinematics from a guess one 1 ms period of motion away: iterations,
//!   agreement with the answer started at the true pose and with the `f64` solution,
//!   and the round trip forward(inverse(p)) against p;
//! * unreachable poses: refused by the checked inverse with their reason, and by the
//!   Jacobian where the inverse itself refuses them;
//! * the analytic Jacobian against central differences of the reference and of the
//!   fixed-point inverse.
//!
//! Adding a machine kind: a function returning its [`Machine`], an arm in
//! [`reference::inverse`] and in [`kind`], and one line in the table.

use super::reference::{self as re, lcg, real};
use super::{Jacobian, Joints, Kinematics, MachineKinematics, Pose, Unreachable};
use crate::config::{H4TableGeometry, KinematicsConfig, MachineConfig, AXES, MAX_JOINTS};

/// One machine kind as the suite sees it.
pub struct Machine {
    /// The machine.
    pub config: MachineConfig,
    /// A reachable pose over the usable box, from uniform numbers in [0, 1) drawn from
    /// the source given.
    pub sample: fn(&MachineConfig, &mut dyn FnMut() -> f64) -> Pose,
    /// The joints at the machine's home, within `home_tolerance` (and within 1 unit of
    /// the reference).
    pub home: &'static [i64],
    /// See `home`.
    pub home_tolerance: i64,
    /// Seeds of the random poses: the inverse's comparison, the forward runs.
    pub seeds: [u64; 2],
    /// Largest joint error of the inverse against the reference, joint units.
    pub ik_budget: f64,
    /// Pose axes the forward kinematics solves for, from the first `solved.len()`
    /// joints; the others come from the guess or from a joint.
    pub solved: &'static [usize],
    /// Moves the solved angles of a guess by one period of motion.
    pub turn: fn(&mut Pose, &mut dyn FnMut() -> f64),
    /// Forward kinematics' largest error on X Y Z (nm) and on the angles (n°: the
    /// angle that moves a joint by 1 nm), both against the answer started at the true
    /// pose and against the `f64` solution of the same joints.
    pub fk_budget: (i64, i64),
    /// Largest X Y Z difference of forward(inverse(p)) from p, nm.
    pub round_trip: i64,
    /// Poses the checked inverse refuses, with the reason.
    pub unreachable: fn(&MachineConfig) -> Vec<(Pose, Unreachable)>,
}

/// Index of a kinematics kind: a new kind fails to compile here until it is given an
/// index, and [`KINDS`] counts them.
fn kind(k: &KinematicsConfig) -> usize {
    match k {
        KinematicsConfig::Cartesian { .. } => 0,
        KinematicsConfig::H4Table(_) => 1,
        KinematicsConfig::Hexapod(_) => 2,
        KinematicsConfig::HexapodXy(_) => 3,
    }
}

/// Number of kinematics kinds.
const KINDS: usize = 4;

/// The H-4 geometry of `m`.
pub fn h4_geometry(m: &MachineConfig) -> H4TableGeometry {
    match m.kinematics {
        KinematicsConfig::H4Table(g) => g,
        _ => unreachable!(),
    }
}

/// The Cartesian XYZ machine: poses anywhere within the joints' travel.
pub fn cartesian() -> Machine {
    Machine {
        config: MachineConfig::cartesian_xyz(),
        sample: |m, u| {
            let KinematicsConfig::Cartesian { axis_of_joint } = m.kinematics else {
                unreachable!()
            };
            let mut p = [0; AXES];
            for (j, &a) in m.joints.iter().zip(&axis_of_joint) {
                p[a as usize] = j.min + ((j.max - j.min) as f64 * u()).round() as i64;
            }
            p
        },
        home: &[0, 0, 0],
        home_tolerance: 0,
        seeds: [1, 5],
        ik_budget: 0.0,
        solved: &[0, 1, 2],
        turn: |_, _| {},
        fk_budget: (0, 0),
        round_trip: 0,
        unreachable: |_| {
            vec![(
                [0, 0, 500_000_000, 0, 0, 0],
                Unreachable::JointLimit { joint: 2 },
            )]
        },
    }
}

/// The H-4 with rolling table: E within |x|, |y| ≤ 100 mm, |z| ≤ 50 mm of home,
/// |θ| ≤ 45°, A in 0..90°.
pub fn h4_table() -> Machine {
    Machine {
        config: MachineConfig::h4_table(),
        sample: |m, u| {
            let mut u = |lo: f64, hi: f64| lo + (hi - lo) * u();
            let e = [u(-100.0, 100.0), u(-100.0, 100.0), u(-50.0, 50.0)];
            re::h4_pose_from_head(&h4_geometry(m), e, u(-45.0, 45.0), u(0.0, 90.0))
        },
        // sqrt(550² − (190² + 200²)) mm = 475.8150901… mm
        home: &[475_815_090, 475_815_090, 475_815_090, 475_815_090, 0],
        home_tolerance: 0,
        seeds: [1, 5],
        ik_budget: 5.0,
        solved: &[0, 1, 2, 5],
        // 90 °/s on θ.
        turn: |p, u| p[5] -= if u() < 0.5 { 90_000_000 } else { -90_000_000 },
        // C: 954 n° moves a bar end by 1 nm.
        fk_budget: (1, 954),
        round_trip: 5,
        unreachable: |m| {
            let g = h4_geometry(m);
            let head = |x: f64, z: f64, a: f64| re::h4_pose_from_head(&g, [x, 0.0, z], 0.0, a);
            vec![
                // E at x = +280 mm: arm 1 (rail at x −250) has ρ ≈ 511 mm: 22° elevation.
                (head(280.0, 0.0, 0.0), Unreachable::Singular),
                (head(400.0, 0.0, 0.0), Unreachable::OutOfReach),
                ([i64::MAX, 0, 0, 0, 0, 0], Unreachable::OutOfReach),
                // Carriages at 675.8 mm, beyond 650 mm; the table beyond 90°.
                (head(0.0, 200.0, 0.0), Unreachable::JointLimit { joint: 0 }),
                (head(0.0, 0.0, 100.0), Unreachable::JointLimit { joint: 4 }),
            ]
        },
    }
}

/// The hexapod: translations within ±50 mm of home (0, 0, 450 mm), A B C ±10°.
pub fn hexapod() -> Machine {
    Machine {
        config: MachineConfig::hexapod(),
        sample: |_, u| {
            let mut u = |half: f64, scale: f64| ((u() * 2.0 - 1.0) * half * scale).round() as i64;
            [
                u(50.0, 1e6),
                u(50.0, 1e6),
                450_000_000 + u(50.0, 1e6),
                u(10.0, 1e9),
                u(10.0, 1e9),
                u(10.0, 1e9),
            ]
        },
        // |(0, 0, 450) + b_1 − a_1| = 492.126… mm, the same for all six legs.
        home: &[492_126_000; 6],
        home_tolerance: 999,
        seeds: [3, 9],
        ik_budget: 5.0,
        solved: &[0, 1, 2, 3, 4, 5],
        // Up to 90 °/s on each angle.
        turn: |p, u| {
            for a in &mut p[3..] {
                *a -= ((u() * 2.0 - 1.0) * 90_000_000.0).round() as i64;
            }
        },
        // Angles: 382 n° moves a platform joint by 1 nm.
        fk_budget: (1, 382),
        round_trip: 5,
        unreachable: |_| {
            vec![
                ([0, 0, i64::MIN, 0, 0, 0], Unreachable::OutOfReach),
                // Legs of about 320 mm, short of 350 mm.
                (
                    [0, 0, 250_000_000, 0, 0, 0],
                    Unreachable::JointLimit { joint: 0 },
                ),
            ]
        },
    }
}

/// The hexapod under an X-Y table's tool: the workpiece point within ±20 mm in X and
/// Y of the platform's axis, Z 245..305 mm, A and B ±10° (the table follows within its
/// travel).
pub fn hexapod_xy() -> Machine {
    Machine {
        config: MachineConfig::hexapod_xy(),
        sample: |_, u| {
            let mut u =
                |lo: f64, hi: f64, scale: f64| ((lo + (hi - lo) * u()) * scale).round() as i64;
            [
                u(-20.0, 20.0, 1e6),
                u(-20.0, 20.0, 1e6),
                u(245.0, 305.0, 1e6),
                u(-10.0, 10.0, 1e9),
                u(-10.0, 10.0, 1e9),
                0,
            ]
        },
        // |(0, 0, 260) + b_1 − a_1| = 327.549… mm for every leg; the table at 0.
        home: &[
            327_549_000,
            327_549_000,
            327_549_000,
            327_549_000,
            327_549_000,
            327_549_000,
            0,
            0,
        ],
        home_tolerance: 999,
        seeds: [4, 10],
        ik_budget: 5.0,
        solved: &[0, 1, 2, 3, 4],
        // Up to 90 °/s on A and B.
        turn: |p, u| {
            for a in &mut p[3..5] {
                *a -= ((u() * 2.0 - 1.0) * 90_000_000.0).round() as i64;
            }
        },
        fk_budget: (2, 382),
        round_trip: 5,
        unreachable: |_| {
            vec![
                ([0, 0, i64::MIN, 0, 0, 0], Unreachable::OutOfReach),
                // The workpiece point 100 mm above the tool's height: the platform
                // would go down to 175 mm, legs of about 265 mm, short of 280 mm.
                (
                    [0, 0, 360_000_000, 0, 0, 0],
                    Unreachable::JointLimit { joint: 0 },
                ),
            ]
        },
    }
}

/// Largest joint error of `k`'s inverse against the `f64` reference at `pose`.
pub fn ik_error(m: &MachineConfig, k: &MachineKinematics, pose: &Pose) -> f64 {
    let want = re::inverse(m, &real(pose)).expect("reference: reachable");
    let mut q = [0; MAX_JOINTS];
    k.inverse(pose, &mut q).expect("fixed point: reachable");
    (0..m.joints.len())
        .map(|i| (q[i] as f64 - want[i]).abs())
        .fold(0.0, f64::max)
}

/// The joints at home are as described, and within 1 unit of the reference.
fn home_joints_are_as_expected(m: &Machine) {
    let k = MachineKinematics::new(&m.config);
    let mut q = [0; MAX_JOINTS];
    k.inverse_checked(&m.config.home, &m.config.joints, &mut q)
        .unwrap();
    assert_eq!(m.home.len(), m.config.joints.len());
    for (q, want) in q.iter().zip(m.home) {
        assert!((q - want).abs() <= m.home_tolerance, "{q:?}");
    }
    assert!(ik_error(&m.config, &k, &m.config.home) <= 1.0);
}

/// The inverse is within the budget of the reference over 100 000 random poses.
fn inverse_agrees_with_the_reference(m: &Machine) {
    let k = MachineKinematics::new(&m.config);
    let mut seed = m.seeds[0];
    let mut worst = 0.0f64;
    let n = 100_000;
    for _ in 0..n {
        let p = (m.sample)(&m.config, &mut || lcg(&mut seed));
        worst = worst.max(ik_error(&m.config, &k, &p));
    }
    eprintln!(
        "{} inverse: max joint error {worst:.3} over {n} poses",
        m.config.name
    );
    assert!(worst <= m.ik_budget, "{worst}");
}

/// The same at the pose sampled from the numbers `u`.
fn inverse_agrees_with_the_reference_at(m: &Machine, u: [f64; 6]) -> f64 {
    let k = MachineKinematics::new(&m.config);
    let mut u = u.into_iter();
    let p = (m.sample)(&m.config, &mut || u.next().unwrap());
    ik_error(&m.config, &k, &p)
}

/// Runs forward kinematics from a guess one 1 ms period of motion away (200 mm/s in a
/// random direction, the machine's turn on the angles) and from the true pose.
fn forward_case(m: &Machine, k: &MachineKinematics, s: &mut u64, stats: &mut re::FkStats) {
    let p = (m.sample)(&m.config, &mut || lcg(s));
    let mut q: Joints = [0; MAX_JOINTS];
    k.inverse(&p, &mut q).unwrap();
    let dir = [lcg(s) - 0.5, lcg(s) - 0.5, lcg(s) - 0.5];
    let norm = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
    let mut guess = p;
    for i in (0..3).filter(|i| m.solved.contains(i)) {
        guess[i] -= (200_000.0 * dir[i] / norm).round() as i64;
    }
    (m.turn)(&mut guess, &mut || lcg(s));
    let (mut out, mut at) = ([0; AXES], [0; AXES]);
    let it = match k.forward_counted(&q, &guess, &mut out) {
        Ok(it) => it,
        Err(e) => panic!("{e:?}: p {p:?} guess {guess:?}"),
    };
    k.forward(&q, &p, &mut at).unwrap();
    for a in (0..AXES).filter(|a| !m.solved.contains(a)) {
        assert_eq!(out[a], p[a], "axis {a} is not solved for");
    }
    let mut want = real(&p);
    let target: Vec<f64> = q.iter().map(|&v| v as f64).collect();
    re::newton(
        |x| re::inverse(&m.config, x).unwrap().to_vec(),
        &target,
        &mut want,
        m.solved,
    );
    let angles: Vec<usize> = m.solved.iter().copied().filter(|&a| a >= 3).collect();
    stats.add(it, &out, &at, &p, &want, &angles);
}

/// Forward kinematics converges in at most 3 iterations from the previous period's
/// pose, to within the machine's budget.
fn forward_converges_from_the_previous_period(m: &Machine) {
    let k = MachineKinematics::new(&m.config);
    let mut seed = m.seeds[1];
    let mut st = re::FkStats::default();
    let n = 5_000;
    for _ in 0..n {
        forward_case(m, &k, &mut seed, &mut st);
    }
    eprintln!(
        "{} forward ({n} cases): iterations histogram {:?}; converged to within {} nm, {} \
         n° of the answer started at the true pose; against the f64 solution {:.3} nm, \
         {:.0} n°; round trip {} nm",
        m.config.name, st.hist, st.conv_lin, st.conv_ang, st.lin, st.ang, st.round_trip
    );
    assert!(st.max_iterations() <= 3);
    let (lin, ang) = m.fk_budget;
    assert!(
        st.conv_lin <= lin && st.conv_ang <= ang,
        "{} {}",
        st.conv_lin,
        st.conv_ang
    );
    assert!(
        st.lin <= lin as f64 && st.ang <= ang as f64,
        "{} {}",
        st.lin,
        st.ang
    );
    assert!(st.round_trip <= m.round_trip, "{}", st.round_trip);
}

/// Each unreachable pose is refused with its reason, and where the inverse itself
/// refuses it (not the travel check), so does the Jacobian.
fn unreachable_poses_are_refused(m: &Machine) {
    let k = MachineKinematics::new(&m.config);
    let (mut q, mut jac) = ([0; MAX_JOINTS], [[0.0; AXES]; MAX_JOINTS]);
    for (p, why) in (m.unreachable)(&m.config) {
        assert_eq!(
            k.inverse_checked(&p, &m.config.joints, &mut q),
            Err(why),
            "{p:?}"
        );
        if !matches!(why, Unreachable::JointLimit { .. }) {
            assert_eq!(k.jacobian(&p, &mut jac), Err(why), "{p:?}");
        }
    }
}

/// Central differences of `inverse` at `p`: step `lin` on X Y Z, `ang` on A B C.
fn differences(
    p: &Pose,
    lin: i64,
    ang: i64,
    inverse: impl Fn(&Pose) -> [f64; MAX_JOINTS],
) -> Jacobian {
    let mut d = [[0.0; AXES]; MAX_JOINTS];
    for k in 0..AXES {
        let h = if k < 3 { lin } else { ang };
        let (mut hi, mut lo) = (*p, *p);
        hi[k] += h;
        lo[k] -= h;
        let (qh, ql) = (inverse(&hi), inverse(&lo));
        for (row, (a, b)) in d.iter_mut().zip(qh.iter().zip(&ql)) {
            row[k] = ((a - b) / (2 * h) as f64) as f32;
        }
    }
    d
}

/// Largest error of `jac` against `d`, relative per block of joint units (linear,
/// rotary joints) and pose units (X Y Z, A B C): to the largest entry of `d` in that
/// block, the largest rate a path tangent can give such joints per unit of such axes
/// at this pose; where that block of `d` is 0, `jac` must be exactly 0 there.
fn relative_error(jac: &Jacobian, d: &Jacobian, rotary: &[bool]) -> f32 {
    let is_rotary = |i: usize| rotary.get(i).copied().unwrap_or(false);
    let mut worst = 0.0f32;
    for unit in [false, true] {
        for g in [0..3, 3..6] {
            let rows = || (0..MAX_JOINTS).filter(move |&i| is_rotary(i) == unit);
            let scale = rows()
                .flat_map(|i| d[i][g.clone()].iter())
                .fold(0.0f32, |s, v| s.max(v.abs()));
            for i in rows() {
                for k in g.clone() {
                    let err = (jac[i][k] - d[i][k]).abs();
                    worst = worst.max(if scale > 0.0 { err / scale } else { err * 1e30 });
                }
            }
        }
    }
    worst
}

/// The analytic Jacobian against central differences at home and 2 000 random poses.
///
/// Of the `f64` reference (1 µm and 0.001° steps: truncation and rounding below
/// 1e-9): within 1e-5 relative. The Jacobian is a few `f32` operations on O(1) values
/// (2^-24 = 6e-8 each; the H-4's A column from E in `f32`), ~1e-6 at worst.
///
/// Of the fixed-point inverse the planner used to difference (0.1 mm and 0.1° steps):
/// within 2e-4 relative. Each joint is within the 5 nm budget of exact, so a difference
/// is off by at most 5 nm / 0.1 mm = 5e-5 nm/nm on X Y Z, whose rows have a largest
/// entry ≥ 1/√3 (a unit leg direction; the H-4's (gx, gy, 1)·Rx(A)): ≤ 8.7e-5; and by
/// 5 nm / 0.1° = 5e-8 nm/n° on A B C, whose rows have a largest entry ≥ 1e-3 nm/n°
/// (the levers ≥ 57 mm): ≤ 5e-5. Truncation (h²·q‴/6) stays below 1e-6.
fn jacobian_matches_central_differences(m: &Machine) {
    let k = MachineKinematics::new(&m.config);
    let mut seed = 11;
    let mut poses = vec![m.config.home];
    for _ in 0..2_000 {
        poses.push((m.sample)(&m.config, &mut || lcg(&mut seed)));
    }
    let (mut worst_ref, mut worst_fixed) = (0.0f32, 0.0f32);
    let mut jac = [[0.0; AXES]; MAX_JOINTS];
    let rotary: Vec<bool> = m.config.joints.iter().map(|j| j.rotary).collect();
    for p in &poses {
        k.jacobian(p, &mut jac).unwrap();
        let exact = differences(p, 1_000, 1_000_000, |x| {
            re::inverse(&m.config, &real(x)).unwrap()
        });
        let fixed = differences(p, 100_000, 100_000_000, |x| {
            let mut q = [0; MAX_JOINTS];
            k.inverse(x, &mut q).unwrap();
            q.map(|v| v as f64)
        });
        let (e, f) = (
            relative_error(&jac, &exact, &rotary),
            relative_error(&jac, &fixed, &rotary),
        );
        assert!(e <= 1e-5, "{p:?}: {e} against the reference");
        assert!(f <= 2e-4, "{p:?}: {f} against the fixed-point inverse");
        worst_ref = worst_ref.max(e);
        worst_fixed = worst_fixed.max(f);
    }
    eprintln!(
        "{} Jacobian: relative error {worst_ref:.2e} against the reference, \
         {worst_fixed:.2e} against the fixed-point inverse ({} poses)",
        m.config.name,
        poses.len()
    );
}

/// Expands to one test module per machine kind running the whole suite, and a check
/// that every kind is listed.
macro_rules! every_machine {
    ($($name:ident: $machine:expr;)*) => {
        $(
            mod $name {
                use super::*;
                use proptest::prelude::*;

                fn machine() -> Machine {
                    $machine
                }

                #[test]
                fn home_joints_are_as_expected() {
                    super::home_joints_are_as_expected(&machine());
                }

                #[test]
                fn inverse_agrees_with_the_reference_over_the_usable_box() {
                    inverse_agrees_with_the_reference(&machine());
                }

                proptest! {
                    #![proptest_config(ProptestConfig::with_cases(20_000))]
                    #[test]
                    fn inverse_error_is_within_the_budget(
                        u in proptest::array::uniform6(0.0..1.0f64),
                    ) {
                        let m = machine();
                        prop_assert!(inverse_agrees_with_the_reference_at(&m, u) <= m.ik_budget);
                    }
                }

                #[test]
                fn forward_converges_in_3_iterations_from_the_previous_period() {
                    forward_converges_from_the_previous_period(&machine());
                }

                #[test]
                fn unreachable_poses_are_refused_with_their_reason() {
                    unreachable_poses_are_refused(&machine());
                }

                #[test]
                fn the_jacobian_matches_central_differences_of_the_inverse() {
                    jacobian_matches_central_differences(&machine());
                }
            }
        )*

        #[test]
        fn every_kinematics_kind_runs_the_suite() {
            let mut seen = [false; KINDS];
            $(seen[kind(&$machine.config.kinematics)] = true;)*
            assert!(seen.iter().all(|&s| s), "{seen:?}");
        }
    };
}

every_machine! {
    cartesian: cartesian();
    h4_table: h4_table();
    hexapod: hexapod();
    hexapod_xy: hexapod_xy();
}
