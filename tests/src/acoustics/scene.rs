//! A scene: the room, its sources' signals and how impulse responses are built,
//! defined once up front and shared by every array rendered in it. Each array
//! gets its own renderer (`Scene::renderer`, defined in the renderer module,
//! which depends on this one and not the other way round).

use super::rir::{RirConfig, RirModel};
use super::room::ShoeboxRoom;
use super::signals::SourceSignal;
use crate::error::SimError;

/// Room, source signals and impulse-response settings.
///
/// Source positions are not part of the scene: they are given block by block
/// (a loudspeaker may be carried around), in the order of [`Scene::sources`].
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// The room.
    pub room: ShoeboxRoom,
    /// What each source emits.
    pub sources: Vec<SourceSignal>,
    /// How impulse responses are built (sample rate included).
    pub rir: RirConfig,
}

impl Scene {
    /// Checks the scene as a whole.
    pub fn validate(&self) -> Result<RirModel, SimError> {
        if self.sources.is_empty() {
            return Err(SimError::invalid("scene.sources", "at least one source is needed"));
        }
        for s in &self.sources {
            s.validate(self.rir.sample_rate_hz)?;
        }
        RirModel::new(&self.room, &self.rir)
    }
}
