//! The memory layout of every message type, as a program in another language must build
//! it to take part in a run (`scmpc schema`, docs/python.md).
//!
//! Offsets come from the compiler (`offset_of!`), type names from iceoryx2's
//! `ZeroCopySend`, so the description cannot drift from the types; what is written by hand
//! is each field's name and type, beside its type ([`protocol::layouts!`]), and [`tests`]
//! check that the fields cover every byte that is not alignment padding.

use crate::ipc;
use iceoryx2::prelude::ZeroCopySend;
use protocol::layout::Layout;
use protocol::messages::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::mem::{align_of, size_of};

pub use protocol::layout::Field;

/// A `#[repr(C)]` type crossing a process boundary.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TypeLayout {
    /// The iceoryx2 type name: a service opened with another name is refused.
    pub type_name: &'static str,
    pub size: usize,
    pub alignment: usize,
    pub fields: Vec<Field>,
}

/// One topic: its iceoryx2 publish-subscribe service (and the event service of the same
/// name), the payload it carries and the settings every process opens it with.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ServiceLayout {
    /// The topic's name.
    pub topic: &'static str,
    /// Whether each robot has its own: a robot's topic is its service `robot<id>/<topic>`
    /// ([`protocol::topics::service_name`]); the run's (swap requests and replies) is
    /// `<topic>`.
    pub per_robot: bool,
    /// The iceoryx2 service name, under the run's prefix ([`ipc::run_config`]), of the
    /// first robot's ([`protocol::FIRST_ROBOT`]) for a robot's topic.
    pub service: String,
    pub type_name: &'static str,
    pub max_publishers: usize,
    pub max_subscribers: usize,
    pub subscriber_max_buffer_size: usize,
    pub history_size: usize,
    pub safe_overflow: bool,
    /// The event service notified, besides the topic's own, of the samples whose tick
    /// starts a sample (`<service>/sample_starts`, for the topics of
    /// [`protocol::graph::SAMPLE_START_TOPICS`]): a publisher of the topic notifies it too.
    pub sample_starts: Option<String>,
}

/// The layout of `T` from its fields ([`protocol::layouts!`]).
fn described<T: Layout + ZeroCopySend>() -> TypeLayout {
    TypeLayout {
        // SAFETY: `type_name` only returns the name given in `#[type_name(..)]`.
        type_name: unsafe { <T as ZeroCopySend>::type_name() },
        size: size_of::<T>(),
        alignment: align_of::<T>(),
        fields: T::fields(),
    }
}

