//! The recorder's refusals, worded (`drive::recorder::RecorderError`).

use core::fmt;

impl fmt::Display for crate::drive::recorder::RecorderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use crate::drive::recorder::{RecorderError as E, MAX_SIGNALS};
        match *self {
            E::BadSignal { index, id } => {
                write!(
                    f,
                    "signal {} of the request: id {id:#04x} names no signal",
                    index + 1
                )
            }
            E::SignalCount { count } => {
                write!(
                    f,
                    "{count} signals asked for: a capture holds 1 to {MAX_SIGNALS}"
                )
            }
            E::Decimation => f.write_str("a decimation of 0: at least 1"),
            E::TriggerSignal { index } => write!(
                f,
                "the level trigger names signal {}, beyond the request's signals",
                index + 1
            ),
            E::PreTrigger { pre, capacity } => write!(
                f,
                "{pre} pre-trigger samples asked for: the ring holds {capacity} samples of \
                 these signals, so at most {} before the trigger",
                capacity.saturating_sub(1)
            ),
            E::Malformed { at: 255 } => f.write_str("a recorder request of an unknown kind"),
            E::Malformed { at } => write!(f, "the recorder request is malformed at byte {at}"),
            E::ExciteBusy => f.write_str(
                "a test signal needs a homed machine standing idle, with no job and \
                 nothing queued (a machine without home switches: unlocked)",
            ),
            E::ExciteJoint { joint } => write!(
                f,
                "joint {joint} is not driven by a servo channel: only servo joints take \
                 a test signal"
            ),
            E::ExciteAmplitude { joint, limit } => write!(
                f,
                "the test signal's amplitude must be below joint {joint}'s standstill \
                 following-error limit of {limit} counts"
            ),
            E::ExciteTravel { joint } => write!(
                f,
                "the test signal would take joint {joint} outside its travel"
            ),
        }
    }
}
