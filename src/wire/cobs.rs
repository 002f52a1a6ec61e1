//! Consistent Overhead Byte Stuffing (Cheshire and Baker, 1999): removes every zero
//! byte from a frame so that a single 0x00 can delimit frames on a byte stream. Worst
//! case overhead is one byte per 254 bytes plus one.

/// Largest encoded length of `n` source bytes (without the 0x00 delimiter).
pub const fn max_encoded_len(n: usize) -> usize {
    n + n / 254 + 1
}

/// Why COBS decoding failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum CobsError {
    /// A zero byte inside the encoded data.
    ZeroInData,
    /// A code byte points past the end of the frame.
    Truncated,
    /// The output buffer is too small.
    NoRoom,
}

/// Encodes `src` into `dst` (no delimiter); returns the encoded length, or `None` when
/// `dst` is shorter than [`max_encoded_len`] requires.
pub fn encode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    if dst.len() < max_encoded_len(src.len()) {
        return None;
    }
    let mut code_at = 0;
    let mut out = 1;
    let mut code = 1u8;
    for &b in src {
        if b == 0 {
            dst[code_at] = code;
            code_at = out;
            out += 1;
            code = 1;
        } else {
            dst[out] = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                dst[code_at] = code;
                code_at = out;
                out += 1;
                code = 1;
            }
        }
    }
    dst[code_at] = code;
    Some(out)
}

/// Decodes `src` (without the delimiter) into `dst`; returns the decoded length.
pub fn decode(src: &[u8], dst: &mut [u8]) -> Result<usize, CobsError> {
    let mut i = 0;
    let mut out = 0;
    while i < src.len() {
        let code = src[i] as usize;
        if code == 0 {
            return Err(CobsError::ZeroInData);
        }
        i += 1;
        let end = i + code - 1;
        if end > src.len() {
            return Err(CobsError::Truncated);
        }
        for &b in &src[i..end] {
            if b == 0 {
                return Err(CobsError::ZeroInData);
            }
            if out >= dst.len() {
                return Err(CobsError::NoRoom);
            }
            dst[out] = b;
            out += 1;
        }
        i = end;
        if code < 0xFF && i < src.len() {
            if out >= dst.len() {
                return Err(CobsError::NoRoom);
            }
            dst[out] = 0;
            out += 1;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip(data: &[u8]) {
        let mut enc = [0u8; 1200];
        let n = encode(data, &mut enc).unwrap();
        assert!(!enc[..n].contains(&0), "encoded data holds no zero");
        let mut dec = [0u8; 1200];
        let m = decode(&enc[..n], &mut dec).unwrap();
        assert_eq!(&dec[..m], data);
    }

    #[test]
    fn known_vectors_encode_as_published() {
        let mut out = [0u8; 16];
        let n = encode(&[0x11, 0x22, 0x00, 0x33], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x03, 0x11, 0x22, 0x02, 0x33]);
        let n = encode(&[0x00], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x01, 0x01]);
        let n = encode(&[], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x01]);
    }

    #[test]
    fn any_data_survives_a_round_trip() {
        round_trip(&[]);
        round_trip(&[0, 0, 0]);
        let long: Vec<u8> = (0..1000u32).map(|i| (i % 255 + 1) as u8).collect();
        round_trip(&long);
        let mixed: Vec<u8> = (0..600u32).map(|i| (i * 7 % 256) as u8).collect();
        round_trip(&mixed);
        let run254: Vec<u8> = vec![1; 254];
        round_trip(&run254);
    }

    #[test]
    fn a_zero_inside_a_frame_is_an_error() {
        let mut dec = [0u8; 8];
        assert_eq!(decode(&[0x02, 0x00], &mut dec), Err(CobsError::ZeroInData));
        assert_eq!(decode(&[0x05, 0x11], &mut dec), Err(CobsError::Truncated));
    }
}
