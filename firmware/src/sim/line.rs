//! A serial line between a model of the outside world and a firmware task: the bytes in flight, bounded like the
//! UART's receive buffer (the DMA ring of the FPGA link), plus injected receive errors.
//!
//! - [`Line::rx`] is the task's end: `embedded_io_async::Read`, with the error kinds of the STM32 USART
//!   ([`SimRxError`]). An error is reported once, at the byte position where it was injected, then reception goes on
//!   — as embassy-stm32's ring-buffered UART restarts its DMA on the next read.
//! - The world writes with [`Line::push`] (never waits: what does not fit is lost and reported to the reader as an
//!   overrun, as a real ring that is not read in time) or with [`LineWriter`], which waits for room (`--fast`
//!   replay) or paces the bytes at a baud rate (a UART transmitter: the bus at 115200 baud).
//! - Threads use [`Line::push`] and [`Line::pop_blocking`] (the SITL's serial port I/O).

use core::task::Poll;
use std::collections::VecDeque;
use std::sync::{Condvar, Mutex, MutexGuard};
use std::vec::Vec;

use embassy_sync::waitqueue::AtomicWaker;
use embassy_time::{Duration, Timer};

use crate::app::{ClassifyRxError, RxFault};

/// A receive error of the modelled USART.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimRxError {
    /// Bytes were lost: the receive buffer was full.
    Overrun,
    /// A framing error (bad stop bit).
    Framing,
    /// Noise detected on the line.
    Noise,
}

impl ClassifyRxError for SimRxError {
    fn classify(&self) -> RxFault {
        match self {
            SimRxError::Overrun => RxFault::Overrun,
            SimRxError::Framing | SimRxError::Noise => RxFault::Line,
        }
    }
}

impl core::fmt::Display for SimRxError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Debug::fmt(self, f)
    }
}

impl core::error::Error for SimRxError {}

impl embedded_io_async::Error for SimRxError {
    fn kind(&self) -> embedded_io_async::ErrorKind {
        embedded_io_async::ErrorKind::Other
    }
}

#[derive(Default)]
struct State {
    bytes: VecDeque<u8>,
    /// Errors to report, each before the byte at this stream position (bytes written so far, lost ones excluded).
    faults: VecDeque<(u64, SimRxError)>,
    written: u64,
    read: u64,
    /// Bytes the next writes lose (the bytes an injected error garbles).
    lose: usize,
    overrun_pending: bool,
}

/// One direction of a serial line.
pub struct Line {
    capacity: usize,
    state: Mutex<State>,
    changed: Condvar,
    reader: AtomicWaker,
    writer: AtomicWaker,
}

impl Line {
    /// A line whose receiver buffers `capacity` bytes.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            state: Mutex::new(State::default()),
            changed: Condvar::new(),
            reader: AtomicWaker::new(),
            writer: AtomicWaker::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock is a test failure already; the state is still consistent.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Appends `bytes` without waiting. Bytes that do not fit are lost, and the reader gets one overrun error before
    /// the first byte that arrived after the loss. Returns the number of bytes lost.
    pub fn push(&self, bytes: &[u8]) -> usize {
        let mut s = self.lock();
        let mut lost = 0usize;
        for &b in bytes {
            if s.lose > 0 {
                s.lose -= 1;
                continue;
            }
            if s.bytes.len() >= self.capacity {
                lost += 1;
                s.overrun_pending = true;
                continue;
            }
            if s.overrun_pending {
                s.overrun_pending = false;
                let at = s.written;
                s.faults.push_back((at, SimRxError::Overrun));
            }
            s.bytes.push_back(b);
            s.written += 1;
        }
        drop(s);
        self.reader.wake();
        self.changed.notify_all();
        lost
    }

