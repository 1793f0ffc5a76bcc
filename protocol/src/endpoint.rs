//! Where a host's agent listens (docs/hosts.md): a Zenoh endpoint `tcp/ADDR:PORT` or
//! `tls/ADDR:PORT`, the names hosts are given, and what a link between hosts carried
//! ([`LinkCounters`], kept by the `hosts` bridges and written by the record).

use std::net::{IpAddr, ToSocketAddrs};

/// The transport of an endpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transport {
    Tcp,
    Tls,
}

/// A parsed endpoint.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoint {
    pub transport: Transport,
    /// An IP address or a host name.
    pub address: String,
    pub port: u16,
}

impl Endpoint {
    /// Parses `tcp/ADDR:PORT` or `tls/ADDR:PORT` (an IPv6 address in brackets).
    pub fn parse(text: &str) -> Result<Endpoint, String> {
        let (transport, rest) = match text.split_once('/') {
            Some(("tcp", rest)) => (Transport::Tcp, rest),
            Some(("tls", rest)) => (Transport::Tls, rest),
            _ => return Err(format!("`{text}` is not tcp/ADDR:PORT or tls/ADDR:PORT")),
        };
        let (address, port) = rest
            .rsplit_once(':')
            .ok_or_else(|| format!("`{text}` has no port"))?;
        let port = port
            .parse::<u16>()
            .map_err(|_| format!("`{text}`: `{port}` is not a port"))?;
        let address = address.trim_start_matches('[').trim_end_matches(']');
        if address.is_empty() {
            return Err(format!("`{text}` has no address"));
        }
        Ok(Endpoint {
            transport,
            address: address.to_string(),
            port,
        })
    }

    /// Whether every address the endpoint names is on this machine's loopback interface
    /// (a name that does not resolve counts as not loopback).
    pub fn is_loopback(&self) -> bool {
        if let Ok(ip) = self.address.parse::<IpAddr>() {
            return ip.is_loopback();
        }
        (self.address.as_str(), self.port)
            .to_socket_addrs()
            .map(|addrs| {
                let addrs: Vec<_> = addrs.collect();
                !addrs.is_empty() && addrs.iter().all(|a| a.ip().is_loopback())
            })
            .unwrap_or(false)
    }

    /// The endpoint as Zenoh writes it.
    pub fn zenoh(&self) -> String {
        let transport = match self.transport {
            Transport::Tcp => "tcp",
            Transport::Tls => "tls",
        };
        if self.address.contains(':') {
            format!("{transport}/[{}]:{}", self.address, self.port)
        } else {
            format!("{transport}/{}:{}", self.address, self.port)
        }
    }
}

/// Whether `name` can name a host: letters, digits, `-` and `_` (it is part of Zenoh keys).
/// The name the orchestrator's host goes by (refused as the name of another host).
pub const ORCHESTRATOR_HOST: &str = "orchestrator";

pub fn is_host_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// What a bridge has carried and refused.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LinkCounters {
    /// Samples sent on the link.
    pub sent: u64,
    /// Samples received and published on this host.
    pub received: u64,
    /// Data samples dropped by `fault.link_loss`.
    pub lost: u64,
    /// Data samples dropped while `fault.link_down_s` cut the link.
    pub down: u64,
    /// Samples received whose tag did not verify (not from a bridge of the run).
    pub refused_tag: u64,
    /// Samples not sent: not from the publisher their producer is pinned to.
    pub refused_origin: u64,
}

impl std::ops::Add for LinkCounters {
    type Output = LinkCounters;
    fn add(self, o: LinkCounters) -> LinkCounters {
        LinkCounters {
            sent: self.sent + o.sent,
            received: self.received + o.received,
            lost: self.lost + o.lost,
            down: self.down + o.down,
            refused_tag: self.refused_tag + o.refused_tag,
            refused_origin: self.refused_origin + o.refused_origin,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_parse_and_know_loopback() {
        let e = Endpoint::parse("tcp/127.0.0.1:7447").unwrap();
        assert_eq!((e.transport, e.port), (Transport::Tcp, 7447));
        assert!(e.is_loopback());
        assert!(Endpoint::parse("tls/[::1]:9000").unwrap().is_loopback());
        assert!(!Endpoint::parse("tcp/10.1.2.3:7447").unwrap().is_loopback());
        assert!(Endpoint::parse("tcp/localhost:7447").unwrap().is_loopback());
        assert_eq!(
            Endpoint::parse("tls/[::1]:9000").unwrap().zenoh(),
            "tls/[::1]:9000"
        );
        for bad in [
            "udp/1.2.3.4:5",
            "tcp/1.2.3.4",
            "tcp/:80",
            "tcp/host:99999",
            "host:1",
        ] {
            assert!(Endpoint::parse(bad).is_err(), "{bad}");
        }
        assert!(is_host_name("compute-1") && !is_host_name("a/b") && !is_host_name(""));
    }
}
