//! The client's side of the controller's data recorder (`pkmc::drive::recorder`,
//! protocol 13): arming it, asking where it is, and reading a finished capture out,
//! each a small frame beside a running job's blocks (a read is answered at once and
//! neither waits for blocks nor holds them back).

use super::{Link, LinkError, Transport};
use pkmc::drive::excite::Excite;
use pkmc::drive::recorder::{Phase, Reply, Setup, Signal};
use pkmc::wire::{CtrlMsg, HostMsg, RECORD_ARM, RECORD_DISARM, RECORD_EXCITE, RECORD_READ};
use std::time::{Duration, Instant};

/// A finished capture, read out.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Recording {
    /// The capture's signals, in its order.
    pub signals: Vec<Signal>,
    /// Sampled every servo period (else every tick).
    pub servo: bool,
    /// Periods or ticks between samples.
    pub decimate: u16,
    /// Samples before the trigger's.
    pub pre: usize,
    /// Each sample's values, oldest first.
    pub samples: Vec<Vec<i32>>,
}

impl Recording {
    /// Seconds between samples.
    pub fn period_s(&self) -> f64 {
        let hz = if self.servo {
            pkmc::drive::servo::SERVO_HZ as f64
        } else {
            pkmc::units::TICK_HZ as f64
        };
        self.decimate as f64 / hz
    }

    /// The capture's samples from `bytes` (a whole capture, as the controller reads it
    /// out), each signal 2 or 4 bytes little-endian.
    pub fn decode(signals: Vec<Signal>, bytes: &[u8]) -> Vec<Vec<i32>> {
        let width: usize = signals.iter().map(|s| s.width() as usize).sum();
        bytes
            .chunks_exact(width.max(1))
            .map(|s| {
                let mut at = 0;
                signals
                    .iter()
                    .map(|sig| {
                        let v = if sig.width() == 2 {
                            i16::from_le_bytes([s[at], s[at + 1]]) as i32
                        } else {
                            i32::from_le_bytes([s[at], s[at + 1], s[at + 2], s[at + 3]])
                        };
                        at += sig.width() as usize;
                        v
                    })
                    .collect()
            })
            .collect()
    }
}

/// A piece of the recorder's continuous stream: consecutive samples from number
/// `first` (counted since arming, wrapping). A gap between pieces is samples the
/// controller overwrote because the link fell behind.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Piece {
    /// The first sample's number.
    pub first: u32,
    /// The signals, in order.
    pub signals: Vec<Signal>,
    /// Sampled every servo period (else every tick).
    pub servo: bool,
    /// Periods or ticks between samples.
    pub decimate: u16,
    /// Each sample's values.
    pub samples: Vec<Vec<i32>>,
}

/// The signals a recorder answer names.
fn signals_of(reply: &Reply) -> Vec<Signal> {
    reply.signals[..(reply.count as usize).min(reply.signals.len())]
        .iter()
        .filter_map(|&id| Signal::from_id(id))
        .collect()
}

impl<T: Transport> Link<T> {
    /// Keeps a streamed piece of the recorder (other recorder answers are the
    /// queries' own).
    pub(super) fn keep_streamed(&mut self, bytes: &[u8]) {
        let Some((reply, data)) = Reply::unpack(bytes) else {
            return;
        };
        if !reply.streamed || reply.capture.samples == 0 {
            return;
        }
        let signals = signals_of(&reply);
        let mut samples = Recording::decode(signals.clone(), data);
        samples.truncate(reply.capture.samples as usize);
        self.streamed.push(Piece {
            first: reply.offset,
            signals,
            servo: reply.servo,
            decimate: reply.decimate,
            samples,
        });
    }

    /// The streamed pieces received since the last call, oldest first.
    pub fn record_take(&mut self) -> Vec<Piece> {
        std::mem::take(&mut self.streamed)
    }

    /// Reads what the port has (streamed pieces, status) for up to `wait`, without
    /// sending anything.
    pub fn record_listen(&mut self, wait: Duration) -> Result<(), LinkError> {
        let msgs = self.pump(wait)?;
        self.absorb(&msgs);
        Ok(())
    }

    /// Starts a test signal on a servo joint (`pkmc::drive::excite`); a request the
    /// controller refuses (machine busy or not homed, not a servo joint, amplitude,
    /// travel) is an error naming why.
    pub fn record_excite(&mut self, excite: &Excite) -> Result<(), LinkError> {
        self.record_control(RECORD_EXCITE, &excite.pack(), "starting the test signal")
    }

    /// Arms the recorder with `setup`; a request the controller refuses is an error
    /// naming why.
    pub fn record_arm(&mut self, setup: &Setup) -> Result<(), LinkError> {
        self.record_control(RECORD_ARM, &setup.pack(), "arming the recorder")
    }

