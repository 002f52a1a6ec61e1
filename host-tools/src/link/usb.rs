//! The board's USB identity: finding its port among this computer's serial ports, at
//! the start (`nc-send` without `--port`) and again after a replug, when the port may
//! come back under another name (`/dev/ttyACM0` then `/dev/ttyACM1`) but keeps its USB
//! serial number.
//!
//! The firmware enumerates as a USB CDC-ACM device with VID 0x1209 (pid.codes) and PID
//! 0x0001, manufacturer "pkmc", product "pkmc motion controller"
//! (`src/bin/firmware/board.rs`). Two sources name it:
//! - `serialport`'s list of ports: built without libudev, on Linux it scans
//!   `/sys/class/tty` and reads `idVendor`, `idProduct` and `serial` from each USB
//!   port's sysfs directory (serialport 4.10, `src/posix/enumerate.rs`). It panics
//!   when `/sys/class/tty` is missing (a container without sysfs): that case is taken
//!   as "no ports" here.
//! - udev's `/dev/serial/by-id` directory of links named
//!   `usb-<manufacturer>_<product>_<serial>-if<interface>`, blanks made `_` (systemd's
//!   `60-serial.rules`). `PKMC_SERIAL_BY_ID` names another directory of that form (the
//!   virtual board's `--by-id`).

use serialport::{SerialPortInfo, SerialPortType};
use std::path::{Path, PathBuf};

/// USB vendor ID of the board (pid.codes).
pub const USB_VID: u16 = 0x1209;
/// USB product ID of the board (pid.codes test PID).
pub const USB_PID: u16 = 0x0001;
/// How the board's manufacturer and product strings begin its `/dev/serial/by-id` name.
const BY_ID_PREFIX: &str = "usb-pkmc_pkmc_motion_controller_";

/// A controller board found on USB.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Found {
    /// Port to open, e.g. `/dev/ttyACM0`.
    pub port: String,
    /// USB serial number, if the device has one.
    pub serial: Option<String>,
}

/// The boards among `ports`.
pub fn controllers(ports: &[SerialPortInfo]) -> Vec<Found> {
    ports
        .iter()
        .filter_map(|p| match &p.port_type {
            SerialPortType::UsbPort(u) if u.vid == USB_VID && u.pid == USB_PID => Some(Found {
                port: p.port_name.clone(),
                serial: u.serial_number.clone(),
            }),
            _ => None,
        })
        .collect()
}

/// Lists the serial ports of this computer.
pub fn list_ports() -> Result<Vec<SerialPortInfo>, String> {
    if cfg!(target_os = "linux") && !Path::new("/sys/class/tty").is_dir() {
        return Ok(Vec::new());
    }
    serialport::available_ports().map_err(|e| e.to_string())
}

/// The directory of links named by USB identity.
fn by_id_dir() -> PathBuf {
    std::env::var_os("PKMC_SERIAL_BY_ID").map_or_else(|| "/dev/serial/by-id".into(), PathBuf::from)
}

/// The serial number in a `/dev/serial/by-id` name of the board, if it is one.
pub fn serial_of_by_id_name(name: &str) -> Option<&str> {
    let rest = name.strip_prefix(BY_ID_PREFIX)?;
    let (serial, interface) = rest.rsplit_once("-if")?;
    (!serial.is_empty() && !interface.is_empty() && interface.bytes().all(|b| b.is_ascii_digit()))
        .then_some(serial)
}

/// The boards named in the by-id directory, each with the port its link points at.
pub fn by_id() -> Vec<Found> {
    let Ok(entries) = std::fs::read_dir(by_id_dir()) else {
        return Vec::new();
    };
    let mut found: Vec<Found> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let serial = serial_of_by_id_name(&name)?.to_string();
            let port = std::fs::canonicalize(e.path()).ok()?;
            Some(Found {
                port: port.to_str()?.to_string(),
                serial: Some(serial),
            })
        })
        .collect();
    found.sort_by(|a, b| a.port.cmp(&b.port));
    found
}

/// Every board attached: those the port list names, else those the by-id directory
/// names.
pub fn boards() -> Result<Vec<Found>, String> {
    let listed = controllers(&list_ports()?);
    Ok(if listed.is_empty() { by_id() } else { listed })
}

/// The port of the board with USB serial number `serial`, if it is attached now.
pub fn port_of(serial: &str) -> Option<String> {
    let found = boards().ok()?;
    found
        .into_iter()
        .find(|f| f.serial.as_deref() == Some(serial))
        .map(|f| f.port)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_by_id_name_of_the_board_gives_its_serial_number_and_others_none() {
        let name = "usb-pkmc_pkmc_motion_controller_pkmc-g474-0001-if00";
        assert_eq!(serial_of_by_id_name(name), Some("pkmc-g474-0001"));
        assert_eq!(
            serial_of_by_id_name("usb-FTDI_FT232R_USB_UART_A10K1-if00-port0"),
            None
        );
        assert_eq!(
            serial_of_by_id_name("usb-pkmc_pkmc_motion_controller_-if00"),
            None
        );
        assert_eq!(
            serial_of_by_id_name("usb-pkmc_pkmc_motion_controller_x-ifzz"),
            None
        );
    }
}
