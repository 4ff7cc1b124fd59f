//! Bounded frame streams: a stream encodes a frame only when the transport asks for the next
//! one, so it holds at most two (one in the transport's buffers, one waiting); the frames of all streams together hold at most a byte
//! budget (past it, frames are withheld and counted as skipped); and a reader that takes no
//! frame for the stall timeout has its connection cut, which frees what the transport held.

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use cathlab_api::{mode_to_wire, pb, status_of};
use cathlab_engine::session::RenderedFrame;
use cathlab_engine::{Encoded, Encoding, EngineMetrics, encode_in_pool};
use parking_lot::Mutex;
use tokio::sync::oneshot;
use tokio_stream::Stream;
use tokio_stream::wrappers::WatchStream;
use tonic::Status;

use crate::connections::Cutter;

/// Bytes the streams' encoded frames may hold together, and the share of them one client
/// address may hold (a quarter), so that one client's stalled streams cannot starve others'.
#[derive(Debug)]
pub struct StreamBudget {
    used: AtomicUsize,
    limit: usize,
    by_address: Mutex<HashMap<IpAddr, usize>>,
    metrics: EngineMetrics,
}

impl StreamBudget {
    /// A budget of `limit` bytes, reported in `metrics.stream_buffer_bytes`.
    pub fn new(limit: usize, metrics: EngineMetrics) -> Arc<Self> {
        Arc::new(Self {
            used: AtomicUsize::new(0),
            limit,
            by_address: Mutex::default(),
            metrics,
        })
    }

    /// The most one address may hold.
    pub fn per_address(&self) -> usize {
        self.limit / 4
    }

    /// Bytes held now.
    pub fn used(&self) -> usize {
        self.used.load(Ordering::Relaxed)
    }

    /// `bytes` of the budget for a stream of `address`, or `None` when they do not fit in the
    /// budget or in the address's share.
    pub fn try_reserve(self: &Arc<Self>, address: IpAddr, bytes: usize) -> Option<BytesPermit> {
        let mut by_address = self.by_address.lock();
        let held = by_address.get(&address).copied().unwrap_or(0);
        if held + bytes > self.per_address() {
            return None;
        }
        self.used
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |used| {
                (used + bytes <= self.limit).then_some(used + bytes)
            })
            .ok()?;
        by_address.insert(address, held + bytes);
        self.metrics.stream_buffer_bytes.inc_by(bytes as i64);
        Some(BytesPermit {
            budget: self.clone(),
            address,
            bytes,
        })
    }
}

/// Bytes taken from a [`StreamBudget`], given back when dropped.
#[derive(Debug)]
pub struct BytesPermit {
    budget: Arc<StreamBudget>,
    address: IpAddr,
    bytes: usize,
}

impl BytesPermit {
    /// Gives back all but `bytes` (no-op when it holds fewer).
    pub fn shrink_to(&mut self, bytes: usize) {
        if bytes < self.bytes {
            let freed = self.bytes - bytes;
            let mut by_address = self.budget.by_address.lock();
            match by_address.get_mut(&self.address) {
                Some(held) if *held > freed => *held -= freed,
                _ => {
                    by_address.remove(&self.address);
                }
            }
            self.budget.used.fetch_sub(freed, Ordering::AcqRel);
            self.budget.metrics.stream_buffer_bytes.dec_by(freed as i64);
            self.bytes = bytes;
        }
    }
}

impl Drop for BytesPermit {
    fn drop(&mut self) {
        self.shrink_to(0);
    }
}

/// What a reader asked for.
#[derive(Debug, Clone, Copy)]
pub struct FrameRequest {
    /// Encoding.
    pub encoding: Encoding,
    /// Size (0 × 0: the detector's).
    pub width: u32,
    /// Size (0 × 0: the detector's).
    pub height: u32,
}

impl FrameRequest {
    /// Bytes reserved to encode `frame` (an upper bound for the compressed encodings).
    fn bytes_for(&self, frame: &RenderedFrame) -> usize {
        let (w, h) = if self.width == 0 {
            (frame.frame.width, frame.frame.height)
        } else {
            (self.width, self.height)
        };
        let per_pixel = if self.encoding == Encoding::Raw16 {
            2
        } else {
            1
        };
        (w as usize) * (h as usize) * per_pixel + 1024
    }
}

