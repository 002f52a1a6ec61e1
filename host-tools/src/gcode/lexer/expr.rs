//! Expressions: `[bracketed expressions]` with LinuxCNC's binary operators and their
//! precedence, unary functions (`SIN[30]`, `ATAN[y]/[x]`, `EXISTS[#<name>]`) and
//! parameter reads (`#1`, `##1`, `#<name>`), evaluated in `f64` while the line is read.
//!
//! Invariants: recursion is bounded by [`MAX_NESTING`] (brackets, unary signs, parameter
//! indirection and function arguments all count); every result is finite or an error at
//! the operator or function that produced it; angles are in degrees; a named parameter
//! read before it was set is an error, a numbered one reads as 0.
//!
//! Source: LinuxCNC G-code overview (parameters, expressions, binary operators,
//! functions).

use super::number::Num;
use super::{Cursor, LexError};
use crate::gcode::params::NUM_PARAMS;
use crate::gcode::{ErrorKind, MAX_NESTING};

/// Binary operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    Pow,
    Mul,
    Div,
    Mod,
    Add,
    Sub,
    Eq,
    Ne,
    Gt,
    Ge,
    Lt,
    Le,
    And,
    Or,
    Xor,
}

impl Op {
    /// LinuxCNC's precedence: logical 2, comparison 3, additive 4, multiplicative 5,
    /// power 6; all left-associative.
    fn precedence(self) -> u8 {
        match self {
            Op::And | Op::Or | Op::Xor => 2,
            Op::Eq | Op::Ne | Op::Gt | Op::Ge | Op::Lt | Op::Le => 3,
            Op::Add | Op::Sub => 4,
            Op::Mul | Op::Div | Op::Mod => 5,
            Op::Pow => 6,
        }
    }
}

/// Tolerance of EQ and NE: LinuxCNC's `TOLERANCE_EQUAL` (its `rs274` says
/// `[1.00009 EQ 1]` is 1 and `[1.00011 EQ 1]` is 0).
const EQUAL_TOLERANCE: f64 = 1e-4;

