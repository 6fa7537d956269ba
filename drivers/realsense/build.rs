//! Link settings of this crate's tests and benchmarks, which link librealsense.
//!
//! Static C libraries elsewhere in the workspace (LZ4 and zstd for MCAP chunks) must not be
//! exported from an executable that also loads librealsense: librealsense carries its own LZ4 and,
//! with default ELF symbol interposition, would call the executable's copy instead and then fail
//! to read a `.bag`'s LZ4 chunks. The `op3dsgd` binaries do the same in their build script.

fn main() {
    if std::env::var("CARGO_CFG_TARGET_OS").is_ok_and(|os| os == "linux") {
        println!("cargo:rustc-link-arg-tests=-Wl,--exclude-libs,ALL");
        println!("cargo:rustc-link-arg-benches=-Wl,--exclude-libs,ALL");
    }
}
