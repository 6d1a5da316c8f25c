//! The committed `include/gpm.h` is what cbindgen generates from `src/lib.rs` (by `build.rs`,
//! into `OUT_DIR`). `GPM_BLESS_HEADER=1 cargo test --test header` rewrites the committed file.

#[test]
fn committed_header_is_generated() {
    let fresh = include_str!(concat!(env!("OUT_DIR"), "/gpm.h"));
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../include/gpm.h");
    let committed = std::fs::read_to_string(path).unwrap_or_default();
    if committed != fresh {
        if std::env::var_os("GPM_BLESS_HEADER").is_some() {
            std::fs::write(path, fresh).expect("write include/gpm.h");
            return;
        }
        panic!(
            "include/gpm.h differs from the header cbindgen generates from capi/src/lib.rs; \
             run `GPM_BLESS_HEADER=1 cargo test --release --test header` in capi/ and commit it"
        );
    }
}