macro_rules! data_layouts {
    ($($(#[$doc:meta])* $variant:ident($t:ty) = $topic:ident $name:literal @ $rate:ident),* $(,)?) => {
        /// Every data message ([`protocol::data_topics!`]).
        fn data_types() -> Vec<TypeLayout> {
            vec![$(described::<$t>()),*]
        }
    };
}
protocol::data_topics!(data_layouts);

/// Every type that crosses a process boundary, nested ones first.
pub fn types() -> Vec<TypeLayout> {
    let mut types = vec![described::<Header>(), described::<Track>()];
    types.extend(data_types());
    types.extend([
        described::<EpochSchedule>(),
        described::<Control>(),
        described::<Status>(),
        described::<SwapRequest>(),
        described::<SwapReply>(),
    ]);
    types
}

/// The codes of every enumeration a message carries, and the constants a foreign role
/// needs, by name.
pub fn codes() -> BTreeMap<&'static str, BTreeMap<&'static str, u64>> {
    let commands = [
        ("grant", ControlCommand::Grant),
        ("start", ControlCommand::Start),
        ("stop", ControlCommand::Stop),
        ("epochs", ControlCommand::Epochs),
        ("replay", ControlCommand::Replay),
        ("goal", ControlCommand::Goal),
    ];
    let events = [
        ("ready", StatusEvent::Ready),
        ("input_lost", StatusEvent::InputLost),
        ("rejected", StatusEvent::Rejected),
    ];
    let mut codes = message_codes();
    codes.extend([
        ("role", named(&Role::ALL, Role::as_str, |r| r as u32)),
        (
            "control_command",
            commands.iter().map(|(n, c)| (*n, *c as u64)).collect(),
        ),
        (
            "status_event",
            events.iter().map(|(n, e)| (*n, *e as u64)).collect(),
        ),
        (
            "rejection",
            named(&Rejection::ALL, Rejection::as_str, |r| r as u32),
        ),
        (
            "output_slot",
            protocol::graph::TOPICS
                .iter()
                .filter_map(|t| {
                    let producer = ipc::producer_of(t.name)?;
                    Some((t.name, ipc::output_slot(producer, t.name)? as u64))
                })
                .collect(),
        ),
        (
            "constant",
            BTreeMap::from([
                ("max_horizon", MAX_HORIZON as u64),
                ("route_capacity", ROUTE_CAPACITY as u64),
                ("switch_unscheduled", SWITCH_UNSCHEDULED),
                ("no_producer", u64::from(NO_PRODUCER)),
                ("plan_missing", u64::from(PLAN_MISSING)),
                ("role_count", Role::COUNT as u64),
            ]),
        ),
    ]);
    codes
}

/// The codes of the enumerations the data messages carry, by name.
fn message_codes() -> BTreeMap<&'static str, BTreeMap<&'static str, u64>> {
    BTreeMap::from([
        (
            "plan_status",
            named(
                &[
                    PlanStatus::Solved,
                    PlanStatus::Infeasible,
                    PlanStatus::MaxIterations,
                    PlanStatus::NumericalError,
                ],
                PlanStatus::as_str,
                |s| s as u32,
            ),
        ),
        (
            "command_mode",
            named(
                &[
                    CommandMode::Nominal,
                    CommandMode::Shifted,
                    CommandMode::Brake,
                    CommandMode::ZetaGuard,
                    CommandMode::SafetyBrake,
                    CommandMode::Hold,
                    CommandMode::Evasion,
                    CommandMode::Watchdog,
                ],
                CommandMode::as_str,
                |m| m as u32,
            ),
        ),
        (
            "intervention",
            named(
                &[
                    Intervention::None,
                    Intervention::PlanRefused,
                    Intervention::CommittedUnsafe,
                    Intervention::LeastUnsafe,
                    Intervention::MovingContact,
                    Intervention::FreeRange,
                    Intervention::Evasion,
                ],
                Intervention::as_str,
                |i| i as u32,
            ),
        ),
        (
            "route_status",
            BTreeMap::from([
                ("ok", RouteStatus::Ok as u64),
                ("no_route", RouteStatus::NoRoute as u64),
            ]),
        ),
        (
            "replan_reason",
            named(&ReplanReason::ALL, ReplanReason::as_str, |r| r as u32),
        ),
        (
            "route_switch",
            named(&RouteSwitch::ALL, RouteSwitch::as_str, |r| r as u32),
        ),
    ])
}

fn named<T: Copy>(
    all: &[T],
    name: impl Fn(T) -> &'static str,
    code: impl Fn(T) -> u32,
) -> BTreeMap<&'static str, u64> {
    all.iter().map(|&v| (name(v), u64::from(code(v)))).collect()
}

/// Every topic, with the type it carries.
pub fn services() -> Vec<ServiceLayout> {
    let topic = |topic: &'static str, type_name: &'static str| {
        let per_robot = !ipc::RUN_TOPICS.contains(&topic);
        let service = if per_robot {
            ipc::service_name(protocol::FIRST_ROBOT, topic)
        } else {
            topic.to_string()
        };
        ServiceLayout {
            topic,
            per_robot,
            sample_starts: (protocol::graph::SAMPLE_START_TOPICS.contains(&topic))
                .then(|| ipc::sample_starts_service(&service)),
            service,
            type_name,
            max_publishers: if topic == ipc::STATUS {
                ipc::MAX_STATUS_PUBLISHERS
            } else {
                ipc::MAX_PUBLISHERS
            },
            max_subscribers: ipc::MAX_SUBSCRIBERS,
            subscriber_max_buffer_size: ipc::SUBSCRIBER_BUFFER,
            history_size: 0,
            safe_overflow: true,
        }
    };
    let data = protocol::graph::TOPICS
        .iter()
        .map(|t| topic(t.name, t.message));
    data.chain([
        topic(ipc::CONTROL, "scmpc::Control"),
        topic(ipc::STATUS, "scmpc::Status"),
        topic(ipc::SWAP, "scmpc::SwapRequest"),
        topic(ipc::SWAP_REPLY, "scmpc::SwapReply"),
    ])
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fields_of_every_type_cover_it_but_for_alignment_padding() {
        for t in types() {
            let mut end = 0;
            for f in &t.fields {
                assert!(f.offset >= end, "{}.{} overlaps", t.type_name, f.name);
                // Padding before a field is less than the type's alignment.
                assert!(
                    f.offset - end < t.alignment,
                    "{}.{}: gap",
                    t.type_name,
                    f.name
                );
                end = f.offset + f.size;
            }
            assert!(
                t.size - end < t.alignment,
                "{}: bytes after the last field",
                t.type_name
            );
        }
    }

    #[test]
    fn every_service_carries_a_described_type_and_array_lengths_are_numbers() {
        let types = types();
        for s in services() {
            assert!(
                types.iter().any(|t| t.type_name == s.type_name),
                "{}",
                s.service
            );
        }
        let plan = types.iter().find(|t| t.type_name == "scmpc::Plan").unwrap();
        let z = plan.fields.iter().find(|f| f.name == "z").unwrap();
        assert_eq!(z.ty, "[[f64; 4]; 65]");
        assert_eq!(z.size, 65 * 4 * 8);
        let control = types
            .iter()
            .find(|t| t.type_name == "scmpc::Control")
            .unwrap();
        let epochs = control.fields.iter().find(|f| f.name == "epochs").unwrap();
        assert_eq!(epochs.ty, "scmpc::EpochSchedule");
    }
}
