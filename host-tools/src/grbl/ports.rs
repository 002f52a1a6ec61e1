//! Where senders connect: a pseudo-terminal (its path printed, and linked at a fixed
//! path when asked) and a TCP port on localhost. One sender at a time: bytes from the
//! other end while one holds the bridge are answered with a message saying so.
//!
//! Reader threads hand bytes over a bounded channel: a sender that writes faster than
//! the bridge reads is held back by its own end of the pipe, and nothing is lost.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::Duration;

/// Which end bytes came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum End {
    /// The pseudo-terminal.
    Pty,
    /// A TCP connection (its number).
    Tcp(u32),
}

/// What the reader threads report.
pub enum Event {
    /// Bytes from a sender.
    Bytes(End, Vec<u8>),
    /// A TCP sender connected; write to it here.
    Connected(u32, TcpStream),
    /// A TCP sender went away.
    Closed(u32),
}

/// The open ends.
pub struct Ports {
    /// Path of the pseudo-terminal a sender opens.
    pub pty_path: String,
    /// The fixed path linked to it, if any (removed on drop).
    link: Option<std::path::PathBuf>,
    /// TCP address, if listening.
    pub tcp_addr: Option<std::net::SocketAddr>,
    pty: serialport::TTYPort,
    /// Kept open so that the pseudo-terminal stays usable between senders.
    _slave: serialport::TTYPort,
    /// Events from the readers.
    pub events: Receiver<Event>,
    stop: Arc<AtomicBool>,
}

/// Chunks the channel holds before readers wait.
const CHANNEL_DEPTH: usize = 256;

impl Ports {
    /// Opens the pseudo-terminal (linked at `link` if given) and, with `tcp`, a
    /// listener on `tcp` (`127.0.0.1:PORT`, or another address given with `--listen`).
    pub fn open(link: Option<&std::path::Path>, tcp: Option<&str>) -> Result<Self, String> {
        let (master, slave) = serialport::TTYPort::pair()
            .map_err(|e| format!("cannot create a pseudo-terminal: {e}"))?;
        let pty_path = serialport::SerialPort::name(&slave)
            .ok_or_else(|| "the pseudo-terminal has no name".to_string())?;
        let linked = match link {
            Some(p) => {
                let _ = std::fs::remove_file(p);
                std::os::unix::fs::symlink(&pty_path, p)
                    .map_err(|e| format!("cannot link {} to {pty_path}: {e}", p.display()))?;
                Some(p.to_path_buf())
            }
            None => None,
        };
        let (tx, rx) = sync_channel(CHANNEL_DEPTH);
        let stop = Arc::new(AtomicBool::new(false));
        let reader = master
            .try_clone_native()
            .map_err(|e| format!("pseudo-terminal: {e}"))?;
        spawn_pty_reader(reader, tx.clone(), stop.clone());
        let tcp_addr = match tcp {
            Some(addr) => {
                let listener =
                    TcpListener::bind(addr).map_err(|e| format!("cannot listen on {addr}: {e}"))?;
                let bound = listener.local_addr().map_err(|e| e.to_string())?;
                spawn_listener(listener, tx, stop.clone());
                Some(bound)
            }
            None => None,
        };
        Ok(Self {
            pty_path,
            link: linked,
            tcp_addr,
            pty: master,
            _slave: slave,
            events: rx,
            stop,
        })
    }

    /// Writes `bytes` to the pseudo-terminal.
    pub fn write_pty(&mut self, bytes: &[u8]) {
        write_all_patiently(&mut self.pty, bytes);
    }
}

impl Drop for Ports {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(p) = &self.link {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Writes all of `bytes`, waiting while the other end is full (a sender that stopped
/// reading: given up after 2 s, as a closed end).
pub fn write_all_patiently(w: &mut dyn Write, mut bytes: &[u8]) -> bool {
    let start = std::time::Instant::now();
    while !bytes.is_empty() {
        match w.write(bytes) {
            Ok(0) => return false,
            Ok(n) => bytes = &bytes[n..],
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                if start.elapsed() > Duration::from_secs(2) {
                    return false;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(_) => return false,
        }
    }
    let _ = w.flush();
    true
}

fn send(tx: &SyncSender<Event>, mut ev: Event, stop: &AtomicBool) -> bool {
    loop {
        match tx.try_send(ev) {
            Ok(()) => return true,
            Err(TrySendError::Full(back)) => {
                if stop.load(Ordering::Relaxed) {
                    return false;
                }
                ev = back;
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(TrySendError::Disconnected(_)) => return false,
        }
    }
}

fn spawn_pty_reader(mut port: serialport::TTYPort, tx: SyncSender<Event>, stop: Arc<AtomicBool>) {
    let _ = serialport::SerialPort::set_timeout(&mut port, Duration::from_millis(20));
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            match port.read(&mut buf) {
                Ok(0) => std::thread::sleep(Duration::from_millis(5)),
                Ok(n) => {
                    if !send(&tx, Event::Bytes(End::Pty, buf[..n].to_vec()), &stop) {
                        return;
                    }
                }
                // No sender has the terminal open (EIO), or nothing came: wait.
                Err(_) => std::thread::sleep(Duration::from_millis(5)),
            }
        }
    });
}

fn spawn_listener(listener: TcpListener, tx: SyncSender<Event>, stop: Arc<AtomicBool>) {
    let _ = listener.set_nonblocking(true);
    std::thread::spawn(move || {
        let mut next = 1u32;
        while !stop.load(Ordering::Relaxed) {
            match listener.accept() {
                Ok((stream, _)) => {
                    let id = next;
                    next += 1;
                    let _ = stream.set_nodelay(true);
                    let _ = stream.set_nonblocking(false);
                    let Ok(reader) = stream.try_clone() else {
                        continue;
                    };
                    if !send(&tx, Event::Connected(id, stream), &stop) {
                        return;
                    }
                    spawn_tcp_reader(id, reader, tx.clone(), stop.clone());
                }
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    });
}

fn spawn_tcp_reader(id: u32, mut s: TcpStream, tx: SyncSender<Event>, stop: Arc<AtomicBool>) {
    let _ = s.set_read_timeout(Some(Duration::from_millis(50)));
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            quick_ack(&s);
            match s.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    quick_ack(&s);
                    if !send(&tx, Event::Bytes(End::Tcp(id), buf[..n].to_vec()), &stop) {
                        return;
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(_) => break,
            }
        }
        send(&tx, Event::Closed(id), &stop);
    });
}

/// Acknowledges what arrives at once (Linux's `TCP_QUICKACK`, which the kernel clears
/// again as it goes, hence asked before and after every read). A sender with Nagle's
/// algorithm on (most) holds a lone `?` back until its previous byte, a `!` say, is
/// acknowledged; a delayed acknowledgement (about 40 ms) would hold the `?` that long.
fn quick_ack(s: &TcpStream) {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        let one: libc::c_int = 1;
        // SAFETY: a valid socket and an int option of the right size; failure is
        // harmless (acknowledgements are merely delayed as usual).
        unsafe {
            libc::setsockopt(
                s.as_raw_fd(),
                libc::IPPROTO_TCP,
                libc::TCP_QUICKACK,
                (&one as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            );
        }
    }
}
