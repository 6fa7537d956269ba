#!/bin/sh
# rustc for the workspace's own crates in scripts/test.sh (cargo's RUSTC_WORKSPACE_WRAPPER): clippy's
# lints on top of rustc, warnings as errors, in the same compilation that makes the test binaries.
# cargo calls it as `clippy-rustc.sh <rustc> <args>`; clippy-driver accepts that form.
exec clippy-driver "$@" -D warnings
