//! The connections the server accepts: at most so many in all and from one address, each
//! closed when it passes no byte either way for the idle timeout, and each with a handle
//! that can cut it (a reader that stalls a stream past its timeout loses its connection, and
//! with it everything the transport had buffered for it). One file descriptor a connection.

use std::collections::HashMap;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use parking_lot::Mutex;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio::time::{Instant, Sleep};
use tokio_stream::{Stream, StreamExt};
use tonic::transport::server::{Connected, TcpConnectInfo, TlsConnectInfo};

/// A proxy's address, or a range of them (`10.0.0.0/8`, `fd00::/8`, `127.0.0.1`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(try_from = "String")]
pub struct ProxyRange {
    network: IpAddr,
    prefix: u8,
}

impl TryFrom<String> for ProxyRange {
    type Error = String;

    fn try_from(text: String) -> Result<Self, String> {
        text.parse()
    }
}

impl std::str::FromStr for ProxyRange {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || format!("{text:?} is not an IP address or a range such as 10.0.0.0/8");
        let (address, prefix) = match text.split_once('/') {
            Some((a, p)) => (a, Some(p.parse::<u8>().map_err(|_| bad())?)),
            None => (text, None),
        };
        let network: IpAddr = address.trim().parse().map_err(|_| bad())?;
        let bits = if network.is_ipv4() { 32 } else { 128 };
        let prefix = prefix.unwrap_or(bits);
        if prefix > bits {
            return Err(bad());
        }
        Ok(Self { network, prefix })
    }
}

impl ProxyRange {
    /// Whether `address` is in the range.
    pub fn contains(&self, address: IpAddr) -> bool {
        let (a, n, bits) = match (address, self.network) {
            (IpAddr::V4(a), IpAddr::V4(n)) => {
                (u128::from(a.to_bits()), u128::from(n.to_bits()), 32)
            }
            (IpAddr::V6(a), IpAddr::V6(n)) => (a.to_bits(), n.to_bits(), 128),
            (IpAddr::V6(a), IpAddr::V4(n)) => match a.to_ipv4_mapped() {
                Some(a) => (u128::from(a.to_bits()), u128::from(n.to_bits()), 32),
                None => return false,
            },
            (IpAddr::V4(_), IpAddr::V6(_)) => return false,
        };
        let shift = bits - u32::from(self.prefix);
        shift >= 128 || (a >> shift) == (n >> shift)
    }
}

/// Whether `address` is one of `proxies`.
pub fn is_trusted(proxies: &[ProxyRange], address: IpAddr) -> bool {
    proxies.iter().any(|r| r.contains(address))
}

/// How many connections may be open, and for how long one may be idle.
#[derive(Debug, Clone)]
pub struct ConnectionLimits {
    /// Most connections open at once.
    pub max_total: usize,
    /// Most connections open at once from one address (trusted proxies are not limited).
    pub max_per_address: usize,
    /// A connection that passes no byte either way for this long is closed.
    pub idle_timeout: Duration,
    /// Proxies whose `X-Forwarded-For` header names the real client.
    pub trusted_proxies: Vec<ProxyRange>,
}

/// What cutting a connection and its transport's tasks share: whether it was cut, and who
/// waits on it.
#[derive(Debug, Default)]
struct Shared {
    cut: AtomicBool,
    wakers: Mutex<[Option<Waker>; 2]>,
    /// Requests whose handler is still working (a scene loading): not idle meanwhile.
    busy: AtomicUsize,
}

impl Shared {
    fn cut(&self) -> bool {
        let was = self.cut.swap(true, Ordering::SeqCst);
        for waker in self.wakers.lock().iter_mut() {
            if let Some(w) = waker.take() {
                w.wake();
            }
        }
        !was
    }

    fn is_cut(&self) -> bool {
        self.cut.load(Ordering::SeqCst)
    }

    fn park(&self, slot: usize, cx: &Context<'_>) {
        let mut wakers = self.wakers.lock();
        match &wakers[slot] {
            Some(w) if w.will_wake(cx.waker()) => {}
            _ => wakers[slot] = Some(cx.waker().clone()),
        }
    }
}

/// Cuts one connection: its reads and writes fail from then on, so the transport sees it
/// end, drops its streams and frees their buffers. Cutting a connection that already ended
/// does nothing.
#[derive(Debug, Clone)]
pub struct Cutter(Arc<Shared>);

