//! The in-orbit update's ground tools (`host_test::update`, `ground fw-*`; `docs/update.md`): the signed image
//! checked by the satellite's own `verify_slot` and independently by Python's `cryptography` and `hashlib`; keys
//! exchanged with `openssl`; the flash contents of an ELF written here; the upload client against the satellite's
//! `Receiver` over a lossy link in virtual time, resumed after an interruption; and the three commands end to end,
//! the upload over a pseudo-terminal.

use host_test::testrng::TestRng;
use host_test::update::link::{BusAddrs, UpdateFramer, max_request_wire_len, max_window};
use host_test::update::uploader::{RewindCause, UploadError, UploadEvent};
use host_test::update::{
    self, APP_BASE, ElfError, PAYLOAD_MAX, SignedImage, UploadConfig, Uploader,
};
use shared::bus::csp::{CspPacket, CspVersion};
use shared::bus::kiss::KissDecoder;
use shared::bus::{MAX_FRAME, MAX_WIRE_FRAME};
use shared::storage::mock::MockFlash;
use shared::update::image::{self, HEADER_LEN};
use shared::update::{
    BOARD_ID, BootState, Context, DfuState, ImageError, PORT_UPDATE, Receiver, UpdateEnvelope,
    UpdateError, UpdateRequest,
};
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// The DFU slot: three 128 KiB sectors (sectors 7–9).
const SECTOR: usize = 128 * 1024;
type Dfu = MockFlash<SECTOR>;
const ACTIVE_LEN: u32 = 256 * 1024;
const RUNNING_VERSION: u32 = 3;

/// A fresh folder for one test.
fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("fw-tools")
        .join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `len` pseudo-random bytes.
fn random_bytes(len: usize, seed: u64) -> Vec<u8> {
    let mut rng = TestRng::new(seed);
    (0..len).map(|_| rng.next_u64() as u8).collect()
}

fn test_key(seed: u8) -> ed25519_dalek::SigningKey {
    ed25519_dalek::SigningKey::from_bytes(&[seed; 32])
}

/// The boot state partition, as the receiver's tests model it.
type Boot = shared::update::MockBoot;

