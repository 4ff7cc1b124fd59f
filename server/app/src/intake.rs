//! Request messages as they arrive, before tonic decodes them: the bytes of messages still
//! arriving are held within one budget for all connections, each message must arrive whole
//! within a timeout once its first byte has (the first message, once its request has),
//! malformed gRPC framing (a bad compression flag,
//! a body that ends inside a message) is the caller's error (INVALID_ARGUMENT), and the
//! connection counts as busy, not idle, while a handler works on its request.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::Body;
use bytes::Bytes;
use http_body::{Body as HttpBody, Frame};
use tonic::Status;

use crate::connections::Peer;

/// The bytes all request messages still arriving may hold together.
#[derive(Debug)]
pub struct RequestBuffer {
    limit: usize,
    held: AtomicUsize,
}

impl RequestBuffer {
    /// A buffer of `limit` bytes.
    pub fn new(limit: usize) -> Arc<Self> {
        Arc::new(Self {
            limit,
            held: AtomicUsize::new(0),
        })
    }

    /// Bytes held now.
    pub fn held(&self) -> usize {
        self.held.load(Ordering::SeqCst)
    }

    fn take(&self, bytes: usize) -> bool {
        self.held
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |held| {
                held.checked_add(bytes).filter(|&n| n <= self.limit)
            })
            .is_ok()
    }

    fn give(&self, bytes: usize) {
        self.held.fetch_sub(bytes, Ordering::SeqCst);
    }
}

/// The layer that meters every request body of the routes it wraps.
#[derive(Debug, Clone)]
pub struct IntakeLayer {
    buffer: Arc<RequestBuffer>,
    message_timeout: Duration,
}

impl IntakeLayer {
    /// Messages arriving hold at most `buffer` together, and each arrives within
    /// `message_timeout` of its first byte.
    pub fn new(buffer: Arc<RequestBuffer>, message_timeout: Duration) -> Self {
        Self {
            buffer,
            message_timeout,
        }
    }
}

impl<S> tower::Layer<S> for IntakeLayer {
    type Service = Intake<S>;

    fn layer(&self, inner: S) -> Intake<S> {
        Intake {
            inner,
            layer: self.clone(),
        }
    }
}

/// The service [`IntakeLayer`] makes.
#[derive(Debug, Clone)]
pub struct Intake<S> {
    inner: S,
    layer: IntakeLayer,
}

impl<S> tower::Service<axum::http::Request<Body>> for Intake<S>
where
    S: tower::Service<axum::http::Request<Body>> + Send,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = Pin<Box<dyn Future<Output = Result<S::Response, S::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), S::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: axum::http::Request<Body>) -> Self::Future {
        let extensions = request.extensions();
        let busy = extensions
            .get::<Peer>()
            .or_else(|| {
                extensions
                    .get::<tonic::transport::server::TlsConnectInfo<Peer>>()
                    .map(|info| info.get_ref())
            })
            .map(Peer::busy);
        let (parts, body) = request.into_parts();
        // The first message's clock starts with the request, not with its first byte: a
        // request whose body never starts would otherwise hold its connection (busy, so never
        // idle) for ever.
        let deadline = (!body.is_end_stream())
            .then(|| Box::pin(tokio::time::sleep(self.layer.message_timeout)));
        let metered = Metered {
            inner: body,
            buffer: self.layer.buffer.clone(),
            timeout: self.layer.message_timeout,
            framing: Framing::default(),
            held: 0,
            deadline,
            failed: false,
        };
        let future = self
            .inner
            .call(axum::http::Request::from_parts(parts, Body::new(metered)));
        Box::pin(async move {
            let response = future.await;
            drop(busy);
            response
        })
    }
}

/// Where the gRPC framing of a body stands: inside a 5-byte message header, or inside a
/// message with so many bytes to come.
#[derive(Debug, Default)]
struct Framing {
    header: [u8; 5],
    header_have: usize,
    remaining: usize,
    messages: u64,
}

impl Framing {
    /// Whether a message has begun and not ended.
    fn inside(&self) -> bool {
        self.header_have > 0 || self.remaining > 0
    }
}

/// A request body that holds its messages' bytes against the shared buffer.
struct Metered {
    inner: Body,
    buffer: Arc<RequestBuffer>,
    timeout: Duration,
    framing: Framing,
    /// Bytes of the message arriving, held against the buffer.
    held: usize,
    deadline: Option<Pin<Box<tokio::time::Sleep>>>,
    failed: bool,
}

impl Metered {
    fn release(&mut self) {
        self.buffer.give(self.held);
        self.held = 0;
        self.deadline = None;
    }

    /// Follows the framing through `data`, holding the bytes of an unfinished message.
    fn account(&mut self, mut data: &[u8]) -> Result<(), Status> {
        while !data.is_empty() {
            if self.framing.remaining == 0 {
                if self.framing.header_have == 0 && self.deadline.is_none() {
                    self.deadline = Some(Box::pin(tokio::time::sleep(self.timeout)));
                }
                let take = (5 - self.framing.header_have).min(data.len());
                let at = self.framing.header_have;
                self.framing.header[at..at + take].copy_from_slice(&data[..take]);
                self.hold(take)?;
                self.framing.header_have += take;
                data = &data[take..];
                if self.framing.header_have < 5 {
                    continue;
                }
                let flag = self.framing.header[0];
                // Bit 7 marks gRPC-Web trailers, which a request never carries.
                if flag > 1 {
                    return Err(Status::invalid_argument(format!(
                        "request message {}: compression flag {flag} (must be 0 or 1)",
                        self.framing.messages + 1
                    )));
                }
                let length = u32::from_be_bytes([
                    self.framing.header[1],
                    self.framing.header[2],
                    self.framing.header[3],
                    self.framing.header[4],
                ]) as usize;
                self.framing.header_have = 0;
                self.framing.remaining = length;
                if length == 0 {
                    self.framing.messages += 1;
                    self.release();
                }
                continue;
            }
            let take = self.framing.remaining.min(data.len());
            self.hold(take)?;
            self.framing.remaining -= take;
            data = &data[take..];
            if self.framing.remaining == 0 {
                self.framing.messages += 1;
                self.release();
            }
        }
        Ok(())
    }

