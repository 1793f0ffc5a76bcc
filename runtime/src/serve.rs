//! Any [`Task`] as a role process: its inputs and outputs opened by its role's declaration
//! ([`protocol::graph`]), and its step run by the one loop of [`Member`]. A role needs nothing of its own here: `scmpc mpc` is `serve::<MpcTask>`.

use crate::ipc::{Input, IpcError, Output, Receiver, Sender, producer_of};
use crate::process::{Member, Next, ProcessArgs, ProcessContext, ProcessError};
use protocol::Data;
use protocol::graph::{Graph, declaration};
use protocol::task::{Cancel, Due, Outputs, Resources, Task, TaskError};
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// Runs a process of task `T` until the orchestrator stops it or a signal comes (`Ok`),
/// or until it fails ([`Member::run`]).
///
/// Every pass hands the task what its inputs hold ([`Task::hear`], the periodic input
/// first: its receipt time is the hop latency), steps it until it has nothing more to
/// give (each output held in real time by its [`hold_ns`](protocol::task::Publish)), and
/// waits as [`Task::next`] says. A task that [warms up](Task::warm_up) is handed a
/// cancel check that holds once its window is over or its periodic input has come.
pub fn serve<T: Task>(args: &ProcessArgs) -> Result<(), ProcessError> {
    let resources = T::Resources::open(&args.scenario)?;
    let task = T::new(&args.scenario, args.epoch, resources)?;
    let member = Member::open(args, T::ROLE)?;
    let inputs = Graph::of(&args.scenario)
        .inputs_of(T::ROLE)
        .filter(|topic| task.takes(topic))
        .map(|topic| InPort::open(&member, topic, task.woken_at_sample_starts(topic)).map(Rc::new))
        .collect::<Result<Vec<_>, _>>()?;
    // In a fleet, the other robots' topics the task takes from them, after its own.
    let peers = (0..args.scenario.robot_count() as u32).filter(|&robot| robot != args.robot);
    let peer_inputs = peers
        .flat_map(|robot| task.peer_topics().iter().map(move |&topic| (robot, topic)))
        .map(|(robot, topic)| InPort::open_peer(&member, robot, topic))
        .collect::<Result<Vec<_>, _>>()?;
    let outputs = declaration(T::ROLE, args.scenario.plant.kind)
        .outputs
        .iter()
        .map(|&topic| OutPort::open(&member, topic))
        .collect::<Result<Vec<_>, _>>()?;
    let task = RefCell::new(task);
    let step = |context: &ProcessContext| {
        let mut task = task.borrow_mut();
        for input in &inputs {
            input.take(|data, latency_ns| {
                if let Ok(input) = T::Input::try_from(data) {
                    task.hear(input, latency_ns, context);
                }
            })?;
        }
        for input in &peer_inputs {
            input.take(|data, _| task.hear_peer(&data))?;
        }
        while let Some(publish) = task.step(context) {
            context.clock.hold(publish.hold_ns);
            let mut sent = Ok(());
            publish.output.each(|data| {
                if sent.is_ok() {
                    sent = send(&outputs, &data);
                }
            });
            sent?;
        }
        if let Some(source) = task.gave_up() {
            return Err(TaskError::GaveUp {
                role: T::ROLE,
                input: task.lost_input(),
                source,
            }
            .into());
        }
        Ok(match task.next() {
            Due::Wait(until_s) => Next::Wait(until_s),
            Due::At(at_s) => Next::At(at_s),
            Due::Expect(at_s) => match inputs.first() {
                Some(input) => Next::expect(input.input(), at_s),
                None => Next::Wait(None),
            },
        })
    };
    // The others' samples do not wake the process: they are taken at each step, which
    // its own periodic input brings (in lockstep after every robot's tick before).
    let input_refs: Vec<&dyn Input> = inputs.iter().map(|i| i.input()).collect();
    let output_refs: Vec<&dyn Output> = outputs.iter().map(|o| o.output()).collect();
    let warms_up = task.borrow().warms_up();
    match inputs.first().filter(|_| warms_up).cloned() {
        Some(periodic) => {
            // The warm-up's end, monotonic ns, set before each warm-up.
            let until_ns = Rc::new(Cell::new(0));
            let cancel: Cancel = {
                let until_ns = until_ns.clone();
                Rc::new(move || {
                    crate::clock::monotonic_ns() >= until_ns.get() || periodic.input().has_samples()
                })
            };
            let warm_up = |window_end_ns| {
                until_ns.set(window_end_ns);
                task.borrow_mut().warm_up(&cancel);
            };
            member.run_warming(&input_refs, &output_refs, step, Some(warm_up))
        }
        None => member.run(&input_refs, &output_refs, step),
    }
}

