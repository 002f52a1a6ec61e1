//! A test signal for tuning a servo joint (issue 35): an offset, in encoder counts,
//! that the controller adds to one channel's target every tick while the machine
//! stands, so that the host can record the loop's response and identify its plant.
//!
//! Two shapes, both of amplitude `amplitude` counts about the joint's standing
//! position, changing only at tick edges (the setpoint interpolator ramps each
//! change over the tick's servo periods):
//!
//! * **Steps** (kind 0): 0, then +A for `hold` ticks, 0 for `hold` ticks, and so on.
//! * **PRBS** (kind 1): ±A from a maximal-length 15-bit shift register
//!   (x¹⁵ + x¹⁴ + 1, period 32 767 bits), one bit every `hold` ticks, from a seed.
//!   Its spectrum is flat up to about 1/(2·hold) kHz, which covers a servo loop's
//!   band with `hold` of 1 to 5.
//!
//! Either ends at 0 after `length` ticks. Safety is the controller's
//! (`controller::recording`): a homed, idle machine, a servo joint, an amplitude
//! below the joint's standstill following-error limit and inside its travel; the
//! loop's following-error trip stays in force, and the signal stops at once on an
//! alarm or when anything else asks to move.

/// A test signal's request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Excite {
    /// The joint.
    pub joint: u8,
    /// 0 steps, 1 PRBS.
    pub kind: u8,
    /// Amplitude, encoder counts.
    pub amplitude: u32,
    /// Ticks a level is held (at least 1).
    pub hold: u16,
    /// Ticks the signal lasts.
    pub length: u32,
    /// The PRBS's start (a zero seed starts at 1).
    pub seed: u16,
}

/// Bytes of a packed [`Excite`].
pub const EXCITE_BYTES: usize = 14;

impl Excite {
    /// The request's bytes: joint, kind, amplitude (u32), hold (u16), length (u32),
    /// seed (u16), little-endian.
    pub fn pack(&self) -> [u8; EXCITE_BYTES] {
        let mut b = [0; EXCITE_BYTES];
        b[0] = self.joint;
        b[1] = self.kind;
        b[2..6].copy_from_slice(&self.amplitude.to_le_bytes());
        b[6..8].copy_from_slice(&self.hold.to_le_bytes());
        b[8..12].copy_from_slice(&self.length.to_le_bytes());
        b[12..14].copy_from_slice(&self.seed.to_le_bytes());
        b
    }

    /// The request in `b`, or the place of its first bad byte.
    pub fn unpack(b: &[u8]) -> Result<Self, u8> {
        let Ok(b) = <&[u8; EXCITE_BYTES]>::try_from(b) else {
            return Err(b.len().min(EXCITE_BYTES) as u8);
        };
        let e = Self {
            joint: b[0],
            kind: b[1],
            amplitude: u32::from_le_bytes([b[2], b[3], b[4], b[5]]),
            hold: u16::from_le_bytes([b[6], b[7]]),
            length: u32::from_le_bytes([b[8], b[9], b[10], b[11]]),
            seed: u16::from_le_bytes([b[12], b[13]]),
        };
        if e.kind > 1 {
            Err(1)
        } else if e.amplitude == 0 {
            Err(2)
        } else if e.hold == 0 {
            Err(6)
        } else {
            Ok(e)
        }
    }
}

/// A running test signal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Signal {
    req: Excite,
    /// Ticks run.
    tick: u32,
    /// The shift register.
    lfsr: u16,
    /// The level held now, counts.
    level: i32,
}

impl Signal {
    /// The signal of `req`, not started.
    pub fn new(req: Excite) -> Self {
        Self {
            req,
            tick: 0,
            lfsr: if req.seed & 0x7fff == 0 {
                1
            } else {
                req.seed & 0x7fff
            },
            level: 0,
        }
    }

    /// The joint it moves.
    pub fn joint(&self) -> usize {
        self.req.joint as usize
    }

    /// The next tick's offset, counts; `None` once it has ended (its last offset was 0).
    pub fn offset(&mut self) -> Option<i32> {
        if self.tick >= self.req.length {
            return None;
        }
        let a = self.req.amplitude as i32;
        if self.tick.is_multiple_of(self.req.hold as u32) {
            let n = self.tick / self.req.hold as u32;
            self.level = match self.req.kind {
                0 => {
                    if n % 2 == 1 {
                        a
                    } else {
                        0
                    }
                }
                _ => {
                    let bit = (self.lfsr ^ (self.lfsr >> 1)) & 1;
                    self.lfsr = (self.lfsr >> 1) | (bit << 14);
                    if bit == 1 {
                        a
                    } else {
                        -a
                    }
                }
            };
        }
        self.tick += 1;
        Some(if self.tick == self.req.length {
            0
        } else {
            self.level
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(kind: u8, hold: u16, length: u32) -> Excite {
        Excite {
            joint: 2,
            kind,
            amplitude: 50,
            hold,
            length,
            seed: 7,
        }
    }

    #[test]
    fn packs_and_refuses_by_place() {
        let r = req(1, 3, 900);
        assert_eq!(Excite::unpack(&r.pack()), Ok(r));
        assert_eq!(Excite::unpack(&r.pack()[..9]), Err(9));
        let mut b = r.pack();
        b[1] = 4;
        assert_eq!(Excite::unpack(&b), Err(1));
        let mut b = r.pack();
        b[6] = 0;
        b[7] = 0;
        assert_eq!(Excite::unpack(&b), Err(6));
    }

    #[test]
    fn steps_alternate_and_end_at_zero() {
        let mut s = Signal::new(req(0, 2, 9));
        let v: Vec<i32> = core::iter::from_fn(|| s.offset()).collect();
        assert_eq!(v, [0, 0, 50, 50, 0, 0, 50, 50, 0]);
    }

    #[test]
    fn prbs_is_balanced_and_maximal() {
        let mut s = Signal::new(req(1, 1, 32_767 + 1));
        let v: Vec<i32> = core::iter::from_fn(|| s.offset()).collect();
        assert_eq!(v.len(), 32_768);
        assert_eq!(*v.last().unwrap(), 0);
        let ones = v[..32_767].iter().filter(|&&x| x == 50).count();
        // A maximal 15-bit sequence has 2^14 ones and 2^14 − 1 zeros in a period.
        assert_eq!(ones, 16_384);
        assert!(v[..32_767].iter().all(|&x| x == 50 || x == -50));
        // The register's state repeats first after 32 767 bits.
        let mut t = Signal::new(req(1, 1, 70_000));
        let w: Vec<i32> = core::iter::from_fn(|| t.offset()).collect();
        assert_eq!(w[..200], w[32_767..32_967]);
        assert_ne!(w[..200], w[100..300]);
    }
}
