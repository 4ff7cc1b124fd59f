//! The connection limits from outside: floods of HTTP/2 streams that never finish their
//! messages, HTTP/1.1 gRPC-Web bodies that stall and sockets that say nothing, malformed
//! gRPC framing over both transports, and `X-Forwarded-For` from a trusted proxy and from
//! anyone else.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bytes::Bytes;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinHandle;

use super::*;

const CREATE_SESSION: &str = "/cathlab.v1.Simulator/CreateSession";
const MIB: f64 = 1048576.0;

/// A gRPC message header declaring `declared` bytes, followed by `sent` zero bytes of it.
fn partial_message(declared: usize, sent: usize) -> Bytes {
    let mut body = Vec::with_capacity(5 + sent);
    body.push(0);
    body.extend_from_slice(&(declared as u32).to_be_bytes());
    body.resize(5 + sent, 0);
    Bytes::from(body)
}

/// Open file descriptors of a process.
fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|d| d.count())
        .unwrap_or(0)
}

/// Samples `measure` every 20 ms until stopped; the task's result is the largest sample.
fn peak_of(measure: impl Fn() -> u64 + Send + 'static) -> (Arc<AtomicBool>, JoinHandle<u64>) {
    let stop = Arc::new(AtomicBool::new(false));
    let stopped = stop.clone();
    let task = tokio::spawn(async move {
        let mut peak = 0;
        while !stopped.load(Ordering::SeqCst) {
            peak = peak.max(measure());
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        peak.max(measure())
    });
    (stop, task)
}

async fn stop_peak((stop, task): (Arc<AtomicBool>, JoinHandle<u64>)) -> u64 {
    stop.store(true, Ordering::SeqCst);
    task.await.unwrap()
}

/// The number after `grpc-status:` in text (headers or a gRPC-Web trailers frame).
fn status_in_text(text: &[u8]) -> Option<u32> {
    let text = String::from_utf8_lossy(text).to_ascii_lowercase();
    let at = text.find("grpc-status:")?;
    let digits: String = text[at + "grpc-status:".len()..]
        .trim_start()
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().ok()
}

fn header_status(headers: &http::HeaderMap) -> Option<(u32, String)> {
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
}

/// Standard base64, decoded four characters at a time (so that concatenated padded
/// chunks, as gRPC-Web-text responses are, decode too); None if it is not base64.
fn base64_decode(text: &[u8]) -> Option<Vec<u8>> {
    let value = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return None,
        })
    };
    let text: Vec<u8> = text
        .iter()
        .copied()
        .filter(|c| !c.is_ascii_whitespace())
        .collect();
    if !text.len().is_multiple_of(4) {
        return None;
    }
    let mut out = Vec::new();
    for group in text.chunks(4) {
        let pad = group.iter().rev().take_while(|&&c| c == b'=').count();
        let mut n = 0u32;
        for &c in &group[..4 - pad] {
            n = (n << 6) | value(c)?;
        }
        n <<= 6 * pad as u32;
        let bytes = n.to_be_bytes();
        out.extend_from_slice(&bytes[1..4 - pad]);
    }
    Some(out)
}

/// The grpc-status in a gRPC-Web body's trailers frame (base64 for grpc-web-text).
fn web_trailer_status(body: &[u8], text: bool) -> Option<(u32, String)> {
    let decoded;
    let mut rest = if text {
        decoded = base64_decode(body)?;
        &decoded[..]
    } else {
        body
    };
    while rest.len() >= 5 {
        let length = u32::from_be_bytes([rest[1], rest[2], rest[3], rest[4]]) as usize;
        let frame = rest.get(5..5 + length)?;
        if rest[0] & 0x80 != 0 {
            let trailers = String::from_utf8_lossy(frame);
            let message = trailers
                .lines()
                .find_map(|l| l.strip_prefix("grpc-message:"))
                .unwrap_or("")
                .trim()
                .to_owned();
            return status_in_text(frame).map(|code| (code, message));
        }
        rest = &rest[5 + length..];
    }
    None
}

/// An HTTP/2 (prior knowledge) connection to `address`: the request handle and the task
/// that drives the connection (abort it to close the socket).
async fn h2_connection(address: &str) -> (h2::client::SendRequest<Bytes>, JoinHandle<()>) {
    let tcp = tokio::time::timeout(
        Duration::from_secs(5),
        tokio::net::TcpStream::connect(address),
    )
    .await
    .expect("connected within 5 s")
    .expect("connected");
    tcp.set_nodelay(true).unwrap();
    let (sender, connection) = h2::client::Builder::new()
        .max_send_buffer_size(4 << 20)
        .handshake::<_, Bytes>(tcp)
        .await
        .expect("HTTP/2 handshake");
    let task = tokio::spawn(async move {
        let _ = connection.await;
    });
    (sender, task)
}

