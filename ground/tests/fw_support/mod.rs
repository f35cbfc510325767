//! What the in-orbit update tests share: the DFU slot and boot state on mock flash, test keys and bytes, a small ARM
//! ELF, and the satellite's side of the link (the receiver behind the bus framing).
#![allow(dead_code)]

use host_test::testrng::TestRng;
use host_test::update::{self, APP_BASE, SignedImage};
use shared::bus::csp::{CspPacket, CspVersion};
use shared::bus::kiss::KissDecoder;
use shared::bus::{MAX_FRAME, MAX_WIRE_FRAME};
use shared::storage::mock::MockFlash;
use shared::update::image::{self, HEADER_LEN};
use shared::update::{BOARD_ID, Context, PORT_UPDATE, Receiver, UpdateEnvelope, UpdateRequest};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The DFU slot: three 128 KiB sectors (sectors 7–9).
pub const SECTOR: usize = 128 * 1024;
pub type Dfu = MockFlash<SECTOR>;
pub const ACTIVE_LEN: u32 = 256 * 1024;
pub const RUNNING_VERSION: u32 = 3;

/// A fresh folder for one test.
pub fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("fw-tools")
        .join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `len` pseudo-random bytes.
pub fn random_bytes(len: usize, seed: u64) -> Vec<u8> {
    let mut rng = TestRng::new(seed);
    (0..len).map(|_| rng.next_u64() as u8).collect()
}

pub fn test_key(seed: u8) -> ed25519_dalek::SigningKey {
    ed25519_dalek::SigningKey::from_bytes(&[seed; 32])
}

/// The boot state partition, as the receiver's tests model it.
pub type Boot = shared::update::MockBoot;

pub fn ctx(pk: &[u8; 32]) -> Context<'_> {
    Context {
        public_key: pk,
        board_id: BOARD_ID,
        running_version: RUNNING_VERSION,
        max_image_len: ACTIVE_LEN,
        writable: Ok(()),
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The ELF.

/// One program header of a test ELF.
pub struct Seg<'a> {
    pub vaddr: u32,
    pub paddr: u32,
    pub data: &'a [u8],
    pub memsz: u32,
}

/// A 32-bit little-endian ARM executable with `segs` as `PT_LOAD` segments (no sections), written by `object`.
pub fn elf(segs: &[Seg]) -> Vec<u8> {
    use object::write::elf::{FileHeader, ProgramHeader, Writer};
    let mut buf = Vec::new();
    let mut w = Writer::new(object::Endianness::Little, false, &mut buf);
    w.reserve_file_header();
    w.reserve_program_headers(segs.len() as u32);
    let offsets: Vec<usize> = segs.iter().map(|s| w.reserve(s.data.len(), 4)).collect();
    w.write_file_header(&FileHeader {
        os_abi: object::elf::ELFOSABI_NONE,
        abi_version: 0,
        e_type: object::elf::ET_EXEC,
        e_machine: object::elf::EM_ARM,
        e_entry: u64::from(APP_BASE) + 0x189,
        e_flags: object::elf::EF_ARM_EABI_VER5,
    })
    .unwrap();
    w.write_align_program_headers();
    for (s, &off) in segs.iter().zip(&offsets) {
        w.write_program_header(&ProgramHeader {
            p_type: object::elf::PT_LOAD,
            p_flags: object::elf::PF_R | object::elf::PF_X,
            p_offset: off as u64,
            p_vaddr: u64::from(s.vaddr),
            p_paddr: u64::from(s.paddr),
            p_filesz: s.data.len() as u64,
            p_memsz: u64::from(s.memsz),
            p_align: 4,
        });
    }
    for s in segs {
        w.write_align(4);
        w.write(s.data);
    }
    buf
}

/// An application-like ELF: vector table and code at `APP_BASE`, `.rodata` after a gap, `.data` loaded in flash
/// and run in RAM, `.bss` (no file contents), and a segment with contents in RAM only.
pub fn app_elf(text: &[u8], rodata: &[u8], data: &[u8]) -> Vec<u8> {
    elf(&[
        Seg {
            vaddr: APP_BASE,
            paddr: APP_BASE,
            data: text,
            memsz: text.len() as u32,
        },
        // Loaded after `.data` in the file, to check the segments are taken by address.
        Seg {
            vaddr: 0x2000_0000,
            paddr: APP_BASE + 0x800,
            data,
            memsz: data.len() as u32,
        },
        Seg {
            vaddr: APP_BASE + 0x400,
            paddr: APP_BASE + 0x400,
            data: rodata,
            memsz: rodata.len() as u32,
        },
        Seg {
            vaddr: 0x2000_0100,
            paddr: 0x2000_0100,
            data: &[],
            memsz: 4096,
        },
        Seg {
            vaddr: 0x2000_2000,
            paddr: 0x2000_2000,
            data: &[1, 2, 3, 4],
            memsz: 4,
        },
    ])
}

