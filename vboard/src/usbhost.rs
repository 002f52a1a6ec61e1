//! The USB host side: what a PC's host controller and its CDC-ACM driver do to the
//! device. It sees the device attach (D+ pull-up), resets it, enumerates it — reads
//! and checks the device, configuration and string descriptors (1209:0001, one CDC-ACM
//! function with a bulk IN/OUT pair), sets the address, the configuration, the line
//! coding and DTR/RTS — then moves bytes between the bulk endpoints and a byte queue
//! each way (the pseudo-terminal's). It can be unplugged and plugged in again.
//!
//! Timing (USB 2.0 specification, "Connect and Disconnect Signaling", "Reset
//! Signaling" and "Request Processing"): attach debounce 100 ms (TATTDB),
//! reset 10 ms (TDRST), 10 ms recovery (TRSTRCY), 2 ms after SET_ADDRESS (TDSETADDR),
//! a start of frame every 1 ms. Transactions are tried at every service of the host
//! (the board's USB service interval); a NAK is tried again at the next.

use crate::periph::usb::{Handshake, UsbDevice};
use crate::time::from_ms;
use std::collections::VecDeque;

/// The device identity the host expects.
pub const VID: u16 = 0x1209;
/// Product ID.
pub const PID: u16 = 0x0001;

/// A control transfer in progress.
#[derive(Debug)]
struct Control {
    setup: [u8; 8],
    /// Data for an OUT data stage.
    out: Vec<u8>,
    /// Data received in an IN data stage.
    got: Vec<u8>,
    stage: Stage,
}

#[derive(Debug, PartialEq, Eq, Clone, Copy)]
enum Stage {
    Setup,
    DataIn,
    DataOut,
    StatusIn,
    StatusOut,
    Done,
}

/// Where the host is.
#[derive(Debug, PartialEq, Eq, Clone, Copy)]
pub enum Phase {
    /// Nothing attached (or the cable is out).
    Detached,
    /// Attach seen; debouncing until then.
    Debounce(u64),
    /// Resetting the bus until then.
    Reset(u64),
    /// Enumeration step k, not before the given time.
    Enumerate(usize, u64),
    /// Configured: bulk traffic flows.
    Configured,
    /// Enumeration failed; the reason is in the log.
    Failed,
}

/// The host.
pub struct Host {
    /// Where it is.
    pub phase: Phase,
    /// The cable is plugged in.
    pub plugged: bool,
    address: u8,
    control: Option<Control>,
    /// Bulk endpoints: IN, OUT; interface of the CDC communication class.
    bulk_in: u8,
    bulk_out: u8,
    comm_interface: u16,
    config_value: u8,
    config_len: u16,
    /// Bytes from the device, for the pseudo-terminal.
    pub from_device: VecDeque<u8>,
    /// Bytes for the device, from the pseudo-terminal.
    pub to_device: VecDeque<u8>,
    next_sof: u64,
    last_frame: u64,
    /// What happened, for the log.
    pub log: Vec<String>,
    /// Time the device was configured (virtual), per enumeration.
    pub configured_at: Vec<u64>,
    /// Bulk packets moved each way (in: from the device).
    pub packets: (u64, u64),
    /// Bulk bytes moved each way (in: from the device).
    pub bytes: (u64, u64),
    /// Frames (COBS-delimited: a zero byte ends each) delivered to the device.
    pub frames_out: u64,
    strings: Vec<String>,
}

impl Default for Host {
    fn default() -> Self {
        Self {
            phase: Phase::Detached,
            plugged: true,
            address: 0,
            control: None,
            bulk_in: 0,
            bulk_out: 0,
            comm_interface: 0,
            config_value: 1,
            config_len: 0,
            from_device: VecDeque::new(),
            to_device: VecDeque::new(),
            next_sof: 0,
            last_frame: 0,
            log: Vec::new(),
            configured_at: Vec::new(),
            packets: (0, 0),
            bytes: (0, 0),
            frames_out: 0,
            strings: Vec::new(),
        }
    }
}