    fn hold(&mut self, bytes: usize) -> Result<(), Status> {
        if !self.buffer.take(bytes) {
            return Err(Status::resource_exhausted(
                "the server's buffer for arriving request messages is full \
                 (request_buffer_mib); retry shortly",
            ));
        }
        self.held += bytes;
        Ok(())
    }

    fn fail(&mut self, status: Status) -> Poll<Option<Result<Frame<Bytes>, axum::BoxError>>> {
        self.failed = true;
        self.release();
        Poll::Ready(Some(Err(Box::new(status))))
    }
}

impl Drop for Metered {
    fn drop(&mut self) {
        self.release();
    }
}

impl HttpBody for Metered {
    type Data = Bytes;
    type Error = axum::BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        if self.failed {
            return Poll::Ready(None);
        }
        match Pin::new(&mut self.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(data) = frame.data_ref()
                    && let Err(status) = self.account(data)
                {
                    return self.fail(status);
                }
                Poll::Ready(Some(Ok(frame)))
            }
            // Whatever the transport or gRPC-Web's decoding says of the bytes the caller
            // sent (bad base64, a reset) is the caller's error.
            Poll::Ready(Some(Err(e))) => {
                let status = match e.into_inner().downcast::<Status>() {
                    // gRPC-Web's decoder calls bad base64 INTERNAL; it is what the caller sent.
                    Ok(status) if status.code() == tonic::Code::Internal => {
                        Status::invalid_argument(format!("request body: {}", status.message()))
                    }
                    Ok(status) => *status,
                    Err(e) => Status::invalid_argument(format!("request body: {e}")),
                };
                self.fail(status)
            }
            Poll::Ready(None) => {
                if self.framing.inside() {
                    let status = Status::invalid_argument(format!(
                        "request body ends inside message {} ({} bytes missing)",
                        self.framing.messages + 1,
                        if self.framing.remaining > 0 {
                            self.framing.remaining
                        } else {
                            5 - self.framing.header_have
                        }
                    ));
                    return self.fail(status);
                }
                self.release();
                Poll::Ready(None)
            }
            Poll::Pending => {
                let timed_out = self
                    .deadline
                    .as_mut()
                    .is_some_and(|d| d.as_mut().poll(cx).is_ready());
                if timed_out {
                    let (seconds, message) =
                        (self.timeout.as_secs_f64(), self.framing.messages + 1);
                    return self.fail(Status::deadline_exceeded(format!(
                        "request message {message} did not arrive whole within {seconds} s of \
                         its first byte (message_read_timeout_s)"
                    )));
                }
                Poll::Pending
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.failed || self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metered(buffer: &Arc<RequestBuffer>) -> Metered {
        Metered {
            inner: Body::empty(),
            buffer: buffer.clone(),
            timeout: Duration::from_secs(10),
            framing: Framing::default(),
            held: 0,
            deadline: None,
            failed: false,
        }
    }

    fn message(payload: &[u8]) -> Vec<u8> {
        let mut out = vec![0];
        out.extend((payload.len() as u32).to_be_bytes());
        out.extend(payload);
        out
    }

    #[tokio::test]
    async fn unfinished_messages_are_held_and_finished_ones_given_back_in_any_split() {
        let buffer = RequestBuffer::new(1 << 20);
        let mut body = message(&[7; 300]);
        body.extend(message(&[]));
        body.extend(message(&[1; 50]));
        // Every split of the body into two chunks frames the same.
        for cut in 0..body.len() {
            let mut m = metered(&buffer);
            m.account(&body[..cut]).unwrap();
            assert_eq!(buffer.held(), m.held);
            m.account(&body[cut..]).unwrap();
            assert_eq!(m.framing.messages, 3, "cut at {cut}");
            assert_eq!(buffer.held(), 0, "cut at {cut}");
        }
        // Half a message is held until it is dropped.
        let mut m = metered(&buffer);
        m.account(&message(&[0; 1000])[..600]).unwrap();
        assert_eq!(buffer.held(), 600);
        drop(m);
        assert_eq!(buffer.held(), 0);
    }

    #[tokio::test]
    async fn the_shared_buffer_refuses_past_its_limit_and_bad_flags_are_invalid() {
        let buffer = RequestBuffer::new(1000);
        let mut a = metered(&buffer);
        a.account(&message(&[0; 5000])[..900]).unwrap();
        let mut b = metered(&buffer);
        let full = b.account(&message(&[0; 5000])[..200]).unwrap_err();
        assert_eq!(full.code(), tonic::Code::ResourceExhausted);
        assert!(full.message().contains("request_buffer_mib"));
        drop(a);
        drop(b);
        assert_eq!(buffer.held(), 0);
        let mut c = metered(&buffer);
        let flag = c.account(&[2, 0, 0, 0, 1, 9]).unwrap_err();
        assert_eq!(flag.code(), tonic::Code::InvalidArgument);
        assert!(flag.message().contains("compression flag 2"));
    }
}
