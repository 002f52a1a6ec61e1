//! The USB full-speed device peripheral (USB) and its packet memory (USB SRAM), as seen
//! from the bus: what a host transaction does to the endpoint registers and buffers.
//!
//! Source: RM0440, "Universal serial bus full-speed device interface (USB)":
//!
//! - the register map: USB_EPnR (0x00–0x1C), USB_CNTR (0x40), USB_ISTR (0x44),
//!   USB_FNR (0x48), USB_DADDR (0x4C), USB_BTABLE (0x50), USB_LPMCSR (0x54), USB_BCDR
//!   (0x58); the packet memory of 1024 bytes at 0x4000 6000 with 16-bit words at
//!   consecutive addresses (the "2 × 16 bits/word" access scheme);
//! - USB_EPnR's bit kinds: CTR_RX and CTR_TX are cleared by writing 0 (rc_w0) and
//!   kept by writing 1; DTOG_RX, STAT_RX, DTOG_TX, STAT_TX toggle where a 1 is
//!   written (t); SETUP is read-only; EP_TYPE, EP_KIND and EA are plain (rw);
//! - USB_ISTR: the event flags are cleared by writing 0 (rc_w0); CTR, DIR and EP_ID
//!   are read-only and name the endpoint with a completed transfer, the lowest
//!   number first; an interrupt is raised while a flag is set with its mask bit in
//!   USB_CNTR;
//! - "Buffer descriptor table": per endpoint n, at BTABLE + 8n, ADDRn_TX, COUNTn_TX,
//!   ADDRn_RX, COUNTn_RX (BL_SIZE, NUM_BLOCK: the receive buffer's size, and COUNT
//!   written by the peripheral);
//! - "Reception of packets" / "Transmission of packets": a packet is accepted (ACK)
//!   only with STAT = VALID; NAK and STALL answer otherwise; on success the
//!   peripheral writes the data and COUNT (OUT) or reads COUNT bytes (IN), toggles the
//!   DTOG bit, sets CTR and sets STAT to NAK; a SETUP is always accepted on a control
//!   endpoint, sets SETUP, and both DTOG bits are set to 1 for the data stage;
//! - "USB reset": the endpoint registers and DADDR are cleared, RESET is set;
//! - USB_BCDR.DPPU connects the internal D+ pull-up: the host sees the device attach.

use super::Unmodelled;

/// Packet memory size.
pub const PMA_SIZE: usize = 1024;
/// The NVIC line of USB_LP.
pub const IRQ_USB_LP: usize = 20;

/// How a transaction went, from the host's side.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Handshake {
    /// Accepted (ACK), with the data of an IN.
    Ack(Vec<u8>),
    /// Not ready: try again.
    Nak,
    /// The endpoint is halted.
    Stall,
    /// No answer (disabled endpoint, address not matched, function not enabled).
    Timeout,
}

const STAT_DISABLED: u16 = 0;
const STAT_STALL: u16 = 1;
const STAT_NAK: u16 = 2;
const STAT_VALID: u16 = 3;

/// The USB device peripheral.
pub struct UsbDevice {
    epr: [u16; 8],
    cntr: u16,
    istr: u16,
    fnr: u16,
    daddr: u16,
    btable: u16,
    lpmcsr: u16,
    bcdr: u16,
    /// The packet memory.
    pub pma: [u8; PMA_SIZE],
    /// A write armed an endpoint (STAT_TX or STAT_RX changed to VALID): the host may
    /// want to act.
    pub armed: bool,
}

impl Default for UsbDevice {
    fn default() -> Self {
        Self {
            epr: [0; 8],
            cntr: 0x0003,
            istr: 0,
            fnr: 0,
            daddr: 0,
            btable: 0,
            lpmcsr: 0,
            bcdr: 0,
            pma: [0; PMA_SIZE],
            armed: false,
        }
    }
}

