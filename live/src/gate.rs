//! The gate in front of the live view's server: every client's HTTP upgrade request is
//! read here first, and a client without the run's token, or one more than
//! [`MAX_CLIENTS`](crate::MAX_CLIENTS), is answered with an HTTP error and closed before
//! it sees a channel. An admitted connection is handed, request and all, to the server on
//! loopback, and its bytes are copied both ways until either side closes. A connection
//! takes its seat as it is accepted, before its request comes, so connections that say
//! nothing hold at most [`MAX_CLIENTS`](crate::MAX_CLIENTS) sockets, each for at most
//! [`HEAD_TIMEOUT`].

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// The longest request head read (a browser's is well under 2 KiB).
const MAX_HEAD_BYTES: usize = 8192;
/// How long a client may take to send its request.
const HEAD_TIMEOUT: Duration = Duration::from_secs(2);
/// How long the gate waits after failing to accept (out of file descriptors, say).
const ACCEPT_BACKOFF: Duration = Duration::from_millis(50);

/// Why a client is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Refusal {
    #[error("400 Bad Request")]
    BadRequest,
    #[error("401 Unauthorized")]
    NoToken,
    #[error("503 Service Unavailable")]
    Full,
}

impl Refusal {
    /// The whole HTTP response.
    fn response(self) -> String {
        let body = match self {
            Refusal::BadRequest => "not an HTTP request\n",
            Refusal::NoToken => {
                "this live view needs its token: add ?token=... to the URL or send \
                 Authorization: Bearer ...\n"
            }
            Refusal::Full => "too many clients are watching this run\n",
        };
        format!(
            "HTTP/1.1 {self}\r\ncontent-type: text/plain\r\ncontent-length: {}\r\n\
             connection: close\r\n\r\n{body}",
            body.len()
        )
    }
}

/// Accepts clients on `listener` for as long as the run lasts.
pub(crate) async fn serve(listener: TcpListener, server: SocketAddr, token: Option<String>) {
    let token: Arc<Option<String>> = Arc::new(token);
    let clients = Arc::new(AtomicUsize::new(0));
    loop {
        let Ok((mut client, peer)) = listener.accept().await else {
            tokio::time::sleep(ACCEPT_BACKOFF).await;
            continue;
        };
        let (token, clients) = (token.clone(), clients.clone());
        tokio::spawn(async move {
            let Some(_seat) = Seat::take(&clients) else {
                let _ = client.write_all(Refusal::Full.response().as_bytes()).await;
                return;
            };
            if let Err(e) = connection(client, server, &token).await {
                tracing::debug!("live view: client {peer}: {e}");
            }
        });
    }
}

/// A client counted while it is connected.
struct Seat<'a>(&'a AtomicUsize);

impl<'a> Seat<'a> {
    fn take(clients: &'a AtomicUsize) -> Option<Seat<'a>> {
        let taken = clients.fetch_add(1, Ordering::AcqRel);
        let seat = Seat(clients);
        (taken < crate::MAX_CLIENTS).then_some(seat)
    }
}

impl Drop for Seat<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// A client with a seat: its request read and judged, and if admitted, its connection
/// handed to the server.
async fn connection(
    mut client: TcpStream,
    server: SocketAddr,
    token: &Option<String>,
) -> std::io::Result<()> {
    let head = match tokio::time::timeout(HEAD_TIMEOUT, read_head(&mut client)).await {
        Ok(head) => head?,
        Err(_) => return Ok(()),
    };
    if let Err(refusal) = admit(&head, token.as_deref()) {
        client.write_all(refusal.response().as_bytes()).await?;
        return client.shutdown().await;
    }
    let mut upstream = TcpStream::connect(server).await?;
    upstream.set_nodelay(true)?;
    client.set_nodelay(true)?;
    upstream.write_all(&head).await?;
    tokio::io::copy_bidirectional(&mut client, &mut upstream).await?;
    Ok(())
}

/// Reads up to the end of the request head (and whatever came with it).
async fn read_head(client: &mut TcpStream) -> std::io::Result<Vec<u8>> {
    let mut head = Vec::with_capacity(1024);
    let mut buffer = [0u8; 1024];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = client.read(&mut buffer).await?;
        if n == 0 || head.len() + n > MAX_HEAD_BYTES {
            return Err(std::io::Error::other("no whole request head"));
        }
        head.extend_from_slice(&buffer[..n]);
    }
    Ok(head)
}

