#!/usr/bin/env bash
# rustc for the workspace's own crates in scripts/test.sh (cargo's RUSTC_WORKSPACE_WRAPPER): clippy's
# lints on top of rustc, warnings as errors, in the same compilation that makes the test binaries.
# cargo calls it as `clippy-rustc.sh <rustc> <args>`; clippy-driver accepts that form. bash, not
# sh: dash drops environment variables whose names are no shell names, such as cargo's
# CARGO_BIN_EXE_op3dsg-layers, which the integration tests read at compile time.
exec clippy-driver "$@" -D warnings
