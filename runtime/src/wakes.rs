//! Which listeners of a wait set fired since their wake-ups were last cleared
//! ([`Wakes`]): a role's, and a fleet's orchestrator's in lockstep.

use crate::ipc::{IpcError, Wake, wait_fired};
use iceoryx2::prelude::*;
use std::time::Duration;

/// Which listeners of a wait set fired since their wake-ups were last cleared. A wake-up
/// is cleared with two system calls (iceoryx2's `try_wait`); in lockstep a process clears
/// only the listeners a wait saw fire, and every one after a pass that did not wait (the
/// first, one after a poll or a spin) or a wait that timed out. The timeout also rearms a
/// listener that iceoryx2 left notified with nothing to wake a wait (a notification that
/// came between the two steps of its clearing): that costs a lockstep run a wait of at
/// most the timeout, never a sample, which is taken from shared memory. In real time a
/// role clears every listener after every wait.
pub struct Wakes {
    /// The listeners' attachments, in the order their indices name them.
    attachments: Vec<WaitSetAttachmentId<ipc::Service>>,
    /// Which of them fired since the last clearing.
    fired: Vec<bool>,
    /// Whether a wake-up may be pending that no wait saw fire: from a clearing until a
    /// wait that an input ended.
    unseen: bool,
}

impl Wakes {
    /// For the listeners attached with `guards`, indexed in that order.
    pub fn new<'g, 'w: 'g, 'a: 'g>(
        guards: impl IntoIterator<Item = &'g WaitSetGuard<'w, 'a, ipc::Service>>,
    ) -> Wakes {
        let attachments: Vec<_> = guards
            .into_iter()
            .map(WaitSetAttachmentId::from_guard)
            .collect();
        Wakes {
            fired: vec![false; attachments.len()],
            attachments,
            unseen: true,
        }
    }

    /// Blocks on `waitset` at most `timeout` ([`wait_fired`]), noting what fired. A wait
    /// that an input ended saw every wake-up pending then.
    pub fn wait(
        &mut self,
        waitset: &WaitSet<ipc::Service>,
        timeout: Duration,
    ) -> Result<Wake, IpcError> {
        let mut unknown = false;
        let wake = wait_fired(waitset, timeout, |attachment| {
            match self.attachments.iter().position(|a| *a == attachment) {
                Some(i) => self.fired[i] = true,
                None => unknown = true,
            }
        })?;
        self.unseen = unknown || wake != Wake::Input;
        Ok(wake)
    }

    /// Whether to clear listener `index`: every one unless in `lockstep` and each wake-up
    /// pending was seen to fire.
    pub fn to_clear(&self, lockstep: bool, index: usize) -> bool {
        !lockstep || self.unseen || self.fired[index]
    }

    /// The wake-ups were cleared ([`Wakes::to_clear`]); what comes next is unseen until
    /// a wait sees it fire.
    pub fn cleared(&mut self) {
        self.fired.fill(false);
        self.unseen = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ipc::{end_run, new_prefix, run_config};

    #[test]
    fn in_lockstep_only_the_listeners_a_wait_saw_fire_are_cleared_and_all_after_a_timeout() {
        let prefix = new_prefix();
        wait_and_clear(&prefix);
        end_run(&prefix).unwrap();
    }

    fn wait_and_clear(prefix: &str) {
        let config = run_config(prefix).unwrap();
        let node = NodeBuilder::new()
            .config(&config)
            .create::<ipc::Service>()
            .unwrap();
        let event = |name: &str| {
            let name: ServiceName = name.try_into().unwrap();
            node.service_builder(&name)
                .event()
                .open_or_create()
                .unwrap()
        };
        let (control, input) = (event("wakes/control"), event("wakes/input"));
        let control_listener = control.listener_builder().create().unwrap();
        let input_listener = input.listener_builder().create().unwrap();
        let input_notifier = input.notifier_builder().create().unwrap();
        let waitset = WaitSetBuilder::new().create::<ipc::Service>().unwrap();
        let control_guard = waitset.attach_notification(&control_listener).unwrap();
        let input_guard = [waitset.attach_notification(&input_listener).unwrap()];
        let mut wakes = Wakes::new(std::iter::once(&control_guard).chain(&input_guard));
        assert!(
            wakes.to_clear(true, 0) && wakes.to_clear(true, 1),
            "before any wait"
        );
        wakes.cleared();
        assert!(
            wakes.to_clear(true, 0),
            "a pass without a wait after a clearing"
        );

        input_notifier.notify().unwrap();
        let wake = wakes.wait(&waitset, Duration::from_secs(5)).unwrap();
        assert_eq!(wake, Wake::Input);
        assert!(wakes.to_clear(true, 1), "the input fired");
        assert!(!wakes.to_clear(true, 0), "the control topic did not");
        assert!(wakes.to_clear(false, 0), "real time clears every listener");
        input_listener.try_wait(|_| {}).unwrap();
        wakes.cleared();

        let wake = wakes.wait(&waitset, Duration::from_millis(10)).unwrap();
        assert_eq!(wake, Wake::Timeout);
        assert!(
            wakes.to_clear(true, 0) && wakes.to_clear(true, 1),
            "after a timeout"
        );
    }
}
