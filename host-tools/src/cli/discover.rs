//! Finding the controller board by its USB identity when no port is given
//! ([`crate::link::usb`] lists the boards attached).

pub use crate::link::usb::{controllers, Found, USB_PID, USB_VID};
use serialport::SerialPortInfo;
use std::fmt;

/// Why no single controller could be chosen.
#[derive(Debug, PartialEq, Eq)]
pub enum DiscoverError {
    /// The ports could not be listed.
    Enumerate(String),
    /// No port has the board's USB identity.
    NoneFound {
        /// Serial ports seen (of other devices).
        others: Vec<String>,
    },
    /// More than one board: the user must choose.
    Several(Vec<Found>),
}

impl fmt::Display for DiscoverError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DiscoverError::Enumerate(e) => write!(f, "cannot list the serial ports: {e}"),
            DiscoverError::NoneFound { others } => {
                write!(
                    f,
                    "no pkmc controller found (no USB serial port with ID {USB_VID:04x}:{USB_PID:04x}); \
                     connect the board, or give --port DEV (or --sim for the simulator)"
                )?;
                if !others.is_empty() {
                    write!(f, "; other serial ports: {}", others.join(", "))?;
                }
                Ok(())
            }
            DiscoverError::Several(found) => {
                let list: Vec<String> = found
                    .iter()
                    .map(|c| match &c.serial {
                        Some(s) => format!("{} (serial {s})", c.port),
                        None => c.port.clone(),
                    })
                    .collect();
                write!(
                    f,
                    "several pkmc controllers found: {}; choose one with --port DEV",
                    list.join(", ")
                )
            }
        }
    }
}

impl std::error::Error for DiscoverError {}

/// Chooses the one board among `ports`.
pub fn choose(ports: &[SerialPortInfo]) -> Result<Found, DiscoverError> {
    let mut found = controllers(ports);
    match found.len() {
        0 => Err(DiscoverError::NoneFound {
            others: ports.iter().map(|p| p.port_name.clone()).collect(),
        }),
        1 => Ok(found.remove(0)),
        _ => Err(DiscoverError::Several(found)),
    }
}

/// Lists the serial ports of this computer.
pub fn list_ports() -> Result<Vec<SerialPortInfo>, DiscoverError> {
    crate::link::usb::list_ports().map_err(DiscoverError::Enumerate)
}

/// Finds the one board attached to this computer: among the serial ports, else in the
/// by-id directory ([`crate::link::usb::by_id`]).
pub fn find() -> Result<Found, DiscoverError> {
    let ports = list_ports()?;
    if controllers(&ports).is_empty() {
        let mut named = crate::link::usb::by_id();
        match named.len() {
            0 => {}
            1 => return Ok(named.remove(0)),
            _ => return Err(DiscoverError::Several(named)),
        }
    }
    choose(&ports)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serialport::{SerialPortType, UsbPortInfo};

    fn usb(name: &str, vid: u16, pid: u16, serial: Option<&str>) -> SerialPortInfo {
        SerialPortInfo {
            port_name: name.into(),
            port_type: SerialPortType::UsbPort(UsbPortInfo {
                vid,
                pid,
                serial_number: serial.map(String::from),
                manufacturer: None,
                product: None,
            }),
        }
    }

    #[test]
    fn the_board_is_chosen_by_its_vendor_and_product_id() {
        let ports = vec![
            usb("/dev/ttyUSB0", 0x0403, 0x6001, None),
            usb("/dev/ttyACM1", USB_VID, USB_PID, Some("pkmc-g474-0001")),
            SerialPortInfo {
                port_name: "/dev/ttyS0".into(),
                port_type: SerialPortType::Unknown,
            },
        ];
        assert_eq!(
            choose(&ports),
            Ok(Found {
                port: "/dev/ttyACM1".into(),
                serial: Some("pkmc-g474-0001".into())
            })
        );
    }

    #[test]
    fn no_board_is_an_error_that_lists_the_other_ports() {
        let ports = vec![usb("/dev/ttyUSB0", 0x0403, 0x6001, None)];
        let e = choose(&ports).unwrap_err();
        let text = e.to_string();
        assert!(text.contains("no pkmc controller found"), "{text}");
        assert!(text.contains("1209:0001"), "{text}");
        assert!(text.contains("/dev/ttyUSB0"), "{text}");
    }

    #[test]
    fn two_boards_ask_the_user_to_choose() {
        let ports = vec![
            usb("/dev/ttyACM0", USB_VID, USB_PID, Some("a")),
            usb("/dev/ttyACM1", USB_VID, USB_PID, Some("b")),
        ];
        let text = choose(&ports).unwrap_err().to_string();
        assert!(
            text.contains("/dev/ttyACM0 (serial a), /dev/ttyACM1 (serial b)"),
            "{text}"
        );
    }
}
