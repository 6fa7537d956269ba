//! The live view's front door: a thin layer before the `foxglove` crate's WebSocket server that
//! accepts the Foxglove WebSocket protocol under both of its names.
//!
//! The protocol's first name is `foxglove.websocket.v1` (Foxglove Studio, Lichtblick and the
//! `@foxglove/ws-protocol` clients offer only that); Foxglove's SDK servers, the `foxglove` crate
//! among them, negotiate the same v1 messages under `foxglove.sdk.v1` (and `foxglove.sdk.v1.1`,
//! whose channel advertisements reference a schema table) and answer any other name with HTTP
//! 400. Foxglove says the two v1 names are one protocol: the SDK renamed it, nothing on the wire
//! changed (the Lichtblick and Flora apps added the new name beside the old one on that basis).
//!
//! So the crate's server listens on a loopback port of its own, and this layer listens where
//! `live_view.bind` says. For each connection it reads the HTTP upgrade request and looks at the
//! subprotocols offered:
//!
//! - `foxglove.sdk.v1.1` or `foxglove.sdk.v1` among them: the request goes on unchanged, and the
//!   server picks the newest (v1.1 before v1);
//! - only `foxglove.websocket.v1`: the request goes on offering `foxglove.sdk.v1` instead, and the
//!   server's answer is given back naming `foxglove.websocket.v1`, the name the client offered;
//! - none of them: HTTP 400 naming the accepted subprotocols, and nothing reaches the server.
//!
//! Why that is safe: only the one header of the handshake is rewritten, and only between two
//! names of one protocol; from the server's `101 Switching Protocols` on, the bytes are copied
//! both ways unchanged, so the server's own limits, backlog and message framing apply as before.
//! A request head longer than [`MAX_HEAD_BYTES`] or slower than [`HEAD_TIMEOUT`] is refused.

use std::net::SocketAddr;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tracing::{debug, warn};

/// The name Foxglove's first clients (Studio, Lichtblick) offer.
pub const LEGACY_SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// The names the `foxglove` crate's server negotiates, newest first.
pub const SDK_SUBPROTOCOLS: [&str; 2] = ["foxglove.sdk.v1.1", "foxglove.sdk.v1"];
/// What the legacy name is offered to the server as: the SDK's name of the same v1.
const SDK_V1: &str = SDK_SUBPROTOCOLS[1];

/// The longest HTTP request or response head taken.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// How long a client may take to send its request head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);

/// What the layer does with one upgrade request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decision {
    /// Forward as it is (an SDK name was offered).
    Forward,
    /// Forward offering `foxglove.sdk.v1`, answer with the legacy name.
    Rename,
    /// Refuse with 400: none of the accepted names was offered (what was, for the log).
    Refuse(String),
}

/// The value of `line` when it is a `Sec-WebSocket-Protocol` header (names are case-insensitive).
fn protocol_header(line: &str) -> Option<&str> {
    line.split_once(':').filter(|(name, _)| name.trim().eq_ignore_ascii_case("sec-websocket-protocol")).map(|(_, v)| v)
}

/// The subprotocols a request head offers (every `Sec-WebSocket-Protocol` header, comma lists).
fn offered(head: &str) -> Vec<String> {
    head.split("\r\n")
        .skip(1)
        .filter_map(protocol_header)
        .flat_map(|value| value.split(',').map(|v| v.trim().to_owned()))
        .filter(|v| !v.is_empty())
        .collect()
}

/// What to do with a request whose head is `head`.
pub fn decide(head: &str) -> Decision {
    let offered = offered(head);
    if offered.iter().any(|o| SDK_SUBPROTOCOLS.contains(&o.as_str())) {
        Decision::Forward
    } else if offered.iter().any(|o| o == LEGACY_SUBPROTOCOL) {
        Decision::Rename
    } else if offered.is_empty() {
        Decision::Refuse("no Sec-WebSocket-Protocol header".to_owned())
    } else {
        Decision::Refuse(offered.join(", "))
    }
}

/// `head` with every `Sec-WebSocket-Protocol` header replaced by one offering `value`.
fn with_subprotocol(head: &str, value: &str) -> String {
    let mut out = String::with_capacity(head.len());
    let mut replaced = false;
    for (i, line) in head.split("\r\n").enumerate() {
        if i > 0 && protocol_header(line).is_some() {
            if !replaced {
                out.push_str("Sec-WebSocket-Protocol: ");
                out.push_str(value);
                out.push_str("\r\n");
                replaced = true;
            }
            continue;
        }
        out.push_str(line);
        out.push_str("\r\n");
    }
    // `split` gave one empty piece after each of the head's closing CRLFs; keep exactly one blank line.
    while out.ends_with("\r\n\r\n\r\n") {
        out.truncate(out.len() - 2);
    }
    out
}

/// The answer to a request offering none of the accepted subprotocols.
pub fn refusal() -> String {
    let body = format!(
        "The op3dsg live view speaks the Foxglove WebSocket protocol: offer one of the subprotocols {}, {} or {} \
         in Sec-WebSocket-Protocol (Foxglove, Lichtblick: open a Foxglove WebSocket connection to this address).\n",
        SDK_SUBPROTOCOLS[0], SDK_SUBPROTOCOLS[1], LEGACY_SUBPROTOCOL
    );
    format!(
        "HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
}

/// Reads up to the end of an HTTP head (the blank line); returns the head as text and any bytes
/// read after it.
async fn read_head<R: AsyncRead + Unpin>(stream: &mut R) -> Result<(String, Vec<u8>), String> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    loop {
        if let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            let rest = buf.split_off(end + 4);
            let head = String::from_utf8(buf).map_err(|_| "the HTTP head is not UTF-8".to_owned())?;
            return Ok((head, rest));
        }
        if buf.len() > MAX_HEAD_BYTES {
            return Err(format!("the HTTP head is longer than {MAX_HEAD_BYTES} bytes"));
        }
        let n = stream.read(&mut chunk).await.map_err(|e| e.to_string())?;
        if n == 0 {
            return Err("the connection closed inside the HTTP head".to_owned());
        }
        buf.extend_from_slice(&chunk[..n]);
    }
}

