//! A slow link for one viewer: the reader takes at most `kbps` kbit/s from its socket
//! (a token bucket), so the kernel's receive buffer fills and the server meets the same
//! back-pressure as from a real slow client. Writes (poses, acks) pass through.

use std::future::Future as _;
use std::io;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::{Instant, Sleep};

/// Largest read the bucket grants at once: 50 ms of the rate (at least one 1500-byte
/// packet), so the bytes arrive evenly rather than in bursts.
const BURST_S: f64 = 0.05;
const MIN_BURST_BYTES: f64 = 1500.0;

/// `inner`, its reads limited to a byte rate (or not at all). Hand it to
/// `tokio_tungstenite::client_async` as the stream under a WebSocket.
pub struct Throttled<S> {
    inner: S,
    bucket: Option<Bucket>,
}

struct Bucket {
    bytes_per_s: f64,
    burst_bytes: f64,
    tokens: f64,
    refilled_at: Instant,
    sleep: Pin<Box<Sleep>>,
    scratch: Vec<u8>,
}

impl Bucket {
    fn refill(&mut self) {
        let now = Instant::now();
        let earned = now.duration_since(self.refilled_at).as_secs_f64() * self.bytes_per_s;
        self.tokens = (self.tokens + earned).min(self.burst_bytes);
        self.refilled_at = now;
    }
}

impl<S> Throttled<S> {
    /// Reads limited to `kbps` kbit/s (1000 bits per kbit); `None` passes everything through.
    pub fn new(inner: S, kbps: Option<u32>) -> Throttled<S> {
        let bucket = kbps.map(|kbps| {
            let bytes_per_s = f64::from(kbps.max(1)) * 1000.0 / 8.0;
            let burst_bytes = (bytes_per_s * BURST_S).max(MIN_BURST_BYTES);
            Bucket {
                bytes_per_s,
                burst_bytes,
                // Start empty: the first grant comes after a burst's worth of time.
                tokens: 0.0,
                refilled_at: Instant::now(),
                sleep: Box::pin(tokio::time::sleep(Duration::ZERO)),
                scratch: vec![0; burst_bytes.ceil() as usize],
            }
        });
        Throttled { inner, bucket }
    }

    /// The wrapped stream.
    pub fn get_ref(&self) -> &S {
        &self.inner
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Throttled<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let Some(b) = this.bucket.as_mut() else {
            return Pin::new(&mut this.inner).poll_read(cx, buf);
        };
        loop {
            b.refill();
            if b.tokens >= 1.0 {
                break;
            }
            // Wait for half a burst rather than waking for every byte.
            let wait_s = (b.burst_bytes / 2.0 - b.tokens) / b.bytes_per_s;
            b.sleep
                .as_mut()
                .reset(Instant::now() + Duration::from_secs_f64(wait_s));
            ready!(b.sleep.as_mut().poll(cx));
        }
        let allowed = (b.tokens as usize)
            .min(buf.remaining())
            .min(b.scratch.len());
        let mut limited = ReadBuf::new(&mut b.scratch[..allowed]);
        ready!(Pin::new(&mut this.inner).poll_read(cx, &mut limited))?;
        let n = limited.filled().len();
        buf.put_slice(limited.filled());
        b.tokens -= n as f64;
        Poll::Ready(Ok(()))
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Throttled<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().inner).poll_write(cx, data)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.get_mut().inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}
