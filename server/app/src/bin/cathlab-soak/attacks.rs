//! The random clients' attacks: hostile inline scenes, garbage on the port, floods of
//! HTTP/2 streams that never finish their messages, HTTP/1.1 bodies that stall or never
//! start, sockets that say nothing, and scenes naming decompression bombs.

use std::time::Duration;

use anyhow::Result;
use cathlab_api::authorized as authed;
use cathlab_api::pb;
use rand::RngExt;

use crate::client::Chaos;
use crate::common::{IDLE_TIMEOUT_S, KEY};
use crate::raw::{
    h2_streams, http1_stall, partial_message, raw_exchange, stall_limit, web_post_head,
};

impl Chaos {
    /// Inline scenes that must be refused: unparsable, naming files outside the data roots,
    /// out of range, or sent without the instructor key.
    pub(crate) async fn hostile_scene(&mut self) -> Result<()> {
        let scenes = [
            "this is not toml [[[".to_owned(),
            "name = \"x\"\n[anatomy]\nkind = \"volume\"\nvolume = \"/etc/hostname\"\n".to_owned(),
            "name = \"x\"\n[ct]\npath = \"../../../etc/passwd\"\n".to_owned(),
            format!("name = \"x{}\"\n[fidelity]\nstep_rate_hz = 1e9\n", self.seq),
            "x".repeat(self.rng.random_range(1..200_000)),
        ];
        let text = self.pick(&scenes);
        let key = if self.rng.random_bool(0.7) { KEY } else { "" };
        let r = self
            .client
            .create_session(authed(
                pb::CreateSessionRequest {
                    scene: Some(pb::create_session_request::Scene::SceneToml(text)),
                    label: "hostile".into(),
                    ..Default::default()
                },
                key,
            ))
            .await;
        if let Ok(created) = &r {
            // Nothing above is a valid scene: say so, and give the place back.
            self.tally
                .faults
                .lock()
                .push("a hostile inline scene was accepted".into());
            let _ = self
                .client
                .close_session(authed(
                    pb::CloseSessionRequest {
                        session_id: created.get_ref().session_id.clone(),
                    },
                    &created.get_ref().controller_token,
                ))
                .await;
        }
        self.tally.answer("hostile scene", &r);
        Ok(())
    }

