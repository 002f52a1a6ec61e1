//! CRC-32 (IEEE 802.3: reflected polynomial 0xEDB88320, initial value and final XOR
//! 0xFFFFFFFF), table-driven with the tables built at compile time. Check value of the
//! ASCII string "123456789" is 0xCBF43926 (the standard catalogue value).
//!
//! Host and firmware use the byte-wide table (1 KiB, one lookup per byte): the
//! controller runs the CRC over every byte it receives and sends, inside the tick's
//! lock, and the byte table takes the worst 1 ms period of `.ci/m4count.py` down by
//! 3.8k instructions (3 %) for 1.1 KB of flash. The nibble-wide table (64 bytes, two
//! lookups per byte: [`update_nibbles`]) gives the same CRC (tested), for a build that
//! must save that flash.

const fn make_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

static TABLE: [u32; 256] = make_table();

/// Every 16th entry of the byte table is the CRC of a nibble: the nibble table.
const fn make_nibble_table() -> [u32; 16] {
    let full = make_table();
    let mut t = [0u32; 16];
    let mut i = 0;
    while i < 16 {
        t[i] = full[i * 16];
        i += 1;
    }
    t
}

static NIBBLES: [u32; 16] = make_nibble_table();

/// The register before the first byte.
pub const INIT: u32 = 0xFFFF_FFFF;

/// The register after a message followed by its own CRC (little-endian): a frame
/// whose CRC is right leaves this whatever its message (the register is not yet
/// complemented; `!RESIDUE` is the catalogue's residue 0x2144DF1C).
pub const RESIDUE: u32 = 0xDEBB_20E3;

/// The register after one more byte `b` (no final XOR).
#[inline(always)]
pub fn update(c: u32, b: u8) -> u32 {
    TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8)
}

/// [`update`], four bits per lookup.
#[inline(always)]
pub fn update_nibbles(c: u32, b: u8) -> u32 {
    let c = c ^ b as u32;
    let c = NIBBLES[(c & 0xF) as usize] ^ (c >> 4);
    NIBBLES[(c & 0xF) as usize] ^ (c >> 4)
}

/// Tables for four bytes at a time ("slicing by four"): `WORD[k][i]` is the register
/// after byte `i` followed by `k` zero bytes. 4 KiB of flash, for the controller's
/// receive path, which runs the CRC over every block frame inside the tick's lock.
const fn make_word_tables() -> [[u32; 256]; 4] {
    let t0 = make_table();
    let mut t = [[0u32; 256]; 4];
    t[0] = t0;
    let mut k = 1;
    while k < 4 {
        let mut i = 0;
        while i < 256 {
            let prev = t[k - 1][i];
            t[k][i] = (prev >> 8) ^ t0[(prev & 0xFF) as usize];
            i += 1;
        }
        k += 1;
    }
    t
}

static WORD: [[u32; 256]; 4] = make_word_tables();

/// The register after four more bytes, `w` little-endian (the same as four [`update`]s).
#[inline(always)]
pub fn update_word(c: u32, w: u32) -> u32 {
    let c = c ^ w;
    WORD[3][(c & 0xFF) as usize]
        ^ WORD[2][((c >> 8) & 0xFF) as usize]
        ^ WORD[1][((c >> 16) & 0xFF) as usize]
        ^ WORD[0][(c >> 24) as usize]
}

/// CRC-32 of `data`.
pub fn crc32(data: &[u8]) -> u32 {
    !data.iter().fold(INIT, |c, &b| update(c, b))
}

/// CRC-32 of `data`, four bits per lookup.
pub fn crc32_nibbles(data: &[u8]) -> u32 {
    !data.iter().fold(INIT, |c, &b| update_nibbles(c, b))
}

#[cfg(test)]
mod tests {
    #[test]
    fn check_value_matches_the_catalogue() {
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(super::crc32_nibbles(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn the_nibble_table_agrees_with_the_byte_table() {
        let mut x = 0x1234_5678u32;
        let data: Vec<u8> = (0..4096)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x as u8
            })
            .collect();
        for n in [0, 1, 2, 7, 64, 4096] {
            assert_eq!(super::crc32(&data[..n]), super::crc32_nibbles(&data[..n]));
        }
    }

    #[test]
    fn four_bytes_at_a_time_agree_with_one_at_a_time() {
        let mut x = 0x8765_4321u32;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let (c, w) = (x, x.rotate_left(11) ^ 0x5A5A_0F0F);
            let bytes = w.to_le_bytes().iter().fold(c, |c, &b| super::update(c, b));
            assert_eq!(super::update_word(c, w), bytes);
        }
    }

    #[test]
    fn a_message_followed_by_its_crc_leaves_the_residue() {
        for data in [&b""[..], b"123456789", &[0u8; 100], &[0xFF; 3]] {
            let mut framed = data.to_vec();
            framed.extend_from_slice(&super::crc32(data).to_le_bytes());
            let reg = framed.iter().fold(super::INIT, |c, &b| super::update(c, b));
            assert_eq!(reg, super::RESIDUE);
            assert_eq!(!reg, 0x2144_DF1C);
            framed[0] ^= 1;
            let reg = framed.iter().fold(super::INIT, |c, &b| super::update(c, b));
            assert_ne!(reg, super::RESIDUE);
        }
    }
}
