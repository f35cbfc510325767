//! The in-orbit update in the loop (`docs/update.md`): the ground's `Uploader` (what `ground fw-upload` runs) talks
//! CSP/KISS to the firmware's own tasks over the simulated bus, through loss, duplicates, corruption and a reset;
//! then `shared::update::boot::prepare` (what the bootloader runs) swaps the image on the flash models, the trial
//! image confirms itself, or, reset too early, is reverted.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]
#![allow(clippy::arithmetic_side_effects)]

mod common;

use common::{Ground, Sat, update_reports};
use ed25519_dalek::SigningKey;
use embassy_time::{Duration, Instant, Timer};
use firmware::sim::flash::{self as simflash, DfuModel, StateModel};
use host_test::update::link::{BusAddrs, UpdateFramer};
use host_test::update::uploader::{UploadConfig, Uploader};
use host_test::update::{SignedImage, sign};
use shared::storage::mock::MockFlash;
use shared::telemetry::{Command, Mode};
use shared::update::{BOARD_ID, BootAction, BootState, DfuState, UpdateOutcome, boot, image};

const ACTIVE_SECTOR: usize = 128 * 1024;
type ActiveModel = MockFlash<ACTIVE_SECTOR>;

fn key() -> SigningKey {
    SigningKey::from_bytes(&[42; 32])
}

