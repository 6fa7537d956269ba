//! op3dsg-ros2's integration tests: CDR against golden bytes and an independent encoder, key
//! expressions, the TF buffer. One test binary, a module per area.

mod golden;
mod keys;
mod tf_buffer;
