//! Link settings of the `op3dsgd` and `op3dsg` binaries.
//!
//! The C libraries linked in statically (LZ4 and zstd for MCAP chunks, among others) must not be
//! exported from the executable: librealsense carries its own LZ4 and, with default ELF symbol
//! interposition, would call the executable's copy (another version) instead of its own, and
//! then cannot read the LZ4-compressed chunks of a `.bag` ("Config cannot be resolved by any
//! active devices / stream combinations"). `--exclude-libs,ALL` keeps every static archive's
//! symbols out of the dynamic symbol table.
//!
//! With the camera (feature `realsense`) the binaries look for librealsense in `../lib/op3dsg/`
//! beside themselves before the system's folders (ELF RUNPATH `$ORIGIN/../lib/op3dsg`): the
//! Debian package and `systemd/install.sh` put the tested librealsense there, so an installed
//! `/usr/bin/op3dsgd` loads `/usr/lib/op3dsg/librealsense2.so.2.56` and a staged copy (`dpkg
//! --root`, `install.sh --destdir`) its own. Binaries in cargo's `target/` have no such folder
//! and load the system's librealsense (or `LD_LIBRARY_PATH`'s, which comes before RUNPATH).

fn main() {
    let target_os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    if target_os == "linux" {
        println!("cargo:rustc-link-arg-bins=-Wl,--exclude-libs,ALL");
        if std::env::var_os("CARGO_FEATURE_REALSENSE").is_some() {
            println!("cargo:rustc-link-arg-bins=-Wl,-rpath,$ORIGIN/../lib/op3dsg");
        }
    }
}
