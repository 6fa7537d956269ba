//! `fusion.method = "conceptgraphs"`, registered with the runtime's backends like the simulator's
//! source and detector: its section `[fusion.conceptgraphs]` is checked when the profile loads.

use op3dsg_runtime::backend::{FusionBackend, SectionError, StartError};
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::fusion::Fusion;
use serde::Deserialize as _;

use super::{ConceptGraphsConfig, ConceptGraphsFusion};

/// The name in `fusion.method` and of its section `[fusion.conceptgraphs]`.
pub const CONCEPTGRAPHS_FUSION: &str = "conceptgraphs";

/// ConceptGraphs' association and merging as a fusion a profile can name (the benchmark's peer,
/// here for a user who wants to compare both on their own robot; its maps are not saved in
/// snapshots).
#[derive(Debug, Clone, Copy, Default)]
pub struct ConceptGraphsBackend;

impl ConceptGraphsBackend {
    /// `[fusion.conceptgraphs]` of `profile`, typed (the defaults without one).
    pub fn config(profile: &Profile) -> Result<ConceptGraphsConfig, StartError> {
        let section = profile.section("fusion.conceptgraphs").cloned().unwrap_or_default();
        ConceptGraphsConfig::deserialize(toml::Value::Table(section))
            .map_err(|e| StartError::Incompatible { field: "fusion.conceptgraphs", reason: e.to_string() })
    }
}

impl FusionBackend for ConceptGraphsBackend {
    fn name(&self) -> &'static str {
        CONCEPTGRAPHS_FUSION
    }

    fn load_section(&self, section: &mut toml::Table) -> Result<(), SectionError> {
        let config: ConceptGraphsConfig = serde_path_to_error::deserialize(toml::Value::Table(section.clone()))
            .map_err(|e| {
                let path = e.path().to_string();
                let inner = e.into_inner().to_string();
                (if path == "." { String::new() } else { path }, inner.lines().next().unwrap_or("").trim().to_owned())
            })?;
        config.validate("").map_err(|e| {
            let e = e.trim_start_matches('.');
            match e.split_once(": ") {
                Some((field, message)) => (field.to_owned(), message.to_owned()),
                None => (String::new(), e.to_owned()),
            }
        })
    }

    fn build(&self, profile: &Profile) -> Result<Box<dyn Fusion>, StartError> {
        Ok(Box::new(ConceptGraphsFusion::new(Self::config(profile)?).with_up_axis(profile.world.up_axis)))
    }
}
