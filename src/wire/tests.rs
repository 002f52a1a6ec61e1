//! The wire's tests: round trips, the hand-written writer and decoder against
//! postcard, the frame reader.

use super::decode::*;
use super::frame::*;
use super::messages::*;
use super::reader::*;
use crate::config::{AXES, MAX_JOINTS};
use crate::motion::block::*;

fn sample_block() -> HostMsg {
    HostMsg::Block(PlannedBlock {
        block: Block {
            line: 12,
            motion: Motion::Arc {
                center: [i64::MIN, i64::MAX],
                plane: Plane::Zx,
                clockwise: true,
                turns: u16::MAX,
            },
            target: [10_000_000, -5, i64::MAX, i64::MIN, 0, 1],
            feed: 16_666_666,
            tolerance_nm: u32::MAX,
        },
        // Every field at its widest: the largest block message there is.
        plan: Plan {
            length: i64::MIN,
            shape: Shape::Arc {
                // Not sent (the block has them): they decode as the defaults.
                plane: Plane::Xy,
                center: [0, 0],
                r0: i64::MIN,
                dr: i64::MIN,
                phi0: u64::MAX,
                phi_rate: i128::MIN,
                r_rate: i64::MIN,
                unit: [i64::MIN; AXES],
            },
            v_limit: f32::MAX,
            accel: f32::MIN,
            entry: f32::INFINITY,
            stop: true,
        },
    })
}

/// What [`FrameReader`] then [`decode_body`] make of `stream`: per frame, its
/// sequence number and message bytes, or `None` when refused.
fn read_two_pass(stream: &[u8]) -> Vec<Option<(u16, Vec<u8>)>> {
    let mut reader = FrameReader::new();
    let mut out = Vec::new();
    for &b in stream {
        match reader.push(b) {
            Pushed::Pending => {}
            Pushed::Overlong => out.push(None),
            Pushed::Frame(f) => {
                let mut body = [0u8; MAX_BODY];
                out.push(decode_body(f, &mut body).ok().map(|(s, m)| (s, m.to_vec())));
            }
        }
    }
    out
}

/// What [`FrameDecoder`] makes of `stream` fed in pieces of `chunk` bytes.
fn read_one_pass(stream: &[u8], chunk: usize) -> Vec<Option<(u16, Vec<u8>)>> {
    let mut dec = FrameDecoder::new();
    let mut out = Vec::new();
    for piece in stream.chunks(chunk.max(1)) {
        let mut rest = piece;
        while !rest.is_empty() {
            let (n, frame) = dec.feed(rest);
            rest = &rest[n..];
            if let Some(f) = frame {
                out.push(f.ok().map(|(s, m)| (s, m.to_vec())));
            }
        }
    }
    out
}

/// A frame of `message` bytes with sequence number `seq`, delimiter included.
fn raw_frame(seq: u16, message: &[u8]) -> Vec<u8> {
    let mut body = seq.to_le_bytes().to_vec();
    body.extend_from_slice(message);
    body.extend_from_slice(&crate::wire::crc::crc32(&body).to_le_bytes());
    body.iter_mut().for_each(|b| *b ^= WHITEN);
    let mut enc = vec![0u8; crate::wire::cobs::max_encoded_len(body.len())];
    let n = crate::wire::cobs::encode(&body, &mut enc).unwrap();
    enc.truncate(n);
    enc.push(0);
    enc
}

