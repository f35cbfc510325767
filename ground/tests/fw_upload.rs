//! The in-orbit update's upload client (`host_test::update::Uploader`) against the satellite's `Receiver` over a
//! lossy link in virtual time: verified and committed, resumed after an interruption, refusals reported, the window
//! bounded by the satellite's bus ring. (Signing, keys, the ELF and the commands: `fw_tools`.)

mod fw_support;

use fw_support::*;
use host_test::testrng::TestRng;
use host_test::update::link::{BusAddrs, UpdateFramer, max_request_wire_len, max_window};
use host_test::update::uploader::{RewindCause, UploadError, UploadEvent};
use host_test::update::{self, SignedImage, UploadConfig, Uploader};
use shared::bus::csp::CspVersion;
use shared::update::image::{self, HEADER_LEN};
use shared::update::{
    BOARD_ID, BootState, DfuState, ImageError, UpdateEnvelope, UpdateError, UpdateRequest,
};
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// The link, lossy, in virtual time.

/// How the link treats each frame, in each direction.
#[derive(Clone, Copy)]
struct Faults {
    loss: f64,
    duplicate: f64,
    corrupt: f64,
    delay: f64,
}

const CLEAN: Faults = Faults {
    loss: 0.0,
    duplicate: 0.0,
    corrupt: 0.0,
    delay: 0.0,
};

#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Debug)]
enum Dir {
    Up,
    Down,
}

/// A frame in flight: when it arrives, its sequence number, which way it goes, its bytes.
type InFlight = (Instant, u64, Dir, Vec<u8>);

/// Frames in flight, delivered in time order (then in the order sent).
struct Net {
    faults: Faults,
    rng: TestRng,
    queue: BinaryHeap<Reverse<InFlight>>,
    seq: u64,
    /// When each line (up, down) is free again.
    line_free: [Option<Instant>; 2],
    /// Frames sent each way, and what the faults did.
    sent: [u64; 2],
    lost: u64,
    duplicated: u64,
    corrupted: u64,
    delayed: u64,
}

impl Net {
    fn new(faults: Faults, seed: u64) -> Self {
        Self {
            faults,
            rng: TestRng::new(seed),
            queue: BinaryHeap::new(),
            seq: 0,
            line_free: [None; 2],
            sent: [0; 2],
            lost: 0,
            duplicated: 0,
            corrupted: 0,
            delayed: 0,
        }
    }

    /// A frame leaving at `t`, once the line is free: its time on a 115200-baud line (87 µs a byte) plus 10 ms of
    /// latency, and the faults.
    fn send(&mut self, dir: Dir, mut frame: Vec<u8>, t: Instant) {
        self.sent[dir as usize] += 1;
        let f = self.faults;
        if self.rng.uniform() < f.loss {
            self.lost += 1;
            return;
        }
        if self.rng.uniform() < f.corrupt {
            self.corrupted += 1;
            let i = (self.rng.next_u64() % frame.len() as u64) as usize;
            frame[i] ^= 1 << (self.rng.next_u64() % 8);
        }
        // One frame at a time on each line (FIFO): it starts when the line is free.
        let line = &mut self.line_free[dir as usize];
        let start = line.map_or(t, |free| free.max(t));
        *line = Some(start + Duration::from_micros(frame.len() as u64 * 87));
        let mut at =
            start + Duration::from_millis(10) + Duration::from_micros(frame.len() as u64 * 87);
        if self.rng.uniform() < f.delay {
            self.delayed += 1;
            at += Duration::from_millis(50 + self.rng.next_u64() % 250);
        }
        let copies = if self.rng.uniform() < f.duplicate {
            self.duplicated += 1;
            2
        } else {
            1
        };
        for k in 0..copies {
            self.seq += 1;
            self.queue.push(Reverse((
                at + Duration::from_millis(3 * k),
                self.seq,
                dir,
                frame.clone(),
            )));
        }
    }
}

