//! Which topics cross which link, for a placement of the roles on hosts (docs/hosts.md).
//! Only topics with a producer on one host and a consumer on another go over Zenoh, and
//! every link goes through the orchestrator's host: it records every topic, so each topic
//! made on another host comes to it, and it forwards what a third host takes.

use protocol::Role;
use protocol::graph::Graph;
use runtime::ipc::{CONTROL, STATUS};
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

/// The routes for the roles of `graph`, `host_of` each (`None`: the orchestrator's host).
pub fn plan<'a>(graph: &Graph, host_of: impl Fn(Role) -> Option<&'a str>) -> Routes {
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
    for (topic, producer) in graph.topics() {
        let made_at = host_of(producer);
        if let Some(host) = made_at {
            push_once(
                routes.host_sends.entry(host.to_string()).or_default(),
                topic,
            );
            push_once(&mut routes.orchestrator_receives, topic);
        }
        for consumer in graph.consumers_of(topic) {
            if let Some(host) = host_of(consumer).filter(|h| Some(*h) != made_at) {
                send_to(&mut routes, topic, host);
            }
        }
    }
    let mut hosts: Vec<&str> = protocol::Role::ALL
        .into_iter()
        .filter(|r| graph.runs(*r))
        .filter_map(&host_of)
        .collect();
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
        let graph = Graph::of_roles(&Role::ALL, protocol::PlantKind::Sim);
        let routes = plan(&graph, |r| match r {
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
        // The planner takes the tracks with a lidar (routes are the graph's, whatever a
        // task leaves out: without a lidar they cross unused, as to a DFL without its check).
        assert_eq!(
            routes.host_receives["planning"],
            [ESTIMATE, TRACKS, CONTROL]
        );
        assert_eq!(routes.orchestrator_sends[ROUTE], ["compute"]);
        assert_eq!(routes.orchestrator_sends[TRACKS], ["compute", "planning"]);
        assert!(!routes.orchestrator_sends.contains_key(MEASUREMENT));
        assert!(
            !routes.orchestrator_sends.contains_key(PLAN),
            "the DFL is local"
        );
        assert_eq!(routes.orchestrator_receives, [PLAN, ROUTE, STATUS]);
        let single = plan(&graph, |_| None);
        assert_eq!(single, Routes::default(), "one host: nothing crosses");
    }
}
