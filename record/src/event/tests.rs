use super::*;
use std::collections::BTreeSet;

/// One event of every kind, with fields unlike their defaults.
fn one_of_each() -> Vec<Event> {
    let host = Some("far".to_string());
    vec![
        Event::Spawned {
            role: Role::Plant,
            pid: 17,
            host: None,
        },
        Event::Ready(Ready::Run {
            iceoryx2_prefix: "scmpc1_".into(),
        }),
        Event::Ready(Ready::Role { role: Role::Mpc }),
        Event::ClockStarted {
            tick0_monotonic_ns: 123_456_789,
        },
        Event::BrakingToRest {},
        Event::HostJoined {
            host: "far".into(),
            endpoint: "tcp/127.0.0.1:7447".into(),
            agent_pid: 4,
            prefix: "scmpc2_".into(),
            round_trip_us: 81.5,
            clock_correction_ms: -0.25,
        },
        Event::HostLost {
            host: "far".into(),
            roles: vec![Role::Mpc, Role::Planner],
        },
        Event::DeadlineMiss {
            sample: 9,
            status: "missing".into(),
            production_us: None,
            arrival_ms: Some(52.5),
            fallback: "shifted".into(),
        },
        Event::CommandTimeout { tick: 460 },
        Event::RecordGap {
            tick: 40,
            missing: vec!["truth".into(), "actuation".into()],
        },
        Event::Crashed {
            role: Role::Dfl,
            epoch: 1,
            status: "signal: 9".into(),
            nodes_cleaned: 2,
        },
        Event::DeadNode {
            node: "dfl-1".into(),
            role: Role::Dfl,
            epoch: 1,
            child_killed: Some(12),
        },
        Event::GaveWay {
            sample: 181,
            to_robot: 3,
        },
        Event::Restarted(Restart::Process(NewProcess {
            role: Role::Mpc,
            pid: 88,
            epoch: 2,
            host: host.clone(),
        })),
        Event::Restarted(Restart::InProcess {
            role: Role::Estimator,
            reason: "estimate refused".into(),
        }),
        Event::FailedOver(NewProcess {
            role: Role::Planner,
            pid: 90,
            epoch: 3,
            host: None,
        }),
        Event::Aborted {
            role: Role::Plant,
            reason: "the plant failed".into(),
        },
        Event::InputLost {
            role: Role::Plant,
            input: Some("/cmd_vel".into()),
        },
        Event::Rejected {
            consumer: "orchestrator".into(),
            reason: "wrong_epoch".into(),
            count: 3,
        },
        Event::RefusedTooLong {
            role: Role::Mpc,
            epoch: 0,
            pid: Some(5),
            limit_s: 1.5,
        },
        Event::SwapStarted {
            role: Role::Mpc,
            epoch: 4,
            replaces: 0,
            pid: 91,
            command: "scmpc role mpc".into(),
            host,
        },
        Event::SwapScheduled {
            role: Role::Mpc,
            epoch: 4,
            switch_tick: 400,
        },
        Event::Swapped {
            role: Role::Mpc,
            from_epoch: 0,
            to_epoch: 4,
            old_pid: None,
            new_pid: 91,
            switch_tick: Some(400),
            how: "at its switch tick".into(),
            warmup_s: 0.75,
        },
        Event::SwapFailed {
            role: Role::Mpc,
            epoch: 5,
            command: "false".into(),
            reason: "exited".into(),
        },
        Event::SwapRefused {
            role: None,
            command: "x".into(),
            reason: "no role `x`".into(),
        },
        Event::Retired {
            role: Role::Mpc,
            epoch: 0,
            status: "exit status: 0".into(),
        },
        Event::SafetyIntervention {
            tick: 77,
            reason: "plan_refused".into(),
            command: "shifted".into(),
            plan_sample: 7,
            clearance_m: -0.01,
            dfl_count: 2,
        },
        Event::NoRoute {
            sample: 0,
            reason: "first".into(),
        },
        Event::Goal {
            serial: 1,
            from_tick: 40,
            x: 5.5,
            y: -4.5,
            heading: Some(1.5),
            from: "live".into(),
        },
        Event::Exited {
            role: Role::Tracker,
            epoch: 0,
            status: "exit status: 0".into(),
            killed: false,
        },
        Event::End {
            outcome: Outcome::Interrupted,
            signal: Some("SIGINT".into()),
        },
    ]
}

/// The `event` tags a JSON schema allows: every `const` given for a property `event`.
fn tags_in(schema: &serde_json::Value, tags: &mut BTreeSet<String>) {
    match schema {
        serde_json::Value::Object(map) => {
            if let Some(tag) = map
                .get("properties")
                .and_then(|p| p.get("event"))
                .and_then(|e| e.get("const"))
                .and_then(|c| c.as_str())
            {
                tags.insert(tag.to_string());
            }
            map.values().for_each(|v| tags_in(v, tags));
        }
        serde_json::Value::Array(items) => items.iter().for_each(|v| tags_in(v, tags)),
        _ => {}
    }
}

#[test]
fn every_kind_of_event_is_written_with_its_tag_and_read_back_the_same() {
    for event in one_of_each() {
        let line = EventLine {
            wall_s: 0.5,
            t: 12.25,
            event: event.clone(),
        };
        let written = line.to_json().unwrap().to_string();
        let json: serde_json::Value = serde_json::from_str(&written).unwrap();
        assert_eq!(json["event"], event.kind(), "{written}");
        assert_eq!(json["t"], 12.25, "{written}");
        let read: EventLine = serde_json::from_str(&written).unwrap();
        assert_eq!(read, line, "{written}");
    }
}

#[test]
fn a_line_is_written_as_before_the_type_keys_sorted_and_absent_values_null() {
    let line = EventLine {
        wall_s: 0.031836172,
        t: 0.0,
        event: Event::Spawned {
            role: Role::Plant,
            pid: 17058,
            host: None,
        },
    };
    assert_eq!(
        line.to_json().unwrap().to_string(),
        r#"{"event":"spawned","host":null,"pid":17058,"role":"plant","t":0.0,"wall_s":0.031836172}"#
    );
}

#[test]
fn the_schema_allows_every_kind_and_the_examples_cover_them_all() {
    let mut in_schema = BTreeSet::new();
    tags_in(&EventLine::schema(), &mut in_schema);
    let written: BTreeSet<String> = one_of_each().iter().map(|e| e.kind().to_string()).collect();
    assert_eq!(in_schema, written);
}

#[test]
fn docs_running_md_lists_every_kind_of_event() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/running.md");
    let docs = std::fs::read_to_string(&path).unwrap();
    let unlisted: Vec<&str> = one_of_each()
        .iter()
        .map(Event::kind)
        .filter(|kind| !docs.contains(&format!("`{kind}`")))
        .collect();
    assert!(
        unlisted.is_empty(),
        "{} does not list {unlisted:?}",
        path.display()
    );
}