impl Cutter {
    /// Cuts the connection; returns whether it was still open.
    pub fn cut(&self) -> bool {
        self.0.cut()
    }
}

/// Counts a connection busy while it lives (a request whose handler is working).
#[derive(Debug)]
pub struct Busy(Arc<Shared>);

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.busy.fetch_sub(1, Ordering::SeqCst);
    }
}

impl Peer {
    /// Counts the connection busy (never idle) until the guard drops.
    pub fn busy(&self) -> Busy {
        self.cutter.0.busy.fetch_add(1, Ordering::SeqCst);
        Busy(self.cutter.0.clone())
    }
}

/// What a request knows of its connection: the addresses, and the handle that cuts it.
#[derive(Debug, Clone)]
pub struct Peer {
    /// Local and remote addresses.
    pub tcp: TcpConnectInfo,
    /// Cuts the connection.
    pub cutter: Cutter,
    /// Whether the remote end is a trusted proxy (its `X-Forwarded-For` is believed).
    pub trusted_proxy: bool,
}

/// The connection a request came on (absent for in-process calls).
pub fn peer<T>(request: &tonic::Request<T>) -> Option<&Peer> {
    let extensions = request.extensions();
    extensions.get::<Peer>().or_else(|| {
        extensions
            .get::<TlsConnectInfo<Peer>>()
            .map(|info| info.get_ref())
    })
}

/// The caller's address: the connection's remote address, or, when that is a trusted
/// proxy, the nearest address its `X-Forwarded-For` header names (unspecified for
/// in-process callers).
pub fn address<T>(request: &tonic::Request<T>) -> IpAddr {
    let peer = peer(request);
    let remote = peer
        .and_then(|p| p.tcp.remote_addr)
        .or_else(|| request.remote_addr())
        .map_or(IpAddr::from([0, 0, 0, 0]), |a: SocketAddr| a.ip());
    if peer.is_some_and(|p| p.trusted_proxy)
        && let Some(forwarded) = request
            .metadata()
            .get("x-forwarded-for")
            .and_then(|v| v.to_str().ok())
        && let Some(client) = forwarded_client(forwarded)
    {
        return client;
    }
    remote
}

/// The client a proxy's `X-Forwarded-For` names: its last entry (the one the proxy itself
/// added; earlier ones are the client's own word).
fn forwarded_client(header: &str) -> Option<IpAddr> {
    header.rsplit(',').next().and_then(|last| {
        let last = last.trim();
        last.parse::<IpAddr>()
            .ok()
            .or_else(|| last.parse::<SocketAddr>().ok().map(|a| a.ip()))
    })
}

/// The open connections, counted in all and per address.
#[derive(Debug, Default)]
struct Open {
    total: usize,
    per_address: HashMap<IpAddr, usize>,
}

/// Counts open connections against the limits.
#[derive(Debug)]
pub struct Admission {
    limits: ConnectionLimits,
    open: Mutex<Open>,
}

/// A connection's place among the open ones, given back when it closes.
#[derive(Debug)]
struct Place {
    admission: Arc<Admission>,
    address: IpAddr,
}

impl Drop for Place {
    fn drop(&mut self) {
        let mut open = self.admission.open.lock();
        open.total -= 1;
        if let Some(n) = open.per_address.get_mut(&self.address) {
            *n -= 1;
            if *n == 0 {
                open.per_address.remove(&self.address);
            }
        }
    }
}

impl Admission {
    /// Counts connections against `limits`.
    pub fn new(limits: ConnectionLimits) -> Arc<Self> {
        Arc::new(Self {
            limits,
            open: Mutex::new(Open::default()),
        })
    }

    /// Connections open now (in all).
    pub fn open(&self) -> usize {
        self.open.lock().total
    }

    /// A place for a connection from `address`, or why there is none.
    fn admit(self: &Arc<Self>, address: IpAddr) -> Result<Place, &'static str> {
        let mut open = self.open.lock();
        if open.total >= self.limits.max_total {
            return Err("the server's connections are all taken (max_connections)");
        }
        let trusted = is_trusted(&self.limits.trusted_proxies, address);
        let from = open.per_address.get(&address).copied().unwrap_or(0);
        if !trusted && from >= self.limits.max_per_address {
            return Err(
                "this address has all the connections it may (max_connections_per_address)",
            );
        }
        open.total += 1;
        *open.per_address.entry(address).or_insert(0) += 1;
        Ok(Place {
            admission: self.clone(),
            address,
        })
    }
}

