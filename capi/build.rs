//! Generates the C header from `src/lib.rs` with cbindgen into `$OUT_DIR/gpm.h`;
//! `tests/header.rs` checks that the committed `include/gpm.h` is the same file
//! (`GPM_BLESS_HEADER=1 cargo test --test header` rewrites it).

use std::path::PathBuf;

fn main() {
    let dir = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets it"));
    println!("cargo:rerun-if-changed=src/lib.rs");
    println!("cargo:rerun-if-changed=cbindgen.toml");
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    cbindgen::Builder::new()
        .with_config(config)
        .with_src(dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen could not generate gpm.h")
        .write_to_file(out.join("gpm.h"));
}
