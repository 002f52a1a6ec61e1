//! The drives: what turns a tick's joint targets into motion of the joints and keeps
//! them there — step trains ([`stepper`]), the 10 kHz servo loops ([`servo`], with
//! [`lqg`] controllers), contour control across the servo channels ([`contour`]),
//! homing ([`homing`]) and the switch filters ([`debounce`]).

pub mod contour;
pub mod debounce;
pub mod homing;
pub mod lqg;
pub mod servo;
pub mod stepper;
