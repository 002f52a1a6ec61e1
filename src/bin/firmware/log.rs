//! The defmt log, over an RTT up-channel as a debug probe reads it, without a global
//! critical section.
//!
//! A logger that masks every interrupt while it encodes a line holds the 10 kHz servo
//! interrupt off for the whole line: the diagnostics line took over 70 µs on the
//! virtual board, most of a servo period (`docs/vboard.md`). This one raises BASEPRI
//! to the tick's priority instead, as [`crate::shared`]'s lock does: the tick, USB,
//! the time base and thread mode cannot log while a line is being written, and the
//! servo interrupt keeps running. The servo interrupt does not log; should it all the
//! same (a failed assertion's message), while a line is being written, its line is
//! dropped (the frame being written is not corrupted).
//!
//! The channel never blocks: a line that does not fit in the free part of the buffer
//! is cut there, and what is cut is counted ([`dropped`]). The control block is the
//! SEGGER RTT layout a probe (and the virtual board) finds by its symbol,
//! `_SEGGER_RTT`, or by its ID: 16 bytes of ID, the numbers of up and down channels,
//! then the up-channel's descriptor (name, buffer, size, write offset, read offset,
//! flags). The probe advances the read offset.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU32, AtomicU8, AtomicUsize, Ordering};

/// Bytes of the up-channel's buffer: a few dozen of the firmware's lines, which a probe
/// drains far faster than they come.
const BUFFER_BYTES: usize = 512;

/// An RTT up-channel's descriptor.
#[repr(C)]
struct Channel {
    name: *const u8,
    buffer: *mut u8,
    size: usize,
    write: AtomicUsize,
    read: AtomicUsize,
    flags: AtomicU32,
}

/// The RTT control block.
#[repr(C)]
struct Header {
    id: [u8; 16],
    max_up_channels: usize,
    max_down_channels: usize,
    up: Channel,
}

// SAFETY: the raw pointers are to statics that live forever; the buffer is written by
// the one context holding the logger (see `Logger`) and read by the probe.
unsafe impl Sync for Header {}

/// The up-channel's storage.
struct Buffer(UnsafeCell<[u8; BUFFER_BYTES]>);

// SAFETY: written only by the context that holds the logger.
unsafe impl Sync for Buffer {}

static BUFFER: Buffer = Buffer(UnsafeCell::new([0; BUFFER_BYTES]));
static NAME: [u8; 6] = *b"defmt\0";

/// RTT's "no blocking, trim what does not fit" mode, in the channel's flags.
const MODE_NON_BLOCKING_TRIM: u32 = 1;

#[no_mangle]
static _SEGGER_RTT: Header = Header {
    id: *b"SEGGER RTT\0\0\0\0\0\0",
    max_up_channels: 1,
    max_down_channels: 0,
    up: Channel {
        name: NAME.as_ptr(),
        buffer: BUFFER.0.get() as *mut u8,
        size: BUFFER_BYTES,
        write: AtomicUsize::new(0),
        read: AtomicUsize::new(0),
        flags: AtomicU32::new(MODE_NON_BLOCKING_TRIM),
    },
};

/// Bytes cut from lines that did not fit.
static DROPPED: AtomicU32 = AtomicU32::new(0);

/// Bytes of log cut because the buffer was full (the probe not reading fast enough),
/// since start-up.
pub fn dropped() -> u32 {
    DROPPED.load(Ordering::Relaxed)
}

/// Copies `bytes` into the channel, as much as fits.
fn put(bytes: &[u8]) {
    let ch = &_SEGGER_RTT.up;
    let write = ch.write.load(Ordering::Relaxed) % BUFFER_BYTES;
    let read = ch.read.load(Ordering::Acquire) % BUFFER_BYTES;
    // One byte stays free: write == read means empty.
    let free = if read > write {
        read - write - 1
    } else {
        BUFFER_BYTES - write + read - 1
    };
    let n = bytes.len().min(free);
    if n < bytes.len() {
        DROPPED.fetch_add((bytes.len() - n) as u32, Ordering::Relaxed);
    }
    let first = n.min(BUFFER_BYTES - write);
    let buf = BUFFER.0.get() as *mut u8;
    // SAFETY: `write + first <= BUFFER_BYTES` and `n - first < BUFFER_BYTES`; the probe
    // reads only below the write offset, which moves after the copy.
    unsafe {
        core::ptr::copy_nonoverlapping(bytes.as_ptr(), buf.add(write), first);
        core::ptr::copy_nonoverlapping(bytes.as_ptr().add(first), buf, n - first);
    }
    ch.write
        .store((write + n) % BUFFER_BYTES, Ordering::Release);
}

/// Loggers holding the logger: 1 while a line is written, 2 when the servo interrupt
/// logs meanwhile (its line dropped).
static DEPTH: AtomicU8 = AtomicU8::new(0);

/// What the outermost holder owns: the BASEPRI to restore and the line's encoder.
struct Frame {
    basepri: UnsafeCell<u8>,
    encoder: UnsafeCell<defmt::Encoder>,
}

// SAFETY: touched only by the outermost holder (`DEPTH` 0 → 1), which no context but
// the servo interrupt can preempt, and that one only at depth 2, where it does not touch
// the frame.
unsafe impl Sync for Frame {}

static FRAME: Frame = Frame {
    basepri: UnsafeCell::new(0),
    encoder: UnsafeCell::new(defmt::Encoder::new()),
};

#[defmt::global_logger]
struct Logger;

// SAFETY: a frame is written only between the outermost `acquire` and its `release`,
// with every context that could log masked but the servo interrupt, whose nested lines
// are dropped (module documentation).
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        let previous = crate::shared::mask_to_tick();
        if DEPTH.fetch_add(1, Ordering::Acquire) == 0 {
            // SAFETY: the outermost holder (see `Frame`).
            unsafe {
                *FRAME.basepri.get() = previous;
                (*FRAME.encoder.get()).start_frame(put);
            }
        }
    }

    unsafe fn flush() {}

    unsafe fn release() {
        if DEPTH.load(Ordering::Relaxed) == 1 {
            // SAFETY: the outermost holder (see `Frame`).
            let previous = unsafe {
                (*FRAME.encoder.get()).end_frame(put);
                *FRAME.basepri.get()
            };
            DEPTH.store(0, Ordering::Release);
            // SAFETY: the outermost holder's own mask, from its `acquire`.
            unsafe { crate::shared::unmask(previous) };
        } else {
            // A nested holder (the servo interrupt): its BASEPRI write changed
            // nothing, the outer holder's being at least as high.
            DEPTH.fetch_sub(1, Ordering::Release);
        }
    }

    unsafe fn write(bytes: &[u8]) {
        if DEPTH.load(Ordering::Relaxed) == 1 {
            // SAFETY: the outermost holder (see `Frame`).
            unsafe { (*FRAME.encoder.get()).write(bytes, put) };
        }
    }
}
