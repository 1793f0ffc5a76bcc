//! The live view (docs/foxglove.md, "Live"): `scmpc run --live` serves the run over
//! Foxglove's WebSocket protocol while it drives, as one more sink of the run
//! ([`open`]).
//!
//! The channels and their messages are `run.mcap`'s, made by the same encoder
//! ([`record::Encoded`]) on a thread of its own, which hands each message to Foxglove's
//! server ([`foxglove::WebSocketServer`], the SDK's). Nothing here runs in the control
//! tier or can block the orchestrator: the recorder hands the encoder a copy per message
//! and goes on, dropping them while [`QUEUED_BATCHES`] batches wait; a client's queue
//! holds [`CLIENT_BACKLOG`] messages and drops its oldest for a client that reads too
//! slowly; the server's threads run at the normal policy.
//!
//! Clients reach the server through a gate ([`gate`]): it refuses a client without the
//! run's token (`live.token`) and the client after [`MAX_CLIENTS`] before it sees a
//! channel, and hands every other connection to the server, which listens on loopback
//! only. A client that subscribes late gets each channel's newest message at once
//! ([`Latch`]): the obstacles, logged once at time 0, and the newest scene. A client may
//! send the robot a goal ([`goals`]).

mod gate;
mod goals;

use foxglove::websocket::{Capability, ChannelView, Client, ClientChannel, ServerListener};
use foxglove::{
    ChannelBuilder, ChannelId, Context, PartialMetadata, RawChannel, Schema, WebSocketServer,
    WebSocketServerHandle,
};
use protocol::LiveConfig;
use record::{Channels, Encoded, RunStart, Sink};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

/// Messages a client's queue holds; a client that reads slower than the run publishes
/// loses the oldest. About a fifth of a second of the paper scenario's messages.
pub const CLIENT_BACKLOG: usize = 256;
/// Batches of messages (64 each) waiting for the live view's encoder; the recorder drops
/// the next while they are all waiting.
const QUEUED_BATCHES: usize = 16;
/// Clients connected at once; the gate refuses the next (HTTP 503).
pub const MAX_CLIENTS: usize = 16;
/// How long the end of a run waits for the clients to be closed.
const CLOSE_WAIT: std::time::Duration = std::time::Duration::from_secs(1);
/// The topic whose messages set a run's view's clock (Foxglove's `time`); in a fleet's
/// view every robot's (`/robot1/robot/truth`).
const CLOCK_TOPIC: &str = "/robot/truth";

/// The sink's opener (`run::sinks`): the live view of a scenario with `[live]`.
pub fn open(run: &RunStart) -> std::io::Result<Option<Box<dyn Sink>>> {
    let Some(config) = &run.scenario.live else {
        return Ok(None);
    };
    let desk = goals::GoalDesk::new(run.scenario, run.goals.clone());
    let channels = LiveChannels::serve(config, desk)?;
    announce(config, channels.address);
    Ok(Some(Box::new(Encoded::start_lossy(
        "live view",
        channels,
        run.scenario,
        QUEUED_BATCHES,
    )?)))
}

/// Tells the user where the view is.
fn announce(config: &LiveConfig, address: std::net::SocketAddr) {
    println!(
        "live view: ws://{address} (Foxglove: Open connection, Foxglove WebSocket{})",
        if config.token.is_empty() {
            ""
        } else {
            ", with ?token=… in the URL"
        }
    );
}

/// A fleet's live view (docs/fleet.md, "A live view"): one server for every robot's
/// record, each robot's channels under its id as in the fleet's `run.mcap`
/// ([`record::mcap::fleet_topic`]: `/robot1/mpc/plan`), the view's clock the newest time
/// of any robot's truth (so it goes on after robot 0's record ends).
/// Each robot's record has a sink of its own ([`FleetView::sink`], an encoder on a thread
/// of its own, as a run's live view has) that ends with the robot's record; the server
/// serves until the fleet's run ends ([`FleetView::finish`]). With `live.accept_goals` a
/// client sends robot `i` a goal on `/robot<i>/goal` while its record runs.
pub struct FleetView {
    channels: Arc<Mutex<LiveChannels>>,
    goals: goals::GoalDesk,
    config: LiveConfig,
    /// Where clients connect.
    address: std::net::SocketAddr,
}

impl FleetView {
    /// The view of a fleet of scenario `fleet`, serving from now on ([`FleetView::announce`]
    /// says where); `None` without `[live]`.
    pub fn serve(fleet: &protocol::Scenario) -> std::io::Result<Option<FleetView>> {
        let Some(config) = &fleet.live else {
            return Ok(None);
        };
        let desk = goals::GoalDesk::fleet(fleet);
        let channels = LiveChannels::serve(config, desk.clone())?;
        Ok(Some(FleetView {
            address: channels.address,
            channels: Arc::new(Mutex::new(channels)),
            goals: desk,
            config: config.clone(),
        }))
    }