/// An accepted TCP connection that can be cut from elsewhere and closes itself when idle.
#[derive(Debug)]
pub struct Tracked {
    inner: TcpStream,
    shared: Arc<Shared>,
    trusted_proxy: bool,
    idle_timeout: Duration,
    idle: Pin<Box<Sleep>>,
    last_active: Instant,
    _place: Place,
}

impl Tracked {
    fn active(&mut self) {
        self.last_active = Instant::now();
    }

    /// Whether the connection is to end: cut, or idle past its timeout (then it is cut).
    /// Registers `cx` to be woken at either.
    fn ended(&mut self, slot: usize, cx: &mut Context<'_>) -> Option<io::Error> {
        self.shared.park(slot, cx);
        if self.shared.is_cut() {
            return Some(io::Error::new(
                io::ErrorKind::ConnectionAborted,
                "connection cut by the server",
            ));
        }
        if self.shared.busy.load(Ordering::SeqCst) > 0 {
            // A handler is working: the connection is waiting on the server, not idle.
            self.active();
        }
        loop {
            let deadline = self.last_active + self.idle_timeout;
            if Instant::now() >= deadline {
                self.shared.cut();
                return Some(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "connection idle past connection_idle_timeout_s",
                ));
            }
            if self.idle.deadline() != deadline {
                self.idle.as_mut().reset(deadline);
            }
            if self.idle.as_mut().poll(cx).is_pending() {
                return None;
            }
        }
    }
}

impl Tracked {
    /// One write through `write`: refused once cut, counted as activity when it moved bytes,
    /// and, while the socket cannot take more, ended when cut or idle past the timeout.
    fn write_with(
        &mut self,
        cx: &mut Context<'_>,
        write: impl FnOnce(&mut TcpStream, &mut Context<'_>) -> Poll<io::Result<usize>>,
    ) -> Poll<io::Result<usize>> {
        if self.shared.is_cut() {
            return Poll::Ready(Err(io::ErrorKind::ConnectionAborted.into()));
        }
        match write(&mut self.inner, cx) {
            Poll::Ready(Ok(n)) => {
                if n > 0 {
                    self.active();
                }
                Poll::Ready(Ok(n))
            }
            Poll::Ready(Err(e)) => Poll::Ready(Err(e)),
            Poll::Pending => match self.ended(1, cx) {
                Some(e) => Poll::Ready(Err(e)),
                None => Poll::Pending,
            },
        }
    }
}

impl Connected for Tracked {
    type ConnectInfo = Peer;

    fn connect_info(&self) -> Peer {
        Peer {
            tcp: self.inner.connect_info(),
            cutter: Cutter(self.shared.clone()),
            trusted_proxy: self.trusted_proxy,
        }
    }
}

impl AsyncRead for Tracked {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if self.shared.is_cut() {
            return Poll::Ready(Err(io::ErrorKind::ConnectionAborted.into()));
        }
        let before = buf.filled().len();
        match Pin::new(&mut self.inner).poll_read(cx, buf) {
            Poll::Ready(result) => {
                if buf.filled().len() > before {
                    self.active();
                }
                Poll::Ready(result)
            }
            Poll::Pending => match self.ended(0, cx) {
                Some(e) => Poll::Ready(Err(e)),
                None => Poll::Pending,
            },
        }
    }
}

