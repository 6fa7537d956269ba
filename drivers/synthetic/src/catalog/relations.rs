//! The canonical relation phrases the catalog writes into the ground truth.

// Canonical functional relations.
pub(super) const PULL: &str = "pull to open or close";
pub(super) const WATER: &str = "control the water flow";
pub(super) const ADJUST: &str = "rotate to adjust the setting or temperature";
pub(super) const PRESS_START: &str = "press to start and operate";
pub(super) const SWITCH: &str = "turn on or turn off";
pub(super) const REMOTE: &str = "remote to control";
pub(super) const FLUSH: &str = "press to flush";
pub(super) const POWER: &str = "provide power";
pub(super) const PUSH_OPEN: &str = "push or press to open";
pub(super) const FLOW_SETTING: &str = "operate or adjust the flow or setting";
pub(super) const ROTATE_OPEN: &str = "rotate to open or close";

/// The 11 canonical functional relation phrases.
pub const FUNCTIONAL_RELATIONS: [&str; 11] =
    [PULL, WATER, ADJUST, PRESS_START, SWITCH, REMOTE, FLUSH, POWER, PUSH_OPEN, FLOW_SETTING, ROTATE_OPEN];
/// Spatial relation phrases used in ground truth.
pub const SPATIAL_RELATIONS: [&str; 7] = ["part of", "on", "under", "above", "below", "next to", "inside"];
