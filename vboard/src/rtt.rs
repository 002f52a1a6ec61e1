//! The defmt log, read as a debug probe reads it: from the RTT control block
//! `_SEGGER_RTT` in the target's RAM (up-buffer 0: its buffer, size and write offset;
//! the reader advances the read offset), decoded with the ELF's defmt table.
//!
//! Layout (SEGGER RTT, as the firmware's logger lays it out, `src/bin/firmware/log.rs`): 16 bytes of ID, the numbers of up
//! and down buffers (two i32), then each up-buffer descriptor: name, buffer pointer,
//! size, write offset, read offset, flags (six u32).

use crate::board::Board;
use crate::elf::Image;
use anyhow::{Context, Result};
use defmt_decoder::{DecodeError, StreamDecoder, Table};
use unicorn_engine::Unicorn;

/// The log reader.
pub struct Log {
    control: Option<u32>,
    decoder: Option<Box<dyn StreamDecoder + Send + Sync>>,
    /// Bytes read in all.
    pub bytes: u64,
}

fn read32(uc: &Unicorn<Board>, a: u32) -> u32 {
    let mut b = [0u8; 4];
    let _ = uc.mem_read(u64::from(a), &mut b);
    u32::from_le_bytes(b)
}

impl Log {
    /// A reader for the firmware `image` (`raw`: its ELF bytes).
    pub fn new(image: &Image, raw: &[u8]) -> Result<Self> {
        let control = image.symbol("_SEGGER_RTT").map(|s| s.addr);
        let table = Table::parse(raw).context("the ELF's defmt table")?;
        // The decoder borrows the table for the life of the program.
        let decoder = table.map(|t| {
            let t: &'static Table = Box::leak(Box::new(t));
            t.new_stream_decoder()
        });
        Ok(Self {
            control,
            decoder,
            bytes: 0,
        })
    }

    /// New log lines since the last poll.
    pub fn poll(&mut self, uc: &mut Unicorn<Board>) -> Result<Vec<String>> {
        let (Some(cb), Some(dec)) = (self.control, self.decoder.as_mut()) else {
            return Ok(Vec::new());
        };
        let up = cb + 24;
        let buf = read32(uc, up + 4);
        let size = read32(uc, up + 8);
        let write = read32(uc, up + 12);
        let read = read32(uc, up + 16);
        if size == 0 || write == read || write >= size || read >= size {
            return Ok(Vec::new());
        }
        let mut data = Vec::new();
        let mut r = read;
        while r != write {
            let end = if write > r { write } else { size };
            let mut chunk = vec![0u8; (end - r) as usize];
            let _ = uc.mem_read(u64::from(buf + r), &mut chunk);
            data.extend_from_slice(&chunk);
            r = if end == size { 0 } else { end };
        }
        let _ = uc.mem_write(u64::from(up + 16), &write.to_le_bytes());
        self.bytes += data.len() as u64;
        dec.received(&data);
        let mut lines = Vec::new();
        loop {
            match dec.decode() {
                Ok(frame) => lines.push(format!("fw: {}", frame.display(false))),
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) => {
                    lines.push("fw: (malformed defmt frame)".into());
                    break;
                }
            }
        }
        Ok(lines)
    }
}