impl UsbDevice {
    /// Is the D+ pull-up connected (the device attached)?
    pub fn attached(&self) -> bool {
        self.bcdr & (1 << 15) != 0 && self.cntr & 3 == 0
    }

    /// The device address, if the function is enabled.
    pub fn address(&self) -> Option<u8> {
        (self.daddr & 0x80 != 0).then_some((self.daddr & 0x7F) as u8)
    }

    /// Is the USB_LP interrupt asserted?
    pub fn irq(&self) -> bool {
        let flags = self.istr & 0xFF80;
        let mask = self.cntr & 0xFF80;
        let ctr = self.epr.iter().any(|e| e & 0x8080 != 0);
        (flags & mask) != 0 || (ctr && self.cntr & (1 << 15) != 0)
    }

    fn istr_value(&self) -> u16 {
        let mut v = self.istr & 0x7F80;
        if let Some((n, e)) = self.epr.iter().enumerate().find(|(_, e)| *e & 0x8080 != 0) {
            v |= 1 << 15 | n as u16;
            if e & 0x8000 != 0 {
                v |= 1 << 4;
            }
        }
        v
    }

    /// Reads `offset` (from 0x4000 5C00).
    pub fn read(&self, offset: u32) -> Result<u32, Unmodelled> {
        Ok(u32::from(match offset {
            0x00..=0x1C if offset % 4 == 0 => self.epr[(offset / 4) as usize],
            0x40 => self.cntr,
            0x44 => self.istr_value(),
            0x48 => self.fnr,
            0x4C => self.daddr,
            0x50 => self.btable,
            0x54 => self.lpmcsr,
            0x58 => self.bcdr,
            _ => return Err(Unmodelled),
        }))
    }

    /// Writes `offset` (from 0x4000 5C00).
    pub fn write(&mut self, offset: u32, value: u32) -> Result<(), Unmodelled> {
        let v = value as u16;
        match offset {
            0x00..=0x1C if offset % 4 == 0 => {
                let n = (offset / 4) as usize;
                let old = self.epr[n];
                // rw: EP_TYPE, EP_KIND, EA; t: a 1 flips DTOG/STAT; rc_w0: CTR bits
                // kept by a 1, cleared by a 0; SETUP read-only.
                let new = (v & 0x070F)
                    | ((old & 0x7070) ^ (v & 0x7070))
                    | (old & 0x8080 & v)
                    | (old & 0x0800);
                if (new >> 4) & 3 == STAT_VALID && (old >> 4) & 3 != STAT_VALID
                    || (new >> 12) & 3 == STAT_VALID && (old >> 12) & 3 != STAT_VALID
                {
                    self.armed = true;
                }
                self.epr[n] = new;
            }
            0x40 => self.cntr = v,
            0x44 => self.istr &= v | 0x807F,
            0x48 => {}
            0x4C => self.daddr = v & 0xFF,
            0x50 => self.btable = v & 0xFFF8,
            0x54 => self.lpmcsr = v,
            0x58 => self.bcdr = v,
            _ => return Err(Unmodelled),
        }
        Ok(())
    }

    /// Reads a 16-bit word of packet memory at byte offset `o` (`size` ≤ 4 bytes).
    pub fn pma_read(&self, o: usize, size: usize) -> Option<u32> {
        (o + size <= PMA_SIZE)
            .then(|| (0..size).fold(0u32, |v, k| v | u32::from(self.pma[o + k]) << (8 * k)))
    }

    /// Writes packet memory.
    pub fn pma_write(&mut self, o: usize, size: usize, value: u32) -> Option<()> {
        (o + size <= PMA_SIZE).then(|| {
            for k in 0..size {
                self.pma[o + k] = (value >> (8 * k)) as u8;
            }
        })
    }

    fn bt(&self, n: usize, field: usize) -> u16 {
        let o = self.btable as usize + 8 * n + 2 * field;
        u16::from_le_bytes([self.pma[o % PMA_SIZE], self.pma[(o + 1) % PMA_SIZE]])
    }

