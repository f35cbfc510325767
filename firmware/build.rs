//! For the MCU build only: copies `memory.x` into OUT_DIR (so the linker finds it via `-L`) and adds the
//! cortex-m-rt / defmt linker scripts to the `firmware` binary. The host build (SITL, tests) links as usual.
use std::env;
use std::fs;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=build.rs");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return Ok(());
    }
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("OUT_DIR not set")?);
    fs::copy("../memory.x", out.join("memory.x")).map_err(|e| format!("copy memory.x: {e}"))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=../memory.x");

    println!("cargo:rustc-link-arg-bin=firmware=--nmagic");
    println!("cargo:rustc-link-arg-bin=firmware=-Tlink.x");
    println!("cargo:rustc-link-arg-bin=firmware=-Tdefmt.x");
    Ok(())
}
