//! A sender's bytes: real-time commands taken out wherever they are (even inside a
//! number), the rest assembled into lines. A line too long, or holding a byte that is
//! not text, is not lost: it comes out as a refused line, in its place, so that it
//! still draws its one `error:N`.

/// Longest line accepted, bytes (the G-code front end's own limit).
pub const MAX_LINE: usize = crate::gcode::MAX_LINE;

/// Real-time commands (Grbl 1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RealTime {
    /// `?`: a status report.
    Status,
    /// `!`: feed hold.
    Hold,
    /// `~`: cycle start / resume.
    Resume,
    /// `0x18` (Ctrl-X): soft reset.
    Reset,
    /// `0x84`: safety door (treated as a feed hold).
    Door,
    /// `0x85`: jog cancel.
    JogCancel,
    /// `0x90`–`0x94`: feed override to 100 %, +10, −10, +1, −1.
    Feed(i8),
    /// `0x95`–`0x97`: rapid override to 100, 50, 25 %.
    Rapid(u8),
    /// `0x99`–`0x9D`: spindle override to 100 %, +10, −10, +1, −1.
    Spindle(i8),
    /// `0x9E`, `0xA0`, `0xA1`: spindle stop, flood and mist toggles.
    Toggle(u8),
}

/// What the bytes hold, in order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Item {
    /// A real-time command.
    RealTime(RealTime),
    /// A complete line, without its line break.
    Line(String),
    /// A line that cannot be read, and why.
    Refused {
        /// The Grbl error code it draws.
        code: u8,
        /// Why, for the `[MSG:…]` before the error.
        why: String,
    },
}

/// The line being assembled.
#[derive(Default)]
pub struct Input {
    line: Vec<u8>,
    /// Bytes of the line beyond [`MAX_LINE`] (not kept).
    overflow: usize,
    /// First byte that is not text, and its column.
    bad: Option<(u8, usize)>,
    /// The last byte ended a line with `\r` (a `\n` after it ends nothing more).
    after_cr: bool,
    /// The last byte was 0xC2, which with a real-time byte ≥ 0x80 after it is that
    /// command written as UTF-8 (CNCjs sends its override bytes so).
    after_c2: bool,
}

impl Input {
    /// Reads `bytes`, appending what they complete to `out`.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<Item>) {
        for &b in bytes {
            if std::mem::take(&mut self.after_c2) {
                if let Some(rt) = real_time(b).filter(|_| b >= 0x80) {
                    out.push(Item::RealTime(rt));
                    continue;
                }
                // A lone 0xC2 is a byte of the line like any other.
                self.byte(0xc2, out);
            }
            if b == 0xc2 {
                self.after_c2 = true;
                continue;
            }
            if let Some(rt) = real_time(b) {
                out.push(Item::RealTime(rt));
                continue;
            }
            self.byte(b, out);
        }
    }

    fn byte(&mut self, b: u8, out: &mut Vec<Item>) {
        let after_cr = std::mem::replace(&mut self.after_cr, b == b'\r');
        match b {
            b'\n' if after_cr => {}
            b'\n' | b'\r' => {
                if let Some(item) = self.take() {
                    out.push(item);
                }
            }
            _ if self.line.len() >= MAX_LINE => self.overflow += 1,
            b'\t' | 0x20..=0x7e => self.line.push(b),
            _ => {
                let col = self.line.len() + self.overflow + 1;
                self.bad.get_or_insert((b, col));
                self.line.push(b'?');
            }
        }
    }

    /// Bytes held of the line not yet complete.
    pub fn held(&self) -> usize {
        self.line.len()
    }

    /// Forgets the line being assembled (a soft reset).
    pub fn clear(&mut self) {
        *self = Self::default();
    }

    fn take(&mut self) -> Option<Item> {
        let line = std::mem::take(&mut self.line);
        let overflow = std::mem::take(&mut self.overflow);
        let bad = self.bad.take();
        if overflow > 0 {
            return Some(Item::Refused {
                code: 11,
                why: format!(
                    "line of {} characters; at most {MAX_LINE} are read",
                    line.len() + overflow
                ),
            });
        }
        if let Some((b, col)) = bad {
            return Some(Item::Refused {
                code: 1,
                why: format!("byte 0x{b:02X} at column {col} is not G-code text"),
            });
        }
        let text = String::from_utf8(line).unwrap_or_default();
        if text.trim().is_empty() {
            // Grbl answers an empty line with `ok` too.
            return Some(Item::Line(String::new()));
        }
        Some(Item::Line(text))
    }
}

