//! The receiver on the mock flash (128 KiB sectors, power cuts), against images signed here with a throwaway key.

extern crate std;

use super::*;
use crate::crc::crc32c;
use crate::storage::mock::MockFlash;
use crate::testutil::Rng;
use ed25519_dalek::{Signer, SigningKey};
use embedded_storage::nor_flash::NorFlash;
use sha2::{Digest, Sha512};

const SECTOR: usize = 128 * 1024;
type Dfu = MockFlash<SECTOR>;
const BOARD: u32 = 0x4F05_1601;
const ACTIVE_LEN: u32 = 256 * 1024;

fn key() -> SigningKey {
    SigningKey::from_bytes(&[7; 32])
}

/// A signed image (header bytes, payload) of `len` pseudo-random payload bytes.
fn image(
    len: usize,
    version: u32,
    board: u32,
    signer: &SigningKey,
) -> ([u8; image::OPEN_LEN], std::vec::Vec<u8>) {
    let mut rng = Rng::new(len as u64 ^ u64::from(version));
    let payload: std::vec::Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
    let mut h = Header {
        board_id: board,
        version,
        payload_len: len as u32,
        payload_sha512: Sha512::digest(&payload).into(),
        signature: [0; 64],
    };
    h.signature = signer.sign(&h.signed_bytes()).to_bytes();
    (h.emit(), payload)
}

type Boot = MockBoot;

fn ctx(pk: &[u8; 32]) -> Context<'_> {
    Context {
        public_key: pk,
        board_id: BOARD,
        running_version: 3,
        max_image_len: ACTIVE_LEN,
        writable: Ok(()),
    }
}

fn chunk(payload: &[u8], offset: usize, n: usize) -> UpdateRequest {
    let end = (offset + n).min(payload.len());
    let mut data: Vec<u8, CHUNK_MAX> = Vec::from_slice(&payload[offset..end]).unwrap();
    while !data.len().is_multiple_of(4) {
        data.push(0xFF).unwrap();
    }
    UpdateRequest::Chunk {
        offset: offset as u32,
        crc32c: crc32c(&data),
        data,
    }
}