    fn set_bt(&mut self, n: usize, field: usize, v: u16) {
        let o = self.btable as usize + 8 * n + 2 * field;
        self.pma[o % PMA_SIZE] = v as u8;
        self.pma[(o + 1) % PMA_SIZE] = (v >> 8) as u8;
    }

    fn endpoint(&self, addr: u8, ep: u8) -> Option<usize> {
        if self.cntr & 3 != 0 || self.address() != Some(addr) {
            return None;
        }
        self.epr.iter().position(|e| (e & 0xF) as u8 == ep)
    }

    fn set_stat(&mut self, n: usize, rx: bool, stat: u16) {
        let shift = if rx { 12 } else { 4 };
        self.epr[n] = self.epr[n] & !(3 << shift) | stat << shift;
    }

    fn rx_capacity(&self, n: usize) -> usize {
        let c = self.bt(n, 3);
        let blocks = usize::from((c >> 10) & 0x1F);
        if c & 0x8000 != 0 {
            32 * (blocks + 1)
        } else {
            2 * blocks
        }
    }

    /// A SETUP transaction to `addr`/`ep` with the 8 bytes `data`.
    pub fn setup(&mut self, addr: u8, ep: u8, data: &[u8; 8]) -> Handshake {
        let Some(n) = self.endpoint(addr, ep) else {
            return Handshake::Timeout;
        };
        if (self.epr[n] >> 9) & 3 != 1 {
            return Handshake::Timeout; // not a control endpoint
        }
        self.receive(n, data);
        self.epr[n] |= 0x0800 | 1 << 14 | 1 << 6; // SETUP, DTOG_RX, DTOG_TX
        Handshake::Ack(Vec::new())
    }

    fn receive(&mut self, n: usize, data: &[u8]) {
        let base = usize::from(self.bt(n, 2));
        for (k, &b) in data.iter().take(self.rx_capacity(n)).enumerate() {
            self.pma[(base + k) % PMA_SIZE] = b;
        }
        let count = self.bt(n, 3) & 0xFC00 | data.len() as u16;
        self.set_bt(n, 3, count);
        self.epr[n] = self.epr[n] & !0x0800 | 0x8000;
        self.epr[n] ^= 1 << 14;
        self.set_stat(n, true, STAT_NAK);
    }

    /// An OUT transaction to `addr`/`ep` carrying `data`.
    pub fn out(&mut self, addr: u8, ep: u8, data: &[u8]) -> Handshake {
        let Some(n) = self.endpoint(addr, ep) else {
            return Handshake::Timeout;
        };
        match (self.epr[n] >> 12) & 3 {
            STAT_VALID if data.len() <= self.rx_capacity(n) => {
                self.receive(n, data);
                Handshake::Ack(Vec::new())
            }
            STAT_VALID => Handshake::Stall, // babble: more than the buffer holds
            STAT_NAK => Handshake::Nak,
            STAT_STALL => Handshake::Stall,
            _ => Handshake::Timeout,
        }
    }

    /// An IN transaction from `addr`/`ep`.
    pub fn input(&mut self, addr: u8, ep: u8) -> Handshake {
        let Some(n) = self.endpoint(addr, ep) else {
            return Handshake::Timeout;
        };
        match (self.epr[n] >> 4) & 3 {
            STAT_VALID => {
                let base = usize::from(self.bt(n, 0));
                let count = usize::from(self.bt(n, 1) & 0x3FF);
                let data = (0..count)
                    .map(|k| self.pma[(base + k) % PMA_SIZE])
                    .collect();
                self.epr[n] |= 0x0080;
                self.epr[n] ^= 1 << 6;
                self.set_stat(n, false, STAT_NAK);
                Handshake::Ack(data)
            }
            STAT_NAK => Handshake::Nak,
            STAT_STALL => Handshake::Stall,
            STAT_DISABLED => Handshake::Timeout,
            _ => Handshake::Timeout,
        }
    }

