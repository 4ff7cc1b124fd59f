//! The connection attacks' raw side: gRPC messages begun and never finished, HTTP/1.1
//! requests written on a bare socket, HTTP/2 streams opened by hand, and how each ended
//! (counted in the tally, a fault where the server must not answer so).

use std::sync::Arc;
use std::time::{Duration, Instant};

use bytes::Bytes;

use crate::common::{IDLE_TIMEOUT_S, MESSAGE_TIMEOUT_S};
use crate::tally::Tally;

/// A gRPC message header declaring `declared` bytes, then `sent` zero bytes of it.
pub(crate) fn partial_message(declared: usize, sent: usize) -> Bytes {
    let mut body = Vec::with_capacity(5 + sent);
    body.push(0);
    body.extend_from_slice(&(declared as u32).to_be_bytes());
    body.resize(5 + sent, 0);
    Bytes::from(body)
}

/// How long a stalled request or a silent socket is given before it counts as kept open:
/// both timeouts and a margin for a loaded machine.
pub(crate) fn stall_limit() -> Duration {
    Duration::from_secs(MESSAGE_TIMEOUT_S + IDLE_TIMEOUT_S + 4)
}

/// The head of an HTTP/1.1 gRPC-Web POST to GetSession declaring a body of `length` bytes.
pub(crate) fn web_post_head(address: &str, length: usize) -> Vec<u8> {
    format!(
        "POST /cathlab.v1.Simulator/GetSession HTTP/1.1\r\nHost: {address}\r\n\
         content-type: application/grpc-web+proto\r\nx-grpc-web: 1\r\n\
         content-length: {length}\r\n\r\n"
    )
    .into_bytes()
}

/// The number after the first `grpc-status:` in `bytes` (HTTP/1.1 headers or a gRPC-Web
/// trailers frame).
pub(crate) fn grpc_status_in(bytes: &[u8]) -> Option<u32> {
    let text = String::from_utf8_lossy(bytes).to_ascii_lowercase();
    let at = text.find("grpc-status:")? + "grpc-status:".len();
    text[at..]
        .trim_start()
        .chars()
        .take_while(char::is_ascii_digit)
        .collect::<String>()
        .parse()
        .ok()
}

/// The name of a gRPC status code.
pub(crate) fn code_name(code: u32) -> String {
    format!("{:?}", tonic::Code::from_i32(code as i32))
}

/// What became of one raw connection: what the server sent, and when it closed (None:
/// still open at the limit).
pub(crate) struct RawEnd {
    pub(crate) received: Vec<u8>,
    pub(crate) closed_after: Option<Duration>,
}

/// Connects to `address`, writes `request` (keeping the connection open) and reads until the
/// server closes it or `limit` passes; the socket is closed then.
pub(crate) async fn raw_exchange(address: &str, request: Vec<u8>, limit: Duration) -> RawEnd {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let started = Instant::now();
    let deadline = tokio::time::Instant::now() + limit;
    let mut received = Vec::new();
    let closed = |received| RawEnd {
        received,
        closed_after: Some(started.elapsed()),
    };
    let Ok(Ok(mut stream)) =
        tokio::time::timeout_at(deadline, tokio::net::TcpStream::connect(address)).await
    else {
        return closed(received);
    };
    match tokio::time::timeout_at(deadline, stream.write_all(&request)).await {
        Ok(Ok(())) => {}
        Ok(Err(_)) => return closed(received),
        Err(_) => {
            return RawEnd {
                received,
                closed_after: None,
            };
        }
    }
    let mut buffer = vec![0u8; 16 << 10];
    loop {
        match tokio::time::timeout_at(deadline, stream.read(&mut buffer)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return closed(received),
            Ok(Ok(n)) => received.extend_from_slice(&buffer[..n]),
            Err(_) => {
                return RawEnd {
                    received,
                    closed_after: None,
                };
            }
        }
    }
}

/// One HTTP/1.1 request that stalls (`request` is all of it the server gets): counted under
/// `action` by the grpc-status it was answered with, or as closed unanswered; a status of
/// INTERNAL or UNKNOWN, or a connection kept past both timeouts, is a fault.
pub(crate) async fn http1_stall(
    tally: &Tally,
    action: &'static str,
    address: &str,
    request: Vec<u8>,
) {
    let end = raw_exchange(address, request, stall_limit()).await;
    let status = grpc_status_in(&end.received);
    if let Some(code @ (2 | 13)) = status {
        tally.wrong(format!(
            "{action}: answered {}: {}",
            code_name(code),
            String::from_utf8_lossy(&end.received)
                .chars()
                .take(300)
                .collect::<String>()
        ));
    }
    let answer = match (status, end.received.is_empty()) {
        (Some(code), _) => code_name(code),
        (None, true) => "unanswered".to_owned(),
        (None, false) => String::from_utf8_lossy(&end.received)
            .lines()
            .next()
            .unwrap_or("")
            .chars()
            .take(40)
            .collect(),
    };
    match end.closed_after {
        Some(_) => tally.row(action, format!("{answer}, closed"), 1),
        None => {
            tally.row(action, format!("{answer}, kept open"), 1);
            tally.wrong(format!(
                "{action}: the server kept the connection open {} s \
                 (message_read_timeout_s {MESSAGE_TIMEOUT_S}, connection_idle_timeout_s \
                 {IDLE_TIMEOUT_S}), answered: {answer}",
                stall_limit().as_secs()
            ));
        }
    }
}