#[test]
fn the_one_pass_decoder_agrees_with_the_reader_on_streams_of_damaged_frames() {
    let mut x = 0x9E37_79B9u32;
    let mut rnd = move |n: u32| {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x % n
    };
    let (mut frames, mut refused) = (0, 0);
    for _ in 0..400 {
        let mut stream = Vec::new();
        for _ in 0..rnd(12) + 1 {
            let len = match rnd(8) {
                0 => rnd(4) as usize,
                1 => MAX_BODY - 6 + rnd(5) as usize, // at and past the limit
                2 => 250 + rnd(10) as usize,         // around a 254-byte COBS block
                _ => rnd(200) as usize,
            };
            // One byte in `every` is a zero (none with 0: runs of 254 and more).
            let every = [0, 2, 4, 40][rnd(4) as usize];
            let message: Vec<u8> = (0..len)
                .map(|_| {
                    if every > 0 && rnd(every) == 0 {
                        0
                    } else {
                        rnd(255) as u8 + 1
                    }
                })
                .collect();
            let mut f = raw_frame(rnd(65536) as u16, &message);
            match rnd(10) {
                0 => {
                    let i = rnd(f.len() as u32) as usize;
                    f[i] ^= 1 << rnd(8); // may become or stop being a delimiter
                }
                1 => f.truncate(rnd(f.len() as u32) as usize), // runs into the next
                2 => f.insert(0, 0),                           // an empty frame
                3 => f = (0..rnd(500)).map(|_| rnd(255) as u8 + 1).collect(), // garbage
                4 => f.splice(0..0, vec![0xFF; 300]).for_each(drop), // overlong
                _ => {}
            }
            stream.extend(f);
        }
        let want = read_two_pass(&stream);
        frames += want.iter().filter(|f| f.is_some()).count();
        refused += want.iter().filter(|f| f.is_none()).count();
        for chunk in [1, 7, 64, stream.len()] {
            assert_eq!(read_one_pass(&stream, chunk), want, "stream {stream:02x?}");
        }
    }
    assert!(
        frames > 1000 && refused > 500,
        "{frames} good, {refused} refused"
    );
}

/// `decode_block`, then `HostMsgOf<NotBlock>` for what is not a block, against
/// `postcard::from_bytes::<HostMsg>` on `message`.
fn check_block_decoder(message: &[u8]) -> bool {
    let by_serde = postcard::from_bytes::<HostMsg>(message);
    match (decode_block(message), by_serde) {
        (None, Ok(HostMsg::Block(_))) => panic!("a block missed: {message:02x?}"),
        (None, want) => {
            let got = postcard::from_bytes::<HostMsgOf<NotBlock>>(message);
            let (mut a, mut b) = ([0u8; MAX_BODY], [0u8; MAX_BODY]);
            match (got, want) {
                (Ok(got), Ok(want)) => assert_eq!(
                    postcard::to_slice(&got, &mut a).unwrap(),
                    postcard::to_slice(&want, &mut b).unwrap(),
                    "{message:02x?}"
                ),
                (Err(_), Err(_)) => {}
                (got, want) => panic!("{message:02x?}: decoded {got:?}, postcard {want:?}"),
            }
            false
        }
        (Some(Err(_)), Err(_)) => false,
        (Some(Ok(got)), Ok(HostMsg::Block(want))) => {
            // Compared through their encoding: the same bits (NaNs included).
            let (mut a, mut b) = ([0u8; MAX_BODY], [0u8; MAX_BODY]);
            assert_eq!(
                postcard::to_slice(&got, &mut a).unwrap(),
                postcard::to_slice(&want, &mut b).unwrap(),
                "{message:02x?}"
            );
            true
        }
        (got, want) => panic!("{message:02x?}: decoded {got:?}, postcard {want:?}"),
    }
}

