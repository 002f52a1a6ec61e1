//! Byte transports under the client: a serial port ([`PortTransport`], a board or a
//! simulator behind a pseudo-terminal) or anything else that moves bytes, such as the
//! in-process simulator of `--check` (`crate::sim::serve::InProcess`).

use super::LinkError;
use serialport::SerialPort;
use std::io::{self, ErrorKind, Read, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Is `e` a read or write that timed out (or would have blocked) rather than failed?
pub fn is_timeout(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
    )
}

/// A byte pipe to a controller.
pub trait Transport {
    /// Name for messages (the port's path).
    fn name(&self) -> &str;
    /// Writes some of `bytes`, waiting at most `wait` for room; returns how many were
    /// taken (0 on timeout).
    fn write_some(&mut self, bytes: &[u8], wait: Duration) -> io::Result<usize>;
    /// Reads what has arrived, waiting at most `wait` for the first byte; 0 on timeout.
    fn read_some(&mut self, buf: &mut [u8], wait: Duration) -> io::Result<usize>;
    /// Simulated time at the other end, ticks, when it is a simulator on this host
    /// ([`InProcess`], or a pseudo-terminal with a [`SimClock`]): the stall guard runs
    /// on it. `None` for a board: its operator watches the machine.
    fn sim_ticks(&self) -> Option<u64> {
        None
    }
}

/// The clock of a simulator serving in another thread, read by the client's stall
/// guard: the server stores its tick count after every tick.
#[derive(Clone, Debug, Default)]
pub struct SimClock(Arc<AtomicU64>);

impl SimClock {
    /// Records the simulator's tick count.
    pub fn set(&self, ticks: u64) {
        self.0.store(ticks, Ordering::Relaxed);
    }

    /// The simulator's tick count last recorded.
    pub fn ticks(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
}

/// A serial port (a board's USB CDC port or a pseudo-terminal).
pub struct PortTransport {
    port: Box<dyn SerialPort>,
    name: String,
    clock: Option<SimClock>,
    /// The port's descriptor (non-blocking, see [`PortTransport::open`]).
    #[cfg(unix)]
    #[cfg_attr(not(test), allow(dead_code))]
    fd: i32,
}

impl PortTransport {
    /// Opens the port at `path`.
    pub fn open(path: &str) -> Result<Self, LinkError> {
        let open_error = |source| LinkError::Open {
            port: path.to_string(),
            source,
        };
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(10))
            .open_native()
            .map_err(open_error)?;
        // Non-blocking: the port is polled with a timeout before each read, but another
        // process reading the same port can take the bytes between the poll and the
        // read, and a blocking read would then wait forever (the link timeout could
        // never fire). A read that finds nothing returns at once instead.
        #[cfg(unix)]
        let fd = {
            use std::os::fd::AsRawFd;
            let fd = port.as_raw_fd();
            // SAFETY: fcntl on a descriptor this function owns (the open port).
            let ok = unsafe {
                let flags = libc::fcntl(fd, libc::F_GETFL);
                flags >= 0 && libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) == 0
            };
            if !ok {
                return Err(open_error(serialport::Error::from(
                    io::Error::last_os_error(),
                )));
            }
            fd
        };
        Ok(Self {
            #[cfg(unix)]
            fd,
            port: Box::new(port),
            name: path.to_string(),
            clock: None,
        })
    }

    /// The port of a simulator whose clock is `clock`: turns the stall guard on.
    pub fn with_sim_clock(mut self, clock: SimClock) -> Self {
        self.clock = Some(clock);
        self
    }
}

impl Transport for PortTransport {
    fn name(&self) -> &str {
        &self.name
    }

    fn write_some(&mut self, bytes: &[u8], wait: Duration) -> io::Result<usize> {
        self.port.set_timeout(wait)?;
        match self.port.write(bytes) {
            Ok(n) => Ok(n),
            Err(e) if is_timeout(&e) => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn read_some(&mut self, buf: &mut [u8], wait: Duration) -> io::Result<usize> {
        self.port.set_timeout(wait)?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if is_timeout(&e) => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn sim_ticks(&self) -> Option<u64> {
        self.clock.as_ref().map(SimClock::ticks)
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    #[cfg(unix)]
    #[test]
    fn a_port_reads_without_blocking_so_bytes_taken_by_another_reader_cannot_hang_the_client() {
        use std::io::Write;
        let (mut master, slave) = serialport::TTYPort::pair().unwrap();
        let path = serialport::SerialPort::name(&slave).unwrap();
        let mut port = super::PortTransport::open(&path).unwrap();
        // Another process opens the same port and takes what arrives.
        let mut thief = std::fs::File::open(&path).unwrap();
        master.write_all(b"x").unwrap();
        let mut one = [0u8; 1];
        std::io::Read::read(&mut thief, &mut one).unwrap();
        // The descriptor does not block: a read that finds nothing (as after a poll
        // that saw the stolen byte) returns at once instead of waiting forever.
        // SAFETY: fcntl on the transport's own, open descriptor.
        let flags = unsafe { libc::fcntl(port.fd, libc::F_GETFL) };
        assert_ne!(
            flags & libc::O_NONBLOCK,
            0,
            "a blocking read would wait forever"
        );
        // SAFETY: read into a live one-byte buffer from the same descriptor.
        let n = unsafe { libc::read(port.fd, one.as_mut_ptr().cast(), 1) };
        assert_eq!(n, -1);
        assert_eq!(
            std::io::Error::last_os_error().kind(),
            std::io::ErrorKind::WouldBlock
        );
        let start = std::time::Instant::now();
        let got = super::Transport::read_some(&mut port, &mut one, Duration::from_millis(50));
        assert_eq!(got.unwrap(), 0);
        assert!(start.elapsed() < Duration::from_secs(1));
    }
}