fn ctx(pk: &[u8; 32]) -> Context<'_> {
    Context {
        public_key: pk,
        board_id: BOARD_ID,
        running_version: RUNNING_VERSION,
        max_image_len: ACTIVE_LEN,
        writable: Ok(()),
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The signed image.

#[test]
fn signed_image_verifies_in_a_slot_as_the_satellite_checks_it() {
    let key = test_key(7);
    let pk = key.verifying_key().to_bytes();
    let payload = random_bytes(10_001, 1);
    let signed = update::sign(&payload, &key, 4, BOARD_ID).unwrap();
    assert_eq!(signed.len(), HEADER_LEN + payload.len());
    assert!(
        signed[image::OPEN_LEN..HEADER_LEN]
            .iter()
            .all(|&b| b == 0xFF),
        "the erase marks' room is erased"
    );
    assert_eq!(&signed[HEADER_LEN..], &payload[..]);
    let mut slot = Dfu::erased(2);
    slot.mem[..signed.len()].copy_from_slice(&signed);
    let h = image::verify_slot(&mut slot, &pk, BOARD_ID, RUNNING_VERSION, ACTIVE_LEN).unwrap();
    assert_eq!(
        (h.board_id, h.version, h.payload_len),
        (BOARD_ID, 4, 10_001)
    );
    // Read back: the same header, the signature checks with the key, not with another.
    let parsed = SignedImage::parse(&signed).unwrap();
    assert_eq!(parsed.header, h);
    parsed.check_signature(&key.verifying_key()).unwrap();
    assert!(
        parsed
            .check_signature(&test_key(8).verifying_key())
            .is_err()
    );
    // One payload bit changed: the slot fails the hash, the file does not parse.
    let mut bad = signed.clone();
    bad[HEADER_LEN + 5000] ^= 0x04;
    slot.mem[..bad.len()].copy_from_slice(&bad);
    assert_eq!(
        image::verify_slot(&mut slot, &pk, BOARD_ID, RUNNING_VERSION, ACTIVE_LEN),
        Err(ImageError::Hash)
    );
    assert!(matches!(
        SignedImage::parse(&bad),
        Err(update::ImageFileError::Hash)
    ));
    assert!(matches!(
        SignedImage::parse(&signed[..signed.len() - 1]),
        Err(update::ImageFileError::Length { .. })
    ));
    // Another board, an older version: refused by the satellite's check.
    let other = update::sign(&payload, &key, 4, BOARD_ID + 1).unwrap();
    slot.mem[..other.len()].copy_from_slice(&other);
    assert_eq!(
        image::verify_slot(&mut slot, &pk, BOARD_ID, RUNNING_VERSION, ACTIVE_LEN),
        Err(ImageError::Board)
    );
    assert!(matches!(
        update::sign(&[], &key, 4, BOARD_ID),
        Err(update::SignError::Empty)
    ));
    assert!(matches!(
        update::sign(&vec![0; PAYLOAD_MAX as usize + 1], &key, 4, BOARD_ID),
        Err(update::SignError::TooLarge(_))
    ));
}

fn have_python_cryptography() -> bool {
    Command::new("python3")
        .args(["-c", "import cryptography"])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Python's own reading of the image: the header's fields by `struct`, the payload's SHA-512 by `hashlib`, the
/// Ed25519 signature over bytes 0..128 by `cryptography`. Prints board, version and payload length.
const PY_CHECK: &str = r#"
import sys, struct, hashlib
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
img = open(sys.argv[1], 'rb').read()
text = open(sys.argv[2]).read()
pub = bytes.fromhex(''.join(''.join(l.split()) for l in text.splitlines() if not l.lstrip().startswith('#')))
magic, fmt, hlen, board, version, plen = struct.unpack_from('<4sHHIII', img, 0)
assert magic == b'IMUF' and fmt == 1 and hlen == 512, (magic, fmt, hlen)
assert img[20:32] == bytes(12) and img[96:128] == bytes(32), 'reserved bytes'
assert all(b == 0xFF for b in img[192:512]), 'erased tail'
assert len(img) == 512 + plen, (len(img), plen)
assert hashlib.sha512(img[512:]).digest() == img[32:96], 'payload hash'
Ed25519PublicKey.from_public_bytes(pub).verify(img[128:192], img[0:128])
print(board, version, plen)
"#;

#[test]
fn python_cryptography_verifies_the_signature_and_the_hash() {
    if !have_python_cryptography() {
        println!("SKIPPED: python3 with the `cryptography` package is not available");
        return;
    }
    let d = dir("python");
    let key = update::generate_keypair().unwrap();
    let (_, public) = update::write_keypair(&key, &d.join("k")).unwrap();
    let payload = random_bytes(3001, 2);
    let signed = update::sign(&payload, &key, 0x0102_0304, BOARD_ID).unwrap();
    let img = d.join("app.img");
    std::fs::write(&img, &signed).unwrap();
    let check = |img: &std::path::Path| {
        Command::new("python3")
            .args(["-c", PY_CHECK])
            .arg(img)
            .arg(&public)
            .output()
            .unwrap()
    };
    let out = check(&img);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        format!("{BOARD_ID} {} 3001", 0x0102_0304)
    );
    // The check is real: a signed byte changed (the version), or the payload, and Python refuses.
    for at in [12, HEADER_LEN + 17] {
        let mut bad = signed.clone();
        bad[at] ^= 1;
        std::fs::write(&img, &bad).unwrap();
        let out = check(&img);
        assert!(!out.status.success(), "byte {at} changed, still accepted");
    }
}

fn have_openssl() -> bool {
    Command::new("openssl")
        .arg("version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// The raw public key of a PEM private key, as openssl derives it (the last 32 bytes of the DER public key).
fn openssl_public(pem: &Path) -> [u8; 32] {
    let out = Command::new("openssl")
        .args(["pkey", "-pubout", "-outform", "DER", "-in"])
        .arg(pem)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "openssl pkey: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout[out.stdout.len() - 32..].try_into().unwrap()
}

#[test]
fn keys_are_exchanged_with_openssl() {
    let d = dir("openssl");
    let key = update::generate_keypair().unwrap();
    let (pem, public) = update::write_keypair(&key, &d.join("ours")).unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&pem).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600, "{mode:o}");
    }
    assert!(
        update::write_keypair(&key, &d.join("ours")).is_err(),
        "an existing private key is not overwritten"
    );
    // Our public key file, read back, and (below) as openssl sees the private key.
    let read = update::read_public_key(&public).unwrap();
    assert_eq!(read, key.verifying_key());
    assert_eq!(update::read_private_key(&pem).unwrap(), key);
    if !have_openssl() {
        println!("SKIPPED (openssl part): openssl is not installed");
        return;
    }
    assert_eq!(openssl_public(&pem), key.verifying_key().to_bytes());
    // A key openssl made: our loader reads it, its public half is openssl's.
    let theirs = d.join("theirs.pem");
    let st = Command::new("openssl")
        .args(["genpkey", "-algorithm", "ed25519", "-out"])
        .arg(&theirs)
        .status()
        .unwrap();
    assert!(st.success());
    let k = update::read_private_key(&theirs).unwrap();
    assert_eq!(k.verifying_key().to_bytes(), openssl_public(&theirs));
    // An image signed with it: openssl verifies the signature over the header's first 128 bytes.
    let signed = update::sign(&random_bytes(700, 3), &k, 9, BOARD_ID).unwrap();
    std::fs::write(d.join("signed.bin"), &signed[..image::SIGNED_LEN]).unwrap();
    std::fs::write(
        d.join("sig.bin"),
        &signed[image::SIGNED_LEN..image::OPEN_LEN],
    )
    .unwrap();
    let pubpem = d.join("theirs.pub.pem");
    assert!(
        Command::new("openssl")
            .args(["pkey", "-pubout", "-in"])
            .arg(&theirs)
            .arg("-out")
            .arg(&pubpem)
            .status()
            .unwrap()
            .success()
    );
    let out = Command::new("openssl")
        .args(["pkeyutl", "-verify", "-pubin", "-rawin", "-inkey"])
        .arg(&pubpem)
        .arg("-in")
        .arg(d.join("signed.bin"))
        .arg("-sigfile")
        .arg(d.join("sig.bin"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "openssl pkeyutl -verify: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn public_key_files_allow_comments_and_white_space() {
    let key = test_key(5);
    let hex = update::public_key_hex(&key.verifying_key());
    assert_eq!(hex.len(), 64);
    let p = Path::new("k.pub");
    for text in [
        hex.clone(),
        format!("{hex}\n"),
        format!("# update key\n{}\n  {}\n# end\n", &hex[..32], &hex[32..]),
        hex.to_uppercase(),
    ] {
        assert_eq!(
            update::parse_public_key(&text, p).unwrap(),
            key.verifying_key(),
            "{text:?}"
        );
    }
    for bad in [
        &hex[..62],
        &format!("{hex}00"),
        &format!("{}zz", &hex[..62]),
    ] {
        assert!(matches!(
            update::parse_public_key(bad, p),
            Err(update::KeyError::PublicHex { .. })
        ));
    }
    // The repository's development key, if it is there by now.
    let dev = Path::new(env!("CARGO_MANIFEST_DIR")).join("../keys/update-dev.pub");
    if dev.exists() {
        update::read_public_key(&dev).unwrap();
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The ELF.

/// One program header of a test ELF.
struct Seg<'a> {
    vaddr: u32,
    paddr: u32,
    data: &'a [u8],
    memsz: u32,
}

/// A 32-bit little-endian ARM executable with `segs` as `PT_LOAD` segments (no sections), written by `object`.
fn elf(segs: &[Seg]) -> Vec<u8> {
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
fn app_elf(text: &[u8], rodata: &[u8], data: &[u8]) -> Vec<u8> {
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

#[test]
fn image_from_elf_takes_the_flash_contents_by_load_address() {
    let (text, rodata, data) = (
        random_bytes(0x388, 4),
        random_bytes(0x100, 5),
        random_bytes(40, 6),
    );
    let p = update::image_from_elf(&app_elf(&text, &rodata, &data)).unwrap();
    // The expected flash contents, laid out by hand: text at 0, rodata at 0x400, data's image at 0x800, 0xFF
    // between.
    let mut want = vec![0xFF; 0x800 + 40];
    want[..0x388].copy_from_slice(&text);
    want[0x400..0x500].copy_from_slice(&rodata);
    want[0x800..].copy_from_slice(&data);
    assert_eq!(p.base, APP_BASE);
    assert_eq!(p.bytes, want);

    let one = |paddr: u32| {
        elf(&[Seg {
            vaddr: paddr,
            paddr,
            data: &[0; 64],
            memsz: 64,
        }])
    };
    assert!(matches!(
        update::image_from_elf(&one(APP_BASE + 0x10)),
        Err(ElfError::Misaligned(a)) if a == APP_BASE + 0x10
    ));
    assert!(matches!(
        update::image_from_elf(&one(0x0802_0000)),
        Err(ElfError::Base { found: 0x0802_0000 })
    ));
    assert!(matches!(
        update::image_from_elf(&one(0x2000_0000)),
        Err(ElfError::NoFlashSegment)
    ));
    let overlap = elf(&[
        Seg {
            vaddr: APP_BASE,
            paddr: APP_BASE,
            data: &[0; 64],
            memsz: 64,
        },
        Seg {
            vaddr: 0x2000_0000,
            paddr: APP_BASE + 60,
            data: &[0; 8],
            memsz: 8,
        },
    ]);
    assert!(matches!(
        update::image_from_elf(&overlap),
        Err(ElfError::Overlap(a)) if a == APP_BASE + 60
    ));
    let big = vec![0; PAYLOAD_MAX as usize + 4];
    assert!(matches!(
        update::image_from_elf(&elf(&[Seg {
            vaddr: APP_BASE,
            paddr: APP_BASE,
            data: &big,
            memsz: big.len() as u32,
        }])),
        Err(ElfError::TooLarge { .. })
    ));
    assert!(matches!(
        update::image_from_elf(b"not an ELF"),
        Err(ElfError::Parse(_))
    ));
}

// ---------------------------------------------------------------------------------------------------------------
// The upload over a lossy link, in virtual time.

/// The satellite's side: the receiver on the DFU slot, behind the bus framing, one request at a time, each taking
/// the time its flash work stalls the CPU.
struct Sat {
    rx: Receiver,
    dfu: Dfu,
    boot: Boot,
    pk: [u8; 32],
    kiss: KissDecoder<MAX_FRAME>,
    busy_until: Option<Instant>,
    /// Probability that a chunk's data is corrupted after the bus CRCs passed (it then fails the chunk's CRC-32C).
    corrupt: f64,
    rng: TestRng,
}

impl Sat {
    fn new(dfu: Dfu, boot: Boot, pk: [u8; 32], corrupt: f64, seed: u64) -> Self {
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
    fn receive(&mut self, mut bytes: &[u8], t: Instant) -> Vec<(Instant, Vec<u8>)> {
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

/// A signed image of `len` pseudo-random bytes and its parsed form.
fn test_image(len: usize, version: u32, seed: u64) -> (SignedImage, Vec<u8>) {
    let payload = random_bytes(len, seed);
    let signed = update::sign(&payload, &test_key(7), version, BOARD_ID).unwrap();
    (SignedImage::parse(&signed).unwrap(), signed)
}

/// Whether the DFU slot holds `signed`, checked as the bootloader checks it.
fn slot_holds(dfu: &mut Dfu, signed: &[u8]) {
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

// ---------------------------------------------------------------------------------------------------------------
// The commands, end to end: a key, an ELF signed, the upload over a pseudo-terminal to the receiver.

fn ground(args: &[&dyn AsRef<std::ffi::OsStr>]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ground"))
        .args(args.iter().map(|a| a.as_ref()))
        .output()
        .expect("running ground")
}

fn ok(out: &std::process::Output) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

#[cfg(unix)]
#[test]
fn keygen_sign_upload_over_a_pty() {
    use nix::sys::termios;
    use sha2::Digest;
    use std::io::{Read, Write};
    let d = dir("cli");
    let prefix = d.join("flight");
    let out = ok(&ground(&[&"fw-keygen", &"--out", &prefix]));
    let pub_text = std::fs::read_to_string(d.join("flight.pub")).unwrap();
    let pub_hex = pub_text.trim();
    assert!(out.contains(pub_hex), "{out}");
    let mut pk = [0u8; 32];
    hex::decode_to_slice(pub_hex, &mut pk).unwrap();

    let (text, rodata, data) = (
        random_bytes(0x388, 4),
        random_bytes(0x100, 5),
        random_bytes(40, 6),
    );
    let elf_path = d.join("app.elf");
    std::fs::write(&elf_path, app_elf(&text, &rodata, &data)).unwrap();
    let img_path = d.join("app.img");
    let out = ok(&ground(&[
        &"fw-sign",
        &elf_path,
        &"--key",
        &d.join("flight.pem"),
        &"--version",
        &"7",
        &"--pubkey",
        &d.join("flight.pub"),
        &"--out",
        &img_path,
    ]));
    let signed = std::fs::read(&img_path).unwrap();
    let payload_len = 0x800 + 40;
    assert_eq!(signed.len(), HEADER_LEN + payload_len);
    let sha = sha2::Sha512::digest(&signed[HEADER_LEN..]);
    let sha_prefix: String = sha[..8].iter().map(|b| format!("{b:02x}")).collect();
    for want in [
        "version 7".to_string(),
        format!("payload {payload_len} bytes"),
        format!("SHA-512 {sha_prefix}"),
        pub_hex.to_string(),
        format!("board {BOARD_ID:#010x}"),
    ] {
        assert!(out.contains(&want), "{want:?} not in {out}");
    }

    // The satellite on the pty's master side: the receiver behind the bus framing, replies at once.
    let pty = nix::pty::openpty(None, None).unwrap();
    let mut t = termios::tcgetattr(&pty.slave).unwrap();
    termios::cfmakeraw(&mut t);
    termios::tcsetattr(&pty.slave, termios::SetArg::TCSANOW, &t).unwrap();
    let path = nix::unistd::ttyname(&pty.slave).unwrap();
    let master = std::fs::File::from(pty.master);
    let sat_thread = std::thread::spawn(move || {
        let mut sat = Sat::new(Dfu::erased(3), Boot::default(), pk, 0.0, 1);
        let (mut r, mut w) = (master.try_clone().unwrap(), master);
        let mut buf = [0u8; 512];
        // Ends when no one holds the slave side any more (EIO).
        while let Ok(n) = r.read(&mut buf) {
            if n == 0 {
                break;
            }
            for (_, reply) in sat.receive(&buf[..n], Instant::now()) {
                w.write_all(&reply).unwrap();
            }
        }
        sat
    });
    // A window the ring cannot hold is refused before anything is sent.
    let out = ground(&[
        &"fw-upload",
        &img_path,
        &"--link",
        &path,
        &"--window",
        &"38",
    ]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("1 to 37"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = ok(&ground(&[
        &"fw-upload",
        &img_path,
        &"--link",
        &path,
        &"--no-commit",
    ]));
    assert!(out.contains("verified on board"), "{out}");
    assert!(!out.contains("committed:"), "{out}");
    assert!(
        out.contains(&format!("{payload_len} payload bytes delivered")),
        "{out}"
    );
    // Again, committing: the slot holds it all, nothing is sent again but the last word if it is 0xFF.
    let out = ok(&ground(&[&"fw-upload", &img_path, &"--link", &path]));
    assert!(
        out.contains("committed: the satellite swaps it in"),
        "{out}"
    );
    assert!(out.contains("were already there"), "{out}");
    drop(pty.slave);
    let mut sat = sat_thread.join().unwrap();
    image::verify_slot(&mut sat.dfu, &pk, BOARD_ID, RUNNING_VERSION, ACTIVE_LEN).unwrap();
    assert_eq!(
        &sat.dfu.mem[HEADER_LEN..signed.len()],
        &signed[HEADER_LEN..]
    );
    assert_eq!(sat.boot.state, BootState::Swap);
}
