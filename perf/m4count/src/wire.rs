//! The controller's tick inputs and outputs as flat `i64` words: the form in which the
//! host logs them and the emulator passes and compares them. Every field is named
//! (no `..`): a field added to [`Inputs`] or [`Outputs`] stops this from compiling
//! until the harness carries it. The word counts follow the core's capacities
//! ([`MAX_SERVOS`], [`MAX_STEPPERS`]); `.ci/m4count.py` reads them from the host run
//! (the `wire` line) and checks them against the image's ([`crate::bench_wire_words`]).

use pkmc::config::{MAX_SERVOS, MAX_STEPPERS};
use pkmc::controller::{Inputs, Outputs};
use pkmc::drive::recorder::MAX_SIGNALS;
use pkmc::drive::servo::Trip;
use pkmc::drive::stepper::StepTrain;
use pkmc::kinematics::{ContourMap, POSE_AXES};

/// Words of one [`Inputs`]: encoder counts, index (flag, count) per servo channel,
/// e-stop, limit, home and drive-fault bits, trip (code, error, limit) per channel,
/// the probe (debounced, raw, edge time or -1), then each channel's mean DAC code and
/// the contour error (the data recorder's).
pub const INPUT_WORDS: usize =
    MAX_SERVOS + 2 * MAX_SERVOS + 4 + 3 * MAX_SERVOS + 3 + MAX_SERVOS + POSE_AXES;
/// Words of one [`ContourMap`]: its `f32` entries' bits, `to_pose` row by row, then
/// `to_joint` row by row.
pub const MAP_WORDS: usize = 2 * POSE_AXES * MAX_SERVOS;
/// Words of one [`Outputs`]: five per step train, the servo targets, three flags, the
/// data recorder's servo-side signals, and the contour map (a presence flag, then
/// [`MAP_WORDS`], zero when absent).
pub const OUTPUT_WORDS: usize = 5 * MAX_STEPPERS + MAX_SERVOS + 3 + 2 * MAX_SIGNALS + 1 + MAP_WORDS;

/// `inputs` as words.
pub fn inputs_words(inputs: &Inputs) -> [i64; INPUT_WORDS] {
    let Inputs {
        encoder_counts,
        index,
        estop,
        limit,
        home,
        drive_fault,
        servo_trip,
        probe,
        probe_raw,
        probe_edge_us,
        servo_dac,
        contour,
    } = *inputs;
    let mut w = [0; INPUT_WORDS];
    let mut k = 0;
    let mut put = |v: i64| {
        w[k] = v;
        k += 1;
    };
    for c in encoder_counts {
        put(c);
    }
    for i in index {
        put(i.is_some() as i64);
        put(i.unwrap_or(0));
    }
    put(estop as i64);
    put(limit as i64);
    put(home as i64);
    put(drive_fault as i64);
    for t in servo_trip {
        let (code, error, limit) = match t {
            None => (0, 0, 0),
            Some(Trip::FollowingError { error, limit }) => (1, error, limit),
            Some(Trip::AmplifierFault) => (2, 0, 0),
            // A kind this harness does not know: no rebuilt input equals it, so the
            // recording's round-trip check fails and names it.
            Some(_) => (-1, 0, 0),
        };
        put(code);
        put(error as i64);
        put(limit as i64);
    }
    put(probe as i64);
    put(probe_raw as i64);
    put(probe_edge_us.map_or(-1, i64::from));
    for d in servo_dac {
        put(i64::from(d));
    }
    for e in contour {
        put(i64::from(e));
    }
    w
}

/// The [`Inputs`] that [`inputs_words`] flattened.
pub fn inputs_from(w: &[i64; INPUT_WORDS]) -> Inputs {
    let s = MAX_SERVOS;
    // The probe's three words, then the recorder's.
    let p = 3 * s + 4 + 3 * s;
    let dac = p + 3;
    let contour = dac + s;
    Inputs {
        encoder_counts: core::array::from_fn(|c| w[c]),
        index: core::array::from_fn(|c| (w[s + 2 * c] != 0).then_some(w[s + 2 * c + 1])),
        estop: w[3 * s] != 0,
        limit: w[3 * s + 1] as u16,
        home: w[3 * s + 2] as u16,
        drive_fault: w[3 * s + 3] as u16,
        servo_trip: core::array::from_fn(|c| {
            let t = 3 * s + 4 + 3 * c;
            match w[t] {
                1 => Some(Trip::FollowingError {
                    error: w[t + 1] as i32,
                    limit: w[t + 2] as i32,
                }),
                2 => Some(Trip::AmplifierFault),
                _ => None,
            }
        }),
        probe: w[p] != 0,
        probe_raw: w[p + 1] != 0,
        probe_edge_us: (w[p + 2] >= 0).then_some(w[p + 2] as u16),
        servo_dac: core::array::from_fn(|c| w[dac + c] as u16),
        contour: core::array::from_fn(|a| w[contour + a] as i32),
    }
}

/// `map`'s entries as words (their bits: the comparison is exact).
fn map_words(map: &ContourMap, w: &mut [i64]) {
    let ContourMap { to_pose, to_joint } = map;
    let entries = to_pose.iter().flatten().chain(to_joint.iter().flatten());
    for (o, v) in w.iter_mut().zip(entries) {
        *o = v.to_bits() as i64;
    }
}

/// `outputs` as words.
pub fn outputs_words(outputs: &Outputs, contour_map: Option<&ContourMap>) -> [i64; OUTPUT_WORDS] {
    let Outputs {
        steps,
        servo_target,
        enable,
        servo_enable,
        servo_reset,
        servo_record,
        servo_record_add,
    } = *outputs;
    let mut w = [0; OUTPUT_WORDS];
    for (c, t) in steps.iter().enumerate() {
        let StepTrain {
            count,
            forward,
            first_edge_ns,
            interval_ns,
            pulse_ns,
        } = *t;
        w[5 * c..5 * c + 5].copy_from_slice(&[
            count as i64,
            forward as i64,
            first_edge_ns as i64,
            interval_ns as i64,
            pulse_ns as i64,
        ]);
    }
    let s = 5 * MAX_STEPPERS;
    w[s..s + MAX_SERVOS].copy_from_slice(&servo_target);
    let f = s + MAX_SERVOS;
    w[f] = enable as i64;
    w[f + 1] = servo_enable as i64;
    w[f + 2] = servo_reset as i64;
    for (o, &id) in w[f + 3..].iter_mut().zip(&servo_record) {
        *o = i64::from(id);
    }
    let a = f + 3 + MAX_SIGNALS;
    for (o, &v) in w[a..].iter_mut().zip(&servo_record_add) {
        *o = i64::from(v);
    }
    let m = a + MAX_SIGNALS;
    if let Some(map) = contour_map {
        w[m] = 1;
        map_words(map, &mut w[m + 1..]);
    }
    w
}