// ---------------------------------------------------------------------------------------------------------------
// The satellite's side of the link.

/// The satellite's side: the receiver on the DFU slot, behind the bus framing, one request at a time, each taking
/// the time its flash work stalls the CPU.
pub struct Sat {
    pub rx: Receiver,
    pub dfu: Dfu,
    pub boot: Boot,
    pub pk: [u8; 32],
    pub kiss: KissDecoder<MAX_FRAME>,
    pub busy_until: Option<Instant>,
    /// Probability that a chunk's data is corrupted after the bus CRCs passed (it then fails the chunk's CRC-32C).
    pub corrupt: f64,
    pub rng: TestRng,
}

impl Sat {
    pub fn new(dfu: Dfu, boot: Boot, pk: [u8; 32], corrupt: f64, seed: u64) -> Self {
        Self {
            rx: Receiver::default(),
            dfu,
            boot,
            pk,
            kiss: KissDecoder::new(),
            busy_until: None,
            corrupt,
            rng: TestRng::new(seed),
        }
    }

    /// Bus bytes arriving at `t`: the reply frames, each with the time it leaves.
    pub fn receive(&mut self, mut bytes: &[u8], t: Instant) -> Vec<(Instant, Vec<u8>)> {
        let mut out = Vec::new();
        while let Some(frame) = self.kiss.decode(&mut bytes) {
            let Ok(frame) = frame else { continue };
            let Ok(p) = CspPacket::parse(frame, CspVersion::V1) else {
                continue;
            };
            if p.header.dst != 10 || p.header.dport != PORT_UPDATE {
                continue;
            }
            let reply_header = p.header.reply();
            let mut payload = p.payload.to_vec();
            let request = postcard::from_bytes::<UpdateEnvelope>(&payload).map(|e| e.request);
            if let Ok(UpdateRequest::Chunk { data, .. }) = &request
                && self.rng.uniform() < self.corrupt
            {
                // The data ends the envelope.
                let i = payload.len() - 1 - (self.rng.next_u64() % data.len() as u64) as usize;
                payload[i] ^= 1 << (self.rng.next_u64() % 8);
            }
            let cost = match request {
                Ok(UpdateRequest::Erase { .. }) => Duration::from_secs(2),
                Ok(UpdateRequest::Verify | UpdateRequest::Commit) => Duration::from_millis(300),
                Ok(UpdateRequest::Chunk { .. }) => Duration::from_millis(5),
                _ => Duration::from_millis(1),
            };
            let mut reply = [0u8; 256];
            let n = self
                .rx
                .handle_bytes(
                    &payload,
                    &mut self.dfu,
                    &ctx(&self.pk),
                    &mut self.boot,
                    &mut reply,
                )
                .unwrap();
            let start = self.busy_until.map_or(t, |b| b.max(t));
            let done = start + cost;
            self.busy_until = Some(done);
            let mut wire = [0u8; MAX_WIRE_FRAME];
            let m = CspPacket::emit_kiss(&reply_header, CspVersion::V1, &reply[..n], &mut wire)
                .unwrap();
            out.push((done, wire[..m].to_vec()));
        }
        out
    }
}

/// A signed image of `len` pseudo-random bytes and its parsed form.
pub fn test_image(len: usize, version: u32, seed: u64) -> (SignedImage, Vec<u8>) {
    let payload = random_bytes(len, seed);
    let signed = update::sign(&payload, &test_key(7), version, BOARD_ID).unwrap();
    (SignedImage::parse(&signed).unwrap(), signed)
}

/// Whether the DFU slot holds `signed`, checked as the bootloader checks it.
pub fn slot_holds(dfu: &mut Dfu, signed: &[u8]) {
    let pk = test_key(7).verifying_key().to_bytes();
    image::verify_slot(dfu, &pk, BOARD_ID, RUNNING_VERSION, ACTIVE_LEN).unwrap();
    assert_eq!(
        &dfu.mem[image::OPEN_LEN..image::OPEN_LEN + 8],
        &[0; 8],
        "two erase marks"
    );
    assert_eq!(&dfu.mem[..image::OPEN_LEN], &signed[..image::OPEN_LEN]);
    assert_eq!(&dfu.mem[HEADER_LEN..signed.len()], &signed[HEADER_LEN..]);
}
