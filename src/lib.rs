//! # pkmc core
//!
//! The motion-controller core shared by the STM32G474 firmware, the host simulator and
//! the tests: fixed-point units, machine configuration, the wire protocol (postcard +
//! COBS + CRC-32 + sequence numbers), the block queue, per-block trapezoidal profiles,
//! the fixed-period interpolator, kinematics, step scheduling, the [`Controller`]
//! state machine, and the pacing of the servo loops and the tick with the switch
//! debouncing ([`pacing`], [`debounce`]) that the firmware and the simulator share.
//!
//! Invariants: `no_std`, no allocator, no HAL types, no globals, no `async`. Every
//! part is a synchronous `&mut self` state machine advanced by explicit calls, so the
//! same code runs bit for bit on the MCU, in the simulator and under `cargo test`.
//!
//! [`Controller`]: controller::Controller
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

pub mod cobs;
pub mod config;
pub mod contour;
pub mod controller;
pub mod crc;
pub mod debounce;
pub mod geometry;
pub mod homing;
pub mod interp;
pub mod kinematics;
pub mod lqg;
pub mod math;
pub mod pacing;
pub mod place;
pub mod planner;
pub mod profile;
pub mod protocol;
pub mod ring;
pub mod servo;
pub mod stepper;
pub mod store;
pub mod units;
pub mod wording;