/// Serves one client: the handshake through the layer, then bytes both ways.
async fn serve(mut client: TcpStream, peer: SocketAddr, server: SocketAddr) {
    let (head, rest) = match tokio::time::timeout(HEAD_TIMEOUT, read_head(&mut client)).await {
        Ok(Ok(read)) => read,
        Ok(Err(e)) => {
            debug!(%peer, error = %e, "live view: no upgrade request");
            return;
        }
        Err(_) => {
            debug!(%peer, "live view: no upgrade request within {} s", HEAD_TIMEOUT.as_secs());
            return;
        }
    };
    let decision = decide(&head);
    let head = match &decision {
        Decision::Forward => head,
        Decision::Rename => with_subprotocol(&head, SDK_V1),
        Decision::Refuse(offered) => {
            warn!(%peer, offered = %offered, "live view: refused a client offering no Foxglove WebSocket subprotocol");
            let _ = client.write_all(refusal().as_bytes()).await;
            let _ = client.shutdown().await;
            return;
        }
    };
    let mut upstream = match TcpStream::connect(server).await {
        Ok(stream) => stream,
        Err(e) => {
            warn!(%peer, error = %e, "live view: the WebSocket server does not answer");
            return;
        }
    };
    let _ = upstream.set_nodelay(true);
    let _ = client.set_nodelay(true);
    if upstream.write_all(head.as_bytes()).await.is_err() || upstream.write_all(&rest).await.is_err() {
        return;
    }
    let (answer, rest) = match read_head(&mut upstream).await {
        Ok(read) => read,
        Err(e) => {
            debug!(%peer, error = %e, "live view: the server's answer");
            return;
        }
    };
    // The server's answer names the subprotocol it picked; after a rename, the client's name.
    let answer = if decision == Decision::Rename { with_subprotocol(&answer, LEGACY_SUBPROTOCOL) } else { answer };
    if client.write_all(answer.as_bytes()).await.is_err() || client.write_all(&rest).await.is_err() {
        return;
    }
    let _ = tokio::io::copy_bidirectional(&mut client, &mut upstream).await;
}

/// Accepts clients on `listener` and passes each through the layer to the server at `server`
/// (the crate's loopback port), until the runtime stops.
pub async fn accept(listener: TcpListener, server: SocketAddr) {
    loop {
        match listener.accept().await {
            Ok((client, peer)) => {
                tokio::spawn(serve(client, peer, server));
            }
            Err(e) => {
                warn!(error = %e, "live view: accepting a connection failed");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(protocols: &[&str]) -> String {
        let mut head =
            "GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n".to_owned();
        if !protocols.is_empty() {
            head.push_str(&format!("Sec-WebSocket-Protocol: {}\r\n", protocols.join(", ")));
        }
        head.push_str("Sec-WebSocket-Version: 13\r\n\r\n");
        head
    }

    #[test]
    fn each_name_of_the_protocol_is_taken_and_any_other_refused() {
        assert_eq!(decide(&request(&["foxglove.sdk.v1"])), Decision::Forward);
        assert_eq!(decide(&request(&["foxglove.sdk.v1.1"])), Decision::Forward);
        assert_eq!(decide(&request(&["foxglove.websocket.v1", "foxglove.sdk.v1"])), Decision::Forward);
        assert_eq!(decide(&request(&["foxglove.websocket.v1"])), Decision::Rename);
        assert_eq!(decide(&request(&["chat", "superchat"])), Decision::Refuse("chat, superchat".to_owned()));
        assert!(matches!(decide(&request(&[])), Decision::Refuse(_)));
        // Header names are case-insensitive; a prefix of a name is not the name.
        let lower = request(&["foxglove.websocket.v1"]).replace("Sec-WebSocket-Protocol", "sec-websocket-protocol");
        assert_eq!(decide(&lower), Decision::Rename);
        assert!(matches!(decide(&request(&["foxglove.sdk"])), Decision::Refuse(_)));
    }

    #[test]
    fn the_rename_touches_only_the_subprotocol_header() {
        let head = request(&["foxglove.websocket.v1"]);
        let renamed = with_subprotocol(&head, SDK_V1);
        assert_eq!(renamed, head.replace("foxglove.websocket.v1", "foxglove.sdk.v1"));
        assert!(renamed.ends_with("Sec-WebSocket-Version: 13\r\n\r\n"), "{renamed:?}");
        let answer =
            "HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\nUpgrade: websocket\r\n\r\n";
        assert_eq!(
            with_subprotocol(answer, LEGACY_SUBPROTOCOL),
            "HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\nUpgrade: websocket\r\n\r\n"
        );
        assert!(refusal().starts_with("HTTP/1.1 400 Bad Request\r\n"));
        assert!(refusal().contains("foxglove.sdk.v1.1, foxglove.sdk.v1 or foxglove.websocket.v1"));
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_head_is_read_to_its_blank_line_and_what_follows_is_kept() {
        let (mut a, mut b) = tokio::io::duplex(64);
        tokio::spawn(async move { a.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\nextra").await });
        let (head, rest) = read_head(&mut b).await.unwrap();
        assert_eq!(head, "GET / HTTP/1.1\r\nHost: x\r\n\r\n");
        assert_eq!(rest, b"extra");
    }
}
