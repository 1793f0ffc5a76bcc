//! Samples as bytes, for the bridge between hosts (docs/hosts.md): a sample crosses a link
//! in its `#[repr(C)]` layout (`scmpc schema`), byte for byte, and is published on the
//! other side as it was made (its header, with the producer's epoch, run id and publish
//! time, untouched).
//!
//! Every message type is `#[repr(C)]` of integers and floats only (no `bool`, no enum: codes
//! are `u32`; the layout test checks the field types), so any bytes of the right length are
//! a value of the type; whether it makes sense is the consumers' border check.

use super::*;
use protocol::messages::*;

/// A subscriber that hands over each sample's bytes as they are in shared memory.
pub trait WireTap {
    /// The listener a WaitSet blocks on.
    fn listener(&self) -> &Listener<ipc::Service>;
    /// Every pending sample: its bytes and the iceoryx2 id of its publisher.
    fn take(&self, each: &mut dyn FnMut(&[u8], u128)) -> Result<(), IpcError>;
    /// Consumes the pending wake-ups.
    fn clear_wakeups(&self);
}

/// A publisher that publishes bytes from another host as the sample they are.
pub trait WireRelay {
    /// Publishes `bytes` as a sample and notifies; false if they are not one (a wrong
    /// length). `edit` may change the sample first (the control topic's publisher pins).
    fn relay(
        &self,
        bytes: &[u8],
        edit: &mut dyn FnMut(&mut dyn std::any::Any),
    ) -> Result<bool, IpcError>;
    /// The iceoryx2 id of its publisher: what local consumers pin the producers it carries to.
    fn publisher_id(&self) -> u128;
}

struct Tap<T: Wire> {
    subscriber: Subscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
}

impl<T: Wire> WireTap for Tap<T> {
    fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    fn take(&self, each: &mut dyn FnMut(&[u8], u128)) -> Result<(), IpcError> {
        while let Some(sample) = self.subscriber.receive().map_err(ctx("receiving"))? {
            let payload: &T = sample.payload();
            // SAFETY: the payload is a `T` in shared memory, `size_of::<T>()` bytes written
            // by its publisher (another process): read as bytes, as they are.
            let bytes = unsafe {
                std::slice::from_raw_parts(payload as *const T as *const u8, size_of::<T>())
            };
            each(bytes, sample.origin().value());
        }
        Ok(())
    }

    fn clear_wakeups(&self) {
        let _ = self.listener.try_wait(|_| {});
    }
}

/// A relay does not know a sample's length in ticks: it announces every sample of a topic
/// that announces its sample starts as one (a consumer woken only at sample starts is then
/// woken at every sample, as without the announcement).
struct Relay<T: Wire> {
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    sample_starts: Option<Notifier<ipc::Service>>,
}

impl<T: Wire> WireRelay for Relay<T> {
    fn relay(
        &self,
        bytes: &[u8],
        edit: &mut dyn FnMut(&mut dyn std::any::Any),
    ) -> Result<bool, IpcError> {
        if bytes.len() != size_of::<T>() {
            return Ok(false);
        }
        // SAFETY: the length is checked, and every bit pattern is a `T` (module docs).
        let mut value: T = unsafe { std::ptr::read_unaligned(bytes.as_ptr() as *const T) };
        edit(&mut value);
        self.publisher.send_copy(value).map_err(ctx("publishing"))?;
        self.notifier.notify().map_err(ctx("notifying"))?;
        if let Some(sample_starts) = &self.sample_starts {
            sample_starts.notify().map_err(ctx("notifying"))?;
        }
        Ok(true)
    }

    fn publisher_id(&self) -> u128 {
        self.publisher.id().value()
    }
}

impl<T: Wire> Topic<T> {
    fn tap(&self) -> Result<Tap<T>, IpcError> {
        let (subscriber, listener) = self.subscribing_ports()?;
        Ok(Tap {
            subscriber,
            listener,
        })
    }

    fn relay(&self) -> Result<Relay<T>, IpcError> {
        let (publisher, notifier) = self.publishing_ports()?;
        Ok(Relay {
            publisher,
            notifier,
            sample_starts: self.sample_start_notifier()?,
        })
    }
}