    /// Tells the user where the view is, once every robot's record has joined it (so a
    /// goal sent at once finds its robot).
    pub fn announce(&self) {
        announce(&self.config, self.address);
    }

    /// The sink of robot `robot`'s record, whose scenario is `member` and which takes
    /// the goals sent to it on `goals` ([`record::Recorder::goal_inbox`]).
    pub fn sink(
        &self,
        robot: usize,
        member: &protocol::Scenario,
        goals: record::goals::GoalInbox,
    ) -> std::io::Result<Box<dyn Sink>> {
        let goal_topic = record::mcap::fleet_topic(robot, goals::GOAL_TOPIC);
        self.goals.join(&goal_topic, member, goals);
        let channels = RobotChannels {
            robot,
            topics: HashMap::new(),
            view: self.channels.clone(),
        };
        let encoded = Encoded::start_lossy("live view", channels, member, QUEUED_BATCHES)?;
        Ok(Box::new(encoded))
    }

    /// Closes the clients' connections and stops the server, once every robot's sink has
    /// ended (a sink still open keeps the server until it ends).
    pub fn finish(self) -> std::io::Result<()> {
        match Arc::try_unwrap(self.channels) {
            Ok(channels) => channels
                .into_inner()
                .unwrap_or_else(PoisonError::into_inner)
                .finish(),
            Err(_) => Ok(()),
        }
    }
}

/// One robot's channels on a fleet's server.
struct RobotChannels {
    robot: usize,
    /// Each of the robot's topics, and the topic under its id it is served on.
    topics: HashMap<String, String>,
    view: Arc<Mutex<LiveChannels>>,
}

impl RobotChannels {
    fn view(&self) -> std::sync::MutexGuard<'_, LiveChannels> {
        self.view.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Channels for RobotChannels {
    fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema: &[u8],
    ) -> std::io::Result<()> {
        let served = record::mcap::fleet_topic(self.robot, topic);
        self.view().add_channel(&served, schema_name, schema)?;
        self.topics.insert(topic.to_string(), served);
        Ok(())
    }

    fn message(&mut self, topic: &str, time_ns: u64, json: &[u8]) -> std::io::Result<()> {
        let served = (self.topics.get(topic)).ok_or_else(|| {
            std::io::Error::other(format!(
                "live view: a message on robot {}'s {topic}, which has no channel",
                self.robot
            ))
        })?;
        self.view().message(served, time_ns, json)
    }

    /// The robot's record is over; the server serves the others on.
    fn finish(self) -> std::io::Result<()> {
        Ok(())
    }
}

/// What the server calls back: the latch, and the goal desk.
struct Listener {
    latch: Arc<Latch>,
    goals: goals::GoalDesk,
}

/// The newest message of each channel, for a client that subscribes later.
#[derive(Default)]
struct Latch(Mutex<HashMap<ChannelId, Latched>>);

struct Latched {
    channel: Arc<RawChannel>,
    json: Vec<u8>,
    time_ns: u64,
}

impl Latch {
    fn keep(&self, channel: &Arc<RawChannel>, time_ns: u64, json: &[u8]) {
        let mut latched = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let newest = latched.entry(channel.id()).or_insert_with(|| Latched {
            channel: channel.clone(),
            json: Vec::new(),
            time_ns,
        });
        newest.json.clear();
        newest.json.extend_from_slice(json);
        newest.time_ns = time_ns;
    }
}

impl ServerListener for Listener {
    /// A client subscribing gets the channel's newest message at once (the server has
    /// registered the subscription before it calls this).
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        let latched = (self.latch.0.lock()).unwrap_or_else(PoisonError::into_inner);
        if let (Some(newest), Some(sink)) = (latched.get(&channel.id()), client.sink_id()) {
            newest.channel.log_with_meta_to_sink(
                &newest.json,
                PartialMetadata {
                    log_time: Some(newest.time_ns),
                },
                Some(sink),
            );
        }
    }

    fn on_client_advertise(&self, client: Client, channel: &ClientChannel) {
        self.goals.advertised(&client, channel);
    }

    fn on_message_data(&self, client: Client, channel: &ClientChannel, payload: &[u8]) {
        self.goals.published(&client, channel, payload);
    }
}

/// The run's channels on Foxglove's server, behind the gate.
struct LiveChannels {
    /// Where clients connect (the gate's address).
    address: std::net::SocketAddr,
    runtime: tokio::runtime::Runtime,
    context: Arc<Context>,
    server: WebSocketServerHandle,
    channels: HashMap<String, Arc<RawChannel>>,
    latch: Arc<Latch>,
    /// The view's clock (Foxglove's `time`), ns: the newest time of a truth so far.
    clock_ns: Option<u64>,
}

