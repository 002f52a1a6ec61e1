//! Message decoder: postcard `HostMsg` and `CtrlMsg` from raw bytes must never panic,
//! and a message that decodes must re-encode and decode to itself.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pkmc::wire::{CtrlMsg, HostMsg};

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = postcard::from_bytes::<HostMsg>(data) {
        let bytes = postcard::to_allocvec(&m).expect("encodes");
        assert_eq!(
            postcard::from_bytes::<HostMsg>(&bytes).expect("re-decodes"),
            m
        );
    }
    if let Ok(m) = postcard::from_bytes::<CtrlMsg>(data) {
        let bytes = postcard::to_allocvec(&m).expect("encodes");
        assert_eq!(
            postcard::from_bytes::<CtrlMsg>(&bytes).expect("re-decodes"),
            m
        );
    }
});