/// Runs `up` against `sat` over `net` from `*now` until it is done, fails, or `stop` says so; returns its events.
fn run(
    up: &mut Uploader,
    sat: &mut Sat,
    net: &mut Net,
    now: &mut Instant,
    stop: impl Fn(&Uploader) -> bool,
) -> (Vec<UploadEvent>, Result<(), UploadError>) {
    let mut framer = UpdateFramer::new(BusAddrs::default());
    let mut events = Vec::new();
    let result = (|| {
        for _ in 0..2_000_000 {
            while let Some(e) = up.poll_event() {
                events.push(e);
            }
            if up.is_done() || stop(up) {
                return Ok(());
            }
            while let Some(req) = up.next_request(*now) {
                net.send(Dir::Up, framer.encode(&req).unwrap(), *now);
            }
            let next = net.queue.peek().map(|Reverse((t, ..))| *t);
            let t = match (next, up.deadline()) {
                (Some(a), Some(b)) => a.min(b),
                (a, b) => a.or(b).expect("nothing in flight and nothing awaited"),
            };
            *now = (*now).max(t);
            while net.queue.peek().is_some_and(|Reverse((t, ..))| *t <= *now) {
                let Reverse((t, _, dir, bytes)) = net.queue.pop().unwrap();
                match dir {
                    Dir::Up => {
                        for (at, reply) in sat.receive(&bytes, t) {
                            net.send(Dir::Down, reply, at);
                        }
                    }
                    Dir::Down => {
                        for r in framer.decode(&bytes) {
                            up.on_reply(&r)?;
                        }
                    }
                }
            }
            up.on_tick(*now)?;
        }
        panic!("the upload does not end");
    })();
    while let Some(e) = up.poll_event() {
        events.push(e);
    }
    (events, result)
}

#[test]
fn upload_gets_through_a_lossy_link_verified_and_committed() {
    let pk = test_key(7).verifying_key().to_bytes();
    // 150 000 bytes + the header span two 128 KiB sectors.
    let (img, signed) = test_image(150_001, 5, 10);
    let faults = Faults {
        loss: 0.05,
        duplicate: 0.03,
        corrupt: 0.03,
        delay: 0.03,
    };
    let (mut causes, mut timeouts) = (Vec::new(), 0);
    for seed in 1..=3u64 {
        let mut sat = Sat::new(Dfu::erased(3), Boot::default(), pk, 0.02, seed);
        let mut net = Net::new(faults, seed);
        let mut up = Uploader::new(&img, UploadConfig::default()).unwrap();
        let mut now = Instant::now();
        let t0 = now;
        let (events, r) = run(&mut up, &mut sat, &mut net, &mut now, |_| false);
        r.unwrap();
        slot_holds(&mut sat.dfu, &signed);
        assert_eq!(sat.boot.state, BootState::Swap, "committed");
        let st = sat.rx.status(&mut sat.dfu, &ctx(&pk), &mut sat.boot);
        assert_eq!(st.dfu, DfuState::Committed);
        let s = up.summary();
        let c = st.counters;
        println!(
            "seed {seed}: {:.1} s virtual, {} chunks ({} again), {} rewinds, {} timeouts, {} ignored; link: {} / {} \
             frames, {} lost, {} duplicated, {} corrupted, {} delayed; satellite: {c:?}",
            (now - t0).as_secs_f64(),
            s.chunks_sent,
            s.chunks_resent,
            s.rewinds,
            s.timeouts,
            s.ignored,
            net.sent[0],
            net.sent[1],
            net.lost,
            net.duplicated,
            net.corrupted,
            net.delayed,
        );
        // Every kind of fault happened, and was got over.
        assert!(net.lost > 0 && net.duplicated > 0 && net.corrupted > 0 && net.delayed > 0);
        assert!(
            c.out_of_order > 0 && c.duplicates > 0 && c.crc_errors > 0,
            "{c:?}"
        );
        assert!(s.chunks_resent > 0 && s.ignored > 0, "{s:?}");
        timeouts += s.timeouts;
        causes.extend(events.iter().filter_map(|e| match e {
            UploadEvent::Rewind { cause, .. } => Some(*cause),
            _ => None,
        }));
        assert_eq!(
            events.last(),
            Some(&UploadEvent::Committed),
            "the last event"
        );
        assert_eq!(s.resumed_from, 0);
        assert_eq!(s.payload_len, 150_004);
        // Never more than the window in flight: chunks sent ≥ the payload's chunks.
        assert!(s.chunks_sent >= 150_004u64.div_ceil(192));
    }
    assert!(timeouts > 0);
    for cause in [
        RewindCause::Lost,
        RewindCause::Corrupted,
        RewindCause::Timeout,
    ] {
        assert!(causes.contains(&cause), "no rewind for {cause:?}");
    }
}

