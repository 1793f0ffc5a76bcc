//! A client of Foxglove's WebSocket protocol, for the live view's bench and tests, written
//! from the protocol's public specification (github.com/foxglove/ws-protocol, docs/spec.md,
//! version 1), not from the server's code:
//! JSON text messages (`serverInfo`, `advertise`, `status`, `subscribe`), binary message
//! data (opcode 1: subscription id u32, timestamp u64 ns, payload; little-endian) and time
//! (opcode 2). The Foxglove SDK's server names the same protocol `foxglove.sdk.v1`; the
//! client offers both names.

use std::collections::HashMap;
use std::io::ErrorKind;
use std::net::TcpStream;
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// What the server sent.
#[derive(Debug, Clone)]
pub enum Frame {
    /// A message of a channel this client subscribed to.
    Data {
        topic: String,
        timestamp_ns: u64,
        payload: Vec<u8>,
    },
    /// The server's clock.
    Time(u64),
    /// Any JSON message (`serverInfo`, `advertise`, `status`, ...).
    Json(serde_json::Value),
}

pub struct Client {
    socket: WebSocket<MaybeTlsStream<TcpStream>>,
    /// Channel id to topic, as advertised.
    pub channels: HashMap<u64, String>,
    /// Subscription id to topic.
    subscriptions: HashMap<u32, String>,
    next_subscription: u32,
    /// Subscribe to every channel as it is advertised.
    subscribe_all: bool,
}

impl Client {
    /// Connects to `url` and reads up to the first advertisement of channels.
    pub fn connect(url: &str, subscribe_all: bool) -> Result<Client, tungstenite::Error> {
        let mut request = url.into_client_request()?;
        request.headers_mut().insert(
            "sec-websocket-protocol",
            tungstenite::http::HeaderValue::from_static("foxglove.sdk.v1, foxglove.websocket.v1"),
        );
        let (socket, _response) = tungstenite::connect(request)?;
        if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
            stream.set_nodelay(true)?;
        }
        let mut client = Client {
            socket,
            channels: HashMap::new(),
            subscriptions: HashMap::new(),
            next_subscription: 0,
            subscribe_all,
        };
        client.set_timeout(Some(Duration::from_secs(10)));
        while client.channels.is_empty() {
            client.read()?;
        }
        Ok(client)
    }

    pub fn set_timeout(&mut self, timeout: Option<Duration>) {
        if let MaybeTlsStream::Plain(stream) = self.socket.get_ref() {
            let _ = stream.set_read_timeout(timeout);
        }
    }

    /// Subscribes to `channels` (ids).
    pub fn subscribe(&mut self, channels: &[u64]) -> Result<(), tungstenite::Error> {
        let mut subscriptions = Vec::new();
        for id in channels {
            let subscription = self.next_subscription;
            self.next_subscription += 1;
            let topic = self.channels.get(id).cloned().unwrap_or_default();
            self.subscriptions.insert(subscription, topic);
            subscriptions.push(serde_json::json!({ "id": subscription, "channelId": id }));
        }
        let text = serde_json::json!({ "op": "subscribe", "subscriptions": subscriptions });
        self.socket.send(Message::text(text.to_string()))
    }

    /// The next frame (subscribing to the channels an advertisement brings, if asked to).
    pub fn read(&mut self) -> Result<Frame, tungstenite::Error> {
        loop {
            let frame = match self.socket.read()? {
                Message::Text(text) => {
                    let json: serde_json::Value = serde_json::from_str(text.as_str())
                        .map_err(|e| tungstenite::Error::Io(std::io::Error::other(e)))?;
                    if json["op"] == "advertise" {
                        let mut new = Vec::new();
                        for channel in json["channels"].as_array().into_iter().flatten() {
                            if let (Some(id), Some(topic)) =
                                (channel["id"].as_u64(), channel["topic"].as_str())
                            {
                                self.channels.insert(id, topic.to_string());
                                new.push(id);
                            }
                        }
                        if self.subscribe_all {
                            self.subscribe(&new)?;
                        }
                    }
                    Frame::Json(json)
                }
                Message::Binary(bytes) => match bytes.first() {
                    Some(1) if bytes.len() >= 13 => {
                        let subscription = u32::from_le_bytes(bytes[1..5].try_into().unwrap());
                        let timestamp_ns = u64::from_le_bytes(bytes[5..13].try_into().unwrap());
                        let Some(topic) = self.subscriptions.get(&subscription) else {
                            continue;
                        };
                        Frame::Data {
                            topic: topic.clone(),
                            timestamp_ns,
                            payload: bytes[13..].to_vec(),
                        }
                    }
                    Some(2) if bytes.len() >= 9 => {
                        Frame::Time(u64::from_le_bytes(bytes[1..9].try_into().unwrap()))
                    }
                    _ => continue,
                },
                _ => continue,
            };
            return Ok(frame);
        }
    }

    /// Whether a channel on `topic` is advertised within `timeout` (one already is, or
    /// one comes in the frames read meanwhile: a server advertises its channels as they
    /// are made, not all in its first advertisement).
    pub fn advertised(&mut self, topic: &str, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        while !self.channels.values().any(|t| t == topic) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            self.set_timeout(Some(left.max(Duration::from_millis(1))));
            if self.read().is_err() {
                return false;
            }
        }
        true
    }

    /// The first message on `topic` within `timeout`.
    pub fn first_on(&mut self, topic: &str, timeout: Duration) -> Option<Frame> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            self.set_timeout(Some(
                deadline
                    .saturating_duration_since(Instant::now())
                    .max(Duration::from_millis(1)),
            ));
            match self.read() {
                Ok(frame @ Frame::Data { .. }) if matches!(&frame, Frame::Data { topic: t, .. } if t == topic) =>
                {
                    return Some(frame);
                }
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) =>
                {
                    return None;
                }
                Err(_) => return None,
            }
        }
        None
    }

    /// Advertises a channel of this client's on `topic` (JSON), as Foxglove's publish panel
    /// does; returns its id.
    pub fn advertise(&mut self, topic: &str, schema_name: &str) -> Result<u32, tungstenite::Error> {
        let id = self.next_subscription + 1000;
        self.next_subscription += 1;
        let text = serde_json::json!({
            "op": "advertise",
            "channels": [{ "id": id, "topic": topic, "encoding": "json", "schemaName": schema_name }],
        });
        self.socket.send(Message::text(text.to_string()))?;
        Ok(id)
    }

    /// Publishes `message` on this client's channel `id` (binary opcode 1).
    pub fn publish(
        &mut self,
        id: u32,
        message: &serde_json::Value,
    ) -> Result<(), tungstenite::Error> {
        let mut frame = vec![1];
        frame.extend_from_slice(&id.to_le_bytes());
        frame.extend_from_slice(message.to_string().as_bytes());
        self.socket.send(Message::binary(frame))
    }

    /// The next status message within `timeout`: its level (0 info, 1 warning, 2 error) and
    /// text.
    pub fn status(&mut self, timeout: Duration) -> Option<(u64, String)> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            let left = deadline.saturating_duration_since(Instant::now());
            self.set_timeout(Some(left.max(Duration::from_millis(1))));
            match self.read() {
                Ok(Frame::Json(json)) if json["op"] == "status" => {
                    let level = json["level"].as_u64().unwrap_or(0);
                    return Some((level, json["message"].as_str().unwrap_or("").to_string()));
                }
                Ok(_) => {}
                Err(_) => return None,
            }
        }
        None
    }

    /// Sends raw frames the protocol does not know.
    pub fn send(&mut self, message: Message) -> Result<(), tungstenite::Error> {
        self.socket.send(message)
    }
}
