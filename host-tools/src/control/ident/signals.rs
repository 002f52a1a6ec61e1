//! The test signal and the empirical transfer function of a record.

use super::{blocks, IdentOptions, Record};
use crate::control::plant::Complex;

/// The empirical transfer function of the record at each of `ws` rad/s (mm or
/// degrees per c.u., as [`Arx::continuous_estimate`]): the cross-spectrum of block
/// output and input over the input's spectrum, averaged over three Hann-windowed
/// segments of half the record overlapping by half (Welch), each with its mean
/// removed (a shorter segment biases the response of a lightly damped resonance). `None` below two cycles per segment or above the block rate's
/// Nyquist frequency.
pub fn empirical_response(rec: &Record, o: &IdentOptions, ws: &[f64]) -> Vec<Option<Complex>> {
    let b = blocks(rec, o);
    // out[j] and U[j − 1] describe the same instant.
    let (x, y) = (&b.u, &b.out[1..]);
    let n = x.len().min(y.len());
    let seg = (n / 2).max(8);
    let t = b.period_s;
    let hann: Vec<f64> = (0..seg)
        .map(|k| 0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / seg as f64).cos())
        .collect();
    let dft = |s: &[f64], w: f64| {
        let mean = s.iter().sum::<f64>() / s.len() as f64;
        s.iter()
            .zip(&hann)
            .enumerate()
            .fold(Complex::new(0.0, 0.0), |acc, (k, (v, h))| {
                acc + Complex::expj(-w * t * k as f64).scale((v - mean) * h)
            })
    };
    ws.iter()
        .map(|&w| {
            if n < seg
                || w < 2.0 * std::f64::consts::TAU / (seg as f64 * t)
                || w * t > std::f64::consts::PI
            {
                return None;
            }
            let (mut cross, mut power) = (Complex::new(0.0, 0.0), 0.0);
            let mut start = 0;
            while start + seg <= n {
                let (xu, yu) = (
                    dft(&x[start..start + seg], w),
                    dft(&y[start..start + seg], w),
                );
                cross = cross + yu * Complex::new(xu.re, -xu.im);
                power += xu.re * xu.re + xu.im * xu.im;
                start += seg / 2;
            }
            let g = cross.scale(1.0 / power);
            let x2 = 0.5 * w * rec.h;
            Some(if o.integrating {
                g / Complex::new(0.0, w * t)
            } else {
                g * Complex::expj(-x2).scale(x2.sin() / x2)
            })
        })
        .collect()
}

/// A pseudo-random binary sequence of ±1, `len` samples, each value held for `hold`
/// samples: the maximal-length sequence of the 15-bit shift register with feedback
/// polynomial x¹⁵ + x¹⁴ + 1 (period 32 767 values), started from state `seed`
/// (0 is taken as 1). Its spectrum is flat to about 0.44/(hold·h) Hz.
pub fn prbs(len: usize, hold: usize, seed: u16) -> Vec<f64> {
    let mut r = seed & 0x7fff;
    if r == 0 {
        r = 1;
    }
    let hold = hold.max(1);
    let mut out = Vec::with_capacity(len);
    while out.len() < len {
        let bit = ((r >> 14) ^ (r >> 13)) & 1;
        r = ((r << 1) | bit) & 0x7fff;
        let v = if bit == 1 { 1.0 } else { -1.0 };
        out.extend(std::iter::repeat_n(v, hold.min(len - out.len())));
    }
    out
}