fn setup(request_type: u8, request: u8, value: u16, index: u16, length: u16) -> [u8; 8] {
    let mut s = [request_type, request, 0, 0, 0, 0, 0, 0];
    s[2..4].copy_from_slice(&value.to_le_bytes());
    s[4..6].copy_from_slice(&index.to_le_bytes());
    s[6..8].copy_from_slice(&length.to_le_bytes());
    s
}

fn le16(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes([
        b.get(o).copied().unwrap_or(0),
        b.get(o + 1).copied().unwrap_or(0),
    ])
}

impl Host {
    /// The device's name as udev's `/dev/serial/by-id` gives it:
    /// `usb-<manufacturer>_<product>_<serial>-if<interface>`, blanks made `_` (systemd's
    /// `60-serial.rules` and `usb_id`); `None` before its strings were read.
    pub fn by_id_name(&self) -> Option<String> {
        if self.strings.len() < 3 {
            return None;
        }
        let id = self.strings[..3]
            .join("_")
            .replace(char::is_whitespace, "_");
        Some(format!("usb-{id}-if{:02}", self.comm_interface))
    }

    fn fail(&mut self, why: String) {
        self.log.push(format!("enumeration failed: {why}"));
        self.phase = Phase::Failed;
        self.control = None;
    }

    /// Pulls the cable (`false`) or plugs it in (`true`).
    pub fn plug(&mut self, plugged: bool, now: u64) {
        self.plugged = plugged;
        self.log.push(format!(
            "{} at {:.3} s",
            if plugged {
                "cable plugged in"
            } else {
                "cable pulled"
            },
            crate::time::to_s(now)
        ));
        if !plugged {
            self.phase = Phase::Detached;
            self.control = None;
        }
    }

    /// One service of the host at `now`.
    pub fn service(&mut self, dev: &mut UsbDevice, now: u64) {
        let attached = self.plugged && dev.attached();
        if !attached {
            if self.phase != Phase::Detached {
                self.log.push("device detached".into());
            }
            self.phase = Phase::Detached;
            if !self.plugged && now >= self.last_frame + from_ms(3) && self.last_frame != 0 {
                dev.suspend();
                self.last_frame = 0;
            }
            return;
        }
        if now >= self.next_sof && matches!(self.phase, Phase::Enumerate(..) | Phase::Configured) {
            dev.sof();
            self.next_sof = now + from_ms(1);
            self.last_frame = now;
        }
        match self.phase {
            Phase::Detached => self.phase = Phase::Debounce(now + from_ms(100)),
            Phase::Debounce(t) if now >= t => {
                dev.bus_reset();
                self.address = 0;
                self.phase = Phase::Reset(now + from_ms(10));
            }
            Phase::Reset(t) if now >= t => {
                self.strings.clear();
                self.phase = Phase::Enumerate(0, now + from_ms(10));
            }
            Phase::Enumerate(step, t) if now >= t => self.enumerate(dev, step, now),
            Phase::Configured => self.bulk(dev),
            _ => {}
        }
    }

