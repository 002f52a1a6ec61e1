//! `(DEBUG, text)`: the operator message with parameters filled in.
//!
//! `#123` and `#<name>` are replaced by the parameter's value; `%d` (no decimals),
//! `%f` (4) and `%.Nf` (N, one digit) set the format of the parameters after them
//! (6 decimals until then); a value within 10⁻⁶ of zero prints as 0; a parameter that
//! does not exist prints as `######`. Anything else is copied.
//!
//! Source: LinuxCNC's interpreter, `convert_param_comment` (`interp_convert.cc`).

use crate::gcode::params::{Params, NUM_PARAMS};

/// `text` with its parameters filled in.
pub(super) fn expand(params: &Params, text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len() + 16);
    let mut decimals = 6usize;
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'%' => match (b.get(i + 1), b.get(i + 2), b.get(i + 3)) {
                (Some(b'd'), ..) => (decimals, i) = (0, i + 2),
                (Some(b'f'), ..) => (decimals, i) = (4, i + 2),
                (Some(b'.'), Some(&d), Some(b'f')) if d.is_ascii_digit() => {
                    (decimals, i) = (usize::from(d - b'0'), i + 4);
                }
                // LinuxCNC drops the '%' before a '.' that starts no format.
                (Some(b'.'), ..) => i += 1,
                _ => {
                    out.push('%');
                    i += 1;
                }
            },
            b'#' => {
                let (value, next) = parameter(params, b, i + 1);
                i = next;
                match value {
                    Some(Some(v)) => {
                        let v = if v.abs() < 1e-6 { 0.0 } else { v };
                        out.push_str(&format!("{v:.decimals$}"));
                    }
                    Some(None) => out.push_str("######"),
                    None => out.push('#'),
                }
            }
            _ => {
                let ch = text[i..].chars().next().unwrap_or(' ');
                out.push(ch);
                i += ch.len_utf8();
            }
        }
    }
    out
}

/// The parameter named at `b[i..]` (after its '#'): `None` when none is named there,
/// `Some(None)` when the named one does not exist; and where the text goes on.
fn parameter(params: &Params, b: &[u8], i: usize) -> (Option<Option<f64>>, usize) {
    match b.get(i) {
        Some(d) if d.is_ascii_digit() => {
            let end = (i..b.len())
                .find(|&k| !b[k].is_ascii_digit())
                .unwrap_or(b.len());
            let n: Option<usize> = std::str::from_utf8(&b[i..end])
                .ok()
                .and_then(|s| s.parse().ok());
            let v = n.filter(|&n| n < NUM_PARAMS).map(|n| params.numbered(n));
            (Some(v), end)
        }
        Some(b'<') => {
            let Some(close) = (i + 1..b.len()).find(|&k| b[k] == b'>') else {
                return (Some(None), b.len());
            };
            let name: Vec<u8> = b[i + 1..close]
                .iter()
                .filter(|c| !c.is_ascii_whitespace())
                .map(u8::to_ascii_lowercase)
                .collect();
            (Some(params.named(&name)), close + 1)
        }
        _ => (None, i),
    }
}