    /// Sends the recorder control `what` with its bytes until acknowledged (`doing`
    /// names it in a timeout), then asks whether the controller refused it: a refusal
    /// is an error naming why.
    fn record_control(
        &mut self,
        what: u8,
        bytes: &[u8],
        doing: &'static str,
    ) -> Result<(), LinkError> {
        let mut req = heapless::Vec::new();
        let _ = req.push(what);
        let _ = req.extend_from_slice(bytes);
        let id = self.fresh_control_id();
        self.stats.controls += 1;
        self.until_acked(id, &HostMsg::Record { id, req }, doing)?;
        let (reply, _) = self.record_query(0)?;
        match reply.refused {
            Some(error) => Err(LinkError::Recorder {
                port: self.port(),
                error,
            }),
            None => Ok(()),
        }
    }

    /// Stops the recorder and drops its capture.
    pub fn record_disarm(&mut self) -> Result<(), LinkError> {
        let mut req = heapless::Vec::new();
        let _ = req.push(RECORD_DISARM);
        let id = self.fresh_control_id();
        self.stats.controls += 1;
        self.until_acked(id, &HostMsg::Record { id, req }, "stopping the recorder")
    }

    /// Where the recorder is, and the capture's bytes from `offset` once it is done.
    pub fn record_query(&mut self, offset: u32) -> Result<(Reply, Vec<u8>), LinkError> {
        let mut req = heapless::Vec::new();
        let _ = req.push(RECORD_READ);
        let _ = req.extend_from_slice(&offset.to_le_bytes());
        let msg = HostMsg::Record { id: 0, req };
        let start = Instant::now();
        loop {
            self.queue(0, &msg)?;
            self.flush()?;
            let until = Instant::now() + Duration::from_millis(100);
            while Instant::now() < until {
                let msgs = self.pump(Duration::from_millis(5))?;
                self.absorb(&msgs);
                for m in msgs {
                    if let CtrlMsg::Record(bytes) = m {
                        if let Some((reply, data)) = Reply::unpack(&bytes) {
                            if !reply.streamed && reply.offset == offset {
                                return Ok((reply, data.to_vec()));
                            }
                        }
                    }
                }
            }
            if self.given_up(start) {
                return Err(self.lost("waiting for the recorder", start));
            }
        }
    }

    /// Reads the finished capture out; `None` while it is not finished (armed and
    /// waiting for its trigger, or filling the samples after it) or nothing is armed.
    pub fn record_read(&mut self) -> Result<Option<Recording>, LinkError> {
        let mut readout = Readout::default();
        loop {
            let (reply, data) = self.record_query(readout.offset())?;
            match readout.answer(&reply, &data) {
                Read::More => {}
                Read::NotDone => return Ok(None),
                Read::Done(rec) => return Ok(Some(rec)),
            }
        }
    }

    /// A recorder read of the capture's bytes from `offset` sent beside a running job
    /// (its answer comes to [`super::JobHooks::record_answer`]).
    pub(super) fn ask_recorder(&mut self, offset: u32) -> Result<(), LinkError> {
        let mut req = heapless::Vec::new();
        let _ = req.push(RECORD_READ);
        let _ = req.extend_from_slice(&offset.to_le_bytes());
        self.queue(0, &HostMsg::Record { id: 0, req })
    }
}

/// A finished capture read out a piece at a time: which bytes to ask for next
/// ([`Readout::offset`]), and each answer taken in ([`Readout::answer`]). Used by
/// [`Link::record_read`], and by job hooks that read a capture while a job runs.
#[derive(Clone, Debug, Default)]
pub struct Readout {
    /// The first answer (the capture's signals, size and pre-trigger samples).
    first: Option<Reply>,
    bytes: Vec<u8>,
}

/// Where a [`Readout`] is after an answer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Read {
    /// Not complete: ask for [`Readout::offset`] next (an answer that was not to the
    /// last question is ignored).
    More,
    /// The capture is not finished, or was re-armed while it was read (the readout
    /// starts again).
    NotDone,
    /// The whole capture.
    Done(Recording),
}

impl Readout {
    /// The offset to ask for next, bytes.
    pub fn offset(&self) -> u32 {
        self.bytes.len() as u32
    }

    /// Takes in the answer `reply` with its `data`.
    pub fn answer(&mut self, reply: &Reply, data: &[u8]) -> Read {
        if reply.streamed || reply.offset != self.offset() {
            return Read::More;
        }
        if reply.capture.phase != Phase::Done || (self.first.is_some() && data.is_empty()) {
            *self = Self::default();
            return Read::NotDone;
        }
        let first = *self.first.get_or_insert(*reply);
        let total = first.capture.samples as usize * first.capture.width as usize;
        self.bytes.extend_from_slice(data);
        if self.bytes.len() < total {
            return Read::More;
        }
        let mut bytes = std::mem::take(&mut self.bytes);
        *self = Self::default();
        bytes.truncate(total);
        let signals = signals_of(&first);
        Read::Done(Recording {
            samples: Recording::decode(signals.clone(), &bytes),
            signals,
            servo: first.servo,
            decimate: first.decimate,
            pre: first.capture.pre as usize,
        })
    }
}
