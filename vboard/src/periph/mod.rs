//! Models of the STM32G474's peripherals, written from RM0440 (rev 8), each behaviour
//! citing its section. A register a model does not know is an [`Unmodelled`] access,
//! which stops the board.

pub mod clocks;
pub mod dac;
pub mod flash;
pub mod gpio;
pub mod hrtim;
pub mod iwdg;
pub mod lptim;
pub mod plain;
pub mod timer;
pub mod usb;

/// An access the model does not implement.
#[derive(Debug)]
pub struct Unmodelled;