    /// Bytes that are not what the port expects: random bytes, or a gRPC-Web call whose body
    /// is not a protobuf message.
    pub(crate) async fn garbage(&mut self) -> Result<()> {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut stream = tokio::net::TcpStream::connect(&self.address).await?;
        let bytes: Vec<u8> = if self.rng.random_bool(0.5) {
            (0..self.rng.random_range(1..4096))
                .map(|_| self.rng.random())
                .collect()
        } else {
            let body: Vec<u8> = (0..64).map(|_| self.rng.random()).collect();
            let mut framed = vec![0u8];
            framed.extend_from_slice(&(body.len() as u32).to_be_bytes());
            framed.extend_from_slice(&body);
            let mut request = format!(
                "POST /cathlab.v1.Simulator/SendCommand HTTP/1.1\r\nHost: {}\r\n\
                 content-type: application/grpc-web+proto\r\nx-grpc-web: 1\r\n\
                 content-length: {}\r\nConnection: close\r\n\r\n",
                self.address,
                framed.len()
            )
            .into_bytes();
            request.extend_from_slice(&framed);
            request
        };
        stream.write_all(&bytes).await?;
        let mut answer = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(2), stream.read_to_end(&mut answer)).await;
        let text = String::from_utf8_lossy(&answer);
        let code = if text.contains("grpc-status: 13") || text.contains("grpc-status:13") {
            self.tally
                .faults
                .lock()
                .push("garbage answered INTERNAL".into());
            "INTERNAL"
        } else if text.starts_with("HTTP/1.1") {
            "answered"
        } else {
            "closed"
        };
        *self
            .tally
            .answers
            .lock()
            .entry(("garbage", code.into()))
            .or_default() += 1;
        Ok(())
    }

    /// An HTTP/2 connection (prior knowledge) opening 16–100 streams to GetSession, each a
    /// gRPC message header declaring 900 KiB and part of it, then nothing more: the server
    /// must cut each (DEADLINE_EXCEEDED after `message_read_timeout_s`, RESOURCE_EXHAUSTED
    /// when the request buffer is full, or a reset). Runs in a task of its own; streams not
    /// opened within the first wave's timeout and a half are counted and given up.
    pub(crate) fn h2_flood(&mut self) -> Result<()> {
        let streams = self.rng.random_range(16..=100);
        let sent = [1 << 10, 64 << 10, 256 << 10, 880 << 10][self.rng.random_range(0..4)];
        let body = partial_message(900 << 10, sent);
        let (tally, address) = (self.tally.clone(), self.address.clone());
        self.stalls.push(tokio::spawn(async move {
            h2_streams(&tally, "h2 flood", &address, streams, Some(body)).await;
        }));
        Ok(())
    }

    /// 1–3 HTTP/1.1 gRPC-Web POSTs whose content-length says 900 KiB more than the body's
    /// first 3 bytes to 512 KiB, then silence: answered DEADLINE_EXCEEDED (or
    /// RESOURCE_EXHAUSTED) and closed. Runs in a task of its own.
    pub(crate) fn stalled_body(&mut self) -> Result<()> {
        for _ in 0..self.rng.random_range(1..=3) {
            let sent = [3, 1 << 10, 64 << 10, 512 << 10][self.rng.random_range(0..4)];
            let mut request = web_post_head(&self.address, 5 + (900 << 10));
            request.extend_from_slice(&partial_message(900 << 10, sent)[..sent.max(3)]);
            let (tally, address) = (self.tally.clone(), self.address.clone());
            self.stalls.push(tokio::spawn(async move {
                http1_stall(&tally, "stalled body", &address, request).await;
            }));
        }
        Ok(())
    }

    /// Requests whose bodies never start: 1–3 HTTP/1.1 gRPC-Web POSTs declaring a body and
    /// sending only their headers, or an HTTP/2 connection with 1–8 streams of headers only.
    /// Neither timeout may be dodged: each must be answered or closed. Runs in a task of
    /// its own.
    pub(crate) fn body_never_starts(&mut self) -> Result<()> {
        let (tally, address) = (self.tally.clone(), self.address.clone());
        if self.rng.random_bool(0.5) {
            let streams = self.rng.random_range(1..=8);
            self.stalls.push(tokio::spawn(async move {
                h2_streams(&tally, "body never starts h2", &address, streams, None).await;
            }));
        } else {
            for _ in 0..self.rng.random_range(1..=3) {
                let request = web_post_head(&self.address, 5 + (900 << 10));
                let (tally, address) = (tally.clone(), address.clone());
                self.stalls.push(tokio::spawn(async move {
                    http1_stall(&tally, "body never starts", &address, request).await;
                }));
            }
        }
        Ok(())
    }

    /// 1–4 sockets that connect and send nothing: the server closes each after
    /// `connection_idle_timeout_s`. Runs in a task of its own.
    pub(crate) fn idle_sockets(&mut self) -> Result<()> {
        for _ in 0..self.rng.random_range(1..=4) {
            let (tally, address) = (self.tally.clone(), self.address.clone());
            self.stalls.push(tokio::spawn(async move {
                let end = raw_exchange(&address, Vec::new(), stall_limit()).await;
                match end.closed_after {
                    None => tally.wrong(format!(
                        "an idle socket was still open after {} s \
                         (connection_idle_timeout_s {IDLE_TIMEOUT_S})",
                        stall_limit().as_secs()
                    )),
                    Some(after) if after.as_secs_f64() < IDLE_TIMEOUT_S as f64 - 0.5 => {
                        tally.row("idle socket", "closed at once", 1);
                    }
                    Some(_) => tally.row("idle socket", "closed by the idle timeout", 1),
                }
                if !end.received.is_empty() {
                    tally.row("idle socket", "sent bytes it was not asked for", 1);
                }
            }));
        }
        Ok(())
    }

    /// An instructor's inline scene whose CT is one of the bomb files: INVALID_ARGUMENT
    /// naming `ct.path` and saying "refused:", no path.
    pub(crate) async fn bomb_file(&mut self) -> Result<()> {
        let bombs = self.bombs.clone();
        let (name, text) = self.pick(&bombs.scenes);
        let r = self
            .client
            .create_session(authed(
                pb::CreateSessionRequest {
                    scene: Some(pb::create_session_request::Scene::SceneToml(text)),
                    label: "bomb".into(),
                    ..Default::default()
                },
                KEY,
            ))
            .await;
        match &r {
            Ok(created) => {
                self.tally.wrong(format!("the bomb {name} was accepted"));
                let _ = self
                    .client
                    .close_session(authed(
                        pb::CloseSessionRequest {
                            session_id: created.get_ref().session_id.clone(),
                        },
                        &created.get_ref().controller_token,
                    ))
                    .await;
            }
            Err(s) if s.code() == tonic::Code::InvalidArgument => {
                let m = s.message();
                if !m.contains("ct.path") || !m.contains("refused:") {
                    self.tally.wrong(format!(
                        "the bomb {name} was refused without naming ct.path and saying \
                         \"refused:\": {m}"
                    ));
                }
                if m.contains(&self.bombs.dir) {
                    self.tally.wrong(format!(
                        "the refusal of the bomb {name} shows its path: {m}"
                    ));
                }
            }
            // A full server or a throttle may answer first: counted, not judged.
            Err(s)
                if matches!(
                    s.code(),
                    tonic::Code::ResourceExhausted | tonic::Code::Unavailable
                ) => {}
            Err(s) => {
                if !matches!(s.code(), tonic::Code::Internal | tonic::Code::Unknown) {
                    self.tally.wrong(format!(
                        "the bomb {name} was answered {:?}: {}",
                        s.code(),
                        s.message()
                    ));
                }
            }
        }
        self.tally.answer("bomb file", &r);
        Ok(())
    }
}
