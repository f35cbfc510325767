//! For the MCU build only: copies `memory.x` (this crate's: the application's memory map) into OUT_DIR, puts that on
//! the `firmware` binary's linker path and adds the cortex-m-rt / defmt linker scripts to it. The host build (SITL,
//! tests) links as usual.
use std::env;
use std::fs;
use std::path::PathBuf;
use std::process::Command;

/// `FW_COMMIT` (the first 8 hex digits of the git commit, "0" outside git) and `FW_DIRTY` ("1" when tracked files
/// differ from it), for the firmware's housekeeping report.
fn firmware_version() {
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let commit = git(&["rev-parse", "--short=8", "HEAD"]).unwrap_or_else(|| "0".into());
    let dirty =
        git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
    println!("cargo:rustc-env=FW_COMMIT={commit}");
    println!("cargo:rustc-env=FW_DIRTY={}", u8::from(dirty));
    if let Some(dir) = git(&["rev-parse", "--git-dir"]) {
        println!("cargo:rerun-if-changed={dir}/HEAD");
        println!("cargo:rerun-if-changed={dir}/index");
    }
}

#[path = "../keys/update_pubkey.rs"]
mod update_pubkey;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=build.rs");
    firmware_version();
    // The update public key (`keys/README.md`), for both builds: the SITL checks uploads as the MCU does.
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("OUT_DIR not set")?);
    update_pubkey::emit(std::path::Path::new(".."), &out)?;
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return Ok(());
    }
    fs::copy("memory.x", out.join("memory.x")).map_err(|e| format!("copy memory.x: {e}"))?;
    // For the `firmware` binary only: a `rustc-link-search` would reach every crate that links this library too
    // (the bootloader, which has its own `memory.x`). Neither script is at the workspace's root, where the linker,
    // run from there, would find it before any `-L` path.
    // Two arguments, as flip-link reads them (`-L`, then the path) when it looks for the RAM region.
    println!("cargo:rustc-link-arg-bin=firmware=-L");
    println!("cargo:rustc-link-arg-bin=firmware={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");

    println!("cargo:rustc-link-arg-bin=firmware=--nmagic");
    println!("cargo:rustc-link-arg-bin=firmware=-Tlink.x");
    println!("cargo:rustc-link-arg-bin=firmware=-Tdefmt.x");
    Ok(())
}