/// The server's SETTINGS_MAX_CONCURRENT_STREAMS as the client applies it (once the
/// server's SETTINGS frame has arrived).
async fn advertised_streams(sender: &h2::client::SendRequest<Bytes>) -> usize {
    let deadline = Instant::now() + Duration::from_secs(5);
    while sender.current_max_send_streams() == usize::MAX && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    sender.current_max_send_streams()
}

fn grpc_request(address: &str, path: &str, content_type: &str) -> http::Request<()> {
    http::Request::builder()
        .method("POST")
        .uri(format!("http://{address}{path}"))
        .header("content-type", content_type)
        .header("te", "trailers")
        .body(())
        .unwrap()
}

/// How an HTTP/2 gRPC call ended: its grpc-status and message, or the transport error.
async fn h2_outcome(
    response: h2::client::ResponseFuture,
    web_text: bool,
) -> Result<(u32, String), String> {
    let response = response.await.map_err(|e| format!("{e}"))?;
    let (parts, mut body) = response.into_parts();
    if let Some(status) = header_status(&parts.headers) {
        return Ok(status);
    }
    let mut data = Vec::new();
    while let Some(chunk) = body.data().await {
        let chunk = chunk.map_err(|e| format!("{e}"))?;
        let _ = body.flow_control().release_capacity(chunk.len());
        data.extend_from_slice(&chunk);
    }
    if let Some(trailers) = body.trailers().await.map_err(|e| format!("{e}"))?
        && let Some(status) = header_status(&trailers)
    {
        return Ok(status);
    }
    web_trailer_status(&data, web_text)
        .ok_or_else(|| format!("no grpc-status (HTTP {})", parts.status))
}

/// One flooding stream's end.
#[derive(Debug)]
struct FloodEnd {
    outcome: Result<(u32, String), String>,
    /// From the first stream's opening to this one's end: a stream the client library held
    /// back until a slot freed is timed from the same start as the others, so the waves
    /// are told apart by when they end, however the library queues them.
    after: Duration,
}

/// `streams` POSTs to CreateSession on the connection of `sender`, each sending `body`
/// (a message it never finishes); h2 opens them as the server's stream limit lets it, queueing
/// the rest. Their ends, in the order they were sent.
async fn open_streams(
    mut sender: h2::client::SendRequest<Bytes>,
    address: &str,
    streams: usize,
    body: &Bytes,
) -> Vec<FloodEnd> {
    let mut ends = Vec::new();
    let opened = Instant::now();
    for _ in 0..streams {
        sender = tokio::time::timeout(Duration::from_secs(20), sender.ready())
            .await
            .expect("the connection is ready within 20 s")
            .expect("the connection is open");
        let (response, mut send) = sender
            .send_request(
                grpc_request(address, CREATE_SESSION, "application/grpc"),
                false,
            )
            .unwrap();
        let body = body.clone();
        ends.push(tokio::spawn(async move {
            // Never finished: the stream stays open until the server ends it.
            let _ = send.send_data(body, false);
            let outcome =
                tokio::time::timeout(Duration::from_secs(25), h2_outcome(response, false))
                    .await
                    .unwrap_or_else(|_| Err("no answer within 25 s".into()));
            drop(send);
            FloodEnd {
                outcome,
                after: opened.elapsed(),
            }
        }));
    }
    let mut ended = Vec::new();
    for end in ends {
        ended.push(end.await.unwrap());
    }
    ended
}

/// The live heap the server's counting allocator reports on /metrics (bytes).
async fn heap_bytes(address: &str) -> u64 {
    let (_, _, text) = http_get(address, "/metrics").await;
    text.lines()
        .find_map(|l| l.strip_prefix("cathlab_heap_bytes "))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .expect("cathlab_heap_bytes in /metrics") as u64
}

/// What one flood did and left.
#[derive(Debug)]
struct Flood {
    ends: Vec<FloodEnd>,
    seconds: f64,
    rss_peak: u64,
    heap_peak: u64,
    rss_after: u64,
    heap_after: u64,
    /// Seconds from the clients leaving to `rss_after` and `heap_after`.
    settled_after: f64,
    fds_after: usize,
}

