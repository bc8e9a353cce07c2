//! The parameter protocol (the set and its checks: [`crate::params`]) and the mission
//! protocol's outcomes (the protocol itself: [`crate::mission`]).

use mavlink::dialects::common::{MavSeverity, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA};

use super::{Autopilot, AutopilotEvent};
use crate::mission::Outcome;
use crate::modes::FlightMode;
use crate::params::{self, DEFS};

impl Autopilot {
    /// PARAM_REQUEST_LIST: every PARAM_VALUE, in index order.
    pub(super) fn param_list(&mut self) {
        let all: Vec<_> = (0..self.params.count())
            .filter_map(|i| self.params.value_message(i))
            .collect();
        self.send(&all);
    }

    /// PARAM_REQUEST_READ by index (≥ 0) or by name (index −1). An unknown name or index is
    /// answered as PX4 does: a STATUSTEXT, no PARAM_VALUE.
    pub(super) fn param_read(&mut self, p: &PARAM_REQUEST_READ_DATA) {
        let index = if p.param_index >= 0 {
            usize::try_from(p.param_index).ok()
        } else {
            self.params.index_of(&params::name_of(&p.param_id[..]))
        };
        match index.and_then(|i| self.params.value_message(i)) {
            Some(msg) => self.send(&[msg]),
            None if p.param_index >= 0 => self.status_text(
                MavSeverity::MAV_SEVERITY_INFO,
                &format!("[pm] param index {} out of range", p.param_index),
            ),
            None => self.status_text(
                MavSeverity::MAV_SEVERITY_INFO,
                &format!("[pm] unknown param: {}", params::name_of(&p.param_id[..])),
            ),
        }
    }

    /// PARAM_SET: typed, range-checked; the new (or, refused, the unchanged) PARAM_VALUE goes
    /// to every peer, a refusal's reason in a STATUSTEXT.
    pub(super) fn param_set(
        &mut self,
        p: &PARAM_SET_DATA,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        let name = params::name_of(&p.param_id[..]);
        match self
            .params
            .set_from_mavlink(&name, p.param_value, p.param_type)
        {
            Ok(index) => {
                if let Some(msg) = self.params.value_message(index) {
                    self.send(&[msg]);
                }
                let value = self.params.get(DEFS[index].param);
                self.notice(format!("parameter {name} = {value}"), on_event);
            }
            Err((index, e)) => {
                self.wire.count_rejected_input();
                let text = e.to_string();
                self.status_text(MavSeverity::MAV_SEVERITY_WARNING, &text);
                if let Some(msg) = index.and_then(|i| self.params.value_message(i)) {
                    self.send(&[msg]);
                }
                self.notice(format!("parameter set refused: {text}"), on_event);
            }
        }
    }

    /// After a mission message: a new mission restarts at item 0 (and a mission being flown
    /// starts over); a failed upload is logged.
    pub(super) fn mission_outcome(
        &mut self,
        outcome: Outcome,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        match outcome {
            Outcome::None => {}
            Outcome::Replaced => {
                self.mission_seq = 0;
                let n = self.missions.items().len();
                if self.commander.mode() == FlightMode::AutoMission {
                    self.enter(FlightMode::AutoMission);
                }
                let msg = self.mission_current();
                self.send(&[msg]);
                self.notice(format!("mission of {n} items in place"), on_event);
            }
            Outcome::Failed(why) => {
                self.wire.count_rejected_input();
                self.notice(format!("mission upload refused: {why}"), on_event);
            }
        }
    }
}