#[test]
fn upload_resumes_where_the_slot_stops() {
    let pk = test_key(7).verifying_key().to_bytes();
    let (img, signed) = test_image(150_001, 6, 11);
    let total = 150_004u32;
    let mut now = Instant::now();
    // First attempt: interrupted (the link drops, the satellite resets) once half the payload is acknowledged.
    let mut sat = Sat::new(Dfu::erased(3), Boot::default(), pk, 0.0, 1);
    let mut net = Net::new(CLEAN, 1);
    let mut up = Uploader::new(&img, UploadConfig::default()).unwrap();
    let (_, r) = run(&mut up, &mut sat, &mut net, &mut now, |u| {
        u.acked() >= total / 2
    });
    r.unwrap();
    let first = up.summary();
    let acked = up.acked();
    assert!(acked >= total / 2 && acked < total);
    assert_eq!(first.erases, 2);
    // A new receiver (a reset) on the same flash, a new uploader, frames in flight lost.
    let dfu = std::mem::replace(&mut sat.dfu, Dfu::erased(1));
    let mut sat = Sat::new(dfu, Boot::default(), pk, 0.0, 2);
    let mut net = Net::new(CLEAN, 2);
    let mut up = Uploader::new(&img, UploadConfig::default()).unwrap();
    let (events, r) = run(&mut up, &mut sat, &mut net, &mut now, |_| false);
    r.unwrap();
    slot_holds(&mut sat.dfu, &signed);
    assert_eq!(sat.boot.state, BootState::Swap);
    let second = up.summary();
    println!("interrupted: {first:?}\nresumed: {second:?}");
    let Some(&UploadEvent::Opened {
        sectors: 2,
        erased: 2,
        next_offset,
    }) = events
        .iter()
        .find(|e| matches!(e, UploadEvent::Opened { .. }))
    else {
        panic!("not opened with both sectors erased: {events:?}")
    };
    // The slot holds at least what was acknowledged (chunks whose acks were still in flight, too).
    assert!(
        next_offset >= acked && next_offset <= first.chunk_bytes as u32,
        "{next_offset} {acked}"
    );
    assert_eq!(second.resumed_from, next_offset);
    assert_eq!(second.erases, 0, "no sector erased again");
    assert_eq!(
        second.chunk_bytes,
        u64::from(total - next_offset),
        "only the rest sent"
    );
    assert!(second.chunk_bytes < u64::from(total));
    assert_eq!(second.chunks_resent, 0);
}