/// Opens, erases and sends everything in order; returns the receiver.
fn upload(
    rx: &mut Receiver,
    dfu: &mut Dfu,
    boot: &mut Boot,
    header: &[u8; image::OPEN_LEN],
    payload: &[u8],
) {
    let pk = key().verifying_key().to_bytes();
    let c = ctx(&pk);
    let UpdateReply::Opened {
        sectors,
        erased,
        mut next_offset,
    } = rx.handle(
        &UpdateRequest::Open {
            header: *header,
            restart: false,
        },
        dfu,
        &c,
        boot,
    )
    else {
        panic!("not opened")
    };
    for s in erased..sectors {
        assert_eq!(
            rx.handle(&UpdateRequest::Erase { sector: s }, dfu, &c, boot),
            UpdateReply::Erased { sector: s }
        );
    }
    while (next_offset as usize) < payload.len() {
        match rx.handle(
            &chunk(payload, next_offset as usize, CHUNK_MAX),
            dfu,
            &c,
            boot,
        ) {
            UpdateReply::Ack { next_offset: n } => next_offset = n,
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn upload_verify_commit() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let (header, payload) = image(200_001, 4, BOARD, &k);
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    upload(&mut rx, &mut dfu, &mut boot, &header, &payload);
    assert_eq!(&dfu.mem[512..512 + payload.len()], &payload[..]);
    assert_eq!(&dfu.mem[..image::OPEN_LEN], &header[..]);
    let c = ctx(&pk);
    assert_eq!(
        rx.handle(&UpdateRequest::Verify, &mut dfu, &c, &mut boot),
        UpdateReply::Verified
    );
    assert_eq!(
        rx.handle(&UpdateRequest::Commit, &mut dfu, &c, &mut boot),
        UpdateReply::Committed
    );
    assert_eq!(boot.state, BootState::Swap);
    assert_eq!(rx.last(), UpdateOutcome::Committed(4));
    let st = rx.status(&mut dfu, &c, &mut boot);
    assert_eq!(
        (st.dfu, st.dfu_version, st.received, st.payload_len),
        (DfuState::Committed, 4, 200_004, 200_001)
    );
    assert_eq!(
        st.counters.erases, 2,
        "200 001 + 512 bytes span two 128 KiB sectors"
    );
    // Abort cancels a swap committed since boot.
    assert_eq!(
        rx.handle(&UpdateRequest::Abort, &mut dfu, &c, &mut boot),
        UpdateReply::Aborted
    );
    assert_eq!(boot.state, BootState::Boot);
    // Reset: acknowledged, and taken once.
    assert!(!rx.take_reset());
    assert_eq!(
        rx.handle(&UpdateRequest::Reset, &mut dfu, &c, &mut boot),
        UpdateReply::Resetting
    );
    assert!(rx.take_reset() && !rx.take_reset(), "one reset per request");
}

/// A fresh upload's first request: open `header`, not restarting.
fn open(header: [u8; image::OPEN_LEN]) -> UpdateRequest {
    UpdateRequest::Open {
        header,
        restart: false,
    }
}

#[test]
fn bad_headers_are_refused_typed_and_write_nothing() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    let refused = |e| UpdateReply::Refused(UpdateError::Image(e));
    // Another key, another board, an older version, too large, not a header.
    let other = SigningKey::from_bytes(&[8; 32]);
    assert_eq!(
        rx.handle(
            &open(image(1000, 4, BOARD, &other).0),
            &mut dfu,
            &c,
            &mut boot
        ),
        refused(ImageError::Signature)
    );
    assert_eq!(
        rx.handle(
            &open(image(1000, 4, BOARD + 1, &k).0),
            &mut dfu,
            &c,
            &mut boot
        ),
        refused(ImageError::Board)
    );
    assert_eq!(
        rx.handle(&open(image(1000, 3, BOARD, &k).0), &mut dfu, &c, &mut boot),
        refused(ImageError::Rollback)
    );
    let big = ACTIVE_LEN as usize - 511;
    assert_eq!(
        rx.handle(&open(image(big, 4, BOARD, &k).0), &mut dfu, &c, &mut boot),
        refused(ImageError::TooLarge)
    );
    let mut h = image(1000, 4, BOARD, &k).0;
    h[0] ^= 1;
    assert_eq!(
        rx.handle(&open(h), &mut dfu, &c, &mut boot),
        refused(ImageError::Magic)
    );
    // A flipped bit anywhere in the signed bytes breaks the signature.
    let mut h = image(1000, 4, BOARD, &k).0;
    h[40] ^= 0x10;
    assert_eq!(
        rx.handle(&open(h), &mut dfu, &c, &mut boot),
        refused(ImageError::Signature)
    );
    assert!(dfu.mem.iter().all(|&b| b == 0xFF), "nothing written");
    assert_eq!(
        rx.handle(&UpdateRequest::Verify, &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::NotOpen)
    );
    assert_eq!(rx.status(&mut dfu, &c, &mut boot).counters.refused, 7);
}

/// Requests out of their order, while not idle, or with a bad chunk are refused, typed, and change nothing.
#[test]
fn requests_out_of_order_are_refused_typed() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    // Not idle: no erase. Out of order erase. Truncated upload: no verify, no commit.
    let (header, payload) = image(5000, 4, BOARD, &k);
    assert!(matches!(
        rx.handle(&open(header), &mut dfu, &c, &mut boot),
        UpdateReply::Opened {
            sectors: 1,
            erased: 0,
            next_offset: 0
        }
    ));
    let busy = Context {
        writable: Err(UpdateError::NotIdle),
        ..c
    };
    assert_eq!(
        rx.handle(
            &UpdateRequest::Erase { sector: 0 },
            &mut dfu,
            &busy,
            &mut boot
        ),
        UpdateReply::Refused(UpdateError::NotIdle)
    );
    assert_eq!(
        rx.handle(&UpdateRequest::Confirm, &mut dfu, &busy, &mut boot),
        UpdateReply::Refused(UpdateError::NotIdle),
        "Confirm rewrites the boot state: not while streaming"
    );
    assert_eq!(
        rx.handle(&UpdateRequest::Erase { sector: 1 }, &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::SectorOrder { expected: 0 })
    );
    assert_eq!(
        rx.handle(&chunk(&payload, 0, 64), &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::NotErased)
    );
    assert_eq!(
        rx.handle(&UpdateRequest::Erase { sector: 0 }, &mut dfu, &c, &mut boot),
        UpdateReply::Erased { sector: 0 }
    );
    assert_eq!(
        rx.handle(&chunk(&payload, 0, 64), &mut dfu, &c, &mut boot),
        UpdateReply::Ack { next_offset: 64 }
    );
    assert_eq!(
        rx.handle(&UpdateRequest::Commit, &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::Incomplete { next_offset: 64 })
    );
    // Bad CRC, misaligned, past the end.
    let UpdateRequest::Chunk { offset, data, .. } = chunk(&payload, 64, 64) else {
        panic!("a chunk")
    };
    assert_eq!(
        rx.handle(
            &UpdateRequest::Chunk {
                offset,
                crc32c: 0,
                data
            },
            &mut dfu,
            &c,
            &mut boot
        ),
        UpdateReply::Refused(UpdateError::Crc)
    );
    assert_eq!(
        rx.handle(&chunk(&payload, 66, 64), &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::Range)
    );
    assert_eq!(
        rx.handle(&chunk(&payload, 128, 64), &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::OutOfOrder { expected: 64 })
    );
    assert_eq!(boot.state, BootState::Boot);
}