/// A block message whose fields are `w`'s random values, its motion and shape chosen
/// by `k`.
fn random_block(k: usize, w: &mut dyn FnMut() -> i64) -> HostMsg {
    let motion = match k % 9 {
        0 => Motion::Rapid,
        1 => Motion::Dwell(w() as u32),
        2 => Motion::Aux(Aux::Pause(k & 1 == 0)),
        3 => Motion::Aux(Aux::SpindleCcw(w() as u32)),
        4 | 5 => Motion::Arc {
            center: [w(), w()],
            plane: [Plane::Xy, Plane::Zx, Plane::Yz][k % 3],
            clockwise: k % 2 == 1,
            turns: w() as u16,
        },
        6 => Motion::Cubic {
            c1: [w(), w(), w(), w(), w(), w()],
            c2: [w(), w(), w(), w(), w(), w()],
        },
        7 if k & 1 == 0 => Motion::Quadratic {
            c: [w(), w(), w(), w(), w(), w()],
        },
        _ => Motion::Linear,
    };
    let shape = match k % 7 {
        5 => Shape::Spline {
            rate: w() as u64,
            dip: k.is_multiple_of(3).then(|| Dip {
                at: w() as u8,
                speed: w() as u16,
                after: w() as u16,
            }),
        },
        0 => Shape::Point,
        1 | 2 => Shape::Arc {
            plane: [Plane::Xy, Plane::Zx, Plane::Yz][k % 3],
            center: [w(), w()],
            r0: w(),
            dr: w(),
            phi0: w() as u64,
            phi_rate: ((w() as i128) << 64) ^ w() as i128,
            r_rate: w(),
            unit: [w(), w(), w(), w(), w(), w()],
        },
        _ => Shape::Line {
            unit: [w(), w(), w(), w(), w(), w()],
        },
    };
    HostMsg::Block(PlannedBlock {
        block: Block {
            line: w() as u32,
            motion,
            target: [w(), w(), w(), w(), w(), w()],
            feed: w(),
            tolerance_nm: w() as u32,
        },
        plan: Plan {
            length: w(),
            shape,
            v_limit: f32::from_bits(w() as u32),
            accel: w() as f32,
            entry: 1.5,
            stop: k & 1 == 0,
        },
    })
}

#[test]
fn blocks_decode_by_hand_exactly_as_postcard_decodes_them() {
    let mut x = 0x2545_F491u32;
    let mut rnd = move |n: u32| {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x % n
    };
    let wide = |r: &mut dyn FnMut(u32) -> u32| -> i64 {
        let v = ((r(1 << 16) as i64) << 48) ^ ((r(1 << 24) as i64) << 24) ^ r(1 << 24) as i64;
        v >> r(64)
    };
    let mut decoded = 0;
    for k in 0..3000 {
        let mut w = || wide(&mut rnd);
        let msg = random_block(k, &mut w);
        let mut buf = [0u8; MAX_BODY];
        let n = postcard::to_slice(&msg, &mut buf).unwrap().len();
        let good = &buf[..n];
        assert!(check_block_decoder(good));
        // Cut short anywhere, with trailing bytes, and damaged.
        for cut in 0..n {
            check_block_decoder(&good[..cut]);
        }
        let mut longer = good.to_vec();
        longer.extend([0xFF, 0x00]);
        assert!(check_block_decoder(&longer));
        for _ in 0..40 {
            let mut bad = good.to_vec();
            for _ in 0..rnd(3) + 1 {
                let i = rnd(n as u32) as usize;
                match rnd(6) {
                    0 => bad[i] = 0xFF,
                    1 => bad[i] = 0x80,
                    2 => bad.insert(i, 0x80), // a longer (non-canonical) varint
                    3 => bad[i] = rnd(4) as u8,
                    _ => bad[i] ^= 1 << rnd(8),
                }
            }
            decoded += check_block_decoder(&bad) as u32;
        }
    }
    // Every value of every byte of the widest block there is (varints at their
    // longest, where postcard checks the last byte's bits).
    let mut buf = [0u8; MAX_BODY];
    let good = postcard::to_slice(&sample_block(), &mut buf)
        .unwrap()
        .to_vec();
    for i in 0..good.len() {
        for v in 0..=255 {
            let mut m = good.clone();
            m[i] = v;
            check_block_decoder(&m);
        }
    }
    // Other messages are left to postcard, as `HostMsgOf<NotBlock>`.
    for m in [
        HostMsg::StatusRequest,
        HostMsg::Control {
            id: 2,
            cmd: Control::FeedOverride(7),
        },
        HostMsg::Control {
            id: 4,
            cmd: match sample_block() {
                HostMsg::Block(b) => Control::Jog(b),
                _ => unreachable!(),
            },
        },
        HostMsg::Hello {
            version: PROTOCOL_VERSION,
            machine: 0xDEAD_BEEF,
            host: 1,
        },
        HostMsg::Machine {
            id: 3,
            offset: 64,
            total: 300,
            crc: 9,
            data: heapless::Vec::from_slice(&[1, 0, 2]).unwrap(),
        },
    ] {
        let mut buf = [0u8; MAX_BODY];
        let good = postcard::to_slice(&m, &mut buf).unwrap().to_vec();
        assert!(decode_block(&good).is_none());
        let got: HostMsgOf<NotBlock> = postcard::from_bytes(&good).unwrap();
        assert_eq!(format!("{got:?}"), format!("{m:?}"));
        for i in 0..good.len() {
            for v in 0..=255 {
                let mut m = good.clone();
                m[i] = v;
                check_block_decoder(&m);
            }
        }
    }
    assert!(decoded > 10_000, "{decoded} damaged messages still decoded");
}

