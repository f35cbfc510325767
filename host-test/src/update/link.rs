//! The upload over the bus: requests as CSP packets to the satellite's update port in KISS frames, replies picked
//! out of the bytes that come back ([`UpdateFramer`]), a byte link ([`Link`]; [`SerialLink`] for a serial device
//! or pseudo-terminal) and the loop that runs an [`Uploader`] over it ([`upload`]).
//!
//! The framing is `shared::bus`'s (`csp::CspPacket::emit_kiss`, `kiss::KissDecoder`): the ground end of the link
//! the satellite's `BusNode` is the other end of. (The firmware's tests have their own ground encoder in test code,
//! `firmware/tests/common`; this is the ground tool's.)

use super::uploader::{UploadError, UploadEvent, UploadSummary, Uploader};
use shared::bus::csp::{CspHeader, CspPacket, CspVersion};
use shared::bus::kiss::KissDecoder;
use shared::bus::{BusConfig, MAX_FRAME, MAX_PAYLOAD, MAX_WIRE_FRAME};
use shared::update::{CHUNK_MAX, PORT_UPDATE, UpdateEnvelope, UpdateRequest, UpdateResponse};
use std::io::{Read, Write};
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The satellite's bus receive ring, bytes (`firmware::layout::BUS_RX_RING_LEN`: 16 KiB, 1.42 s at 115200 baud).
/// While the CPU stalls on flash, what arrives waits there: a window of chunks must fit it ([`max_window`]).
pub const SATELLITE_RING_LEN: usize = 16 * 1024;

/// Addresses, ports and header version of the upload's packets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BusAddrs {
    /// CSP header version of the link.
    pub version: CspVersion,
    /// The satellite's address.
    pub sat_addr: u16,
    /// Ours.
    pub ground_addr: u16,
    /// Our source port: the satellite replies to it.
    pub ground_port: u8,
    /// Priority of our packets.
    pub prio: u8,
}

impl Default for BusAddrs {
    /// `BusConfig::DEFAULT`'s: CSP v1, the satellite node 10, the ground node 1, priority 2; our source port is the
    /// update port's number (12), apart from the telemetry port (10) the ground's telemetry decoder reads.
    fn default() -> Self {
        let c = BusConfig::DEFAULT;
        Self {
            version: c.version,
            sat_addr: c.addr,
            ground_addr: c.ground_addr,
            ground_port: PORT_UPDATE,
            prio: c.prio,
        }
    }
}

/// The largest KISS frame of an upload request on the wire, bytes, worst case (every byte escaped): the largest
/// envelope (a full chunk, the largest tag, offset and CRC) in a CSP packet of `version`.
pub fn max_request_wire_len(version: CspVersion) -> usize {
    let worst = UpdateEnvelope {
        tag: u16::MAX,
        request: UpdateRequest::Chunk {
            offset: u32::MAX,
            crc32c: u32::MAX,
            data: heapless::Vec::from_slice(&[0xC0; CHUNK_MAX]).unwrap_or_default(),
        },
    };
    let payload = postcard::to_allocvec(&worst).map_or(MAX_PAYLOAD, |b| b.len());
    shared::bus::kiss::encoded_len_max(version.header_len() + payload + shared::bus::csp::CRC_LEN)
}

/// The largest window whose chunks, every one the worst case, fit `ring_len` bytes of the satellite's receive ring.
pub fn max_window(ring_len: usize, version: CspVersion) -> usize {
    ring_len / max_request_wire_len(version)
}

/// Why a request could not be framed.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The envelope did not encode.
    #[error("encoding a request: {0}")]
    Encode(#[from] postcard::Error),
    /// The packet does not fit the bus (an address out of the version's range, a payload too long).
    #[error("framing a request as CSP/KISS: {0:?} (addresses within the CSP version's range?)")]
    Csp(shared::bus::csp::CspError),
}

/// Bytes that came back and were not replies for us.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FramerCounters {
    /// Replies decoded.
    pub replies: u64,
    /// KISS frames dropped (bad escape, oversize, other command).
    pub kiss_errors: u64,
    /// Frames that were not CSP packets (CRC).
    pub csp_errors: u64,
    /// Packets for other addresses or ports (telemetry, say).
    pub other: u64,
    /// Packets for us whose payload is not an `UpdateResponse`.
    pub bad_replies: u64,
}

/// The ground end of the upload's framing: envelopes to KISS frames, bus bytes to replies.
#[derive(Clone, Debug)]
pub struct UpdateFramer {
    addrs: BusAddrs,
    kiss: KissDecoder<MAX_FRAME>,
    counters: FramerCounters,
}

impl UpdateFramer {
    /// A framer for `addrs`.
    pub fn new(addrs: BusAddrs) -> Self {
        Self {
            addrs,
            kiss: KissDecoder::new(),
            counters: FramerCounters::default(),
        }
    }

    /// What came back so far.
    pub fn counters(&self) -> FramerCounters {
        self.counters
    }

    /// `envelope` as one KISS frame: postcard, in a CSP packet from our port to the satellite's update port.
    pub fn encode(&self, envelope: &UpdateEnvelope) -> Result<Vec<u8>, FrameError> {
        let payload = postcard::to_allocvec(envelope)?;
        let a = &self.addrs;
        let header = CspHeader {
            prio: a.prio,
            src: a.ground_addr,
            dst: a.sat_addr,
            dport: PORT_UPDATE,
            sport: a.ground_port,
            flags: 0,
        };
        let mut out = [0u8; MAX_WIRE_FRAME];
        if payload.len() > MAX_PAYLOAD {
            return Err(FrameError::Csp(shared::bus::csp::CspError::Invalid));
        }
        let n = CspPacket::emit_kiss(&header, a.version, &payload, &mut out)
            .map_err(FrameError::Csp)?;
        Ok(out[..n].to_vec())
    }

