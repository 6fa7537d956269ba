//! # op3dsgd: the composition
//!
//! The binaries (`op3dsgd`, `op3dsg`, `op3dsg-detectd`) and what joins the layers for them: the
//! drivers stay below the runtime and know nothing of it, so their registration with the
//! runtime's backend registry lives here ([`backends`]), above both.

use op3dsg_runtime::backend::Backends;

#[cfg(feature = "realsense")]
pub mod realsense;

/// The source backends of this build: the simulator's (`synthetic`, `replay`, `mcap`, ...) and,
/// built with the feature `realsense`, `source.kind = "realsense"`.
pub fn backends() -> Backends {
    #[allow(unused_mut)] // registered into only with the feature `realsense`
    let mut backends = op3dsg_sim::backends();
    #[cfg(feature = "realsense")]
    realsense::register(&mut backends);
    backends
}