impl LiveChannels {
    /// Starts the server on loopback and the gate on `config.address`.
    fn serve(config: &LiveConfig, goals: goals::GoalDesk) -> std::io::Result<LiveChannels> {
        let named = |e: String| std::io::Error::other(format!("live view: {e}"));
        let address = config.socket_address().map_err(named)?;
        // The server's threads run at the normal policy: they start before the
        // orchestrator's real-time tier is put in force, on its thread only.
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("live view")
            .enable_io()
            .enable_time()
            .build()?;
        let context = Context::new();
        let latch = Arc::new(Latch::default());
        let server = WebSocketServer::new()
            .name("scmpc")
            .context(&context)
            .bind("127.0.0.1", 0)
            .capabilities([Capability::Time, Capability::ClientPublish])
            .supported_encodings(["json"])
            .message_backlog_size(CLIENT_BACKLOG)
            .listener(Arc::new(Listener {
                latch: latch.clone(),
                goals,
            }))
            .tokio_runtime(runtime.handle())
            .start_blocking()
            .map_err(|e| named(e.to_string()))?;
        let inner = std::net::SocketAddr::from(([127, 0, 0, 1], server.port()));
        let token = (!config.token.is_empty()).then(|| config.token.clone());
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(address))
            .map_err(|e| named(format!("{address}: {e}")))?;
        let address = listener.local_addr()?;
        runtime.spawn(gate::serve(listener, inner, token));
        Ok(LiveChannels {
            address,
            runtime,
            context,
            server,
            channels: HashMap::new(),
            latch,
            clock_ns: None,
        })
    }
}

impl Channels for LiveChannels {
    fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema: &[u8],
    ) -> std::io::Result<()> {
        let channel = ChannelBuilder::new(topic)
            .context(&self.context)
            .message_encoding("json")
            .schema(Schema::new(schema_name, "jsonschema", schema.to_vec()))
            .build_raw()
            .map_err(|e| std::io::Error::other(format!("live view: {topic}: {e}")))?;
        self.channels.insert(topic.to_string(), channel);
        Ok(())
    }

    fn message(&mut self, topic: &str, time_ns: u64, json: &[u8]) -> std::io::Result<()> {
        let channel = (self.channels.get(topic)).ok_or_else(|| {
            std::io::Error::other(format!(
                "live view: a message on {topic}, which has no channel"
            ))
        })?;
        channel.log_with_meta(
            json,
            PartialMetadata {
                log_time: Some(time_ns),
            },
        );
        self.latch.keep(channel, time_ns, json);
        if let Some(now_ns) = clock_advance(self.clock_ns, topic, time_ns) {
            self.clock_ns = Some(now_ns);
            self.server.broadcast_time(now_ns);
        }
        Ok(())
    }

    /// Closes every client's connection and stops the server; a client that does not
    /// read its close is cut off after [`CLOSE_WAIT`].
    fn finish(self) -> std::io::Result<()> {
        let stopped = self.server.stop();
        let closed = async { tokio::time::timeout(CLOSE_WAIT, stopped.wait()).await };
        let _ = self.runtime.block_on(closed);
        self.runtime.shutdown_timeout(CLOSE_WAIT);
        Ok(())
    }
}

/// The view's clock after a message on `topic` at `time_ns`, if it moves it on: a truth's
/// time (a run's `/robot/truth`, a fleet robot's `/robot<id>/robot/truth`) later than the
/// clock's. A fleet's robots are stepped one after the other, and their records end at
/// different times: the clock follows whichever is furthest on, and never goes back.
fn clock_advance(clock_ns: Option<u64>, topic: &str, time_ns: u64) -> Option<u64> {
    let truth = topic.ends_with(CLOCK_TOPIC);
    (truth && clock_ns.is_none_or(|now_ns| time_ns > now_ns)).then_some(time_ns)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clock_follows_the_furthest_truth_of_any_robot_and_never_goes_back() {
        let fleet = |robot| record::mcap::fleet_topic(robot, CLOCK_TOPIC);
        assert_eq!(clock_advance(None, CLOCK_TOPIC, 0), Some(0));
        assert_eq!(clock_advance(None, "/mpc/plan", 7), None);
        assert_eq!(clock_advance(Some(5), &fleet(0), 10), Some(10));
        // Robot 1 at a time robot 0 has passed, then on after robot 0's record ended.
        assert_eq!(clock_advance(Some(10), &fleet(1), 10), None);
        assert_eq!(clock_advance(Some(10), &fleet(1), 5), None);
        assert_eq!(clock_advance(Some(10), &fleet(1), 60), Some(60));
        assert_eq!(
            clock_advance(Some(10), &fleet(1).replace("truth", "estimate"), 60),
            None
        );
    }
}
