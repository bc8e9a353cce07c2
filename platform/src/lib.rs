//! One description of each vehicle of amstack (under construction).

mod actuation;
mod rotor;
mod wrench;

pub use actuation::Actuation;
pub use rotor::{Rotor, RotorLayout, Spin, Tilt};
pub use wrench::Wrench;