struct Pending {
    encoded: oneshot::Receiver<Encoded>,
    frame: Arc<RenderedFrame>,
    permit: BytesPermit,
    skipped: u64,
}

/// When the last frame was handed to the transport, and its index.
type Handed = Arc<Mutex<Option<(Instant, u64)>>>;

/// A session's frames as one reader asked for them.
pub struct FrameStream {
    frames: WatchStream<Option<Arc<RenderedFrame>>>,
    request: FrameRequest,
    budget: Arc<StreamBudget>,
    metrics: EngineMetrics,
    last_index: Option<u64>,
    pending: Option<Pending>,
    /// The permits of the last two frames handed to the transport: when it asks for the next
    /// frame, the last one may still sit in its buffers (it asks once the stream has send
    /// capacity, not once the frame is out), the one before is gone.
    held: VecDeque<BytesPermit>,
    handed: Handed,
    address: IpAddr,
}

impl FrameStream {
    /// A stream of `frames` for a reader at `address`; when a frame waits for its reader
    /// longer than `stall`, the reader's connection is cut with `cutter` (in-process callers
    /// have none).
    pub fn new(
        frames: tokio::sync::watch::Receiver<Option<Arc<RenderedFrame>>>,
        request: FrameRequest,
        budget: Arc<StreamBudget>,
        (address, stall, cutter): (IpAddr, Duration, Option<Cutter>),
    ) -> Self {
        let handed: Handed = Arc::default();
        let metrics = budget.metrics.clone();
        if let Some(cutter) = cutter {
            tokio::spawn(watch_for_stall(
                Arc::downgrade(&handed),
                frames.clone(),
                stall,
                cutter,
                metrics.clone(),
            ));
        }
        Self {
            frames: WatchStream::new(frames),
            request,
            budget,
            metrics,
            last_index: None,
            pending: None,
            held: VecDeque::with_capacity(2),
            handed,
            address,
        }
    }

    fn message(&self, frame: &RenderedFrame, data: Vec<u8>, w: u32, h: u32) -> pb::XrayFrame {
        pb::XrayFrame {
            index: frame.frame.index,
            time_s: frame.frame.time_s,
            width: w,
            height: h,
            encoding: match self.request.encoding {
                Encoding::Raw8 => pb::FrameEncoding::Raw8,
                Encoding::Raw16 => pb::FrameEncoding::Raw16,
                Encoding::Png => pb::FrameEncoding::Png,
                Encoding::Jpeg(_) => pb::FrameEncoding::Jpeg,
            } as i32,
            data,
            mode: mode_to_wire(frame.frame.mode) as i32,
            held: frame.frame.held,
            last_seq: frame.last_seq,
            skipped: 0,
            reference_air_kerma_mgy: frame.dose.reference_air_kerma_mgy,
            kerma_area_product_gy_cm2: frame.dose.kerma_area_product_gy_cm2,
            target_outline: frame.target_outline.iter().flatten().copied().collect(),
        }
    }
}

/// Checks a stream every quarter of `stall`: when its last frame was handed over longer than
/// `stall` ago and newer frames exist, its reader is not keeping up (the frame may still sit
/// in the transport's buffers, holding its part of the budget), and the connection is cut.
/// A stream of a session that shows no new frames (the pedal up) is never cut. Ends with the
/// stream.
async fn watch_for_stall(
    handed: std::sync::Weak<Mutex<Option<(Instant, u64)>>>,
    frames: tokio::sync::watch::Receiver<Option<Arc<RenderedFrame>>>,
    stall: Duration,
    cutter: Cutter,
    metrics: EngineMetrics,
) {
    loop {
        tokio::time::sleep(stall / 4).await;
        let Some(handed) = handed.upgrade() else {
            return;
        };
        let last = *handed.lock();
        let newest = frames.borrow().as_ref().map(|f| f.frame.index);
        if let (Some((at, index)), Some(newest)) = (last, newest)
            && at.elapsed() > stall
            && newest > index
        {
            tracing::warn!(
                waited_s = at.elapsed().as_secs_f64(),
                frames_behind = newest - index,
                "a frame stream's reader stalled: its connection is cut"
            );
            if cutter.cut() {
                metrics.stalled_streams_cut.inc();
            }
            return;
        }
    }
}