fn real_time(b: u8) -> Option<RealTime> {
    Some(match b {
        b'?' => RealTime::Status,
        b'!' => RealTime::Hold,
        b'~' => RealTime::Resume,
        0x18 => RealTime::Reset,
        0x84 => RealTime::Door,
        0x85 => RealTime::JogCancel,
        0x90 => RealTime::Feed(0),
        0x91 => RealTime::Feed(10),
        0x92 => RealTime::Feed(-10),
        0x93 => RealTime::Feed(1),
        0x94 => RealTime::Feed(-1),
        0x95 => RealTime::Rapid(100),
        0x96 => RealTime::Rapid(50),
        0x97 => RealTime::Rapid(25),
        0x99 => RealTime::Spindle(0),
        0x9a => RealTime::Spindle(10),
        0x9b => RealTime::Spindle(-10),
        0x9c => RealTime::Spindle(1),
        0x9d => RealTime::Spindle(-1),
        0x9e | 0xa0 | 0xa1 => RealTime::Toggle(b),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(bytes: &[u8]) -> Vec<Item> {
        let mut input = Input::default();
        let mut out = Vec::new();
        input.push(bytes, &mut out);
        out
    }

    #[test]
    fn real_time_bytes_are_taken_out_even_inside_a_number() {
        let items = read(b"G1 X1?0.5!\x91 F~500\n");
        assert_eq!(
            items,
            vec![
                Item::RealTime(RealTime::Status),
                Item::RealTime(RealTime::Hold),
                Item::RealTime(RealTime::Feed(10)),
                Item::RealTime(RealTime::Resume),
                Item::Line("G1 X10.5 F500".into()),
            ]
        );
    }

    #[test]
    fn crlf_ends_one_line_and_an_empty_line_is_a_line() {
        let items = read(b"G0 X1\r\n\nG0 X2\r");
        assert_eq!(
            items,
            vec![
                Item::Line("G0 X1".into()),
                Item::Line(String::new()),
                Item::Line("G0 X2".into())
            ]
        );
    }

    #[test]
    fn a_ten_kilobyte_line_is_refused_whole_and_the_next_line_reads() {
        let mut bytes = vec![b'X'; 10_000];
        bytes.extend_from_slice(b"\nG0 X1\n");
        let items = read(&bytes);
        assert!(matches!(&items[0], Item::Refused { code: 11, why } if why.contains("10000")));
        assert_eq!(items[1], Item::Line("G0 X1".into()));
        assert_eq!(items.len(), 2);
    }

    #[test]
    fn real_time_bytes_written_as_utf8_act_and_a_lone_c2_refuses_its_line() {
        let items = read(b"G1 X1\xc2\x91 F10\n\xc2G0\n");
        assert_eq!(items[0], Item::RealTime(RealTime::Feed(10)));
        assert_eq!(items[1], Item::Line("G1 X1 F10".into()));
        assert!(matches!(&items[2], Item::Refused { code: 1, why } if why.contains("0xC2")));
    }

    #[test]
    fn binary_bytes_refuse_their_line_naming_the_first() {
        let items = read(b"G0 X\x01\xff1\nG0 X2\n");
        assert!(
            matches!(&items[0], Item::Refused { code: 1, why } if why.contains("0x01 at column 5")),
            "{items:?}"
        );
        assert_eq!(items[1], Item::Line("G0 X2".into()));
    }
}