/// `tap_of` and `relay_of` by a topic's name: a bridge carries every data topic
/// ([`protocol::data_topics!`]), the control topic and the status topic; the live swap
/// requests and their replies stay with the orchestrator.
macro_rules! by_topic {
    ($($(#[$doc:meta])* $variant:ident($t:ty) = $topic:ident $name:literal @ $rate:ident),* $(,)?) => {
        /// A tap on data topic `name` of a running run that has it, never created: what a
        /// tool watching the run reads (`scmpc echo`).
        pub fn watch(node: &Node<ipc::Service>, robot: u32, name: &str) -> Result<Box<dyn WireTap>, IpcError> {
            match name {
                $($topic => Ok(Box::new(open_existing_topic::<$t>(node, robot, $topic)?.tap()?)),)*
                other => Err(IpcError(format!("no data topic `{other}`"))),
            }
        }

        /// A tap on topic `name` (a data topic, control or status).
        pub fn tap(node: &Node<ipc::Service>, robot: u32, name: &str) -> Result<Box<dyn WireTap>, IpcError> {
            match name {
                $($topic => tap_of::<$t>($topic, node, robot),)*
                CONTROL => tap_of::<Control>(CONTROL, node, robot),
                STATUS => tap_of::<Status>(STATUS, node, robot),
                other => Err(IpcError(format!("no bridged topic `{other}`"))),
            }
        }

        /// An input of data topic `name` of robot `robot`, taking samples from `producer`
        /// as [`Data`] (the orchestrator's, for topics it records whatever their type);
        /// `quiet`: without a listener ([`Receiver::quiet`]).
        pub fn data_input(
            node: &Node<ipc::Service>,
            robot: u32,
            name: &str,
            producer: protocol::Role,
            quiet: bool,
        ) -> Result<Box<dyn DataInput>, IpcError> {
            match name {
                $($topic => {
                    let input = open_topic::<$t>(node, robot, $topic)?.receiver_from(producer)?;
                    Ok(Box::new(if quiet { input.quiet() } else { input }))
                })*
                other => Err(IpcError(format!("no data topic `{other}`"))),
            }
        }

        /// A relay onto topic `name` (a data topic, control or status).
        pub fn relay(node: &Node<ipc::Service>, robot: u32, name: &str) -> Result<Box<dyn WireRelay>, IpcError> {
            match name {
                $($topic => relay_of::<$t>($topic, node, robot),)*
                CONTROL => relay_of::<Control>(CONTROL, node, robot),
                STATUS => relay_of::<Status>(STATUS, node, robot),
                other => Err(IpcError(format!("no bridged topic `{other}`"))),
            }
        }
    };
}
protocol::data_topics!(by_topic);

fn tap_of<T: Wire>(
    name: &'static str,
    node: &Node<ipc::Service>,
    robot: u32,
) -> Result<Box<dyn WireTap>, IpcError> {
    Ok(Box::new(open_topic::<T>(node, robot, name)?.tap()?))
}

fn relay_of<T: Wire>(
    name: &'static str,
    node: &Node<ipc::Service>,
    robot: u32,
) -> Result<Box<dyn WireRelay>, IpcError> {
    Ok(Box::new(open_topic::<T>(node, robot, name)?.relay()?))
}

/// An input whose samples are taken as [`Data`], whatever their type.
pub trait DataInput: Input {
    /// Every acceptable sample pending, oldest first, with its receipt latency, ns.
    fn take_data(&self, each: &mut dyn FnMut(Data, u64)) -> Result<(), IpcError>;
}

impl<T: Wire + Into<Data>> DataInput for Receiver<T> {
    fn take_data(&self, each: &mut dyn FnMut(Data, u64)) -> Result<(), IpcError> {
        self.take(|message, latency| each(message.into(), latency))
    }
}

/// The header of a sample's bytes, if they are long enough to hold one.
pub fn header_of(bytes: &[u8]) -> Option<Header> {
    (bytes.len() >= size_of::<Header>())
        // SAFETY: the length is checked; a header is integers and floats (module docs).
        .then(|| unsafe { std::ptr::read_unaligned(bytes.as_ptr() as *const Header) })
}
