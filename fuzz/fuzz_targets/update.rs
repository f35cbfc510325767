//! The update service's receiver (`shared::update::Receiver`) and the image header parser.
//!
//! Input: the DFU slot's initial contents (a few planted bytes over erased flash: a header, marks, payload bytes),
//! whether flash writes are allowed, and a sequence of requests, each either raw bytes or a well-formed request
//! (so that deep states are reached: opened, erased, chunks written).
//! Properties:
//! * `handle_bytes` never panics and its reply always decodes as an `UpdateResponse` with the request's tag;
//! * while writes are refused (`NotIdle`), the slot and the boot state never change;
//! * the boot state becomes `Swap` only through `Commit`, and only with the image in the slot verifying;
//! * `Header::parse` never panics; a header it parses emits back to the same first `OPEN_LEN` bytes.
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use shared::storage::mock::MockFlash;
use shared::update::image::{self, Header, OPEN_LEN};
use shared::update::{
    BootState, CHUNK_MAX, Context, MockBoot, Receiver, UpdateEnvelope, UpdateError, UpdateReply,
    UpdateRequest, UpdateResponse,
};

/// Small sectors keep each run fast; the logic does not depend on their size.
const SECTOR: usize = 1024;

#[derive(Arbitrary, Debug)]
enum Req {
    Raw(Vec<u8>),
    Status,
    Open {
        restart: bool,
        header: Vec<u8>,
    },
    Erase(u8),
    Chunk {
        offset: u16,
        good_crc: bool,
        data: Vec<u8>,
    },
    Verify,
    Commit,
    Confirm,
    Abort,
    Reset,
}

#[derive(Arbitrary, Debug)]
struct Input {
    plant: Vec<(u16, u8)>,
    writable: bool,
    running_version: u8,
    requests: Vec<Req>,
}

fuzz_target!(|input: Input| {
    let mut dfu = MockFlash::<SECTOR>::erased(4);
    for (at, b) in &input.plant {
        if let Some(x) = dfu.mem.get_mut(*at as usize) {
            *x = *b;
        }
    }
    if let Ok(h) = Header::parse(&dfu.mem) {
        assert_eq!(&h.emit()[..], &dfu.mem[..OPEN_LEN]);
    }
    let key = [7u8; 32];
    let ctx = Context {
        public_key: &key,
        board_id: shared::update::BOARD_ID,
        running_version: u32::from(input.running_version),
        max_image_len: 3 * SECTOR as u32,
        writable: if input.writable {
            Ok(())
        } else {
            Err(UpdateError::NotIdle)
        },
    };
    let mut boot = MockBoot::default();
    let mut rx = Receiver::default();
    let before = dfu.mem.clone();
    let mut out = [0u8; 256];
    for (tag, r) in input.requests.iter().take(64).enumerate() {
        let tag = tag as u16 + 1;
        let bytes = match r {
            Req::Raw(b) => b.clone(),
            other => {
                let request = match other {
                    Req::Raw(_) => unreachable!(),
                    Req::Status => UpdateRequest::Status,
                    Req::Open { restart, header } => {
                        let mut h = [0u8; OPEN_LEN];
                        for (d, s) in h.iter_mut().zip(header) {
                            *d = *s;
                        }
                        UpdateRequest::Open {
                            header: h,
                            restart: *restart,
                        }
                    }
                    Req::Erase(s) => UpdateRequest::Erase { sector: *s },
                    Req::Chunk {
                        offset,
                        good_crc,
                        data,
                    } => {
                        let data: heapless::Vec<u8, CHUNK_MAX> =
                            data.iter().copied().take(CHUNK_MAX).collect();
                        let crc = shared::crc::crc32c(&data);
                        UpdateRequest::Chunk {
                            offset: u32::from(*offset),
                            crc32c: if *good_crc { crc } else { crc ^ 1 },
                            data,
                        }
                    }
                    Req::Verify => UpdateRequest::Verify,
                    Req::Commit => UpdateRequest::Commit,
                    Req::Confirm => UpdateRequest::Confirm,
                    Req::Abort => UpdateRequest::Abort,
                    Req::Reset => UpdateRequest::Reset,
                };
                postcard::to_allocvec(&UpdateEnvelope { tag, request }).expect("encodes")
            }
        };
        let state_before = boot.state;
        let n = rx
            .handle_bytes(&bytes, &mut dfu, &ctx, &mut boot, &mut out)
            .expect("every reply fits 256 bytes");
        let resp: UpdateResponse = postcard::from_bytes(&out[..n]).expect("the reply decodes");
        if !matches!(r, Req::Raw(_)) {
            assert_eq!(resp.tag, tag);
        }
        if boot.state == BootState::Swap && state_before != BootState::Swap {
            assert_eq!(resp.reply, UpdateReply::Committed);
            let max = ctx.max_image_len;
            assert!(
                image::verify_slot(&mut dfu, &key, ctx.board_id, ctx.running_version, max).is_ok()
            );
        }
        let _ = rx.take_reset();
    }
    if !input.writable {
        assert!(
            dfu.mem == before,
            "the slot changed while writes were refused"
        );
        assert_ne!(boot.state, BootState::Swap);
    }
});
