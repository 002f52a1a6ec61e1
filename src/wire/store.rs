//! The machine configuration as bytes: how the host sends it to the controller and how
//! the firmware keeps it in flash across resets.
//!
//! Record format: `MAGIC (4) ‖ length (u16 LE) ‖ CRC-32 of the payload (u32 LE) ‖
//! postcard(MachineConfig)`. The CRC of the payload also identifies the machine in the
//! handshake, so host and controller can tell whether they agree without sending it.
//! [`Assembler`] collects the payload from chunks that may arrive repeated (a host
//! resends a chunk until acknowledged) but are applied once, at their offset.

use crate::config::{ConfigError, MachineConfig};

/// Largest serialized machine configuration, bytes.
pub const MAX_CONFIG_BYTES: usize = 2048;
/// Bytes of configuration carried by one message.
pub const CHUNK_BYTES: usize = 160;
/// Start of a stored record ("PKM2" since the configuration holds eight servo channels
/// and LQG designs: a record of the older layout is not read as this one).
pub const MAGIC: [u8; 4] = *b"PKM2";
/// Header length of a stored record.
pub const HEADER_BYTES: usize = 10;

/// Serializes `config` into `out`; returns the payload length.
pub fn encode(config: &MachineConfig, out: &mut [u8; MAX_CONFIG_BYTES]) -> Option<usize> {
    postcard::to_slice(config, out).ok().map(|s| s.len())
}

/// Identity of a configuration: the CRC-32 of its serialized form.
pub fn identity(config: &MachineConfig) -> u32 {
    let mut buf = [0u8; MAX_CONFIG_BYTES];
    match encode(config, &mut buf) {
        Some(n) => crate::wire::crc::crc32(&buf[..n]),
        None => 0,
    }
}

/// Why bytes are not a usable configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum StoreError {
    /// No record (blank or foreign flash).
    NoRecord,
    /// Length or CRC mismatch.
    Damaged,
    /// The payload does not decode as a configuration.
    Undecodable,
    /// The configuration decodes but is refused.
    Invalid(ConfigError),
    /// The controller is moving; a machine can only be loaded at rest.
    Busy,
}

/// Decodes and validates a payload.
pub fn decode(payload: &[u8]) -> Result<MachineConfig, StoreError> {
    let config: MachineConfig =
        postcard::from_bytes(payload).map_err(|_| StoreError::Undecodable)?;
    config.validate().map_err(StoreError::Invalid)?;
    Ok(config)
}

/// Writes a flash record of `config` into `out`; returns its length.
pub fn record(
    config: &MachineConfig,
    out: &mut [u8; HEADER_BYTES + MAX_CONFIG_BYTES],
) -> Option<usize> {
    let mut payload = [0u8; MAX_CONFIG_BYTES];
    let n = encode(config, &mut payload)?;
    out[..4].copy_from_slice(&MAGIC);
    out[4..6].copy_from_slice(&(n as u16).to_le_bytes());
    out[6..10].copy_from_slice(&crate::wire::crc::crc32(&payload[..n]).to_le_bytes());
    out[HEADER_BYTES..HEADER_BYTES + n].copy_from_slice(&payload[..n]);
    Some(HEADER_BYTES + n)
}

/// Reads a flash record.
pub fn read_record(bytes: &[u8]) -> Result<MachineConfig, StoreError> {
    if bytes.len() < HEADER_BYTES || bytes[..4] != MAGIC {
        return Err(StoreError::NoRecord);
    }
    let n = u16::from_le_bytes([bytes[4], bytes[5]]) as usize;
    let crc = u32::from_le_bytes([bytes[6], bytes[7], bytes[8], bytes[9]]);
    let payload = bytes
        .get(HEADER_BYTES..HEADER_BYTES + n)
        .ok_or(StoreError::Damaged)?;
    if n > MAX_CONFIG_BYTES || crate::wire::crc::crc32(payload) != crc {
        return Err(StoreError::Damaged);
    }
    decode(payload)
}

/// Collects a configuration sent in chunks.
pub struct Assembler {
    buf: [u8; MAX_CONFIG_BYTES],
    total: usize,
    crc: u32,
    /// Bit per chunk received.
    have: [bool; MAX_CONFIG_BYTES / CHUNK_BYTES + 1],
}

impl Default for Assembler {
    fn default() -> Self {
        Self::new()
    }
}

impl Assembler {
    /// An empty assembler.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_CONFIG_BYTES],
            total: 0,
            crc: 0,
            have: [false; MAX_CONFIG_BYTES / CHUNK_BYTES + 1],
        }
    }

    /// Adds a chunk at `offset` of a payload of `total` bytes with CRC `crc`. Returns
    /// the decoded configuration once every chunk is in and the CRC matches, an error
    /// when the transfer is inconsistent, and `Ok(None)` while chunks are missing.
    pub fn add(
        &mut self,
        offset: usize,
        total: usize,
        crc: u32,
        data: &[u8],
    ) -> Result<Option<MachineConfig>, StoreError> {
        if total > MAX_CONFIG_BYTES
            || !offset.is_multiple_of(CHUNK_BYTES)
            || offset + data.len() > total
            || data.len() > CHUNK_BYTES
        {
            return Err(StoreError::Damaged);
        }
        if total != self.total || crc != self.crc {
            // A new transfer.
            self.total = total;
            self.crc = crc;
            self.have = [false; MAX_CONFIG_BYTES / CHUNK_BYTES + 1];
        }
        self.buf[offset..offset + data.len()].copy_from_slice(data);
        self.have[offset / CHUNK_BYTES] = true;
        let chunks = total.div_ceil(CHUNK_BYTES);
        if !self.have[..chunks].iter().all(|h| *h) {
            return Ok(None);
        }
        let payload = &self.buf[..total];
        if crate::wire::crc::crc32(payload) != crc {
            self.have = [false; MAX_CONFIG_BYTES / CHUNK_BYTES + 1];
            return Err(StoreError::Damaged);
        }
        decode(payload).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_round_trips_and_damage_is_detected() {
        let m = MachineConfig::cartesian_xyz();
        let mut rec = [0u8; HEADER_BYTES + MAX_CONFIG_BYTES];
        let n = record(&m, &mut rec).unwrap();
        assert_eq!(read_record(&rec[..n]), Ok(m));
        rec[n - 1] ^= 1;
        assert_eq!(read_record(&rec[..n]), Err(StoreError::Damaged));
        assert_eq!(read_record(&[0xFF; 64]), Err(StoreError::NoRecord));
    }

    #[test]
    fn chunks_in_any_order_and_repeated_assemble_once() {
        let m = MachineConfig::cartesian_xyz();
        let mut payload = [0u8; MAX_CONFIG_BYTES];
        let n = encode(&m, &mut payload).unwrap();
        let crc = crate::wire::crc::crc32(&payload[..n]);
        let mut a = Assembler::new();
        let chunks: Vec<usize> = (0..n).step_by(CHUNK_BYTES).collect();
        let mut got = None;
        for &off in chunks.iter().rev().chain(chunks.iter()) {
            let end = (off + CHUNK_BYTES).min(n);
            if let Some(c) = a.add(off, n, crc, &payload[off..end]).unwrap() {
                got = Some(c);
            }
        }
        assert_eq!(got, Some(m.clone()));
        assert_eq!(identity(&m), crc);
    }
}
