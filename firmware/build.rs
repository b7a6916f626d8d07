//! Puts the repository's memory.x on the linker's search path and passes the link scripts (here rather than in
//! .cargo/config.toml rustflags, which an environment RUSTFLAGS would silently replace).
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let memory = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("manifest dir")).join("../memory.x");
    fs::copy(&memory, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=../memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
