//! Which topics cross which link, for a placement of the roles on hosts (docs/hosts.md).
//! Only topics with a producer on one host and a consumer on another go over Zenoh, and
//! every link goes through the orchestrator's host: it records every topic, so each topic
//! made on another host comes to it, and it forwards what a third host takes.

use protocol::Role;
use runtime::ipc::{CONTROL, DATA_FLOW, STATUS};
use std::collections::BTreeMap;

/// The links of a run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Routes {
    /// What the orchestrator's bridge sends, to which hosts.
    pub orchestrator_sends: BTreeMap<String, Vec<String>>,
    /// What it receives.
    pub orchestrator_receives: Vec<String>,
    /// What each other host's bridge sends (to the orchestrator's host).
    pub host_sends: BTreeMap<String, Vec<String>>,
    /// What each other host's bridge receives.
    pub host_receives: BTreeMap<String, Vec<String>>,
}

/// The routes for the roles `running` of a run, `host_of` each (`None`: the
/// orchestrator's host).
pub fn plan<'a>(running: &[Role], host_of: impl Fn(Role) -> Option<&'a str>) -> Routes {
    let mut routes = Routes::default();
    let send_to = |routes: &mut Routes, topic: &str, to: &str| {
        let hosts = routes
            .orchestrator_sends
            .entry(topic.to_string())
            .or_default();
        if !hosts.iter().any(|h| h == to) {
            hosts.push(to.to_string());
        }
        push_once(
            routes.host_receives.entry(to.to_string()).or_default(),
            topic,
        );
    };
    for (topic, producer, consumers) in DATA_FLOW {
        if !running.contains(&producer) {
            continue;
        }
        let made_at = host_of(producer);
        if let Some(host) = made_at {
            push_once(
                routes.host_sends.entry(host.to_string()).or_default(),
                topic,
            );
            push_once(&mut routes.orchestrator_receives, topic);
        }
        for consumer in consumers.iter().filter(|c| running.contains(c)) {
            if let Some(host) = host_of(*consumer).filter(|h| Some(*h) != made_at) {
                send_to(&mut routes, topic, host);
            }
        }
    }
    let mut hosts: Vec<&str> = running.iter().filter_map(|r| host_of(*r)).collect();
    hosts.sort();
    hosts.dedup();
    for host in hosts {
        send_to(&mut routes, CONTROL, host);
        push_once(
            routes.host_sends.entry(host.to_string()).or_default(),
            STATUS,
        );
        push_once(&mut routes.orchestrator_receives, STATUS);
    }
    routes
}

fn push_once(list: &mut Vec<String>, topic: &str) {
    if !list.iter().any(|t| t == topic) {
        list.push(topic.to_string());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use runtime::ipc::{ESTIMATE, MEASUREMENT, PLAN, ROUTE, TRACKS};

    #[test]
    fn only_topics_crossing_a_host_boundary_cross_and_a_third_host_gets_them_through_the_orchestrator()
     {
        let running = Role::ALL;
        let routes = plan(&running, |r| match r {
            Role::Mpc => Some("compute"),
            Role::Planner => Some("planning"),
            _ => None,
        });
        assert_eq!(routes.host_sends["compute"], [PLAN, STATUS]);
        assert_eq!(routes.host_sends["planning"], [ROUTE, STATUS]);
        assert_eq!(
            routes.host_receives["compute"],
            [ESTIMATE, ROUTE, TRACKS, CONTROL]
        );
        assert_eq!(routes.host_receives["planning"], [ESTIMATE, CONTROL]);
        assert_eq!(routes.orchestrator_sends[ROUTE], ["compute"]);
        assert_eq!(routes.orchestrator_sends[TRACKS], ["compute"]);
        assert!(!routes.orchestrator_sends.contains_key(MEASUREMENT));
        assert!(
            !routes.orchestrator_sends.contains_key(PLAN),
            "the DFL is local"
        );
        assert_eq!(routes.orchestrator_receives, [PLAN, ROUTE, STATUS]);
        let single = plan(&running, |_| None);
        assert_eq!(single, Routes::default(), "one host: nothing crosses");
    }
}
