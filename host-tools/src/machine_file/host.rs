//! `host_timeout_s`: how long the controller waits for a silent host before it holds a
//! streamed job for take-over (the job starves on the path meanwhile; docs/safety.md).
//! Sent with each program (`Control::BeginJob`), not stored in the machine's record.

use super::{line_of_field, read, read_file, FieldError, MachineFile, MachineFileError};
use pkmc::controller::{DEFAULT_HOST_TIMEOUT_MS, MAX_HOST_TIMEOUT_MS, MIN_HOST_TIMEOUT_MS};
use std::path::Path;
use std::time::Duration;

/// The host timeout of a machine file that does not give one.
pub const DEFAULT_HOST_TIMEOUT: Duration = Duration::from_millis(DEFAULT_HOST_TIMEOUT_MS as u64);

impl MachineFile {
    /// `host_timeout_s`, checked: from the controller's shortest to its longest.
    pub fn host_timeout(&self) -> Result<Duration, FieldError> {
        let Some(s) = self.host_timeout_s else {
            return Ok(DEFAULT_HOST_TIMEOUT);
        };
        let (min, max) = (
            MIN_HOST_TIMEOUT_MS as f64 / 1000.0,
            MAX_HOST_TIMEOUT_MS as f64 / 1000.0,
        );
        if !(s.is_finite() && (min..=max).contains(&s)) {
            return Err(FieldError(format!(
                "host_timeout_s: must be from {min} to {max} seconds (how long a streamed \
                 job waits for a silent host before it is held), got {s}"
            )));
        }
        Ok(Duration::from_secs_f64(s))
    }
}

/// The host timeout of the machine file at `path`.
pub fn load_host_timeout(path: &Path) -> Result<Duration, MachineFileError> {
    let text = read(path)?;
    let origin = path.display().to_string();
    let file = read_file(&text, &origin)?;
    file.host_timeout()
        .map_err(|error| MachineFileError::Invalid {
            line: line_of_field(&text, &error.0),
            origin,
            error,
        })
}

#[cfg(test)]
mod tests {
    use super::super::{read_file, DEFAULT_MACHINE};
    use super::*;

    fn with(line: &str) -> Result<Duration, FieldError> {
        let text = format!("{line}\n{DEFAULT_MACHINE}");
        read_file(&text, "m.toml").unwrap().host_timeout()
    }

    #[test]
    fn the_host_timeout_defaults_to_thirty_seconds_and_is_read_in_seconds() {
        assert_eq!(with("").unwrap(), Duration::from_secs(30));
        assert_eq!(
            with("host_timeout_s = 5.5").unwrap(),
            Duration::from_millis(5500)
        );
    }

    #[test]
    fn a_host_timeout_out_of_range_is_refused_naming_the_field() {
        for bad in ["0", "1.5", "-3", "4000", "nan", "inf"] {
            let e = with(&format!("host_timeout_s = {bad}")).unwrap_err().0;
            assert!(
                e.starts_with("host_timeout_s: must be from 2 to 3600"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn a_host_timeout_refused_in_a_file_names_its_line() {
        let dir = std::env::temp_dir().join(format!("pkmc-host-timeout-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("m.toml");
        std::fs::write(&p, format!("host_timeout_s = 0.1\n{DEFAULT_MACHINE}")).unwrap();
        let e = load_host_timeout(&p).unwrap_err().to_string();
        assert!(e.contains("m.toml:1: host_timeout_s: must be"), "{e}");
    }
}