#[test]
fn no_commit_stops_at_verified_and_refusals_are_reported() {
    let pk = test_key(7).verifying_key().to_bytes();
    let (img, signed) = test_image(5000, 4, 12);
    let mut sat = Sat::new(Dfu::erased(3), Boot::default(), pk, 0.0, 1);
    let mut net = Net::new(CLEAN, 1);
    let config = UploadConfig {
        commit: false,
        window: 1,
        ..UploadConfig::default()
    };
    let mut up = Uploader::new(&img, config).unwrap();
    let mut now = Instant::now();
    let (events, r) = run(&mut up, &mut sat, &mut net, &mut now, |_| false);
    r.unwrap();
    slot_holds_one_sector(&mut sat.dfu, &signed);
    assert_eq!(sat.boot.state, BootState::Boot, "not committed");
    assert_eq!(events.last(), Some(&UploadEvent::Verified));
    assert!(matches!(
        events.first(),
        Some(UploadEvent::Status(s)) if s.running_version == RUNNING_VERSION
    ));
    // Refusals the upload cannot cure end it, typed: an image for another board, an old version.
    for (signed, want) in [
        (
            update::sign(&random_bytes(100, 1), &test_key(7), 9, BOARD_ID + 1).unwrap(),
            ImageError::Board,
        ),
        (
            update::sign(
                &random_bytes(100, 1),
                &test_key(7),
                RUNNING_VERSION,
                BOARD_ID,
            )
            .unwrap(),
            ImageError::Rollback,
        ),
        (
            update::sign(&random_bytes(100, 1), &test_key(8), 9, BOARD_ID).unwrap(),
            ImageError::Signature,
        ),
    ] {
        let img = SignedImage::parse(&signed).unwrap();
        let mut up = Uploader::new(&img, UploadConfig::default()).unwrap();
        let (_, r) = run(&mut up, &mut sat, &mut net, &mut now, |_| false);
        assert_eq!(
            r,
            Err(UploadError::Refused {
                request: "Open",
                error: UpdateError::Image(want)
            })
        );
    }
    // A satellite that never answers: the upload gives up after max_timeouts.
    let mut sat = Sat::new(Dfu::erased(3), Boot::default(), pk, 0.0, 1);
    let mut net = Net::new(Faults { loss: 1.0, ..CLEAN }, 1);
    let mut up = Uploader::new(
        &img,
        UploadConfig {
            max_timeouts: 7,
            ..UploadConfig::default()
        },
    )
    .unwrap();
    let t0 = now;
    let (_, r) = run(&mut up, &mut sat, &mut net, &mut now, |_| false);
    assert_eq!(r, Err(UploadError::Timeout(7)));
    assert_eq!(now - t0, Duration::from_secs(7), "7 timeouts of 1 s");
}

fn slot_holds_one_sector(dfu: &mut Dfu, signed: &[u8]) {
    let pk = test_key(7).verifying_key().to_bytes();
    image::verify_slot(dfu, &pk, BOARD_ID, RUNNING_VERSION, ACTIVE_LEN).unwrap();
    assert_eq!(&dfu.mem[HEADER_LEN..signed.len()], &signed[HEADER_LEN..]);
}

/// The window's bound: W requests of the largest size on the wire, every byte escaped, fit the satellite's 16 KiB
/// bus ring. The largest request counted by hand: postcard varints (tag 3, variant 1, offset 5, CRC 5, length 2)
/// and 192 data bytes = 208; CSP v1 header 4 (v2 6) and link CRC 4; KISS: FEND, command, 2 per byte, FEND.
#[test]
fn window_fits_the_satellites_bus_ring() {
    let payload = 3 + 1 + 5 + 5 + 2 + 192;
    for (v, head) in [(CspVersion::V1, 4), (CspVersion::V2, 6)] {
        let frame = head + payload + 4;
        assert_eq!(max_request_wire_len(v), 2 * frame + 3);
        assert_eq!(max_window(16 * 1024, v), 16 * 1024 / (2 * frame + 3));
        // A real worst case: the data all FEND bytes; its frame is no longer than the bound.
        let framer = UpdateFramer::new(BusAddrs {
            version: v,
            ..BusAddrs::default()
        });
        let data = heapless::Vec::from_slice(&[0xC0; 192]).unwrap();
        let worst = framer
            .encode(&UpdateEnvelope {
                tag: u16::MAX,
                request: UpdateRequest::Chunk {
                    offset: u32::MAX - 3,
                    crc32c: shared::crc::crc32c(&data),
                    data,
                },
            })
            .unwrap();
        assert!(worst.len() <= max_request_wire_len(v), "{}", worst.len());
        assert!(worst.len() >= 2 * 192, "the data escaped");
    }
    assert_eq!(max_window(16 * 1024, CspVersion::V1), 37);
    assert!(UploadConfig::default().window <= max_window(16 * 1024, CspVersion::V2));
}