#[test]
fn corrupted_payload_fails_the_hash() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (header, mut payload) = image(3000, 4, BOARD, &k);
    payload[1234] ^= 0x01; // sent with a good chunk CRC: corrupted before it was signed-for bytes left the ground
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    upload(&mut rx, &mut dfu, &mut boot, &header, &payload);
    assert_eq!(
        rx.handle(&UpdateRequest::Commit, &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::Image(ImageError::Hash))
    );
    assert_eq!(rx.last(), UpdateOutcome::Refused(ImageError::Hash));
    assert_eq!(boot.state, BootState::Boot, "nothing committed");
}

/// A power cut at every flash operation of an upload: after each, a new receiver (a reset) resumes from what the
/// slot holds, and the image ends verified, byte for byte.
#[test]
fn resumes_after_a_reset_at_every_flash_operation() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (header, payload) = image(150_000, 9, BOARD, &k);
    // Operations of a clean upload.
    let mut dfu = Dfu::erased(3);
    upload(
        &mut Receiver::default(),
        &mut dfu,
        &mut Boot::default(),
        &header,
        &payload,
    );
    let total_ops = dfu.ops;
    let mut cut_at = 0;
    let step = (total_ops / 60).max(1); // 60 cut points spread over the upload, and the first few operations
    while cut_at < total_ops {
        let mut dfu = Dfu::erased(3);
        dfu.budget = Some(cut_at);
        let mut boot = Boot::default();
        let mut rx = Receiver::default();
        // Runs until the power cut makes a request fail.
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            upload(&mut rx, &mut dfu, &mut boot, &header, &payload)
        }));
        dfu.budget = None;
        let mut rx = Receiver::default();
        upload(&mut rx, &mut dfu, &mut boot, &header, &payload);
        assert_eq!(
            rx.handle(&UpdateRequest::Verify, &mut dfu, &c, &mut boot),
            UpdateReply::Verified,
            "cut at {cut_at}"
        );
        cut_at += if cut_at < 8 { 1 } else { step };
    }
}

#[test]
fn resume_reports_what_arrived() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (header, payload) = image(140_000, 5, BOARD, &k);
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    let open = UpdateRequest::Open {
        header,
        restart: false,
    };
    rx.handle(&open, &mut dfu, &c, &mut boot);
    rx.handle(&UpdateRequest::Erase { sector: 0 }, &mut dfu, &c, &mut boot);
    // A reset after one erase: one sector erased, no payload.
    let mut rx = Receiver::default();
    assert_eq!(
        rx.handle(&open, &mut dfu, &c, &mut boot),
        UpdateReply::Opened {
            sectors: 2,
            erased: 1,
            next_offset: 0
        }
    );
    assert_eq!(
        rx.handle(&UpdateRequest::Erase { sector: 0 }, &mut dfu, &c, &mut boot),
        UpdateReply::Erased { sector: 0 },
        "duplicate"
    );
    rx.handle(&UpdateRequest::Erase { sector: 1 }, &mut dfu, &c, &mut boot);
    for off in (0..1000).step_by(100) {
        rx.handle(&chunk(&payload, off, 100), &mut dfu, &c, &mut boot);
    }
    // A duplicate and a resend overlapping new bytes.
    assert_eq!(
        rx.handle(&chunk(&payload, 500, 100), &mut dfu, &c, &mut boot),
        UpdateReply::Ack { next_offset: 1000 }
    );
    assert_eq!(
        rx.handle(&chunk(&payload, 900, 192), &mut dfu, &c, &mut boot),
        UpdateReply::Ack { next_offset: 1092 }
    );
    let mut wrong = payload.clone();
    wrong[950] ^= 1;
    assert_eq!(
        rx.handle(&chunk(&wrong, 900, 100), &mut dfu, &c, &mut boot),
        UpdateReply::Refused(UpdateError::Mismatch)
    );
    // A reset: the slot says 1092 bytes arrived (the payload's bytes there are not all 0xFF).
    let mut rx = Receiver::default();
    assert_eq!(
        rx.handle(&open, &mut dfu, &c, &mut boot),
        UpdateReply::Opened {
            sectors: 2,
            erased: 2,
            next_offset: 1092
        }
    );
    // Restart forgets it.
    assert_eq!(
        rx.handle(
            &UpdateRequest::Open {
                header,
                restart: true
            },
            &mut dfu,
            &c,
            &mut boot
        ),
        UpdateReply::Opened {
            sectors: 2,
            erased: 0,
            next_offset: 0
        }
    );
}

