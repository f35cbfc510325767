//! The update public key at build time, for build scripts (not a crate module): `bootloader/build.rs` (and
//! `firmware/build.rs`, which needs the same key) include this file with
//! `#[path = "../keys/update_pubkey.rs"] mod update_pubkey;` and call [`emit`]; the crate then has
//! `include!(concat!(env!("OUT_DIR"), "/update_pubkey.rs"))`, which defines `UPDATE_PUBLIC_KEY: [u8; 32]`.
//!
//! The key file is the environment variable [`ENV`] (a path; relative paths from the repository's root) or
//! [`DEFAULT`]: 64 hex digits, the raw Ed25519 public key; whitespace and lines starting with `#` are ignored
//! (`keys/README.md`).

use std::fs;
use std::path::{Path, PathBuf};

/// The environment variable naming the key file.
pub const ENV: &str = "FW_UPDATE_PUBKEY";
/// The key file when [`ENV`] is not set, from the repository's root: the development key, whose private half was
/// not kept.
pub const DEFAULT: &str = "keys/update-dev.pub";

/// The 32 bytes in `text`: 64 hex digits, whitespace and `#` comment lines ignored.
pub fn parse(text: &str) -> Result<[u8; 32], String> {
    let digits: Vec<u8> = text
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .flat_map(|l| l.bytes())
        .filter(|b| !b.is_ascii_whitespace())
        .collect();
    if digits.len() != 64 {
        return Err(format!("{} hex digits, want 64", digits.len()));
    }
    let mut key = [0u8; 32];
    for (byte, pair) in key.iter_mut().zip(digits.chunks(2)) {
        let pair = std::str::from_utf8(pair).map_err(|_| "not hex".to_string())?;
        *byte = u8::from_str_radix(pair, 16).map_err(|_| format!("{pair:?} is not hex"))?;
    }
    Ok(key)
}

/// Reads the key (from [`ENV`] or [`DEFAULT`], relative to `repo_root`), writes `out_dir/update_pubkey.rs` and
/// tells cargo to run the build script again when the variable or the file changes. Returns the key file's path.
pub fn emit(repo_root: &Path, out_dir: &Path) -> Result<PathBuf, String> {
    println!("cargo:rerun-if-env-changed={ENV}");
    let named = std::env::var_os(ENV).map(PathBuf::from);
    let path = repo_root.join(named.as_deref().unwrap_or(Path::new(DEFAULT)));
    println!("cargo:rerun-if-changed={}", path.display());
    let text = fs::read_to_string(&path).map_err(|e| format!("{ENV}: {}: {e}", path.display()))?;
    let key = parse(&text).map_err(|e| format!("{ENV}: {}: {e}", path.display()))?;
    let bytes: Vec<String> = key.iter().map(|b| format!("0x{b:02x}")).collect();
    let source = format!(
        "/// The Ed25519 public key that signs update images (`docs/update.md`), built in from `{}` (`{ENV}`).\n\
         pub const UPDATE_PUBLIC_KEY: [u8; 32] = [{}];\n",
        path.display(),
        bytes.join(", ")
    );
    fs::write(out_dir.join("update_pubkey.rs"), source)
        .map_err(|e| format!("update_pubkey.rs: {e}"))?;
    Ok(path)
}
