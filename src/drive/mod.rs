//! The drives: what turns a tick's joint targets into motion of the joints and keeps
//! them there — step trains ([`stepper`]), the 10 kHz servo loops ([`servo`], with
//! [`lqg`] controllers), contour control across the servo channels ([`contour`]),
//! homing ([`homing`]), the switch filters ([`debounce`]), the touch probe's latch
//! ([`probe`]), the data recorder ([`recorder`]) and the tuning test signal
//! ([`excite`]).

pub mod contour;
pub mod debounce;
pub mod excite;
pub mod homing;
pub mod lqg;
pub mod probe;
pub mod recorder;
pub mod servo;
pub mod stepper;
