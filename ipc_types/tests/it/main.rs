//! op3dsg-ipc-types' integration tests over real iceoryx2 services. One test binary; the client's
//! allocation count is its own binary (`client_allocations.rs`: a counting global allocator counts
//! every thread of its process).

#[path = "../common/mod.rs"]
mod common;

mod client_over_iceoryx2;