    /// Injects a receive error here: the reader gets `error` before the next byte written, and the next `garbled`
    /// bytes written are lost (the bytes the line fault destroyed).
    pub fn inject(&self, error: SimRxError, garbled: usize) {
        let mut s = self.lock();
        let at = s.written;
        s.faults.push_back((at, error));
        s.lose += garbled;
        drop(s);
        self.reader.wake();
    }

    /// Bytes waiting for the reader.
    pub fn len(&self) -> usize {
        self.lock().bytes.len()
    }

    /// Whether no byte waits for the reader.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Everything waiting for the reader, without waiting (a test's or the SITL's end of a transmit line).
    pub fn take_all(&self) -> Vec<u8> {
        let mut s = self.lock();
        let n = s.bytes.len() as u64;
        s.read += n;
        let out = s.bytes.drain(..).collect();
        drop(s);
        self.writer.wake();
        out
    }

    /// Waits (blocking the calling thread) up to `timeout` for bytes, then takes all of them.
    pub fn pop_blocking(&self, timeout: std::time::Duration) -> Vec<u8> {
        let s = self.lock();
        let (s, _) = self
            .changed
            .wait_timeout_while(s, timeout, |s| s.bytes.is_empty())
            .unwrap_or_else(|e| e.into_inner());
        drop(s);
        self.take_all()
    }

    /// The task's end of the line.
    pub fn rx(&self) -> LineRx<'_> {
        LineRx { line: self }
    }

    /// A writer that waits for room (`baud: None`) or paces bytes at `baud` (8N1).
    pub fn writer(&self, baud: Option<u32>) -> LineWriter<'_> {
        LineWriter { line: self, baud }
    }
}

/// The receiving end: `embedded_io_async::Read`.
pub struct LineRx<'a> {
    line: &'a Line,
}

impl embedded_io_async::ErrorType for LineRx<'_> {
    type Error = SimRxError;
}

impl embedded_io_async::Read for LineRx<'_> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, SimRxError> {
        let line = self.line;
        core::future::poll_fn(|cx| {
            let mut s = line.lock();
            if let Some(&(at, e)) = s.faults.front()
                && at <= s.read
            {
                s.faults.pop_front();
                return Poll::Ready(Err(e));
            }
            if s.bytes.is_empty() || buf.is_empty() {
                line.reader.register(cx.waker());
                return Poll::Pending;
            }
            // Up to the next error's position, so that it is reported where it happened.
            let until_fault = s
                .faults
                .front()
                .map_or(usize::MAX, |&(at, _)| (at - s.read) as usize);
            let n = buf.len().min(s.bytes.len()).min(until_fault);
            for (dst, src) in buf.iter_mut().zip(s.bytes.drain(..n)) {
                *dst = src;
            }
            s.read += n as u64;
            drop(s);
            line.writer.wake();
            Poll::Ready(Ok(n))
        })
        .await
    }
}

/// A writing end inside the executor: waits for room, or paces at a baud rate.
pub struct LineWriter<'a> {
    line: &'a Line,
    baud: Option<u32>,
}

impl embedded_io_async::ErrorType for LineWriter<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Write for LineWriter<'_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, core::convert::Infallible> {
        let line = self.line;
        let n = core::future::poll_fn(|cx| {
            let s = line.lock();
            let room = line.capacity.saturating_sub(s.bytes.len());
            if room == 0 && !buf.is_empty() {
                line.writer.register(cx.waker());
                return Poll::Pending;
            }
            drop(s);
            Poll::Ready(buf.len().min(room))
        })
        .await;
        let n = n - line.push(buf.get(..n).unwrap_or(&[]));
        if let Some(baud) = self.baud.filter(|&b| b > 0) {
            // 10 bits per byte (start, 8 data, stop).
            Timer::after(Duration::from_micros(
                n as u64 * 10_000_000 / u64::from(baud),
            ))
            .await;
        }
        Ok(n)
    }

    async fn flush(&mut self) -> Result<(), core::convert::Infallible> {
        Ok(())
    }
}
