//! The canonical relation phrases the catalog writes into the ground truth.

use crate::truth::relation::{
    ADJUST, FLOW_SETTING, FLUSH, POWER, PRESS_START, PULL, PUSH_OPEN, REMOTE, ROTATE_OPEN, SWITCH, WATER,
};

/// The 11 canonical functional relation phrases.
pub const FUNCTIONAL_RELATIONS: [&str; 11] =
    [PULL, WATER, ADJUST, PRESS_START, SWITCH, REMOTE, FLUSH, POWER, PUSH_OPEN, FLOW_SETTING, ROTATE_OPEN];
/// Spatial relation phrases used in ground truth.
pub const SPATIAL_RELATIONS: [&str; 7] = ["part of", "on", "under", "above", "below", "next to", "inside"];
