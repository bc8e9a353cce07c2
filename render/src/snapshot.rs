//! The state one frame is drawn from: the vehicle's base pose and joints, and the world poses
//! of the scene's objects. Plain data, so it can be filled from the in-process twin, from a
//! measurement received over a link, or from a log, and sent to a render thread.

use nalgebra::Isometry3;
use platform::Measurement;
use sim_twin::Twin;

/// What a frame shows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Snapshot {
    /// The base link in the world.
    pub world_from_base: Isometry3<f64>,
    /// Every movable joint, configuration order, rad or m.
    pub joint_positions: Vec<f64>,
    /// World pose of each scene object, in the order of the scene the renderer was reset
    /// with ([`sim_twin::Twin::scene_visuals`]).
    pub scene_poses: Vec<Isometry3<f64>>,
}

impl Snapshot {
    /// The twin's state now (exact, without observation noise).
    pub fn of_twin(twin: &Twin) -> Self {
        let mut s = Self::default();
        s.update_from_twin(twin);
        s
    }

    /// Refills this snapshot from the twin's state now; allocates nothing once the vectors
    /// have their capacity (call it every tick).
    pub fn update_from_twin(&mut self, twin: &Twin) {
        self.update_vehicle(twin.truth());
        twin.scene_visual_poses_into(&mut self.scene_poses);
    }

    /// Refills the vehicle part from a measurement (a link's, a log's).
    pub fn update_vehicle(&mut self, measurement: &Measurement) {
        self.world_from_base = measurement.base.pose();
        self.joint_positions.clear();
        self.joint_positions
            .extend_from_slice(&measurement.joint_positions);
    }
}
