//! The in-orbit update's ground tools (`host_test::update`, `ground fw-*`; `docs/update.md`): the signed image
//! checked by the satellite's own `verify_slot` and independently by Python's `cryptography` and `hashlib`; keys
//! exchanged with `openssl`; the flash contents of an ELF written here; the upload client against the satellite's
//! `Receiver` over a lossy link in virtual time, resumed after an interruption; and the three commands end to end,
//! the upload over a pseudo-terminal.

//!
//! The upload over a lossy link is in `fw_upload`; what both share in `fw_support`.

mod fw_support;

use fw_support::*;
use host_test::update::{self, APP_BASE, ElfError, PAYLOAD_MAX, SignedImage};
use shared::update::image::{self, HEADER_LEN};
use shared::update::{BOARD_ID, BootState, ImageError};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

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
// The ELF (the test ELF itself: `fw_support::app_elf`).

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