/// How an HTTP/2 gRPC stream ended: its grpc-status and message, or None when the response
/// carried none.
pub(crate) async fn h2_status(
    response: h2::client::ResponseFuture,
) -> Result<Option<(u32, String)>, h2::Error> {
    let status = |headers: &http::HeaderMap| {
        let code = headers
            .get("grpc-status")?
            .to_str()
            .ok()?
            .trim()
            .parse()
            .ok()?;
        let message = headers
            .get("grpc-message")
            .and_then(|m| m.to_str().ok())
            .unwrap_or("")
            .to_owned();
        Some((code, message))
    };
    let (parts, mut body) = response.await?.into_parts();
    if let Some(s) = status(&parts.headers) {
        return Ok(Some(s));
    }
    while let Some(chunk) = body.data().await {
        let chunk = chunk?;
        let _ = body.flow_control().release_capacity(chunk.len());
    }
    Ok(body.trailers().await?.as_ref().and_then(status))
}

/// An HTTP/2 connection (prior knowledge) to `address` opening `streams` streams to
/// GetSession, each sending `body` (a message it never finishes) or, with None, only its
/// headers. Streams are opened as the server's SETTINGS_MAX_CONCURRENT_STREAMS lets them,
/// until one message timeout and a half has passed; those left are counted "not opened".
/// Each opened stream must end within [`stall_limit`]: with DEADLINE_EXCEEDED or
/// RESOURCE_EXHAUSTED, a reset, or the connection closed; another status, INTERNAL or
/// UNKNOWN (or a reset with INTERNAL_ERROR, which a gRPC client reads as INTERNAL) or no end
/// at all is a fault. Counted under `action` and "h2 flood stream" or `action` alone.
pub(crate) async fn h2_streams(
    tally: &Arc<Tally>,
    action: &'static str,
    address: &str,
    streams: usize,
    body: Option<Bytes>,
) {
    let row: &'static str = if body.is_some() {
        "h2 flood stream"
    } else {
        action
    };
    let connected = async {
        let tcp = tokio::net::TcpStream::connect(address).await?;
        tcp.set_nodelay(true)?;
        let (sender, connection) = h2::client::Builder::new()
            .max_send_buffer_size(4 << 20)
            .handshake::<_, Bytes>(tcp)
            .await?;
        anyhow::Ok((sender, connection))
    };
    let (mut sender, connection) =
        match tokio::time::timeout(Duration::from_secs(3), connected).await {
            Ok(Ok(c)) => c,
            Ok(Err(e)) => {
                tally.row(action, format!("connection failed: {e:#}"), 1);
                return;
            }
            Err(_) => {
                tally.row(action, "connection not made within 3 s", 1);
                return;
            }
        };
    let driver = tokio::spawn(async move {
        let _ = connection.await;
    });
    let opening_ends =
        tokio::time::Instant::now() + Duration::from_millis(MESSAGE_TIMEOUT_S * 1000 + 1500);
    let mut ends = Vec::new();
    for _ in 0..streams {
        sender = match tokio::time::timeout_at(opening_ends, sender.ready()).await {
            Ok(Ok(s)) => s,
            Ok(Err(e)) => {
                tally.row(action, format!("connection ended: {e}"), 1);
                break;
            }
            Err(_) => break,
        };
        let request = http::Request::builder()
            .method("POST")
            .uri(format!("http://{address}/cathlab.v1.Simulator/GetSession"))
            .header("content-type", "application/grpc")
            .header("te", "trailers")
            .body(())
            .expect("a valid request");
        let (response, mut send) = match sender.send_request(request, false) {
            Ok(r) => r,
            Err(e) => {
                tally.row(action, format!("not sent: {e}"), 1);
                break;
            }
        };
        if let Some(body) = &body {
            let _ = send.send_data(body.clone(), false);
        }
        ends.push(tokio::spawn(async move {
            let end = tokio::time::timeout(stall_limit(), h2_status(response)).await;
            drop(send);
            end
        }));
    }
    tally.row(
        row,
        "not opened (waiting for the stream limit)",
        (streams - ends.len()) as u64,
    );
    tally.row(action, "connections", 1);
    for end in ends {
        let Ok(end) = end.await else { continue };
        let outcome = match end {
            Err(_) => {
                tally.wrong(format!(
                    "{action}: a stream had no end within {} s (message_read_timeout_s \
                     {MESSAGE_TIMEOUT_S}, connection_idle_timeout_s {IDLE_TIMEOUT_S})",
                    stall_limit().as_secs()
                ));
                "no end".to_owned()
            }
            Ok(Ok(Some((code, message)))) => {
                if !matches!(code, 4 | 8) {
                    tally.wrong(format!("{action}: answered {}: {message}", code_name(code)));
                }
                code_name(code)
            }
            Ok(Ok(None)) => {
                tally.wrong(format!("{action}: a response without a grpc-status"));
                "no grpc-status".to_owned()
            }
            Ok(Err(e)) => match e.reason() {
                Some(reason) if e.is_reset() => {
                    if reason == h2::Reason::INTERNAL_ERROR {
                        tally.wrong(format!("{action}: a stream reset with INTERNAL_ERROR"));
                    }
                    format!("reset {reason:?}")
                }
                Some(reason) if e.is_go_away() => format!("GOAWAY {reason:?}"),
                _ => "connection closed".to_owned(),
            },
        };
        tally.row(row, outcome, 1);
    }
    driver.abort();
}