/// A signed image of `len` pseudo-random payload bytes at `version`.
fn signed(len: usize, version: u32) -> (Vec<u8>, SignedImage) {
    let mut x = 0x9E37_79B9_7F4A_7C15u64 ^ u64::from(version);
    let payload: Vec<u8> = (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect();
    let bytes = sign(&payload, &key(), version, BOARD_ID).unwrap();
    let image = SignedImage::parse(&bytes).unwrap();
    (bytes, image)
}

/// What the link does to each frame, in turn (a repeating pattern: deterministic).
#[derive(Clone, Copy)]
struct Lossy {
    every: u64,
}

/// Drives `up` against the satellite until it is done or `stop_at` payload bytes are acknowledged; frames to the
/// satellite are lost, duplicated or corrupted on a fixed pattern when `lossy`. Returns the ground's telemetry.
async fn drive(
    board: &firmware::sim::node::Board,
    up: &mut Uploader,
    lossy: Option<Lossy>,
    stop_at: Option<u32>,
    ground: &mut Ground,
) {
    let mut framer = UpdateFramer::new(BusAddrs::default());
    let t0 = std::time::Instant::now();
    let now = || t0 + std::time::Duration::from_micros(Instant::now().as_micros());
    let mut n = 0u64;
    loop {
        while let Some(env) = up.next_request(now()) {
            let mut frame = framer.encode(&env).unwrap();
            n += 1;
            if let Some(l) = lossy {
                match n % l.every {
                    0 => continue, // lost
                    3 => {
                        let mid = frame.len() / 2;
                        frame[mid] ^= 0x20; // corrupted on the wire (the CSP CRC catches it)
                    }
                    5 => {
                        board.bus_rx.push(&frame); // duplicated
                    }
                    _ => {}
                }
            }
            assert_eq!(board.bus_rx.push(&frame), 0, "the bus ring overflowed");
        }
        Timer::after(Duration::from_millis(5)).await;
        let bytes = board.bus_tx.take_all();
        ground.take(&bytes);
        for r in framer.decode(&bytes) {
            up.on_reply(&r).unwrap();
        }
        up.on_tick(now()).unwrap();
        if up.is_done() || stop_at.is_some_and(|s| up.acked() >= s) {
            return;
        }
    }
}

/// A satellite whose update service runs on `dfu` and `state`, with the running image at `running_version`.
fn sat_on(dfu: DfuModel, state: StateModel, running_version: u32) -> Sat {
    let mut sat = Sat::fresh();
    sat.update = simflash::updater_on(
        dfu,
        state,
        key().verifying_key().to_bytes(),
        running_version,
    );
    sat
}

fn models(sat: &mut Sat) -> (DfuModel, StateModel) {
    (sat.update.dfu.0.clone(), sat.update.boot.flash().0.clone())
}

async fn idle(ground: &mut Ground, board: &firmware::sim::node::Board) {
    let ack = ground
        .transact(board, 1, Command::SetMode(Mode::Idle))
        .await;
    assert_eq!(ack.result, Ok(()));
}

#[test]
fn an_upload_through_loss_and_a_reset_is_swapped_in_and_confirms_itself() {
    let (old_bytes, _) = signed(180_000, 4);
    let (new_bytes, new) = signed(150_000, 5);
    // First boot: Idle, upload over a lossy link, cut (a reset) at about half the payload.
    let mut sat = sat_on(DfuModel::erased(3), StateModel::erased(1), 4);
    let mut first = Uploader::new(&new, UploadConfig::default()).unwrap();
    let mut ground = Ground::new();
    sat.run(Duration::from_secs(600), async |_, board| {
        idle(&mut ground, board).await;
        drive(
            board,
            &mut first,
            Some(Lossy { every: 7 }),
            Some(70_000),
            &mut ground,
        )
        .await;
    });
    let half = first.acked();
    assert!((70_000..150_000).contains(&half), "{half}");
    // Second boot: the upload resumes where the DFU slot stops, and commits.
    let (dfu, state) = models(&mut sat);
    let mut sat = sat_on(dfu, state, 4);
    // With `--reset`: the SITL has no reset of its own (a warning); the reply still comes.
    let config = UploadConfig {
        reset: true,
        ..UploadConfig::default()
    };
    let mut second = Uploader::new(&new, config).unwrap();
    let mut ground = Ground::new();
    sat.run(Duration::from_secs(600), async |_, board| {
        idle(&mut ground, board).await;
        drive(
            board,
            &mut second,
            Some(Lossy { every: 11 }),
            None,
            &mut ground,
        )
        .await;
        Timer::after(Duration::from_millis(1500)).await;
        ground.receive(board);
    });
    let sent = second.summary();
    assert!(second.is_done());
    let u = *update_reports(&ground.telemetry).last().unwrap();
    assert_eq!(
        (u.dfu, u.boot, u.last),
        (
            DfuState::Committed,
            BootState::Swap,
            UpdateOutcome::Committed(5)
        )
    );
    assert!(
        u.counters.crc_errors > 0 || u.counters.out_of_order > 0,
        "{:?}",
        u.counters
    );
    println!(
        "resumed at {half} of 150 000 bytes; second boot: {sent:?}; counters {:?}",
        u.counters
    );

    // The bootloader, on ACTIVE (the old image), DFU and the state partition: it swaps.
    let (mut dfu, mut state) = models(&mut sat);
    let mut active = ActiveModel::erased(2);
    active.mem[..old_bytes.len()].copy_from_slice(&old_bytes);
    let pk = key().verifying_key().to_bytes();
    let prepare = |a: &mut ActiveModel, d: &mut DfuModel, s: &mut StateModel| {
        boot::prepare(a, d, s, &mut [0u8; 4096], &mut [0u8; 4], &pk, BOARD_ID).unwrap()
    };
    let r = prepare(&mut active, &mut dfu, &mut state);
    assert_eq!((r.action, r.active_version), (BootAction::Swapped, 5));
    assert_eq!(
        &active.mem[image::HEADER_LEN..new_bytes.len()],
        &new_bytes[image::HEADER_LEN..]
    );

    // A trial boot reset after 10 s (before it confirmed): the next boot reverts.
    let mut early = sat_on(dfu.clone(), state.clone(), 5);
    assert!(early.update.trial);
    early.run(Duration::from_secs(60), async |_, _| {
        Timer::after(Duration::from_secs(10)).await
    });
    let (mut d2, mut s2) = models(&mut early);
    let mut a2 = active.clone();
    assert_eq!(
        prepare(&mut a2, &mut d2, &mut s2).action,
        BootAction::Reverted
    );
    assert_eq!(
        &a2.mem[image::HEADER_LEN..old_bytes.len()],
        &old_bytes[image::HEADER_LEN..]
    );

    // The trial that runs 30 s without a missed deadline confirms itself: the next boot keeps it.
    let mut trial = sat_on(dfu, state, 5);
    let mut ground = Ground::new();
    trial.run(Duration::from_secs(60), async |_, board| {
        Timer::after(Duration::from_secs(32)).await;
        ground.receive(board);
    });
    let u = *update_reports(&ground.telemetry).last().unwrap();
    assert_eq!(
        (u.boot, u.last),
        (BootState::Boot, UpdateOutcome::Confirmed(5))
    );
    let (mut d3, mut s3) = models(&mut trial);
    assert_eq!(
        prepare(&mut active, &mut d3, &mut s3).action,
        BootAction::Booted
    );
    assert_eq!(
        &active.mem[image::HEADER_LEN..new_bytes.len()],
        &new_bytes[image::HEADER_LEN..]
    );
}

#[test]
fn writes_are_refused_while_streaming_and_bad_images_at_open() {
    use shared::update::{ImageError, UpdateEnvelope, UpdateError, UpdateReply, UpdateRequest};
    let (_, new) = signed(10_000, 5);
    let mut sat = sat_on(DfuModel::erased(3), StateModel::erased(1), 4);
    let mut ground = Ground::new();
    let replies = sat.run(Duration::from_secs(60), async |_, board| {
        let mut framer = UpdateFramer::new(BusAddrs::default());
        let mut ask = async |tag: u16, request: UpdateRequest| {
            board
                .bus_rx
                .push(&framer.encode(&UpdateEnvelope { tag, request }).unwrap());
            loop {
                Timer::after(Duration::from_millis(5)).await;
                let bytes = board.bus_tx.take_all();
                ground.take(&bytes);
                if let Some(r) = framer.decode(&bytes).into_iter().find(|r| r.tag == tag) {
                    return r.reply;
                }
            }
        };
        let open = UpdateRequest::Open {
            header: new.open_bytes(),
            restart: false,
        };
        let opened = ask(1, open.clone()).await;
        let streaming = ask(2, UpdateRequest::Erase { sector: 0 }).await;
        let mut forged = new.open_bytes();
        forged[12] ^= 2; // the version (5 → 7), under the signature
        let forged = ask(
            3,
            UpdateRequest::Open {
                header: forged,
                restart: false,
            },
        )
        .await;
        (opened, streaming, forged)
    });
    assert_eq!(
        replies.0,
        UpdateReply::Opened {
            sectors: 1,
            erased: 0,
            next_offset: 0
        }
    );
    assert_eq!(replies.1, UpdateReply::Refused(UpdateError::NotIdle));
    assert_eq!(
        replies.2,
        UpdateReply::Refused(UpdateError::Image(ImageError::Signature))
    );
    assert!(
        sat.update.dfu.0.mem.iter().all(|&b| b == 0xFF),
        "nothing written while streaming"
    );
}

/// Resets the host "MCU": counts.
static RESETS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
fn note_reset() {
    RESETS.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
}

#[test]
fn a_reset_request_is_answered_before_the_reset() {
    use shared::update::{UpdateEnvelope, UpdateReply, UpdateRequest};
    let mut sat = Sat::boot_on(
        simflash::erased(),
        Some(firmware::layout::BUS_BAUD),
        shared::pipeline::PipelineConfig::DEFAULT,
        firmware::app::Platform {
            reset: Some(note_reset),
            ..firmware::app::Platform::default()
        },
    );
    let (reply, resets_at_reply, resets_after) =
        sat.run(Duration::from_secs(60), async |_, board| {
            let mut framer = UpdateFramer::new(BusAddrs::default());
            let request = UpdateEnvelope {
                tag: 9,
                request: UpdateRequest::Reset,
            };
            board.bus_rx.push(&framer.encode(&request).unwrap());
            let reply = loop {
                Timer::after(Duration::from_millis(5)).await;
                if let Some(r) = framer
                    .decode(&board.bus_tx.take_all())
                    .into_iter()
                    .find(|r| r.tag == 9)
                {
                    break r.reply;
                }
            };
            let at_reply = RESETS.load(std::sync::atomic::Ordering::SeqCst);
            Timer::after(firmware::app::RESET_AFTER + Duration::from_millis(100)).await;
            (
                reply,
                at_reply,
                RESETS.load(std::sync::atomic::Ordering::SeqCst),
            )
        });
    assert_eq!(reply, UpdateReply::Resetting);
    assert_eq!(
        (resets_at_reply, resets_after),
        (0, 1),
        "the reply first, then one reset"
    );
}
