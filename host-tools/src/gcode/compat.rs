//! Temporary compatibility with the first `compile(source, file, start)` API, which
//! returned protocol blocks: `job.rs` and the end-to-end tests still call it. Remove
//! the `[i64; AXES]` implementation once they call `compile(…, &Options)` and convert
//! with [`crate::blocks::from_canon`] themselves.

use super::{compile_canon, Diagnostic, Options};
use crate::canon::Canon;
use pkmc::config::AXES;
use pkmc::protocol::Block;

/// What [`super::compile`] accepts as options, and what it returns for them.
pub trait CompileWith {
    /// The result.
    type Output;
    /// Compiles `source`, naming `file` in diagnostics.
    fn compile(self, source: &str, file: &str) -> Self::Output;
}

impl CompileWith for &Options {
    type Output = Result<Vec<Canon>, Vec<Diagnostic>>;
    fn compile(self, source: &str, file: &str) -> Self::Output {
        compile_canon(source, file, self)
    }
}

/// Temporary: a start pose selects the old output, protocol blocks (through
/// [`crate::blocks::from_canon`], operator messages dropped), with default options.
impl CompileWith for [i64; AXES] {
    type Output = Result<Vec<Block>, Vec<Diagnostic>>;
    fn compile(self, source: &str, file: &str) -> Self::Output {
        let options = Options {
            start: self,
            ..Options::default()
        };
        let canon = compile_canon(source, file, &options)?;
        Ok(crate::blocks::from_canon(&canon, self).blocks)
    }
}
