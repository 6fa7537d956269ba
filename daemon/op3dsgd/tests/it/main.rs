//! The binaries' own tests: `op3dsg bench perf` and the IPC benchmark's two processes. One test
//! binary, a module per command.

mod bench_perf;
mod ipc_two_process;