/// `connections` HTTP/2 connections, each with `streams` streams of `body`, all at once;
/// then the clients go away and what the server holds once `settled(rss, heap)` says it
/// has come back, or 15 s after they left if it never does (sampled every 250 ms from 3 s).
/// Resident memory can take 10 s: mimalloc gives a thread's freed pages back to the system
/// when that thread next allocates or exits, and tokio's blocking threads that served the
/// flood exit after 10 s idle (measured: +34 MiB held until 8.5–10.8 s after the clients
/// left, then +2; it had failed a fixed 3 s wait with +69 MiB).
async fn flood(
    server: &ServerProcess,
    connections: usize,
    streams: usize,
    body: &Bytes,
    settled: impl Fn(u64, u64) -> bool,
) -> Flood {
    let pid = server.child.id();
    let rss_peak = peak_of(move || rss_bytes(pid));
    let heap_peak = {
        let (stop, address) = (Arc::new(AtomicBool::new(false)), server.address.clone());
        let stopped = stop.clone();
        let task = tokio::spawn(async move {
            let mut peak = 0;
            while !stopped.load(Ordering::SeqCst) {
                peak = peak.max(heap_bytes(&address).await);
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            peak
        });
        (stop, task)
    };
    let started = Instant::now();
    let mut flooding = Vec::new();
    let mut tasks = Vec::new();
    for _ in 0..connections {
        let (sender, task) = h2_connection(&server.address).await;
        tasks.push(task);
        let (address, body) = (server.address.clone(), body.clone());
        flooding.push(tokio::spawn(async move {
            open_streams(sender, &address, streams, &body).await
        }));
    }
    let mut ends = Vec::new();
    for f in flooding {
        ends.extend(f.await.unwrap());
    }
    let seconds = started.elapsed().as_secs_f64();
    let rss_peak = stop_peak(rss_peak).await;
    let heap_peak = stop_peak(heap_peak).await;
    // The clients go away.
    for task in tasks {
        task.abort();
    }
    let left = Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let (rss_after, heap_after) = loop {
        let heap = heap_bytes(&server.address).await;
        let rss = rss_bytes(pid);
        if settled(rss, heap) || left.elapsed() >= Duration::from_secs(15) {
            break (rss, heap);
        }
        tokio::time::sleep(Duration::from_millis(250)).await;
    };
    Flood {
        ends,
        seconds,
        rss_peak,
        heap_peak,
        rss_after,
        heap_after,
        settled_after: left.elapsed().as_secs_f64(),
        fds_after: open_fds(pid),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http2_stream_floods_stay_within_the_request_buffer_and_memory_returns() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with(
        "h2-flood",
        "request_buffer_mib = 32\nmessage_read_timeout_s = 3\n",
    );
    let pid = server.child.id();
    const CONNECTIONS: usize = 6;
    const STREAMS_PER_CONNECTION: usize = 36;
    const DECLARED: usize = 1000 * 1024;
    const SENT: usize = 996 * 1024;
    // What the server may still hold once a flood's clients have gone (bytes): the live
    // heap all but returns (measured +0.0 MiB); resident memory within twice the request
    // buffer, the pages the allocator keeps for reuse (measured +2 to +3 MiB alone on this
    // machine, +17 and +36 MiB 15 s after two floods in a fresh-clone CI run, the heap back
    // to +0.0 both times). That they are kept for reuse, not lost, is the next check: a
    // second flood's peak stays within 16 MiB of the first's.
    const HEAP_BACK: u64 = 8 << 20;
    const RSS_BACK: u64 = 64 << 20;
    const RSS_RATCHET: u64 = 16 << 20;
    tokio::time::timeout(Duration::from_secs(90), async {
        // The stream limit, from outside: the server's SETTINGS say 32, and of 40 streams
        // on one connection that each stall on 1 KiB of a message, 32 run (cut together by
        // the 3 s message timeout) and 8 wait for them (cut 3 s later).
        let (sender, task) = h2_connection(&server.address).await;
        let advertised = advertised_streams(&sender).await;
        let waves = open_streams(
            sender,
            &server.address,
            40,
            &partial_message(DECLARED, 1024),
        )
        .await;
        task.abort();
        let first_wave = waves
            .iter()
            .filter(|e| matches!(&e.outcome, Ok((4, _))) && e.after.as_secs_f64() < 4.5)
            .count();
        let second_wave = waves
            .iter()
            .filter(|e| matches!(&e.outcome, Ok((4, _))) && e.after.as_secs_f64() >= 4.5)
            .count();
        let wave_span = waves
            .iter()
            .map(|e| e.after.as_secs_f64())
            .fold((f64::MAX, 0.0f64), |(lo, hi), s| (lo.min(s), hi.max(s)));
        println!(
            "HTTP/2 stream limit: SETTINGS_MAX_CONCURRENT_STREAMS {advertised}; 40 stalled \
             streams on one connection: {first_wave} cut by the 3 s timeout at once, \
             {second_wave} after waiting for them ({:.1}-{:.1} s); others {:?}",
            wave_span.0,
            wave_span.1,
            waves
                .iter()
                .filter(|e| !matches!(&e.outcome, Ok((4, _))))
                .map(|e| &e.outcome)
                .collect::<Vec<_>>()
        );
        assert_eq!(advertised, 32);
        assert_eq!((first_wave, second_wave), (32, 8));
        tokio::time::sleep(Duration::from_millis(500)).await;

        let base = rss_bytes(pid);
        let heap_base = heap_bytes(&server.address).await;
        let fds_base = open_fds(pid);
        let body = partial_message(DECLARED, SENT);
        let flood_mib = (CONNECTIONS * STREAMS_PER_CONNECTION * (5 + SENT)) as f64 / MIB;
        let mut rounds = Vec::new();
        for round in 1..=2 {
            let f = flood(&server, CONNECTIONS, STREAMS_PER_CONNECTION, &body, |rss, heap| {
                rss < base + RSS_BACK && heap < heap_base + HEAP_BACK
            })
            .await;
            let count = |code: u32| {
                f.ends
                    .iter()
                    .filter(|e| matches!(&e.outcome, Ok((c, _)) if *c == code))
                    .count()
            };
            let (exhausted, deadline) = (count(8), count(4));
            // RST_STREAM(REFUSED_STREAM): the server's count of open streams can lag the
            // client's by the streams it has just answered.
            let refused = f
                .ends
                .iter()
                .filter(|e| matches!(&e.outcome, Err(e) if e.contains("refused")))
                .count();
            let other: Vec<_> = f
                .ends
                .iter()
                .filter(|e| match &e.outcome {
                    Ok((code, _)) => *code != 8 && *code != 4,
                    Err(e) => !e.contains("refused"),
                })
                .map(|e| format!("{:?} after {:.1} s", e.outcome, e.after.as_secs_f64()))
                .collect();
            let (first_cut, last_cut) = f
                .ends
                .iter()
                .filter(|e| matches!(&e.outcome, Ok((4, _))))
                .map(|e| e.after.as_secs_f64())
                .fold((f64::MAX, 0.0f64), |(lo, hi), s| (lo.min(s), hi.max(s)));
            let mib = |b: u64| b as f64 / MIB;
            let grew = |b: u64, from: u64| (b as f64 - from as f64) / MIB;
            println!(
                "HTTP/2 flood {round}: {CONNECTIONS} connections x {STREAMS_PER_CONNECTION} \
                 streams, each 996 of 1000 KiB ({flood_mib:.0} MiB if all were held), request \
                 buffer 32 MiB, message timeout 3 s: {exhausted} RESOURCE_EXHAUSTED, {deadline} \
                 DEADLINE_EXCEEDED (after {first_cut:.1}-{last_cut:.1} s), {refused} refused \
                 (REFUSED_STREAM), other {other:?}; over in {:.1} s; RSS {:.0} MiB -> peak {:.0} (+{:.0}) -> {:.0} \
                 (+{:.0}) {:.1} s after the clients left; live heap {:.1} MiB -> peak {:.1} \
                 (+{:.1}) -> {:.1} (+{:.1}); fds {fds_base} -> {}",
                f.seconds,
                mib(base),
                mib(f.rss_peak),
                grew(f.rss_peak, base),
                mib(f.rss_after),
                grew(f.rss_after, base),
                f.settled_after,
                mib(heap_base),
                mib(f.heap_peak),
                grew(f.heap_peak, heap_base),
                mib(f.heap_after),
                grew(f.heap_after, heap_base),
                f.fds_after,
            );
            rounds.push((f, exhausted, deadline, refused, other, first_cut, last_cut));
        }
        for (f, exhausted, deadline, refused, other, first_cut, last_cut) in &rounds {
            assert_eq!(f.ends.len(), CONNECTIONS * STREAMS_PER_CONNECTION);
            assert!(other.is_empty(), "{other:?}");
            // The buffer holds 32 streams' worth at most; those stall until the message
            // timeout, and every other stream is refused for the buffer.
            assert!((20..=33).contains(deadline), "{deadline}");
            assert!(*exhausted > 0, "none RESOURCE_EXHAUSTED");
            assert!(exhausted + refused + deadline == f.ends.len());
            assert!(
                *first_cut >= 2.9,
                "a stalled stream was cut before 3 s: {first_cut}"
            );
            assert!(*last_cut <= 3.0 + 6.0, "{last_cut}");
            assert!(
                f.ends.iter().all(|e| match &e.outcome {
                    Ok((4, m)) => m.contains("message_read_timeout_s"),
                    Ok((8, m)) => m.contains("request_buffer_mib"),
                    _ => true,
                }),
                "the messages name the settings"
            );
            // Memory: the 32 MiB buffer and its copies in the transport and the decoder,
            // never the whole flood; the live heap comes back, and resident memory does
            // not ratchet up from one flood to the next.
            assert!(
                f.rss_peak < base + (150 << 20),
                "RSS grew {} MiB",
                (f.rss_peak - base) >> 20
            );
            assert!(
                f.heap_peak < heap_base + (100 << 20),
                "heap grew {} MiB",
                (f.heap_peak - heap_base) >> 20
            );
            assert!(
                f.heap_after < heap_base + HEAP_BACK,
                "the live heap stayed {} MiB above the baseline 15 s after the clients left",
                (f.heap_after.saturating_sub(heap_base)) >> 20
            );
            assert!(
                f.rss_after < base + RSS_BACK,
                "RSS stayed {} MiB above the baseline once settled",
                (f.rss_after.saturating_sub(base)) >> 20
            );
            assert!(f.fds_after <= fds_base + 2, "{fds_base} -> {}", f.fds_after);
        }
        let (first, second) = (&rounds[0].0, &rounds[1].0);
        assert!(
            second.rss_peak < first.rss_peak + RSS_RATCHET,
            "resident memory ratchets: peak {} MiB in the first flood, {} MiB in the second",
            first.rss_peak >> 20,
            second.rss_peak >> 20
        );
    })
    .await
    .expect("the test ran within 90 s");
}

/// One raw HTTP/1.1 connection's end: whether the server said anything, what, and when it
/// closed (None: still open at the deadline).
#[derive(Debug)]
struct RawEnd {
    received: Vec<u8>,
    closed_after: Option<Duration>,
    how: String,
}

/// Connects to `address`, writes `request` (from another task, keeping the socket's
/// writing side open afterwards) and reads until the server closes the connection or
/// `limit` passes.
async fn raw_connection(address: String, request: Vec<Bytes>, limit: Duration) -> RawEnd {
    let started = Instant::now();
    let stream = match tokio::time::timeout(
        Duration::from_secs(5),
        tokio::net::TcpStream::connect(&address),
    )
    .await
    {
        Ok(Ok(s)) => s,
        other => {
            return RawEnd {
                received: Vec::new(),
                closed_after: Some(started.elapsed()),
                how: format!("connect: {other:?}"),
            };
        }
    };
    let (mut reader, mut writer) = stream.into_split();
    // The writing half is returned (not dropped: that would end the body) and kept until the
    // end of the read.
    let writing = tokio::spawn(async move {
        for part in request {
            if writer.write_all(&part).await.is_err() {
                break;
            }
        }
        writer
    });
    let mut received = Vec::new();
    let mut buffer = vec![0u8; 16 << 10];
    let deadline = tokio::time::Instant::now() + limit;
    let (closed_after, how) = loop {
        match tokio::time::timeout_at(deadline, reader.read(&mut buffer)).await {
            Ok(Ok(0)) => break (Some(started.elapsed()), "EOF".to_owned()),
            Ok(Ok(n)) => received.extend_from_slice(&buffer[..n]),
            Ok(Err(e)) => break (Some(started.elapsed()), format!("{}", e.kind())),
            Err(_) => break (None, "open".to_owned()),
        }
    };
    writing.abort();
    drop(writing.await);
    RawEnd {
        received,
        closed_after,
        how,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stalled_http1_bodies_and_idle_sockets_are_closed_and_counted_per_address() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with(
        "h1-stall",
        "max_connections_per_address = 40\nconnection_idle_timeout_s = 3\n\
         message_read_timeout_s = 2\n",
    );
    let pid = server.child.id();
    const DECLARED: usize = 1000 * 1024;
    const SENT: usize = 996 * 1024;
    tokio::time::timeout(Duration::from_secs(40), async {
        // The server answers (and its descriptors settle) before the baseline.
        let (status, _, _) = http_get(&server.address, "/metrics").await;
        assert_eq!(status, 200);
        tokio::time::sleep(Duration::from_millis(300)).await;
        let fds_base = open_fds(pid);
        let head = Bytes::from(format!(
            "POST {CREATE_SESSION} HTTP/1.1\r\nhost: {}\r\ncontent-type: \
             application/grpc-web+proto\r\nx-grpc-web: 1\r\naccept: application/grpc-web+proto\r\n\
             content-length: {}\r\n\r\n",
            server.address,
            5 + DECLARED
        ));
        let body = partial_message(DECLARED, SENT);
        let fds_peak = peak_of(move || open_fds(pid) as u64);
        let started = Instant::now();
        let connections: Vec<_> = (0..100)
            .map(|_| {
                tokio::spawn(raw_connection(
                    server.address.clone(),
                    vec![head.clone(), body.clone()],
                    Duration::from_secs(15),
                ))
            })
            .collect();
        let mut ends = Vec::new();
        for c in connections {
            ends.push(c.await.unwrap());
        }
        let fds_peak = stop_peak(fds_peak).await as usize;
        let all_s = started.elapsed().as_secs_f64();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let fds_after = open_fds(pid);

        let (served, refused): (Vec<&RawEnd>, Vec<&RawEnd>) =
            ends.iter().partition(|e| !e.received.is_empty());
        let still_open = ends.iter().filter(|e| e.closed_after.is_none()).count();
        let span = |ends: &[&RawEnd]| {
            ends.iter()
                .filter_map(|e| e.closed_after.map(|d| d.as_secs_f64()))
                .fold((f64::MAX, 0.0f64), |(lo, hi), s| (lo.min(s), hi.max(s)))
        };
        let (served_first, served_last) = span(&served);
        let (refused_first, refused_last) = span(&refused);
        let statuses: Vec<Option<u32>> =
            served.iter().map(|e| status_in_text(&e.received)).collect();
        let deadline = statuses.iter().filter(|s| **s == Some(4)).count();
        let mut hows: Vec<&str> = ends.iter().map(|e| e.how.as_str()).collect();
        hows.sort_unstable();
        hows.dedup();
        let first_answer = served
            .first()
            .map(|e| String::from_utf8_lossy(&e.received).into_owned());
        println!(
            "100 HTTP/1.1 gRPC-Web bodies 4 KiB short, 40 connections an address, message \
             timeout 2 s, idle 3 s: {} served ({deadline} answered DEADLINE_EXCEEDED, closed \
             after {served_first:.1}-{served_last:.1} s), {} closed unanswered after \
             {refused_first:.2}-{refused_last:.2} s, {still_open} still open; ends {hows:?}; \
             all over in {all_s:.1} s; fds {fds_base} -> peak {fds_peak} (+{}) -> {fds_after}; \
             first answer {first_answer:?}",
            served.len(),
            refused.len(),
            fds_peak - fds_base,
        );
        assert_eq!(still_open, 0, "connections the server never closed");
        assert!(served.len() <= 40, "{} served", served.len());
        assert!(served.len() >= 30, "{} served", served.len());
        assert_eq!(deadline, served.len(), "{statuses:?}");
        // Over the limit: closed at once, sooner than any stalled body could be cut.
        assert!(refused_last < 2.0, "{refused_last}");
        // Stalled: cut by the message timeout (2 s), closed by the idle timeout at worst.
        assert!(served_first >= 1.9, "{served_first}");
        assert!(served_last <= 2.0 + 3.0 + 4.0, "{served_last}");
        // About one descriptor a connection, and all given back.
        let grown = fds_peak - fds_base;
        assert!(grown >= served.len() - 2, "{grown}");
        assert!(grown * 2 <= served.len() * 3 + 2 * 4, "{grown}");
        assert!(fds_after <= fds_base + 1, "{fds_base} -> {fds_after}");

        // Sockets that never send a byte are closed by the idle timeout.
        let idle: Vec<_> = (0..10)
            .map(|_| {
                tokio::spawn(raw_connection(
                    server.address.clone(),
                    Vec::new(),
                    Duration::from_secs(12),
                ))
            })
            .collect();
        let mut idle_ends = Vec::new();
        for c in idle {
            idle_ends.push(c.await.unwrap());
        }
        let idle_refs: Vec<&RawEnd> = idle_ends.iter().collect();
        let (idle_first, idle_last) = span(&idle_refs);
        let idle_open = idle_ends
            .iter()
            .filter(|e| e.closed_after.is_none())
            .count();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let fds_end = open_fds(pid);
        println!(
            "10 silent sockets: closed after {idle_first:.1}-{idle_last:.1} s, {idle_open} still \
             open, {} got bytes; fds at the end {fds_end}",
            idle_ends.iter().filter(|e| !e.received.is_empty()).count()
        );
        assert_eq!(idle_open, 0);
        assert!(idle_first >= 2.5, "{idle_first}");
        assert!(idle_last <= 3.0 + 5.0, "{idle_last}");
        assert!(fds_end <= fds_base + 1, "{fds_base} -> {fds_end}");
    })
    .await
    .expect("the test ran within 40 s");
}

/// POSTs `body` to `path` over a fresh HTTP/1.1 connection; the grpc-status (from the
/// headers or the gRPC-Web trailers frame) and message.
async fn http1_grpc_web(
    address: &str,
    path: &str,
    content_type: &str,
    body: Bytes,
) -> Result<(u32, String), String> {
    use http_body_util::{BodyExt, Full};
    let stream = tokio::net::TcpStream::connect(address)
        .await
        .map_err(|e| format!("{e}"))?;
    let (mut sender, connection) =
        hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
            .await
            .map_err(|e| format!("{e}"))?;
    tokio::spawn(connection);
    let request = hyper::Request::post(path)
        .header("host", address)
        .header("content-type", content_type)
        .header("x-grpc-web", "1")
        .body(Full::new(body))
        .unwrap();
    let response = sender
        .send_request(request)
        .await
        .map_err(|e| format!("{e}"))?;
    let status = response.status();
    let headers = response.headers().clone();
    if let Some(s) = header_status(&headers) {
        return Ok(s);
    }
    let bytes = response
        .into_body()
        .collect()
        .await
        .map_err(|e| format!("{e}"))?
        .to_bytes();
    web_trailer_status(&bytes, content_type.contains("text"))
        .ok_or_else(|| format!("no grpc-status (HTTP {status}, {} body bytes)", bytes.len()))
}

/// Sends `body` as one request on a fresh HTTP/2 connection (ending the stream with it; an
/// empty body ends it with the headers).
async fn h2_grpc(
    address: &str,
    path: &str,
    content_type: &str,
    body: Bytes,
) -> Result<(u32, String), String> {
    let (sender, task) = h2_connection(address).await;
    let mut sender = sender.ready().await.map_err(|e| format!("{e}"))?;
    let empty = body.is_empty();
    let (response, mut send) = sender
        .send_request(grpc_request(address, path, content_type), empty)
        .map_err(|e| format!("{e}"))?;
    if !empty {
        send.send_data(body, true).map_err(|e| format!("{e}"))?;
    }
    let outcome = h2_outcome(response, content_type.contains("text")).await;
    task.abort();
    outcome
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn framing_errors_are_invalid_argument() {
    let _exclusive = EXCLUSIVE.lock().await;
    let (server, _dir) = server_with("framing", "");
    tokio::time::timeout(Duration::from_secs(40), async {
        let truncated = partial_message(100, 10);
        let cases: [(&str, &str, Bytes); 4] = [
            ("empty unary body", "proto", Bytes::new()),
            (
                "compression flag 2",
                "proto",
                Bytes::from_static(&[2, 0, 0, 0, 1, 9]),
            ),
            ("header says 100 bytes, 10 sent", "proto", truncated),
            (
                "bad base64",
                "text",
                Bytes::from_static(b"!!!! this is not base64 ~~~~"),
            ),
        ];
        let mut results = Vec::new();
        for (what, kind, body) in &cases {
            let (web, h2_type) = if *kind == "text" {
                ("application/grpc-web-text", "application/grpc-web-text")
            } else {
                ("application/grpc-web+proto", "application/grpc")
            };
            for (transport, outcome) in [
                (
                    "HTTP/1.1 gRPC-Web",
                    tokio::time::timeout(
                        Duration::from_secs(10),
                        http1_grpc_web(&server.address, CREATE_SESSION, web, body.clone()),
                    )
                    .await
                    .unwrap_or_else(|_| Err("no answer within 10 s".into())),
                ),
                (
                    "HTTP/2",
                    tokio::time::timeout(
                        Duration::from_secs(10),
                        h2_grpc(&server.address, CREATE_SESSION, h2_type, body.clone()),
                    )
                    .await
                    .unwrap_or_else(|_| Err("no answer within 10 s".into())),
                ),
            ] {
                let content_type = if transport == "HTTP/2" { h2_type } else { web };
                println!("{what} over {transport} ({content_type}): {outcome:?}");
                results.push((*what, transport, outcome));
            }
        }
        // The server still serves.
        let mut client = server.client().await;
        let session = create(&mut client).await;
        close(&mut client, &session).await;
        let wrong: Vec<_> = results
            .iter()
            .filter(|(_, _, outcome)| !matches!(outcome, Ok((3, _))))
            .collect();
        assert!(wrong.is_empty(), "not INVALID_ARGUMENT: {wrong:?}");
    })
    .await
    .expect("the test ran within 40 s");
}

/// ListSessions with `key`, as from the client `forwarded` names in `X-Forwarded-For`.
async fn list_as(
    client: &mut pb::simulator_client::SimulatorClient<tonic::transport::Channel>,
    key: &str,
    forwarded: Option<&str>,
) -> Result<(), tonic::Status> {
    let mut request = authed(
        pb::ListSessionsRequest {
            include_recorded: false,
            ..Default::default()
        },
        key,
    );
    if let Some(f) = forwarded {
        request
            .metadata_mut()
            .insert("x-forwarded-for", f.parse().unwrap());
    }
    client.list_sessions(request).await.map(|_| ())
}

/// Ten wrong keys as 203.0.113.9, then the right key as 198.51.100.7, as 203.0.113.9 and
/// with no header: the codes of the ten, and the three answers.
async fn guess_behind_a_proxy(
    server: &ServerProcess,
) -> (Vec<tonic::Code>, [Result<(), tonic::Status>; 3]) {
    let mut client = server.client().await;
    let mut codes = Vec::new();
    for i in 0..10 {
        let error = list_as(&mut client, &format!("guess-{i:02}"), Some("203.0.113.9"))
            .await
            .unwrap_err();
        codes.push(error.code());
    }
    let other = list_as(&mut client, INSTRUCTOR_KEY, Some("198.51.100.7")).await;
    let same = list_as(&mut client, INSTRUCTOR_KEY, Some("203.0.113.9")).await;
    let direct = list_as(&mut client, INSTRUCTOR_KEY, None).await;
    (codes, [other, same, direct])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_trusted_proxys_forwarded_client_is_throttled_alone() {
    let _exclusive = EXCLUSIVE.lock().await;
    tokio::time::timeout(Duration::from_secs(40), async {
        let code = |r: &Result<(), tonic::Status>| r.as_ref().err().map(tonic::Status::code);
        let (proxied, _dir) = server_with(
            "trusted-proxy",
            "trusted_proxies = [\"127.0.0.1\"]\nauth_failures_per_minute = 5\n",
        );
        let (codes, [other, same, direct]) = guess_behind_a_proxy(&proxied).await;
        println!(
            "behind a trusted proxy, 10 wrong keys from 203.0.113.9: {codes:?}; then the right \
             key from 198.51.100.7: {:?}, from 203.0.113.9: {:?}, from the proxy itself: {:?}",
            code(&other),
            code(&same),
            code(&direct)
        );
        let denied = codes
            .iter()
            .filter(|c| **c == tonic::Code::PermissionDenied)
            .count();
        assert_eq!(denied, 5, "{codes:?}");
        assert!(
            codes[5..]
                .iter()
                .all(|c| *c == tonic::Code::ResourceExhausted),
            "{codes:?}"
        );
        assert!(other.is_ok(), "{other:?}");
        assert_eq!(
            code(&same),
            Some(tonic::Code::ResourceExhausted),
            "{same:?}"
        );
        assert!(direct.is_ok(), "{direct:?}");
        drop(proxied);

        // Not a trusted proxy: the header is the client's own word, not believed; the
        // address itself is locked out.
        let (plain, _dir) = server_with("untrusted-proxy", "auth_failures_per_minute = 5\n");
        let (codes, [other, same, direct]) = guess_behind_a_proxy(&plain).await;
        println!(
            "no trusted proxy, 10 wrong keys claiming 203.0.113.9: {codes:?}; then the right key \
             claiming 198.51.100.7: {:?}, 203.0.113.9: {:?}, no header: {:?}",
            code(&other),
            code(&same),
            code(&direct)
        );
        assert_eq!(
            codes
                .iter()
                .filter(|c| **c == tonic::Code::PermissionDenied)
                .count(),
            5,
            "{codes:?}"
        );
        for answer in [&other, &same, &direct] {
            assert_eq!(
                code(answer),
                Some(tonic::Code::ResourceExhausted),
                "{answer:?}"
            );
        }
    })
    .await
    .expect("the test ran within 40 s");
}