/// A lossy link: each request and each reply is lost, duplicated, corrupted or delayed behind the next at random;
/// a go-back-N sender with a window of 4 still gets the image across, verified.
#[test]
fn go_back_n_over_a_lossy_link() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (header, payload) = image(20_000, 6, BOARD, &k);
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    rx.handle(
        &UpdateRequest::Open {
            header,
            restart: false,
        },
        &mut dfu,
        &c,
        &mut boot,
    );
    rx.handle(&UpdateRequest::Erase { sector: 0 }, &mut dfu, &c, &mut boot);
    let mut rng = Rng::new(1);
    let mut acked = 0usize;
    let mut rounds = 0;
    let mut late: std::vec::Vec<UpdateRequest> = std::vec::Vec::new();
    while acked < payload.len() {
        rounds += 1;
        assert!(rounds < 10_000);
        let mut window: std::vec::Vec<UpdateRequest> = (0..4)
            .map(|i| acked + i * 128)
            .filter(|&o| o < payload.len())
            .map(|o| chunk(&payload, o, 128))
            .collect();
        window.append(&mut late);
        for req in window {
            let mut req = req;
            match rng.next_u64() % 8 {
                0 => continue, // lost
                1 => {
                    late.push(req);
                    continue;
                } // reordered: arrives in the next round
                2 => {
                    if let UpdateRequest::Chunk { data, .. } = &mut req {
                        data[3] ^= 0x40; // corrupted (CRC no longer matches)
                    }
                }
                3 => {
                    rx.handle(&req, &mut dfu, &c, &mut boot);
                } // duplicated
                _ => {}
            }
            let reply = rx.handle(&req, &mut dfu, &c, &mut boot);
            if rng.next_u64().is_multiple_of(8) {
                continue; // reply lost
            }
            if let UpdateReply::Ack { next_offset } = reply {
                acked = acked.max(next_offset as usize);
            }
        }
    }
    assert_eq!(
        rx.handle(&UpdateRequest::Verify, &mut dfu, &c, &mut boot),
        UpdateReply::Verified
    );
    let n = rx.status(&mut dfu, &c, &mut boot).counters;
    assert!(
        n.crc_errors > 0 && n.out_of_order > 0 && n.duplicates > 0,
        "{n:?}"
    );
}

#[test]
fn bytes_in_bytes_out() {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let c = ctx(&pk);
    let (mut dfu, mut boot, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    let mut out = [0u8; 256];
    let req = postcard::to_allocvec(&UpdateEnvelope {
        tag: 77,
        request: UpdateRequest::Status,
    })
    .unwrap();
    let n = rx
        .handle_bytes(&req, &mut dfu, &c, &mut boot, &mut out)
        .unwrap();
    let resp: UpdateResponse = postcard::from_bytes(&out[..n]).unwrap();
    assert_eq!(resp.tag, 77);
    assert!(matches!(
        resp.reply,
        UpdateReply::Status(UpdateStatus {
            running_version: 3,
            dfu: DfuState::Idle,
            ..
        })
    ));
    let n = rx
        .handle_bytes(&[0xFF, 0xFF, 0xFF, 9], &mut dfu, &c, &mut boot, &mut out)
        .unwrap();
    let resp: UpdateResponse = postcard::from_bytes(&out[..n]).unwrap();
    assert_eq!(resp.reply, UpdateReply::Refused(UpdateError::Decode));
    // The largest request fits the bus's payload.
    let (header, payload) = image(1000, 4, BOARD, &k);
    for r in [
        chunk(&payload, 0, CHUNK_MAX),
        UpdateRequest::Open {
            header,
            restart: true,
        },
    ] {
        let bytes = postcard::to_allocvec(&UpdateEnvelope {
            tag: u16::MAX,
            request: r,
        })
        .unwrap();
        assert!(bytes.len() <= crate::bus::MAX_PAYLOAD, "{}", bytes.len());
    }
}

mod boot_sequence;
