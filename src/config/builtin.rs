//! The built-in machines: the Cartesian default the controller starts with until a
//! machine file is loaded, and the H-4 and hexapod of `examples/machines/` for the
//! tests and the simulator.

use super::*;

impl MachineConfig {
    /// A Cartesian 3-axis stepper machine (X Y Z on stepper channels 0..2, 400 steps/mm,
    /// 200 × 300 × 100 mm travel, 100 mm/s, 1000 mm/s², PacSci 6410 drives): the
    /// built-in default until a machine file is loaded.
    pub fn cartesian_xyz() -> Self {
        let mm = crate::units::NM_PER_MM;
        let limits = Limits {
            max_velocity: 100 * mm,
            max_accel: 1000 * mm,
        };
        let travel = [(-100, 100), (-150, 150), (-80, 20)];
        let mut joints = heapless::Vec::new();
        for (c, (lo, hi)) in travel.iter().enumerate() {
            let _ = joints.push(JointConfig {
                drive: Drive::Stepper {
                    channel: c as u8,
                    timing: StepTiming::PACSCI_6410,
                    invert_dir: false,
                },
                scale: Scale::new(400, mm as u64),
                rotary: false,
                min: lo * mm,
                max: hi * mm,
                limits,
                homing: Homing {
                    switch_at: hi * mm,
                    search_velocity: 20 * mm,
                    latch_velocity: mm,
                    use_index: false,
                },
            });
        }
        let none = Limits {
            max_velocity: 0,
            max_accel: 0,
        };
        let mut axis_of_joint = [0u8; MAX_JOINTS];
        axis_of_joint[..3].copy_from_slice(&[0, 1, 2]);
        let mut name = heapless::String::new();
        let _ = name.push_str("cartesian-xyz");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::Cartesian { axis_of_joint },
            joints,
            axes: [limits, limits, limits, none, none, none],
            home: [0; AXES],
            servo: ServoConfig::NONE,
            motion: MotionConfig::TRAPEZOID,
        }
    }

    /// The H-4 with rolling table (`examples/machines/h4-table.toml`): rails at
    /// (±250, ±250) mm, forearms 550 mm, bar half-length 60 mm, attachments ±50 mm in Y,
    /// tool 80 mm below E, table axis through (0, 0, −130) mm, forearms ≥ 25° above
    /// horizontal. q1..q4 are servo carriages (1000 counts/mm, 150..650 mm, 500 mm/s)
    /// on servo channels 0..3; q5 the table, a stepper on channel 0 (50 steps/°,
    /// 0..90°, 90 °/s). Home: E at the origin, θ = 0, A = 0, so the tool tip is at
    /// Z −80 mm and every carriage at 475.815 mm.
    pub fn h4_table() -> Self {
        let mm = crate::units::NM_PER_MM;
        let deg = crate::units::NDEG_PER_DEG;
        let mut joints = heapless::Vec::new();
        for c in 0..4u8 {
            let _ = joints.push(JointConfig {
                drive: Drive::Servo { channel: c },
                scale: Scale::new(1000, mm as u64),
                rotary: false,
                min: 150 * mm,
                max: 650 * mm,
                limits: Limits {
                    max_velocity: 500 * mm,
                    max_accel: 5000 * mm,
                },
                homing: Homing {
                    switch_at: 650 * mm,
                    search_velocity: 50 * mm,
                    latch_velocity: mm,
                    use_index: false,
                },
            });
        }
        let _ = joints.push(JointConfig {
            drive: Drive::Stepper {
                channel: 0,
                timing: StepTiming::PACSCI_6410,
                invert_dir: false,
            },
            scale: Scale::new(50, deg as u64),
            rotary: true,
            min: 0,
            max: 90 * deg,
            limits: Limits {
                max_velocity: 90 * deg,
                max_accel: 900 * deg,
            },
            homing: Homing {
                switch_at: 0,
                search_velocity: -10 * deg,
                latch_velocity: deg,
                use_index: false,
            },
        });
        let linear = Limits {
            max_velocity: 200 * mm,
            max_accel: 2000 * mm,
        };
        let rotary = Limits {
            max_velocity: 90 * deg,
            max_accel: 900 * deg,
        };
        let none = Limits {
            max_velocity: 0,
            max_accel: 0,
        };
        let mut name = heapless::String::new();
        let _ = name.push_str("h4-table");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::H4Table(H4TableGeometry {
                rails: [
                    [-250 * mm, 250 * mm],
                    [-250 * mm, -250 * mm],
                    [250 * mm, -250 * mm],
                    [250 * mm, 250 * mm],
                ],
                forearm: 550 * mm,
                bar_half: 60 * mm,
                sides: [-1, -1, 1, 1],
                attach: [
                    [0, 50 * mm, 0],
                    [0, -50 * mm, 0],
                    [0, -50 * mm, 0],
                    [0, 50 * mm, 0],
                ],
                tool_length: 80 * mm,
                table_pivot: [0, 0, -130 * mm],
                min_elevation: 25 * deg,
            }),
            joints,
            axes: [linear, linear, linear, rotary, none, rotary],
            home: [0, 0, -80 * mm, 0, 0, 0],
            servo: ServoConfig {
                gains: core::array::from_fn(|c| {
                    if c < 4 {
                        ServoGains::DEFAULT_PLANT
                    } else {
                        ServoGains::NONE
                    }
                }),
                law: [0; MAX_SERVOS],
                lqg: heapless::Vec::new(),
                contour: ContourConfig::UNCOUPLED,
            },
            motion: MotionConfig::TRAPEZOID,
        }
    }

    /// The thesis hexapod (`examples/machines/hexapod.toml`): base joints on a 300 mm
    /// circle at 348°, 12°, 108°, 132°, 228°, 252°, platform joints on a 150 mm circle
    /// at 312°, 48°, 72°, 168°, 192°, 288° (both in their z = 0 planes; coordinates
    /// rounded to the nm as the host rounds the machine file). Six stepper legs on
    /// channels 0..5, 400 steps/mm, 350..650 mm, 100 mm/s; home (0, 0, 450 mm) level.
    pub fn hexapod() -> Self {
        let mm = crate::units::NM_PER_MM;
        let deg = crate::units::NDEG_PER_DEG;
        let mut joints = heapless::Vec::new();
        for c in 0..6u8 {
            let _ = joints.push(JointConfig {
                drive: Drive::Stepper {
                    channel: c,
                    timing: StepTiming::PACSCI_6410,
                    invert_dir: false,
                },
                scale: Scale::new(400, mm as u64),
                rotary: false,
                min: 350 * mm,
                max: 650 * mm,
                limits: Limits {
                    max_velocity: 100 * mm,
                    max_accel: 1000 * mm,
                },
                homing: Homing {
                    switch_at: 650 * mm,
                    search_velocity: 20 * mm,
                    latch_velocity: mm,
                    use_index: false,
                },
            });
        }
        let linear = Limits {
            max_velocity: 100 * mm,
            max_accel: 1000 * mm,
        };
        let rotary = Limits {
            max_velocity: 30 * deg,
            max_accel: 300 * deg,
        };
        let mut name = heapless::String::new();
        let _ = name.push_str("hexapod");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::Hexapod(HexapodGeometry {
                base: [
                    [293_444_280, -62_373_507, 0],
                    [293_444_280, 62_373_507, 0],
                    [-92_705_098, 285_316_955, 0],
                    [-200_739_182, 222_943_448, 0],
                    [-200_739_182, -222_943_448, 0],
                    [-92_705_098, -285_316_955, 0],
                ],
                platform: [
                    [100_369_591, -111_471_724, 0],
                    [100_369_591, 111_471_724, 0],
                    [46_352_549, 142_658_477, 0],
                    [-146_722_140, 31_186_754, 0],
                    [-146_722_140, -31_186_754, 0],
                    [46_352_549, -142_658_477, 0],
                ],
            }),
            joints,
            axes: [linear, linear, linear, rotary, rotary, rotary],
            home: [0, 0, 450 * mm, 0, 0, 0],
            servo: ServoConfig::NONE,
            motion: MotionConfig::TRAPEZOID,
        }
    }
    /// Report B's machine (`examples/machines/hexapod-xy.toml`; the plants, names and
    /// cylinder areas are the host's): the thesis hexapod's legs (as
    /// [`MachineConfig::hexapod`]) as servo cylinders on channels 0..5, 280..420 mm, with
    /// the platform's home at (0, 0, 260 mm); the table's X and Y on servo channels 6
    /// and 7, ±50 mm; the tool tip 275 mm above the base. All 1000 counts/mm, 20 mm/s,
    /// 200 mm/s²; `seed-b`'s loops (legs as its Z leg, the table as its X and Y), the
    /// legs running the file's LQG design, and CCPM. Home: the workpiece point
    /// (0, 0, 275 mm) under the tool, level.
    pub fn hexapod_xy() -> Self {
        let mm = crate::units::NM_PER_MM;
        let deg = crate::units::NDEG_PER_DEG;
        let KinematicsConfig::Hexapod(legs) = Self::hexapod().kinematics else {
            unreachable!("the built-in hexapod")
        };
        // The legs' scales count 10 nm, the table's 1 µm (the machine file says why).
        let joint = |channel: u8, min: i64, max: i64, per_mm: u32| JointConfig {
            drive: Drive::Servo { channel },
            scale: Scale::new(per_mm, mm as u64),
            rotary: false,
            min,
            max,
            limits: Limits {
                max_velocity: 20 * mm,
                max_accel: 200 * mm,
            },
            homing: Homing::NONE,
        };
        let mut joints = heapless::Vec::new();
        for c in 0..6u8 {
            let _ = joints.push(joint(c, 280 * mm, 420 * mm, 100_000));
        }
        for c in 6..8u8 {
            let _ = joints.push(joint(c, -50 * mm, 50 * mm, 1000));
        }
        let loop_of = |kp: f32, ki: f32, kd: f32, kvff: f32, kaff: f32| ServoGains {
            kp,
            ki,
            kd,
            kvff,
            kaff,
            max_output: 200.0,
            max_integral: 200.0,
            dac_per_unit: 10.0,
            dac_offset: 0,
            ferror: 2000,
            min_ferror: 1000,
        };
        // The legs' LQG design, as the machine file's `lqg_gains` (`contour-study
        // --design-lqg`): the identified L(s) at 100 000 counts/mm, weights position
        // 1e-6, integral 0.004, command 1, load noise 2 c.u., encoder noise 29 counts.
        let leg_lqg = crate::config::LqgGains {
            order: 3,
            phi_minus_i: [
                [-1.8829388e-3, 3.3761698e-3, 5.70642e-6, 0.0e0],
                [-3.376266e-3, -5.7065286e-6, 3.3793426e-3, 0.0e0],
                [-5.696912e-5, -9.6289504e-8, -1.0848189e-10, 0.0e0],
                [0.0e0, 0.0e0, 0.0e0, 0.0e0],
            ],
            gamma: [1.479193e0, 9.372941e-1, 2.6076636e0, 0.0e0],
            c: [1.0e0, 0.0e0, 0.0e0, 0.0e0],
            m: [9.7235724e-2, 6.377594e-2, 1.7082046e-1, 0.0e0],
            k: [1.1118435e-3, 1.6003574e-3, 1.0232325e-3, 0.0e0],
            ki_t: 6.3061966e-6,
        };
        let leg = ServoGains {
            ferror: 200_000,
            min_ferror: 100_000,
            ..loop_of(5.0e-4, 6.0e-3, 5.0e-6, 3.8116e-5, 2.1552e-7)
        };
        let mut gains = [ServoGains::NONE; MAX_SERVOS];
        gains[..6].copy_from_slice(&[leg; 6]);
        gains[6] = loop_of(0.1, 1.6, 0.0, 5.4632e-3, -8.6924e-5);
        gains[7] = loop_of(0.075, 1.2, 3.0e-4, 5.8629e-3, -1.2190e-4);
        let axis = |v: i64, a: i64| Limits {
            max_velocity: v,
            max_accel: a,
        };
        let mut name = heapless::String::new();
        let _ = name.push_str("hexapod-xy");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::HexapodXy(HexapodXyGeometry {
                hexapod: legs,
                platform_home: [0, 0, 260 * mm],
                tool_z: 275 * mm,
            }),
            joints,
            axes: [
                axis(20 * mm, 200 * mm),
                axis(20 * mm, 200 * mm),
                axis(10 * mm, 100 * mm),
                axis(20 * deg, 200 * deg),
                axis(20 * deg, 200 * deg),
                axis(0, 0),
            ],
            home: [0, 0, 275 * mm, 0, 0, 0],
            servo: ServoConfig {
                gains,
                // The legs (channels 0..5) run the LQG design, the table its PID.
                law: [1, 1, 1, 1, 1, 1, 0, 0],
                lqg: heapless::Vec::from_slice(&[leg_lqg]).unwrap_or_default(),
                contour: ContourConfig {
                    mode: ContourMode::Ccpm,
                    kp: 5000.0,
                    ki: 10000.0,
                    max_integral: 50.0,
                    kr: 60.0,
                    max_offset: 0.5,
                },
            },
            motion: MotionConfig::TRAPEZOID,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_machine_is_valid() {
        assert_eq!(MachineConfig::cartesian_xyz().validate(), Ok(()));
    }

    #[test]
    fn the_h4_and_hexapod_machines_are_valid() {
        assert_eq!(MachineConfig::h4_table().validate(), Ok(()));
        assert_eq!(MachineConfig::hexapod().validate(), Ok(()));
        assert_eq!(MachineConfig::hexapod_xy().validate(), Ok(()));
    }

    #[test]
    fn the_h4_and_hexapod_machines_fit_the_configuration_store() {
        let mut buf = [0u8; crate::wire::store::MAX_CONFIG_BYTES];
        for m in [
            MachineConfig::h4_table(),
            MachineConfig::hexapod(),
            MachineConfig::hexapod_xy(),
        ] {
            let n = crate::wire::store::encode(&m, &mut buf).expect("fits");
            let back: MachineConfig = postcard::from_bytes(&buf[..n]).unwrap();
            assert_eq!(back, m);
        }
    }
}
