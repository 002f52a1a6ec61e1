//! Frame decoder: arbitrary bytes through `FrameReader` and `decode_frame` must never
//! panic, and every frame that decodes must re-encode to a frame that decodes to the
//! same sequence number and message.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pkmc::wire::{decode_frame, encode_frame, CtrlMsg, FrameReader, HostMsg, Pushed, MAX_BODY, MAX_FRAME};

fn round_trip<M>(seq: u16, msg: &M)
where
    M: serde::Serialize + for<'de> serde::Deserialize<'de> + PartialEq + core::fmt::Debug,
{
    let mut frame = [0u8; MAX_FRAME];
    let n = encode_frame(seq, msg, &mut frame).expect("a decoded message fits in a frame");
    assert_eq!(frame[n - 1], 0, "a frame ends with its delimiter");
    assert!(
        !frame[..n - 1].contains(&0),
        "COBS leaves no zero inside a frame"
    );
    let mut body = [0u8; MAX_BODY];
    let (seq2, msg2) = decode_frame::<M>(&frame[..n - 1], &mut body).expect("re-decodes");
    assert_eq!(seq2, seq);
    assert_eq!(&msg2, msg);
}

fuzz_target!(|data: &[u8]| {
    let mut reader = FrameReader::new();
    for &b in data {
        if let Pushed::Frame(f) = reader.push(b) {
            let f = f.to_vec();
            let mut body = [0u8; MAX_BODY];
            if let Ok((seq, msg)) = decode_frame::<HostMsg>(&f, &mut body) {
                round_trip(seq, &msg);
            }
            let mut body = [0u8; MAX_BODY];
            if let Ok((seq, msg)) = decode_frame::<CtrlMsg>(&f, &mut body) {
                round_trip(seq, &msg);
            }
        }
    }
});