/// Whether a request head may pass: an HTTP request, with `token` (when the run has one)
/// as the `token` parameter of its URL or as `Authorization: Bearer`.
pub(crate) fn admit(head: &[u8], token: Option<&str>) -> Result<(), Refusal> {
    let text = std::str::from_utf8(head).map_err(|_| Refusal::BadRequest)?;
    let mut lines = text.split("\r\n");
    let request = lines.next().unwrap_or_default();
    let mut parts = request.split(' ');
    let (Some(_method), Some(target), Some(version)) = (parts.next(), parts.next(), parts.next())
    else {
        return Err(Refusal::BadRequest);
    };
    if !version.starts_with("HTTP/") {
        return Err(Refusal::BadRequest);
    }
    let Some(token) = token else {
        return Ok(());
    };
    let in_url = (target.split_once('?').map(|(_, query)| query))
        .into_iter()
        .flat_map(|query| query.split('&'))
        .filter_map(|pair| pair.strip_prefix("token="));
    let in_header = lines
        .take_while(|line| !line.is_empty())
        .filter_map(|line| line.split_once(':'))
        .filter(|(name, _)| name.trim().eq_ignore_ascii_case("authorization"))
        .filter_map(|(_, value)| {
            let (scheme, credentials) = value.trim().split_once(' ')?;
            scheme.eq_ignore_ascii_case("bearer").then_some(credentials)
        });
    let mut given = in_url.chain(in_header);
    if given.any(|g| same(g.trim().as_bytes(), token.as_bytes())) {
        Ok(())
    } else {
        Err(Refusal::NoToken)
    }
}

/// Whether `a` and `b` are equal, in a time that does not tell how much of them is.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOKEN: &str = "0123456789abcdef";

    fn head(target: &str, headers: &str) -> Vec<u8> {
        format!("GET {target} HTTP/1.1\r\nhost: robot\r\n{headers}\r\n").into_bytes()
    }

    #[test]
    fn a_request_with_the_token_in_its_url_or_header_is_admitted_and_any_other_refused() {
        assert_eq!(admit(&head("/", ""), None), Ok(()));
        assert_eq!(
            admit(&head(&format!("/?token={TOKEN}"), ""), Some(TOKEN)),
            Ok(())
        );
        assert_eq!(
            admit(&head(&format!("/?a=1&token={TOKEN}"), ""), Some(TOKEN)),
            Ok(())
        );
        let bearer = format!("Authorization: Bearer {TOKEN}\r\n");
        assert_eq!(admit(&head("/", &bearer), Some(TOKEN)), Ok(()));
        let lower = format!("authorization: bearer {TOKEN}\r\n");
        assert_eq!(admit(&head("/", &lower), Some(TOKEN)), Ok(()));
        assert_eq!(admit(&head("/", ""), Some(TOKEN)), Err(Refusal::NoToken));
        assert_eq!(
            admit(&head("/?token=0123456789abcdeF", ""), Some(TOKEN)),
            Err(Refusal::NoToken)
        );
        assert_eq!(
            admit(&head(&format!("/?token={TOKEN}x"), ""), Some(TOKEN)),
            Err(Refusal::NoToken)
        );
        assert_eq!(
            admit(b"\x16\x03\x01 hello", Some(TOKEN)),
            Err(Refusal::BadRequest)
        );
        assert_eq!(admit(b"GET /\r\n\r\n", None), Err(Refusal::BadRequest));
    }

    #[test]
    fn a_seat_is_taken_by_at_most_max_clients_at_once_and_freed_when_dropped() {
        let clients = AtomicUsize::new(0);
        let seats: Vec<Seat> = (0..crate::MAX_CLIENTS)
            .map(|_| Seat::take(&clients).expect("a free seat"))
            .collect();
        assert!(Seat::take(&clients).is_none());
        drop(seats);
        assert_eq!(clients.load(Ordering::Acquire), 0);
        assert!(Seat::take(&clients).is_some());
    }

    #[test]
    fn a_refusal_is_a_whole_http_response_naming_its_status() {
        let response = Refusal::NoToken.response();
        assert!(response.starts_with("HTTP/1.1 401 Unauthorized\r\n"));
        let (headers, body) = response.split_once("\r\n\r\n").unwrap();
        assert!(headers.contains(&format!("content-length: {}", body.len())));
    }
}