    /// The replies in `bytes` (bus bytes, any split: a frame cut between two calls is completed by the next).
    pub fn decode(&mut self, mut bytes: &[u8]) -> Vec<UpdateResponse> {
        let mut out = Vec::new();
        while let Some(frame) = self.kiss.decode(&mut bytes) {
            let Ok(frame) = frame else {
                self.counters.kiss_errors += 1;
                continue;
            };
            let Ok(p) = CspPacket::parse(frame, self.addrs.version) else {
                self.counters.csp_errors += 1;
                continue;
            };
            let h = p.header;
            if h.dst != self.addrs.ground_addr
                || h.dport != self.addrs.ground_port
                || h.src != self.addrs.sat_addr
                || h.sport != PORT_UPDATE
            {
                self.counters.other += 1;
                continue;
            }
            match postcard::from_bytes::<UpdateResponse>(p.payload) {
                Ok(r) => {
                    self.counters.replies += 1;
                    out.push(r);
                }
                Err(_) => self.counters.bad_replies += 1,
            }
        }
        out
    }
}

/// A byte link to the satellite's bus.
pub trait Link {
    /// Sends one KISS frame.
    fn send(&mut self, kiss_frame: &[u8]) -> std::io::Result<()>;
    /// Bytes received within `timeout` (any number, frames possibly split), `None` if none came.
    fn recv(&mut self, timeout: Duration) -> std::io::Result<Option<Vec<u8>>>;
}

/// A serial device or pseudo-terminal (put in raw mode if it is a terminal; anything else, a FIFO say, is used as
/// it is). A thread reads it; [`Link::recv`] waits on that thread's bytes.
#[derive(Debug)]
pub struct SerialLink {
    writer: std::fs::File,
    rx: mpsc::Receiver<std::io::Result<Vec<u8>>>,
}

impl SerialLink {
    /// Opens `path` for reading and writing (raw 115200 8N1 if it is a terminal; a pseudo-terminal ignores the
    /// rate).
    pub fn open(path: &Path) -> std::io::Result<Self> {
        let f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)?;
        raw_mode(&f)?;
        let mut reader = f.try_clone()?;
        let (tx, rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("link-rx".into())
            .spawn(move || {
                let mut buf = [0u8; 1024];
                loop {
                    match reader.read(&mut buf) {
                        // End of file (a FIFO without a writer): wait for more.
                        Ok(0) => std::thread::sleep(Duration::from_millis(10)),
                        Ok(n) => {
                            if tx.send(Ok(buf[..n].to_vec())).is_err() {
                                return;
                            }
                        }
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(e) => {
                            let _ = tx.send(Err(e));
                            return;
                        }
                    }
                }
            })?;
        Ok(Self { writer: f, rx })
    }
}

/// Raw 115200 8N1 on a terminal; nothing on anything else.
#[cfg(unix)]
fn raw_mode(f: &std::fs::File) -> std::io::Result<()> {
    use nix::sys::termios::{self, BaudRate, SetArg};
    if let Ok(mut t) = termios::tcgetattr(f) {
        termios::cfmakeraw(&mut t);
        termios::cfsetspeed(&mut t, BaudRate::B115200).map_err(std::io::Error::from)?;
        termios::tcsetattr(f, SetArg::TCSANOW, &t).map_err(std::io::Error::from)?;
    }
    Ok(())
}

#[cfg(not(unix))]
fn raw_mode(_: &std::fs::File) -> std::io::Result<()> {
    Ok(())
}

impl Link for SerialLink {
    fn send(&mut self, kiss_frame: &[u8]) -> std::io::Result<()> {
        self.writer.write_all(kiss_frame)?;
        self.writer.flush()
    }

    fn recv(&mut self, timeout: Duration) -> std::io::Result<Option<Vec<u8>>> {
        let mut bytes = match self.rx.recv_timeout(timeout) {
            Ok(r) => r?,
            Err(mpsc::RecvTimeoutError::Timeout) => return Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::BrokenPipe,
                    "the link's reader stopped",
                ));
            }
        };
        while let Ok(more) = self.rx.try_recv() {
            bytes.extend_from_slice(&more?);
        }
        Ok(Some(bytes))
    }
}

/// Why the upload over a link stopped.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The protocol gave up.
    #[error(transparent)]
    Upload(#[from] UploadError),
    /// A request could not be framed.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// The link failed.
    #[error("the link: {0}")]
    Io(#[from] std::io::Error),
}

/// Longest wait for bytes between two looks at the deadlines.
const POLL: Duration = Duration::from_millis(100);

/// Runs `uploader` over `link` until it is done: sends what it asks, feeds it the replies in the bytes that come
/// back, checks its deadlines; `on_event` sees each of its events. Returns its figures.
pub fn upload<L: Link>(
    link: &mut L,
    framer: &mut UpdateFramer,
    uploader: &mut Uploader,
    mut on_event: impl FnMut(&UploadEvent),
) -> Result<UploadSummary, LinkError> {
    loop {
        while let Some(e) = uploader.poll_event() {
            on_event(&e);
        }
        if uploader.is_done() {
            return Ok(uploader.summary());
        }
        let now = Instant::now();
        while let Some(request) = uploader.next_request(now) {
            link.send(&framer.encode(&request)?)?;
        }
        let wait = uploader
            .deadline()
            .map_or(POLL, |d| d.saturating_duration_since(now))
            .min(POLL);
        if let Some(bytes) = link.recv(wait)? {
            for reply in framer.decode(&bytes) {
                uploader.on_reply(&reply)?;
            }
        }
        uploader.on_tick(Instant::now())?;
    }
}