#[test]
fn acks_and_statuses_encode_by_hand_exactly_as_postcard_encodes_them() {
    let mut x = 0x1357_9BDFu32;
    let mut rnd = move |n: u32| {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x % n
    };
    let mut wide = || {
        let v = ((rnd(1 << 16) as i64) << 48) ^ ((rnd(1 << 24) as i64) << 24) ^ rnd(1 << 24) as i64;
        v >> rnd(64)
    };
    let (mut body, mut want, mut got) = ([0u8; MAX_BODY], [0u8; MAX_FRAME], [0u8; MAX_FRAME]);
    let causes = [
        AlarmCause::Unreachable,
        AlarmCause::JointLimit,
        AlarmCause::LinkLoss,
        AlarmCause::HomingFailed,
        AlarmCause::JointSpeed,
    ];
    let states = [State::Idle, State::Running, State::Hold, State::EStop];
    for k in 0..5000usize {
        let seq = wide() as u16;
        let (acked, free, bends, ms) = (wide() as u16, wide() as u16, wide() as u16, wide() as u32);
        let msg = CtrlMsg::Ack {
            seq: acked,
            free_slots: free,
            free_bends: bends,
            buffered_ms: ms,
        };
        let n = encode_frame(seq, &msg, &mut want).unwrap();
        assert_eq!(
            n,
            encode_ack(seq, acked, free, bends, ms, &mut body, &mut got)
        );
        assert_eq!(want[..n], got[..n], "{msg:?}");
        let s = Status {
            state: states[k % 4],
            line: wide() as u32,
            blocks_done: wide() as u32,
            motion_ticks: wide() as u64,
            pose: core::array::from_fn(|_| wide()),
            joints: core::array::from_fn(|_| wide()),
            measured: core::array::from_fn(|_| wide()),
            speed: wide(),
            buffered_ms: wide() as u32,
            free_slots: wide() as u16,
            free_bends: wide() as u16,
            feed_override: wide() as u16,
            alarm: (k % 3 != 0).then(|| Alarm {
                cause: causes[k % 4],
                joint: wide() as u8,
                line: wide() as u32,
            }),
            homed: k & 1 == 0,
            probe_input: k & 2 == 0,
            probes: wide() as u16,
            orphan: k % 5 == 0,
        };
        let msg = CtrlMsg::Status(s.clone());
        let n = encode_frame(seq, &msg, &mut want).unwrap();
        assert_eq!(n, encode_status(seq, &s, &mut body, &mut got));
        assert_eq!(want[..n], got[..n], "{msg:?}");
    }
}

