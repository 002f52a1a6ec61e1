//! Servo position loop, skeleton form: proportional control of the following error plus
//! velocity feed-forward, clamped to the output range. Runs once per interpolation tick
//! on encoder counts. (PID, acceleration feed-forward, anti-windup, following-error
//! trips and contour control come with the servo work.)
//!
//! output = clamp((kp·e + kvff·Δtarget) / 2^16, ±limit), with e = target − feedback
//! and Δtarget the commanded counts per tick.

/// State of one servo loop.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServoLoop {
    last_target: i64,
}

impl ServoLoop {
    /// A loop whose previous target is `target` counts.
    pub const fn new(target: i64) -> Self {
        Self {
            last_target: target,
        }
    }

    /// One update: returns the signed command, in DAC counts around mid-scale.
    pub fn update(
        &mut self,
        target: i64,
        feedback: i64,
        kp_q16: i32,
        kvff_q16: i32,
        limit: i32,
    ) -> i32 {
        let error = (target - feedback) as i128;
        let velocity = (target - self.last_target) as i128;
        self.last_target = target;
        let u = (kp_q16 as i128 * error + kvff_q16 as i128 * velocity) >> 16;
        u.clamp(-(limit as i128), limit as i128) as i32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_pushes_toward_the_target_and_is_clamped() {
        let mut s = ServoLoop::new(0);
        assert!(s.update(100, 0, 1 << 16, 0, 1000) > 0);
        assert_eq!(s.update(1_000_000, 0, 1 << 16, 0, 1000), 1000);
        assert_eq!(s.update(-1_000_000, 0, 1 << 16, 0, 1000), -1000);
    }
}
