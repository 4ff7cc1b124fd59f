//! The connections the server accepts, each with a handle that can cut it: a reader that
//! stalls a stream past its timeout loses its connection, and with it everything the
//! transport had buffered for it.

use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use parking_lot::Mutex;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio_stream::{Stream, StreamExt};
use tonic::transport::server::{Connected, TcpConnectInfo, TlsConnectInfo};

/// Cuts one connection (both directions shut down: the transport sees it end, drops its
/// streams and frees their buffers). Cutting a connection that already ended does nothing.
#[derive(Debug, Clone)]
pub struct Cutter(Arc<Mutex<Option<std::net::TcpStream>>>);

impl Cutter {
    /// Shuts the connection down; returns whether it was still open.
    pub fn cut(&self) -> bool {
        match self.0.lock().take() {
            Some(socket) => socket.shutdown(std::net::Shutdown::Both).is_ok(),
            None => false,
        }
    }
}

/// What a request knows of its connection: the addresses, and the handle that cuts it.
#[derive(Debug, Clone)]
pub struct Peer {
    /// Local and remote addresses.
    pub tcp: TcpConnectInfo,
    /// Cuts the connection.
    pub cutter: Cutter,
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

/// The caller's address (unspecified for in-process callers).
pub fn address<T>(request: &tonic::Request<T>) -> IpAddr {
    peer(request)
        .and_then(|p| p.tcp.remote_addr)
        .or_else(|| request.remote_addr())
        .map_or(IpAddr::from([0, 0, 0, 0]), |a: SocketAddr| a.ip())
}

/// An accepted TCP connection that can be cut from elsewhere.
#[derive(Debug)]
pub struct Tracked {
    inner: TcpStream,
    cutter: Cutter,
}

impl Tracked {
    /// Wraps an accepted stream. A duplicate of its socket is kept to shut it down with.
    pub fn new(inner: TcpStream) -> io::Result<Self> {
        let std = inner.into_std()?;
        let handle = std.try_clone()?;
        let inner = TcpStream::from_std(std)?;
        Ok(Self {
            inner,
            cutter: Cutter(Arc::new(Mutex::new(Some(handle)))),
        })
    }
}

impl Drop for Tracked {
    fn drop(&mut self) {
        // The duplicate goes with the connection (it would keep the socket open).
        self.cutter.0.lock().take();
    }
}

impl Connected for Tracked {
    type ConnectInfo = Peer;

    fn connect_info(&self) -> Peer {
        Peer {
            tcp: self.inner.connect_info(),
            cutter: self.cutter.clone(),
        }
    }
}

impl AsyncRead for Tracked {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl AsyncWrite for Tracked {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
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
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

/// The accepted connections of `incoming`, tracked.
pub fn tracked(
    incoming: impl Stream<Item = io::Result<TcpStream>>,
) -> impl Stream<Item = io::Result<Tracked>> {
    incoming.map(|accepted| accepted.and_then(Tracked::new))
}
