//! The heap allocations iceoryx2 0.10 itself makes in a loop like a role process's, each
//! counted apart, as a minimal reproduction (docs/performance.md, "Timing that tests
//! check"): a publish and a WaitSet wake-up, iceoryx2's API alone, after warm-up.
//!
//! - every loan of a sample (`Publisher::loan_uninit`, and `send_copy`, which loans) boxes
//!   the sample's reference-counted shared state (`ChunkMutSharedState::new`): 1 per send,
//!   whichever sending call, so no call of the API avoids it;
//! - every wake-up of `WaitSet::wait_and_process_once_with_timeout` collects the triggered
//!   file descriptors into a `Vec`, and `handle_all_attachments` another: 2 per wake-up
//!   with an event (a wake-up by timeout alone: none).
//!
//! When an iceoryx2 upgrade stops allocating there, this test fails: the role processes
//! then allocate nothing per tick, and the docs should say so.

use iceoryx2::prelude::*;
use runtime::alloc_count::{Counting, allocations};
use std::time::Duration;

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations `f` made, over `times` calls, per call; `u64::MAX` when the total is not a
/// whole number per call. (This binary's one test runs alone: no other thread allocates.)
fn per_call(times: u64, mut f: impl FnMut()) -> u64 {
    let before = allocations();
    for _ in 0..times {
        f();
    }
    let made = allocations() - before;
    if made.is_multiple_of(times) {
        made / times
    } else {
        u64::MAX
    }
}

#[test]
fn iceoryx2_0_10_allocates_once_per_loan_and_twice_per_waitset_wake_up() {
    let prefix = format!("scmpct{}alloc_", std::process::id());
    let counted = count(&prefix);
    runtime::ipc::remove_run(&prefix).unwrap();
    assert!(runtime::ipc::leftover_files(&prefix).is_empty());
    assert_eq!(
        counted,
        [
            ("receiving with nothing to receive", 0),
            ("send_copy and receive", 1),
            ("loan_uninit, send and receive", 1),
            ("a WaitSet wake-up by an event", 2),
            ("a WaitSet wake-up by timeout", 0),
        ]
    );
}

/// Allocations per call of each part of a loop, on iceoryx2 run `prefix`.
fn count(prefix: &str) -> [(&'static str, u64); 5] {
    let config = runtime::ipc::run_config(prefix).unwrap();
    let node = NodeBuilder::new()
        .config(&config)
        .create::<ipc::Service>()
        .unwrap();
    let name: ServiceName = "alloc/repro".try_into().unwrap();
    let service = node
        .service_builder(&name)
        .publish_subscribe::<u64>()
        .open_or_create()
        .unwrap();
    let events = node
        .service_builder(&name)
        .event()
        .open_or_create()
        .unwrap();
    let publisher = service.publisher_builder().create().unwrap();
    let subscriber = service.subscriber_builder().create().unwrap();
    let notifier = events.notifier_builder().create().unwrap();
    let listener = events.listener_builder().create().unwrap();
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().unwrap();
    let _guard = waitset.attach_notification(&listener).unwrap();

    let mut send_copy = || {
        publisher.send_copy(7).unwrap();
        while subscriber.receive().unwrap().is_some() {}
    };
    let mut loan = || {
        let sample = publisher.loan_uninit().unwrap().write_payload(7);
        sample.send().unwrap();
        while subscriber.receive().unwrap().is_some() {}
    };
    let wake = |notify: bool| {
        if notify {
            notifier.notify().unwrap();
        }
        waitset
            .wait_and_process_once_with_timeout(
                |_| {
                    listener.try_wait(|_| {}).unwrap();
                    CallbackProgression::Continue
                },
                Duration::from_millis(1),
            )
            .unwrap();
    };
    // Warm-up: whatever is sized once.
    for _ in 0..10 {
        send_copy();
        loan();
        wake(true);
        wake(false);
    }
    let receive_only = per_call(100, || while subscriber.receive().unwrap().is_some() {});
    [
        ("receiving with nothing to receive", receive_only),
        ("send_copy and receive", per_call(100, &mut send_copy)),
        ("loan_uninit, send and receive", per_call(100, &mut loan)),
        (
            "a WaitSet wake-up by an event",
            per_call(100, || wake(true)),
        ),
        ("a WaitSet wake-up by timeout", per_call(20, || wake(false))),
    ]
}