#[test]
fn recorder_pieces_encode_by_hand_exactly_as_postcard_encodes_them() {
    let (mut want, mut got) = ([0u8; MAX_FRAME], [0u8; MAX_FRAME]);
    let mut body = [0x5au8; MAX_BODY];
    for len in 0..=crate::wire::store::CHUNK_BYTES {
        let bytes: heapless::Vec<u8, { crate::wire::store::CHUNK_BYTES }> =
            (0..len).map(|i| (i * 37 + len) as u8).collect();
        let seq = (len * 613) as u16;
        let n = encode_frame(seq, &CtrlMsg::Record(bytes.clone()), &mut want).unwrap();
        let fill = |out: &mut [u8]| out.copy_from_slice(&bytes);
        assert_eq!(Some(n), encode_record(seq, len, fill, &mut body, &mut got));
        assert_eq!(want[..n], got[..n], "{len} bytes");
    }
    let beyond = crate::wire::store::CHUNK_BYTES + 1;
    assert_eq!(None, encode_record(0, beyond, |_| {}, &mut body, &mut got));
}

#[test]
fn a_sealed_frame_is_the_cobs_encoding_of_its_body_and_crc() {
    let mut x = 0x0BAD_F00Du32;
    let mut rnd = move |n: u32| {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x % n
    };
    for len in 0..=MAX_BODY - 4 {
        for every in [0, 2, 40] {
            // One byte in `every` is a zero once flipped (none with 0: runs of 254
            // and more).
            let data: Vec<u8> = (0..len)
                .map(|_| {
                    if every > 0 && rnd(every) == 0 {
                        WHITEN
                    } else {
                        (rnd(255) as u8 + 1) ^ WHITEN
                    }
                })
                .collect();
            let mut framed = data.clone();
            framed.extend_from_slice(&crate::wire::crc::crc32(&data).to_le_bytes());
            framed.iter_mut().for_each(|b| *b ^= WHITEN);
            let mut want = vec![0u8; crate::wire::cobs::max_encoded_len(framed.len())];
            let m = crate::wire::cobs::encode(&framed, &mut want).unwrap();
            let (mut body, mut out) = ([0u8; MAX_BODY], [0u8; MAX_FRAME]);
            body[..len].copy_from_slice(&data);
            let n = seal(&mut body, 0, len, &mut out);
            assert_eq!(out[..n - 1], want[..m], "{len} bytes");
            assert_eq!(out[n - 1], 0);
        }
    }
}

#[test]
fn a_frame_round_trips_through_the_reader() {
    let mut frame = [0u8; MAX_FRAME];
    let n = encode_frame(7, &sample_block(), &mut frame).unwrap();
    assert_eq!(frame[n - 1], 0);
    let mut reader = FrameReader::new();
    let mut got = None;
    for &b in &frame[..n] {
        if let Pushed::Frame(f) = reader.push(b) {
            let mut body = [0u8; MAX_BODY];
            got = Some(decode_frame::<HostMsg>(f, &mut body).unwrap());
        }
    }
    assert_eq!(got, Some((7, sample_block())));
}

#[test]
fn the_largest_status_fits_in_a_frame() {
    let s = CtrlMsg::Status(Status {
        state: State::Running,
        line: u32::MAX,
        blocks_done: u32::MAX,
        motion_ticks: u64::MAX,
        pose: [i64::MIN; AXES],
        joints: [i64::MIN; MAX_JOINTS],
        measured: [i64::MIN; MAX_JOINTS],
        speed: i64::MIN,
        buffered_ms: u32::MAX,
        free_slots: u16::MAX,
        free_bends: u16::MAX,
        feed_override: u16::MAX,
        alarm: Some(Alarm {
            cause: AlarmCause::FollowingError,
            joint: 255,
            line: u32::MAX,
        }),
        homed: true,
        orphan: true,
        probe_input: true,
        probes: u16::MAX,
    });
    let mut frame = [0u8; MAX_FRAME];
    assert!(encode_frame(u16::MAX, &s, &mut frame).is_ok());
}