/// Publishes `data` on the output of its topic (none: the task gave a message it did not
/// declare, a programming error reported as such).
fn send(outputs: &[OutPort], data: &Data) -> Result<(), ProcessError> {
    match outputs.iter().find(|o| o.topic() == data.topic()) {
        Some(output) => output.send(data).map_err(ProcessError::from),
        None => Err(ProcessError::Undeclared {
            topic: data.topic(),
        }),
    }
}

/// Declares the input and output ports of every data topic: one variant per topic, so a
/// task's topics, named at run time, open typed iceoryx2 ports.
macro_rules! data_ports {
    ($($(#[$doc:meta])* $variant:ident($t:ident) = $topic:ident $name:literal @ $rate:ident),* $(,)?) => {
        /// An input of one data topic.
        enum InPort {
            $($variant(Receiver<protocol::$t>),)*
        }

        impl InPort {
            /// The input of `topic` from its producer (the data flow's), woken only at
            /// sample starts if `at_sample_starts` ([`Member::input`]).
            fn open(member: &Member, topic: &'static str, at_sample_starts: bool) -> Result<InPort, IpcError> {
                let producer = producer_of(topic)
                    .ok_or_else(|| IpcError(format!("`{topic}` is not a data topic")))?;
                Ok(match topic {
                    $(protocol::topics::$topic => InPort::$variant(member.input::<protocol::$t>(topic, producer, at_sample_starts)?),)*
                    _ => return Err(IpcError(format!("`{topic}` is not a data topic"))),
                })
            }

            /// The input of `topic` of another robot `robot` of a fleet ([`Member::peer_input`]).
            fn open_peer(member: &Member, robot: u32, topic: &'static str) -> Result<InPort, IpcError> {
                Ok(match topic {
                    $(protocol::topics::$topic => InPort::$variant(member.peer_input::<protocol::$t>(robot, topic)?),)*
                    _ => return Err(IpcError(format!("`{topic}` is not a data topic"))),
                })
            }

            /// Takes every sample waiting, each with its publish-to-receipt latency, ns.
            fn take(&self, mut hear: impl FnMut(Data, u64)) -> Result<(), IpcError> {
                match self {
                    $(InPort::$variant(r) => r.take(|m, latency| hear(Data::from(m), latency)),)*
                }
            }

            fn input(&self) -> &dyn Input {
                match self {
                    $(InPort::$variant(r) => r,)*
                }
            }
        }

        /// An output of one data topic. (A sender keeps its last message for replays, so
        /// the plan's is large; a role has one or two, made once.)
        #[allow(clippy::large_enum_variant)]
        enum OutPort {
            $($variant(Sender<protocol::$t>),)*
        }

        impl OutPort {
            fn open(member: &Member, topic: &'static str) -> Result<OutPort, IpcError> {
                Ok(match topic {
                    $(protocol::topics::$topic => OutPort::$variant(member.output::<protocol::$t>(topic)?),)*
                    _ => return Err(IpcError(format!("`{topic}` is not a data topic"))),
                })
            }

            fn topic(&self) -> &'static str {
                match self {
                    $(OutPort::$variant(_) => protocol::topics::$topic,)*
                }
            }

            /// Publishes `data`, a message of this port's topic.
            fn send(&self, data: &Data) -> Result<(), IpcError> {
                match (self, data) {
                    $((OutPort::$variant(s), Data::$variant(m)) => s.send(*m),)*
                    _ => Err(IpcError(format!("a `{}` message on `{}`", data.topic(), self.topic()))),
                }
            }

            fn output(&self) -> &dyn Output {
                match self {
                    $(OutPort::$variant(s) => s,)*
                }
            }
        }
    };
}

protocol::data_topics!(data_ports);
