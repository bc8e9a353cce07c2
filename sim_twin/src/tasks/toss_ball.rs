//! Placeholder scene: replaced by the task's module.

use rapier3d_f64::prelude::*;

use super::{Build, Scene, TaskId, TaskObservation, TaskStatus, View};
use crate::error::TwinError;

#[derive(Debug, Default)]
pub(crate) struct TossBall;

impl Scene for TossBall {
    fn task(&self) -> TaskId {
        TaskId::TossBall
    }

    fn criteria_names(&self) -> &'static [&'static str] {
        &[]
    }

    fn build(&mut self, _b: &mut Build<'_>) -> Result<(), TwinError> {
        Ok(())
    }

    fn after_step(&mut self, _world: &mut PhysicsWorld, _view: &View) -> TaskStatus {
        TaskStatus::default()
    }

    fn observation(&self, _world: &PhysicsWorld) -> TaskObservation {
        TaskObservation::default()
    }
}