    /// A bus reset from the host.
    pub fn bus_reset(&mut self) {
        self.epr = [0; 8];
        self.daddr = 0;
        self.istr |= 1 << 10;
    }

    /// A start of frame.
    pub fn sof(&mut self) {
        self.fnr = (self.fnr + 1) & 0x7FF;
        self.istr |= 1 << 9;
    }

    /// The host stopped sending frames for 3 ms (cable pulled): SUSP.
    pub fn suspend(&mut self) {
        self.istr |= 1 << 11;
    }

    /// Is endpoint `ep` (by address field) at STAT_RX or STAT_TX = VALID?
    pub fn valid(&self, ep: u8, rx: bool) -> bool {
        let shift = if rx { 12 } else { 4 };
        self.epr
            .iter()
            .any(|e| (e & 0xF) as u8 == ep && (e >> shift) & 3 == STAT_VALID)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toggle_bits_flip_on_a_one_and_ctr_clears_on_a_zero() {
        let mut u = UsbDevice::default();
        u.write(0x00, 0x3030 | 0x0200).ok(); // STAT_RX, STAT_TX ← VALID; control
        assert_eq!(u.read(0x00).ok(), Some(0x3230));
        u.write(0x00, 0x1010 | 0x0200).ok(); // flip the low bit of each STAT: NAK
        assert_eq!(u.read(0x00).ok(), Some(0x2220));
        u.write(0x00, 0x4040 | 0x0200).ok(); // flip DTOG_RX, DTOG_TX
        assert_eq!(u.read(0x00).ok(), Some(0x6260));
        // Writing 0 to the toggles leaves them; CTR bits kept by 1, cleared by 0.
        u.epr[0] |= 0x8080;
        u.write(0x00, 0x0080 | 0x0200).ok();
        assert_eq!(u.read(0x00).ok(), Some(0x62E0 & !0x8000 | 0x0080));
    }

    fn device() -> UsbDevice {
        let mut u = UsbDevice::default();
        u.write(0x40, 0).ok();
        u.write(0x4C, 0x80).ok();
        // EP0: TX buffer at 0x40, RX buffer at 0x80 of 64 bytes (BL_SIZE, 1 block).
        u.set_bt(0, 0, 0x40);
        u.set_bt(0, 2, 0x80);
        u.set_bt(0, 3, 0x8400);
        u.write(0x00, 0x0200 | 0x3000).ok(); // control, STAT_RX VALID, TX NAK... DISABLED
        u
    }

    #[test]
    fn an_out_is_naked_until_valid_then_stored_counted_and_naked_again() {
        let mut u = device();
        assert_eq!(u.out(0, 0, b"abc"), Handshake::Ack(Vec::new()));
        assert_eq!(&u.pma[0x80..0x83], b"abc");
        assert_eq!(u.bt(0, 3) & 0x3FF, 3);
        assert_eq!(u.read(0x44).ok().map(|v| v & 0x801F), Some(0x8010));
        assert_eq!(u.out(0, 0, b"d"), Handshake::Nak);
    }

    #[test]
    fn an_in_sends_count_bytes_once_and_sets_ctr_tx() {
        let mut u = device();
        u.pma[0x40..0x44].copy_from_slice(b"wxyz");
        u.set_bt(0, 1, 4);
        assert_eq!(u.input(0, 0), Handshake::Timeout); // STAT_TX disabled
        u.write(0x00, 0x0200 | 0x0030 | 0x8080).ok();
        assert_eq!(u.input(0, 0), Handshake::Ack(b"wxyz".to_vec()));
        assert_eq!(u.input(0, 0), Handshake::Nak);
        assert_ne!(u.read(0x00).ok().unwrap_or(0) & 0x0080, 0);
        assert!(u.irq() || u.cntr & 0x8000 == 0);
    }
}
