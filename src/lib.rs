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

// The rooms, from the bottom: each imports only rooms above it in this list
// (`.ci/structure.py` checks it; docs/architecture.md draws it).
pub mod config;
pub mod controller;
pub mod drive;
pub mod kinematics;
pub mod math;
pub mod motion;
pub mod place;
pub mod units;
pub mod wire;
pub mod wording;