impl AsyncWrite for Tracked {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.write_with(cx, |inner, cx| Pin::new(inner).poll_write(cx, buf))
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        self.write_with(cx, |inner, cx| {
            Pin::new(inner).poll_write_vectored(cx, bufs)
        })
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

/// Whether an accept error is the process running out of file descriptors.
fn out_of_descriptors(e: &io::Error) -> bool {
    // EMFILE (the process's limit) and ENFILE (the system's).
    matches!(e.raw_os_error(), Some(24) | Some(23))
}

/// The accepted connections of `incoming` within `admission`'s limits, tracked: one over a
/// limit is closed at once (and logged); running out of file descriptors is logged as what
/// it is and accepting pauses briefly rather than spinning.
pub fn tracked(
    incoming: impl Stream<Item = io::Result<TcpStream>>,
    admission: Arc<Admission>,
) -> impl Stream<Item = io::Result<Tracked>> {
    incoming
        .then(|accepted| async move {
            if let Err(e) = &accepted
                && out_of_descriptors(e)
            {
                tracing::warn!(
                    "out of file descriptors: a connection waits (raise the descriptor limit \
                     or lower max_connections): {e}"
                );
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            accepted
        })
        .filter_map(move |accepted| {
            let stream = match accepted {
                Ok(stream) => stream,
                // Errors of one accept (a connection reset before it was taken, no
                // descriptor): the server goes on.
                Err(e) => {
                    tracing::debug!("accept: {e}");
                    return None;
                }
            };
            let address = stream
                .peer_addr()
                .map_or(IpAddr::from([0, 0, 0, 0]), |a| a.ip());
            match admission.admit(address) {
                Ok(place) => {
                    let idle_timeout = admission.limits.idle_timeout;
                    Some(Ok(Tracked {
                        inner: stream,
                        shared: Arc::new(Shared::default()),
                        trusted_proxy: is_trusted(&admission.limits.trusted_proxies, address),
                        idle_timeout,
                        idle: Box::pin(tokio::time::sleep(idle_timeout)),
                        last_active: Instant::now(),
                        _place: place,
                    }))
                }
                Err(why) => {
                    tracing::warn!(%address, "connection refused: {why}");
                    None
                }
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::str::FromStr;

    #[test]
    fn proxy_ranges_hold_their_addresses_only() {
        let pods = ProxyRange::from_str("10.0.0.0/8").unwrap();
        assert!(pods.contains("10.42.7.3".parse().unwrap()));
        assert!(!pods.contains("11.0.0.1".parse().unwrap()));
        assert!(pods.contains("::ffff:10.1.2.3".parse().unwrap()));
        let one = ProxyRange::from_str("127.0.0.1").unwrap();
        assert!(one.contains("127.0.0.1".parse().unwrap()));
        assert!(!one.contains("127.0.0.2".parse().unwrap()));
        let v6 = ProxyRange::from_str("fd00::/8").unwrap();
        assert!(
            v6.contains("fd12::1".parse().unwrap()) && !v6.contains("fe80::1".parse().unwrap())
        );
        assert!(
            ProxyRange::from_str("0.0.0.0/0")
                .unwrap()
                .contains("8.8.8.8".parse().unwrap())
        );
        for bad in ["10.0.0.0/33", "ten", "10.0.0.0/x"] {
            assert!(
                ProxyRange::from_str(bad)
                    .unwrap_err()
                    .contains("not an IP address")
            );
        }
    }

    #[test]
    fn the_forwarded_client_is_the_proxys_own_entry() {
        assert_eq!(
            forwarded_client("203.0.113.9"),
            Some("203.0.113.9".parse().unwrap())
        );
        // A client can write any entries before the proxy's; only the last is believed.
        assert_eq!(
            forwarded_client("1.2.3.4, 198.51.100.7"),
            Some("198.51.100.7".parse().unwrap())
        );
        assert_eq!(forwarded_client("garbage"), None);
    }

    #[test]
    fn places_are_counted_in_all_and_per_address_and_given_back() {
        let proxy: IpAddr = "10.0.0.9".parse().unwrap();
        let admission = Admission::new(ConnectionLimits {
            max_total: 3,
            max_per_address: 2,
            idle_timeout: Duration::from_secs(1),
            trusted_proxies: vec![ProxyRange::from_str("10.0.0.9").unwrap()],
        });
        let a: IpAddr = "10.0.0.1".parse().unwrap();
        let first = admission.admit(a).unwrap();
        let _second = admission.admit(a).unwrap();
        assert!(admission.admit(a).unwrap_err().contains("per_address"));
        let _third = admission.admit(proxy).unwrap();
        assert!(
            admission
                .admit(proxy)
                .unwrap_err()
                .contains("max_connections")
        );
        drop(first);
        assert_eq!(admission.open(), 2);
        assert!(
            admission.admit(a).is_ok(),
            "a place given back is free again"
        );
    }
}
