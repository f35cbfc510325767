//! Links the bootloader (thumb only): `memory.x` into OUT_DIR for cortex-m-rt's `link.x`, and the update public key
//! (`FW_UPDATE_PUBKEY`, default `keys/update-dev.pub`: `keys/update_pubkey.rs`) as `OUT_DIR/update_pubkey.rs`.
use std::env;
use std::fs;
use std::path::PathBuf;

#[path = "../keys/update_pubkey.rs"]
mod update_pubkey;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=../keys/update_pubkey.rs");
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("OUT_DIR not set")?);
    let manifest =
        PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").ok_or("CARGO_MANIFEST_DIR not set")?);
    update_pubkey::emit(&manifest.join(".."), &out)?;
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return Ok(());
    }
    fs::copy("memory.x", out.join("memory.x")).map_err(|e| format!("copy memory.x: {e}"))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    Ok(())
}