impl Stream for FrameStream {
    type Item = Result<pb::XrayFrame, Status>;

    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        let this = self.get_mut();
        // Asked for the next: the one before the last has left the transport.
        if this.held.len() == 2 {
            this.held.pop_front();
        }
        loop {
            if let Some(pending) = &mut this.pending {
                let encoded = ready!(Pin::new(&mut pending.encoded).poll(cx));
                let Pending {
                    frame,
                    mut permit,
                    skipped,
                    ..
                } = this.pending.take().expect("pending");
                let message = match encoded {
                    Ok(Ok((data, w, h))) => {
                        permit.shrink_to(data.len() + 1024);
                        Ok(pb::XrayFrame {
                            skipped,
                            ..this.message(&frame, data, w, h)
                        })
                    }
                    Ok(Err(e)) => Err(status_of(&e)),
                    Err(_) => Err(Status::internal("the frame encoder went away")),
                };
                this.held.push_back(permit);
                *this.handed.lock() = Some((Instant::now(), frame.frame.index));
                this.metrics.frames_sent.inc();
                this.metrics.frames_skipped.inc_by(skipped);
                return Poll::Ready(Some(message));
            }
            let Some(frame) = ready!(Pin::new(&mut this.frames).poll_next(cx)) else {
                return Poll::Ready(None);
            };
            let Some(frame) = frame else {
                continue;
            };
            let Some(permit) = this
                .budget
                .try_reserve(this.address, this.request.bytes_for(&frame))
            else {
                this.metrics.frames_withheld.inc();
                continue;
            };
            let skipped = match this.last_index {
                Some(i) if frame.frame.index > i + 1 => frame.frame.index - i - 1,
                _ => 0,
            };
            this.last_index = Some(frame.frame.index);
            let FrameRequest {
                encoding,
                width,
                height,
            } = this.request;
            this.pending = Some(Pending {
                encoded: encode_in_pool(frame.clone(), encoding, width, height),
                frame,
                permit,
                skipped,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_budget_is_never_overdrawn_and_comes_back() {
        let budget = StreamBudget::new(400, EngineMetrics::default());
        let address = |i: u8| IpAddr::from([10, 0, 0, i]);
        let a = budget.try_reserve(address(1), 60).expect("fits");
        // One address holds at most a quarter.
        assert!(budget.try_reserve(address(1), 41).is_none());
        let mut b = budget
            .try_reserve(address(1), 40)
            .expect("fits its share exactly");
        let others: Vec<_> = (2..5)
            .map(|i| budget.try_reserve(address(i), 100).expect("its own share"))
            .collect();
        assert_eq!(budget.used(), 400);
        assert!(
            budget.try_reserve(address(9), 1).is_none(),
            "the budget is spent"
        );
        b.shrink_to(10);
        assert_eq!(budget.used(), 370);
        assert!(budget.try_reserve(address(1), 31).is_none());
        let c = budget
            .try_reserve(address(1), 30)
            .expect("what shrinking gave back");
        drop((a, b, c, others));
        assert_eq!(budget.used(), 0);
        assert!(budget.by_address.lock().is_empty());
        assert_eq!(budget.metrics.stream_buffer_bytes.get(), 0);
    }

    #[test]
    fn concurrent_reservations_stay_within_the_budget() {
        let budget = StreamBudget::new(1000, EngineMetrics::default());
        let peak = Arc::new(AtomicUsize::new(0));
        std::thread::scope(|s| {
            for t in 0..8u8 {
                let (budget, peak) = (budget.clone(), peak.clone());
                s.spawn(move || {
                    for i in 0..10_000 {
                        let address = IpAddr::from([10, 0, 0, t % 5]);
                        if let Some(p) = budget.try_reserve(address, 1 + i % 200) {
                            peak.fetch_max(budget.used(), Ordering::Relaxed);
                            drop(p);
                        }
                    }
                });
            }
        });
        assert!(peak.load(Ordering::Relaxed) <= 1000);
        assert_eq!(budget.used(), 0);
    }
}
