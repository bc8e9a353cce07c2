//! Placeholder policy: replaced by the task's module.

use rand_chacha::ChaCha8Rng;

use super::{PolicyContext, TaskPolicy, identity, wp};
use crate::scripted::WaypointPolicy;

pub(crate) fn policy(
    ctx: &PolicyContext,
    _rng: &mut ChaCha8Rng,
) -> Result<Box<dyn TaskPolicy>, String> {
    Ok(Box::new(WaypointPolicy::new(vec![wp(
        0,
        ctx.init,
        identity(),
        1.0,
    )])?))
}