impl Cursor<'_> {
    /// One operand of an expression: number, `[expr]`, parameter, signed operand or
    /// function call.
    pub(super) fn operand(&mut self, depth: usize) -> Result<f64, LexError> {
        if depth >= MAX_NESTING {
            return Err(self.err(
                self.i,
                ErrorKind::OutOfRange,
                format!("expression nested more than {MAX_NESTING} deep"),
            ));
        }
        match self.peek() {
            Some(b'0'..=b'9' | b'.') => {
                let at = self.i;
                Ok(self.literal(at)?.to_f64())
            }
            Some(b'[') => self.bracket(depth + 1),
            Some(b'#') => self.param_read(depth + 1),
            Some(b'-') => {
                self.i += 1;
                Ok(-self.operand(depth + 1)?)
            }
            Some(b'+') => {
                self.i += 1;
                self.operand(depth + 1)
            }
            Some(c) if c.is_ascii_alphabetic() => self.function(depth + 1),
            _ => Err(self.unexpected(ErrorKind::BadNumber, "expected a value")),
        }
    }

    /// `[ expr ]`, at the `[`.
    pub(super) fn bracket(&mut self, depth: usize) -> Result<f64, LexError> {
        let open = self.i;
        self.i += 1;
        let v = self.binary(0, depth, open)?;
        match self.peek() {
            Some(b']') => {
                self.i += 1;
                Ok(v)
            }
            None => Err(self.err(
                open,
                ErrorKind::BadNumber,
                "'[' opened here is never closed",
            )),
            Some(_) => Err(self.unexpected(ErrorKind::BadNumber, "expected an operator or ']'")),
        }
    }

    /// Precedence climbing over binary operators, left-associative.
    fn binary(&mut self, min_prec: u8, depth: usize, open: usize) -> Result<f64, LexError> {
        let mut lhs = self.operand(depth)?;
        loop {
            let at = self.i;
            let Some((op, len)) = self.peek_op(open)? else {
                return Ok(lhs);
            };
            let prec = op.precedence();
            if prec < min_prec {
                self.i = at;
                return Ok(lhs);
            }
            self.i += len;
            let op_at = self.i - len;
            let rhs = self.binary(prec + 1, depth + 1, open)?;
            lhs = self.apply(op, lhs, rhs, op_at)?;
        }
    }

    /// The operator at the cursor (after blanks) and its length in bytes; `None` at
    /// `]`.
    fn peek_op(&mut self, open: usize) -> Result<Option<(Op, usize)>, LexError> {
        let c = match self.peek() {
            None => {
                return Err(self.err(
                    open,
                    ErrorKind::BadNumber,
                    "'[' opened here is never closed",
                ))
            }
            Some(c) => c,
        };
        let start = self.i;
        let op = match c {
            b']' => return Ok(None),
            b'*' => {
                let mut j = start + 1;
                while let Some(b' ' | b'\t') = self.b.get(j) {
                    j += 1;
                }
                if self.b.get(j) == Some(&b'*') {
                    return Ok(Some((Op::Pow, j + 1 - start)));
                }
                Op::Mul
            }
            b'/' => Op::Div,
            b'+' => Op::Add,
            b'-' => Op::Sub,
            c if c.is_ascii_alphabetic() => {
                // Up to three letters, blanks allowed between them.
                let mut letters = [0u8; 3];
                let mut ends = [0usize; 3];
                let mut n = 0;
                let mut j = start;
                while n < 3 {
                    while let Some(b' ' | b'\t') = self.b.get(j) {
                        j += 1;
                    }
                    match self.b.get(j) {
                        Some(&l) if l.is_ascii_alphabetic() => {
                            letters[n] = l.to_ascii_uppercase();
                            j += 1;
                            ends[n] = j;
                            n += 1;
                        }
                        _ => break,
                    }
                }
                let three = match &letters[..n.min(3)] {
                    [b'M', b'O', b'D'] => Some(Op::Mod),
                    [b'A', b'N', b'D'] => Some(Op::And),
                    [b'X', b'O', b'R'] => Some(Op::Xor),
                    _ => None,
                };
                if let Some(op) = three {
                    return Ok(Some((op, ends[2] - start)));
                }
                let two = if n >= 2 {
                    match [letters[0], letters[1]] {
                        [b'E', b'Q'] => Some(Op::Eq),
                        [b'N', b'E'] => Some(Op::Ne),
                        [b'G', b'T'] => Some(Op::Gt),
                        [b'G', b'E'] => Some(Op::Ge),
                        [b'L', b'T'] => Some(Op::Lt),
                        [b'L', b'E'] => Some(Op::Le),
                        [b'O', b'R'] => Some(Op::Or),
                        _ => None,
                    }
                } else {
                    None
                };
                return match two {
                    Some(op) => Ok(Some((op, ends[1] - start))),
                    None => {
                        Err(self.unexpected(ErrorKind::BadNumber, "expected an operator or ']'"))
                    }
                };
            }
            _ => return Err(self.unexpected(ErrorKind::BadNumber, "expected an operator or ']'")),
        };
        Ok(Some((op, 1)))
    }

    fn apply(&self, op: Op, a: f64, b: f64, at: usize) -> Result<f64, LexError> {
        let bool = |v: bool| if v { 1.0 } else { 0.0 };
        let v = match op {
            Op::Pow => {
                if a < 0.0 && b.fract() != 0.0 {
                    return Err(self.err(
                        at,
                        ErrorKind::BadNumber,
                        "negative number raised to a fractional power",
                    ));
                }
                a.powf(b)
            }
            Op::Mul => a * b,
            Op::Div => {
                if b == 0.0 {
                    return Err(self.err(at, ErrorKind::BadNumber, "division by zero"));
                }
                a / b
            }
            Op::Mod => {
                if b == 0.0 {
                    return Err(self.err(at, ErrorKind::BadNumber, "division by zero (MOD 0)"));
                }
                let r = a % b;
                if r < 0.0 {
                    r + b.abs()
                } else {
                    r
                }
            }
            Op::Add => a + b,
            Op::Sub => a - b,
            Op::Eq => bool((a - b).abs() < EQUAL_TOLERANCE),
            Op::Ne => bool((a - b).abs() >= EQUAL_TOLERANCE),
            Op::Gt => bool(a > b),
            Op::Ge => bool(a >= b),
            Op::Lt => bool(a < b),
            Op::Le => bool(a <= b),
            Op::And => bool(a != 0.0 && b != 0.0),
            Op::Or => bool(a != 0.0 || b != 0.0),
            Op::Xor => bool((a != 0.0) != (b != 0.0)),
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(at, ErrorKind::OutOfRange, "expression result out of range"))
        }
    }

    /// `NAME[expr]`, `ATAN[y]/[x]` or `EXISTS[#<name>]`, at the first letter.
    fn function(&mut self, depth: usize) -> Result<f64, LexError> {
        let at = self.i;
        let mut name = [0u8; 6];
        let mut n = 0;
        loop {
            self.skip_blanks();
            match self.b.get(self.i) {
                Some(&l) if l.is_ascii_alphabetic() => {
                    if n == name.len() {
                        return Err(self.err(at, ErrorKind::UnknownCode, "unknown function"));
                    }
                    name[n] = l.to_ascii_uppercase();
                    n += 1;
                    self.i += 1;
                }
                _ => break,
            }
        }
        let name = &name[..n];
        let shown = String::from_utf8_lossy(name).into_owned();
        let known = matches!(
            name,
            b"ABS"
                | b"ACOS"
                | b"ASIN"
                | b"ATAN"
                | b"COS"
                | b"EXP"
                | b"FIX"
                | b"FUP"
                | b"LN"
                | b"ROUND"
                | b"SIN"
                | b"SQRT"
                | b"TAN"
                | b"EXISTS"
        );
        if !known {
            return Err(self.err(
                at,
                ErrorKind::UnknownCode,
                format!("unknown function {shown}"),
            ));
        }
        if self.peek() != Some(b'[') {
            return Err(
                self.unexpected(ErrorKind::BadNumber, &format!("expected '[' after {shown}"))
            );
        }
        if name == b"EXISTS" {
            return self.exists(depth);
        }
        let x = self.bracket(depth)?;
        let v = self.call(name, &shown, x, at, depth)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(
                at,
                ErrorKind::OutOfRange,
                format!("{shown} result out of range"),
            ))
        }
    }

    /// `EXISTS[#<name>]`, `EXISTS[#n]` or `EXISTS[##n]` (the number read from a
    /// parameter, which must itself be in range), at the `[`: 1 when the parameter
    /// exists.
    fn exists(&mut self, depth: usize) -> Result<f64, LexError> {
        let open = self.i;
        self.i += 1;
        if self.peek() != Some(b'#') {
            return Err(self.unexpected(
                ErrorKind::BadNumber,
                "expected #<name> or #number in EXISTS[…]",
            ));
        }
        self.i += 1;
        let digit = self.peek().is_some_and(|c| c.is_ascii_digit());
        if digit || self.peek() == Some(b'#') {
            // A numbered parameter: #1 … #5601 always exist (they read as 0 until
            // set), as in LinuxCNC; an indirect number out of range does not exist.
            let n: u64 = if digit {
                let start = self.i;
                while self.peek().is_some_and(|c| c.is_ascii_digit()) {
                    self.i += 1;
                }
                std::str::from_utf8(&self.b[start..self.i])
                    .ok()
                    .and_then(|d| d.parse().ok())
                    .unwrap_or(u64::MAX)
            } else {
                let v = self.operand(depth)?;
                Num::Real(v)
                    .whole()
                    .and_then(|n| u64::try_from(n).ok())
                    .unwrap_or(0)
            };
            return match self.peek() {
                Some(b']') => {
                    self.i += 1;
                    Ok(f64::from((1..NUM_PARAMS as u64).contains(&n) as u8))
                }
                None => Err(self.err(
                    open,
                    ErrorKind::BadNumber,
                    "'[' opened here is never closed",
                )),
                Some(_) => Err(self.unexpected(ErrorKind::BadNumber, "expected ']'")),
            };
        }
        if self.peek() != Some(b'<') {
            return Err(self.unexpected(
                ErrorKind::BadNumber,
                "expected #<name> or #number in EXISTS[…]",
            ));
        }
        let mut buf = NameBuf::new();
        self.name(&mut buf)?;
        match self.peek() {
            Some(b']') => {
                self.i += 1;
                Ok(if self.params.named(buf.as_slice()).is_some() {
                    1.0
                } else {
                    0.0
                })
            }
            None => Err(self.err(
                open,
                ErrorKind::BadNumber,
                "'[' opened here is never closed",
            )),
            Some(_) => Err(self.unexpected(ErrorKind::BadNumber, "expected ']'")),
        }
    }

    /// The value of function `name` (shown as `shown`, at byte `at`) of `x`, its
    /// bracketed argument; reads ATAN's second argument `/[x]`.
    fn call(
        &mut self,
        name: &[u8],
        shown: &str,
        x: f64,
        at: usize,
        depth: usize,
    ) -> Result<f64, LexError> {
        let deg = |v: f64| v.to_radians();
        Ok(match name {
            b"ABS" => x.abs(),
            b"ACOS" | b"ASIN" => {
                if !(-1.0..=1.0).contains(&x) {
                    return Err(self.err(
                        at,
                        ErrorKind::BadNumber,
                        format!("{shown} of {x}: outside -1 to 1"),
                    ));
                }
                if name == b"ACOS" {
                    x.acos().to_degrees()
                } else {
                    x.asin().to_degrees()
                }
            }
            b"ATAN" => {
                if self.peek() != Some(b'/') {
                    return Err(
                        self.unexpected(ErrorKind::BadNumber, "expected '/' in ATAN[y]/[x]")
                    );
                }
                self.i += 1;
                if self.peek() != Some(b'[') {
                    return Err(
                        self.unexpected(ErrorKind::BadNumber, "expected '[' in ATAN[y]/[x]")
                    );
                }
                let d = self.bracket(depth)?;
                x.atan2(d).to_degrees()
            }
            b"COS" => deg(x).cos(),
            b"EXP" => x.exp(),
            b"FIX" => x.floor(),
            b"FUP" => x.ceil(),
            b"LN" => {
                if x <= 0.0 {
                    return Err(self.err(
                        at,
                        ErrorKind::BadNumber,
                        format!("LN of {x}: not above zero"),
                    ));
                }
                x.ln()
            }
            b"ROUND" => x.round(),
            b"SIN" => deg(x).sin(),
            b"SQRT" => {
                if x < 0.0 {
                    return Err(self.err(
                        at,
                        ErrorKind::BadNumber,
                        format!("SQRT of {x}: below zero"),
                    ));
                }
                x.sqrt()
            }
            _ => deg(x).tan(),
        })
    }

    /// `#…` read, at the `#`.
    fn param_read(&mut self, depth: usize) -> Result<f64, LexError> {
        let at = self.i;
        self.i += 1;
        if self.peek() == Some(b'<') {
            let mut buf = NameBuf::new();
            self.name(&mut buf)?;
            return self.params.named(buf.as_slice()).ok_or_else(|| {
                self.err(
                    at,
                    ErrorKind::Parameter,
                    format!(
                        "unknown parameter #<{}> (read before it was set)",
                        String::from_utf8_lossy(buf.as_slice())
                    ),
                )
            });
        }
        let n = self.param_index(depth)?;
        Ok(self.params.numbered(n))
    }

    /// The index after `#` of a numbered parameter (a value, itself possibly a
    /// parameter or expression), checked against the parameter range.
    pub(super) fn param_index(&mut self, depth: usize) -> Result<usize, LexError> {
        let at = self.i;
        let v = match self.peek() {
            Some(b'0'..=b'9' | b'.') => self.literal(at)?,
            // An expression, a parameter or a function call (`#ATAN[1]/[1]` is #45): any
            // value, as in LinuxCNC.
            Some(c) if c == b'[' || c == b'#' || c.is_ascii_alphabetic() => {
                Num::Real(self.operand(depth)?)
            }
            _ => {
                return Err(self.unexpected(
                    ErrorKind::BadNumber,
                    "expected a parameter number or <name> after '#'",
                ))
            }
        };
        match v.whole() {
            Some(n) if n >= 1 && (n as u64) < NUM_PARAMS as u64 => Ok(n as usize),
            _ => Err(self.err(
                at,
                ErrorKind::Parameter,
                format!(
                    "parameter number {v} out of range (1 to {})",
                    NUM_PARAMS - 1
                ),
            )),
        }
    }

    /// `<name>`, at the `<`: lower-cased, blanks dropped, into `buf`.
    pub(super) fn name(&mut self, buf: &mut NameBuf) -> Result<(), LexError> {
        let open = self.i;
        self.i += 1;
        loop {
            match self.b.get(self.i) {
                None => {
                    return Err(self.err(
                        open,
                        ErrorKind::BadNumber,
                        "'<' of a parameter name is never closed",
                    ))
                }
                Some(b'>') => {
                    self.i += 1;
                    break;
                }
                Some(b' ' | b'\t') => {}
                Some(&c) if c < 0x20 || c == 0x7f => return Err(self.control(self.i)),
                Some(&c) => buf.push(c.to_ascii_lowercase()),
            }
            self.i += 1;
        }
        if buf.len == 0 {
            return Err(self.err(open, ErrorKind::BadNumber, "empty parameter name"));
        }
        Ok(())
    }
}

/// A parameter name on the stack (names are shorter than a line).
pub(super) struct NameBuf {
    bytes: [u8; crate::gcode::MAX_LINE],
    len: usize,
}

impl NameBuf {
    pub(super) fn new() -> Self {
        Self {
            bytes: [0; crate::gcode::MAX_LINE],
            len: 0,
        }
    }
    pub(super) fn push(&mut self, c: u8) {
        if let Some(slot) = self.bytes.get_mut(self.len) {
            *slot = c;
            self.len += 1;
        }
    }
    pub(super) fn as_slice(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}