    /// Runs the control transfer in progress one transaction further; returns its data
    /// (IN) when done.
    fn control(&mut self, dev: &mut UsbDevice) -> Result<Option<Vec<u8>>, String> {
        let addr = self.address;
        let Some(c) = self.control.as_mut() else {
            return Ok(None);
        };
        let length = usize::from(le16(&c.setup, 6));
        let input = c.setup[0] & 0x80 != 0;
        match c.stage {
            Stage::Setup => match dev.setup(addr, 0, &c.setup) {
                Handshake::Ack(_) => {
                    c.stage = match (length, input) {
                        (0, _) => Stage::StatusIn,
                        (_, true) => Stage::DataIn,
                        (_, false) => Stage::DataOut,
                    };
                }
                h => return Err(format!("SETUP {:02x?}: {h:?}", c.setup)),
            },
            Stage::DataIn => match dev.input(addr, 0) {
                Handshake::Ack(d) => {
                    let short = d.len() < 64;
                    c.got.extend_from_slice(&d);
                    if short || c.got.len() >= length {
                        c.stage = Stage::StatusOut;
                    }
                }
                Handshake::Nak => {}
                h => return Err(format!("IN data of {:02x?}: {h:?}", c.setup)),
            },
            Stage::DataOut => {
                let n = c.out.len().min(64);
                match dev.out(addr, 0, &c.out[..n]) {
                    Handshake::Ack(_) => {
                        c.out.drain(..n);
                        if c.out.is_empty() {
                            c.stage = Stage::StatusIn;
                        }
                    }
                    Handshake::Nak => {}
                    h => return Err(format!("OUT data of {:02x?}: {h:?}", c.setup)),
                }
            }
            Stage::StatusOut => match dev.out(addr, 0, &[]) {
                Handshake::Ack(_) => c.stage = Stage::Done,
                Handshake::Nak => {}
                h => return Err(format!("status OUT of {:02x?}: {h:?}", c.setup)),
            },
            Stage::StatusIn => match dev.input(addr, 0) {
                Handshake::Ack(d) if d.is_empty() => c.stage = Stage::Done,
                Handshake::Ack(d) => {
                    return Err(format!(
                        "status IN of {:02x?} carried {} bytes",
                        c.setup,
                        d.len()
                    ))
                }
                Handshake::Nak => {}
                h => return Err(format!("status IN of {:02x?}: {h:?}", c.setup)),
            },
            Stage::Done => {}
        }
        if c.stage == Stage::Done {
            let got = std::mem::take(&mut c.got);
            self.control = None;
            return Ok(Some(got));
        }
        Ok(None)
    }

    fn start(&mut self, s: [u8; 8], out: Vec<u8>) {
        self.control = Some(Control {
            setup: s,
            out,
            got: Vec::new(),
            stage: Stage::Setup,
        });
    }

    /// The enumeration's steps: each starts a control transfer, then checks its
    /// answer and moves on.
    fn enumerate(&mut self, dev: &mut UsbDevice, step: usize, now: u64) {
        if self.control.is_none() {
            let s = match step {
                0 => setup(0x80, 6, 0x0100, 0, 64),
                1 => setup(0x00, 5, 1, 0, 0),
                2 => setup(0x80, 6, 0x0100, 0, 18),
                3 => setup(0x80, 6, 0x0200, 0, 9),
                4 => setup(0x80, 6, 0x0200, 0, self.config_len),
                5 => setup(0x80, 6, 0x0300, 0, 255),
                6..=8 => setup(0x80, 6, 0x0300 | (step as u16 - 5), 0x0409, 255),
                9 => setup(0x00, 9, u16::from(self.config_value), 0, 0),
                10 => {
                    // SET_LINE_CODING: 115 200 baud, 1 stop bit, no parity, 8 bits.
                    let s = setup(0x21, 0x20, 0, self.comm_interface, 7);
                    let mut coding = 115_200u32.to_le_bytes().to_vec();
                    coding.extend_from_slice(&[0, 0, 8]);
                    self.start(s, coding);
                    return;
                }
                11 => setup(0x21, 0x22, 3, self.comm_interface, 0),
                _ => {
                    self.phase = Phase::Configured;
                    self.configured_at.push(now);
                    self.log.push(format!(
                        "configured at {:.4} s: CDC-ACM, bulk IN {:#04x}, OUT {:#04x}; {}",
                        crate::time::to_s(now),
                        self.bulk_in | 0x80,
                        self.bulk_out,
                        self.strings.join(" / ")
                    ));
                    return;
                }
            };
            self.start(s, Vec::new());
            return;
        }
        let got = match self.control(dev) {
            Ok(Some(g)) => g,
            Ok(None) => return,
            Err(e) => return self.fail(e),
        };
        let mut next_at = now;
        match step {
            0 if got.len() < 8 || got[1] != 1 => {
                return self.fail(format!("device descriptor header {got:02x?}"))
            }
            1 => {
                self.address = 1;
                next_at = now + from_ms(2);
            }
            2 => {
                if let Err(e) = check_device(&got) {
                    return self.fail(e);
                }
            }
            3 if got.len() < 9 || got[1] != 2 => {
                return self.fail(format!("configuration descriptor {got:02x?}"))
            }
            3 => {
                self.config_len = le16(&got, 2);
                self.config_value = got[5];
            }
            4 => match parse_config(&got) {
                Ok((comm, bulk_in, bulk_out)) => {
                    self.comm_interface = comm;
                    self.bulk_in = bulk_in;
                    self.bulk_out = bulk_out;
                }
                Err(e) => return self.fail(e),
            },
            5 if got.len() < 4 || le16(&got, 2) != 0x0409 => {
                return self.fail(format!("language IDs {got:02x?}"))
            }
            6..=8 => self.strings.push(utf16(&got)),
            _ => {}
        }
        self.phase = Phase::Enumerate(step + 1, next_at);
    }

