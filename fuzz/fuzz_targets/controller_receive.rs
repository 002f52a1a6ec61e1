//! The controller's receive path: it must never panic, whatever arrives.
//!
//! The input is a little program of operations so that the fuzzer reaches past the CRC:
//! after a valid `Hello`, each operation byte selects
//! * raw bytes straight into `receive` (garbage, partial frames, stray delimiters),
//! * a postcard `HostMsg` decoded from the following bytes, framed correctly with the
//!   next sequence number (blocks, controls and status requests with any values), or
//! * a run of interpolation ticks, draining the transmit buffer as the firmware does,
//!   or
//! * new safety inputs for the ticks (e-stop, limit, home and drive-fault lines).
#![no_main]

use libfuzzer_sys::fuzz_target;
use pkmc::config::MachineConfig;
use pkmc::controller::{Controller, Inputs, TX_CAPACITY};
use pkmc::wire::{encode_frame, HostMsg, MAX_FRAME, PROTOCOL_VERSION};

fn framed(seq: u16, msg: &HostMsg) -> Option<Vec<u8>> {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(seq, msg, &mut f).ok()?;
    Some(f[..n].to_vec())
}

fuzz_target!(|data: &[u8]| {
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).expect("built-in machine");
    // Unlocked, so that blocks move (a locked controller drops them).
    c.unlock();
    let mut inputs = Inputs::default();
    let hello = HostMsg::Hello {
        version: PROTOCOL_VERSION,
        machine: c.machine_id(),
        host: 1,
    };
    c.receive(&framed(0, &hello).expect("hello frames"));
    let mut seq: u16 = 1;
    let mut out = [0u8; TX_CAPACITY];
    let mut rest = data;
    while let Some((&op, tail)) = rest.split_first() {
        let len = tail
            .first()
            .map_or(0, |&l| l as usize)
            .min(tail.len().saturating_sub(1));
        let chunk = if tail.is_empty() {
            tail
        } else {
            &tail[1..1 + len]
        };
        rest = if tail.is_empty() {
            tail
        } else {
            &tail[1 + len..]
        };
        match op % 5 {
            0 => c.receive(chunk),
            1 => {
                if let Ok(msg) = postcard::from_bytes::<HostMsg>(chunk) {
                    if let Some(f) = framed(seq, &msg) {
                        c.receive(&f);
                        if matches!(msg, HostMsg::Block(_)) {
                            seq = seq.wrapping_add(1);
                        }
                    }
                }
            }
            2 => {
                for _ in 0..(len as u32 + 1) * 8 {
                    c.tick(&inputs);
                }
            }
            3 => {
                // Safety inputs from the chunk: e-stop, limit, home and drive-fault bits.
                let b = |i: usize| chunk.get(i).copied().unwrap_or(0);
                inputs.estop = b(0) & 1 != 0;
                inputs.limit = u16::from(b(1)) & 0b111;
                inputs.home = u16::from(b(2)) & 0b111;
                inputs.drive_fault = u16::from(b(3)) & 0b111;
            }
            _ => {
                let _ = c.transmit(&mut out);
            }
        }
        let _ = c.transmit(&mut out);
    }
    // Let whatever was queued run out (bounded).
    for _ in 0..20_000 {
        if !c.has_work() {
            break;
        }
        c.tick(&inputs);
        let _ = c.transmit(&mut out);
    }
});
