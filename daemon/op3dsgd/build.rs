//! Link settings of the `op3dsgd` and `op3dsg` binaries.
//!
//! The C libraries linked in statically (LZ4 and zstd for MCAP chunks, among others) must not be
//! exported from the executable: librealsense carries its own LZ4 and, with default ELF symbol
//! interposition, would call the executable's copy (another version) instead of its own, and
//! then cannot read the LZ4-compressed chunks of a `.bag` ("Config cannot be resolved by any
//! active devices / stream combinations"). `--exclude-libs,ALL` keeps every static archive's
//! symbols out of the dynamic symbol table.

fn main() {
    let target_os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    if target_os == "linux" {
        println!("cargo:rustc-link-arg-bins=-Wl,--exclude-libs,ALL");
    }
}