    fn bulk(&mut self, dev: &mut UsbDevice) {
        if !self.to_device.is_empty() {
            let n = self.to_device.len().min(64);
            let chunk: Vec<u8> = self.to_device.iter().take(n).copied().collect();
            match dev.out(self.address, self.bulk_out, &chunk) {
                Handshake::Ack(_) => {
                    self.to_device.drain(..n);
                    self.packets.1 += 1;
                    self.bytes.1 += n as u64;
                    self.frames_out += chunk.iter().filter(|&&b| b == 0).count() as u64;
                }
                Handshake::Nak => {}
                h => self.log.push(format!("bulk OUT: {h:?}")),
            }
        }
        loop {
            match dev.input(self.address, self.bulk_in) {
                Handshake::Ack(d) => {
                    self.packets.0 += 1;
                    self.bytes.0 += d.len() as u64;
                    self.from_device.extend(d);
                    if !dev.valid(self.bulk_in, false) {
                        break;
                    }
                }
                Handshake::Nak => break,
                h => {
                    self.log.push(format!("bulk IN: {h:?}"));
                    break;
                }
            }
        }
    }
}

fn utf16(d: &[u8]) -> String {
    let units: Vec<u16> = d
        .get(2..)
        .unwrap_or(&[])
        .chunks(2)
        .map(|c| le16(c, 0))
        .collect();
    String::from_utf16_lossy(&units)
}

fn check_device(d: &[u8]) -> Result<(), String> {
    if d.len() != 18 || d[0] != 18 || d[1] != 1 {
        return Err(format!("device descriptor {d:02x?}"));
    }
    let (vid, pid) = (le16(d, 8), le16(d, 10));
    if (vid, pid) != (VID, PID) {
        return Err(format!(
            "device {vid:04x}:{pid:04x}, expected {VID:04x}:{PID:04x}"
        ));
    }
    if d[7] != 64 {
        return Err(format!("EP0 max packet {}", d[7]));
    }
    Ok(())
}

/// The CDC-ACM function of a configuration: its communication interface and bulk
/// endpoints (IN, OUT), checked to be a CDC ACM (class 2, subclass 2) with a CDC data
/// interface (class 10) carrying a bulk IN and a bulk OUT endpoint.
fn parse_config(d: &[u8]) -> Result<(u16, u8, u8), String> {
    let mut i = 0;
    let mut comm = None;
    let mut class = 0;
    let (mut bulk_in, mut bulk_out) = (None, None);
    while i + 2 <= d.len() {
        let len = usize::from(d[i]);
        if len < 2 || i + len > d.len() {
            return Err(format!(
                "descriptor at byte {i} of the configuration is malformed"
            ));
        }
        match d[i + 1] {
            4 => {
                class = d[i + 5];
                if class == 2 && d[i + 6] == 2 {
                    comm = Some(u16::from(d[i + 2]));
                }
            }
            5 if class == 10 && d[i + 3] & 3 == 2 => {
                let ep = d[i + 2];
                if ep & 0x80 != 0 {
                    bulk_in = Some(ep & 0xF);
                } else {
                    bulk_out = Some(ep & 0xF);
                }
            }
            _ => {}
        }
        i += len;
    }
    match (comm, bulk_in, bulk_out) {
        (Some(c), Some(i), Some(o)) => Ok((c, i, o)),
        _ => Err("no CDC-ACM function with a bulk IN/OUT data interface".into()),
    }
}
