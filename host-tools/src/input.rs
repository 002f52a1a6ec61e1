//! Reading input files with a bound: a program or machine file is read in chunks up
//! to a size limit, and refused at the first NUL byte (binary data, or a device such
//! as `/dev/zero` that never ends), so no input can make `nc-send` or `pkmc-sim` read
//! without bound.

use std::io::Read;
use std::path::Path;

/// Largest G-code program read, bytes (256 MiB: the largest CAM programs in the
/// corpus are a few tens of MiB).
pub const MAX_PROGRAM_BYTES: u64 = 256 << 20;
/// Largest machine file read, bytes.
pub const MAX_MACHINE_FILE_BYTES: u64 = 1 << 20;

/// Why a file was not read.
#[derive(Debug)]
pub enum ReadError {
    /// The file could not be opened or read.
    Io(std::io::Error),
    /// Longer than the limit, bytes.
    TooLarge(u64),
    /// A NUL byte at this 1-based line and column: binary data, not text.
    Binary {
        /// Line.
        line: usize,
        /// Column.
        col: usize,
    },
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReadError::Io(e) => write!(f, "cannot read: {e}"),
            ReadError::TooLarge(limit) => {
                write!(f, "larger than {} MiB: refused", limit >> 20)
            }
            ReadError::Binary { line, col } => {
                write!(f, "{line}:{col}: NUL byte (binary data, not text)")
            }
        }
    }
}

impl std::error::Error for ReadError {}

/// The bytes of the file at `path`, at most `limit` of them, with no NUL byte.
pub fn read_bounded(path: &Path, limit: u64) -> Result<Vec<u8>, ReadError> {
    let file = std::fs::File::open(path).map_err(ReadError::Io)?;
    let mut reader = file.take(limit + 1);
    let mut bytes = Vec::new();
    let mut chunk = vec![0u8; 64 << 10];
    loop {
        let n = match reader.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(ReadError::Io(e)),
        };
        if let Some(i) = chunk[..n].iter().position(|&b| b == 0) {
            let at = bytes.len() + i;
            bytes.extend_from_slice(&chunk[..i]);
            let line = bytes.iter().filter(|&&b| b == b'\n').count() + 1;
            let col = at - bytes.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1) + 1;
            return Err(ReadError::Binary { line, col });
        }
        bytes.extend_from_slice(&chunk[..n]);
        if bytes.len() as u64 > limit {
            return Err(ReadError::TooLarge(limit));
        }
    }
    Ok(bytes)
}

/// [`read_bounded`] as UTF-8 text (an error names the line and column of the first
/// byte that is not).
pub fn read_text(path: &Path, limit: u64) -> Result<String, String> {
    let name = path.display();
    let bytes = read_bounded(path, limit).map_err(|e| match e {
        ReadError::Binary { .. } => format!("{name}:{e}"),
        _ => format!("{name}: {e}"),
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let before = &e.as_bytes()[..at];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let col = at
            - before
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |p| p + 1)
            + 1;
        format!("{name}:{line}:{col}: not text (invalid UTF-8)")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_endless_device_is_refused_at_its_first_nul_byte() {
        let e = read_text(Path::new("/dev/zero"), MAX_PROGRAM_BYTES).unwrap_err();
        assert_eq!(e, "/dev/zero:1:1: NUL byte (binary data, not text)");
    }

    #[test]
    fn a_file_over_the_limit_is_refused_and_one_at_it_is_read() {
        let p = std::env::temp_dir().join(format!("pkmc-input-{}.txt", std::process::id()));
        std::fs::write(&p, "G1 X1\n".repeat(100)).unwrap();
        assert!(read_text(&p, 600).is_ok());
        let e = read_text(&p, 599).unwrap_err();
        assert!(e.ends_with("larger than 0 MiB: refused"), "{e}");
        std::fs::remove_file(&p).unwrap();
    }
}