#[test]
fn every_single_bit_flip_is_detected() {
    let mut frame = [0u8; MAX_FRAME];
    let n = encode_frame(3, &sample_block(), &mut frame).unwrap();
    for i in 0..n - 1 {
        for bit in 0..8 {
            let mut f = frame;
            f[i] ^= 1 << bit;
            if f[i] == 0 {
                continue; // becomes a delimiter: the reader splits the frame instead
            }
            let mut body = [0u8; MAX_BODY];
            assert!(
                decode_frame::<HostMsg>(&f[..n - 1], &mut body).is_err(),
                "flip of byte {i} bit {bit} went unnoticed"
            );
        }
    }
}

/// `decode_planned_control_into` against `postcard::from_bytes::<HostMsg>`: the same
/// id, command and move for a jog or a probing move, `None` for any other message,
/// an error exactly where postcard fails.
fn check_planned_control_decoder(message: &[u8]) -> bool {
    let mut slot = core::mem::MaybeUninit::uninit();
    let got = decode_planned_control_into(message, &mut slot);
    let want = postcard::from_bytes::<HostMsg>(message);
    let (mut a, mut b) = ([0u8; MAX_BODY], [0u8; MAX_BODY]);
    match (got, want) {
        (Some(Ok((id, what, got))), Ok(HostMsg::Control { id: want_id, cmd })) => {
            let want = match (what, cmd) {
                (PlannedControl::Jog, Control::Jog(p)) => p,
                (PlannedControl::Probe(m), Control::Probe { planned, mode }) if m == mode => {
                    planned
                }
                (what, cmd) => panic!("{message:02x?}: decoded {what:?}, postcard {cmd:?}"),
            };
            assert_eq!(id, want_id);
            assert_eq!(
                postcard::to_slice(got, &mut a).unwrap(),
                postcard::to_slice(&want, &mut b).unwrap(),
                "{message:02x?}"
            );
            true
        }
        (Some(Err(_)), Err(_)) => false,
        (None, Ok(HostMsg::Control { cmd, .. })) => {
            assert!(
                !matches!(cmd, Control::Jog(_) | Control::Probe { .. }),
                "missed: {message:02x?}"
            );
            false
        }
        (None, _) => false,
        (got, want) => panic!("{message:02x?}: decoded {got:?}, postcard {want:?}"),
    }
}

#[test]
fn jogs_and_probing_moves_decode_by_hand_exactly_as_postcard_decodes_them() {
    use crate::drive::probe::ProbeMode;
    let mut x = 0x1234_5677u32;
    let mut rnd = move |n: u32| {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        x % n
    };
    let mut decoded = 0;
    for k in 0..1500 {
        let mut w = || ((rnd(1 << 24) as i64) << 20) >> rnd(40);
        let HostMsg::Block(planned) = random_block(k, &mut w) else {
            unreachable!()
        };
        let cmd = match k % 3 {
            0 => Control::Jog(planned),
            1 => Control::Probe {
                planned,
                mode: ProbeMode::Touch,
            },
            _ => Control::Probe {
                planned,
                mode: ProbeMode::Release,
            },
        };
        let msg = HostMsg::Control {
            id: rnd(1 << 16) as u16,
            cmd,
        };
        let mut buf = [0u8; MAX_BODY];
        let good = postcard::to_slice(&msg, &mut buf).unwrap().to_vec();
        assert!(check_planned_control_decoder(&good));
        for cut in 0..good.len() {
            check_planned_control_decoder(&good[..cut]);
        }
        for _ in 0..20 {
            let mut bad = good.clone();
            let i = rnd(good.len() as u32) as usize;
            bad[i] ^= 1 << rnd(8);
            decoded += check_planned_control_decoder(&bad) as u32;
        }
    }
    assert!(decoded > 1000, "{decoded}");
    // Other controls are not taken.
    for cmd in [Control::Hold, Control::FeedOverride(50), Control::EndJob] {
        let mut buf = [0u8; MAX_BODY];
        let m = postcard::to_slice(&HostMsg::Control { id: 3, cmd }, &mut buf).unwrap();
        assert!(!check_planned_control_decoder(m));
    }
}
