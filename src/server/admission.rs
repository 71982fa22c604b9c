//! Who may connect, before anyone is authenticated: connections that have not completed
//! a hello (half-sent HTTP requests, upgrades waiting for a hello) are capped per IP
//! address and in total — they never count against the sessions' capacity — and failed
//! tokens put their address on an exponential back-off.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, Ordering::AcqRel};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Connections not yet past their hello, per address.
pub(crate) struct Pending {
    per_ip: Mutex<HashMap<IpAddr, usize>>,
    max_per_ip: usize,
    max_total: usize,
}

/// One pending connection's place; released after a hello, or when dropped.
pub(crate) struct PendingSlot {
    pending: Arc<Pending>,
    ip: IpAddr,
    released: AtomicBool,
}

impl Pending {
    pub(crate) fn new(max_per_ip: usize, max_total: usize) -> Arc<Pending> {
        Arc::new(Pending {
            per_ip: Mutex::new(HashMap::new()),
            max_per_ip,
            max_total,
        })
    }

    /// A place for a new connection from `ip`, or `None` when its address (or everyone)
    /// already has as many pending connections as allowed.
    pub(crate) fn try_acquire(self: &Arc<Pending>, ip: IpAddr) -> Option<PendingSlot> {
        let mut map = lock(&self.per_ip);
        let total: usize = map.values().sum();
        let mine = map.entry(ip).or_default();
        if *mine >= self.max_per_ip || total >= self.max_total {
            if *mine == 0 {
                map.remove(&ip);
            }
            return None;
        }
        *mine += 1;
        Some(PendingSlot {
            pending: self.clone(),
            ip,
            released: AtomicBool::new(false),
        })
    }

    /// Pending connections from `ip` now.
    #[cfg(test)]
    fn count(&self, ip: IpAddr) -> usize {
        lock(&self.per_ip).get(&ip).copied().unwrap_or(0)
    }
}

impl PendingSlot {
    /// Frees the place (the connection said hello, or ended); later calls do nothing.
    pub(crate) fn release(&self) {
        if self.released.swap(true, AcqRel) {
            return;
        }
        let mut map = lock(&self.pending.per_ip);
        if let Some(n) = map.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                map.remove(&self.ip);
            }
        }
    }
}

impl Drop for PendingSlot {
    fn drop(&mut self) {
        self.release();
    }
}

/// Failed tokens an address may send before backing off (typos happen).
const FREE_FAILURES: u32 = 3;
/// First back-off after the free failures; each further failure doubles it.
const BACKOFF_START: Duration = Duration::from_millis(500);
const BACKOFF_MAX: Duration = Duration::from_secs(60);
/// Addresses remembered at most (the oldest entries go first beyond it).
const BACKOFF_ENTRIES: usize = 10_000;

/// Failed tokens per address: after `3 + n` failures the address waits
/// `0.5 s × 2^(n−1)` (at most 60 s) before its next hello is even checked.
#[derive(Default)]
pub(crate) struct TokenBackoff {
    failures: Mutex<HashMap<IpAddr, (u32, Instant)>>,
}

impl TokenBackoff {
    /// `Err(wait)` while `ip` is backing off.
    pub(crate) fn check(&self, ip: IpAddr) -> Result<(), Duration> {
        let map = lock(&self.failures);
        match map.get(&ip) {
            Some(&(_, until)) if until > Instant::now() => Err(until - Instant::now()),
            _ => Ok(()),
        }
    }

    /// Records a failed token; returns the back-off now in force (zero for the first few).
    pub(crate) fn failed(&self, ip: IpAddr) -> Duration {
        let mut map = lock(&self.failures);
        if map.len() >= BACKOFF_ENTRIES {
            let now = Instant::now();
            map.retain(|_, (_, until)| *until + BACKOFF_MAX > now);
        }
        let n = map.get(&ip).map_or(0, |(n, _)| *n) + 1;
        let wait = match n.checked_sub(FREE_FAILURES + 1) {
            None => Duration::ZERO,
            Some(k) => BACKOFF_START
                .saturating_mul(1u32 << k.min(16))
                .min(BACKOFF_MAX),
        };
        map.insert(ip, (n, Instant::now() + wait));
        wait
    }

    pub(crate) fn succeeded(&self, ip: IpAddr) {
        lock(&self.failures).remove(&ip);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pending_connections_are_capped_per_address() {
        let p = Pending::new(2, 3);
        let (a, b): (IpAddr, IpAddr) = ("10.0.0.1".parse().unwrap(), "10.0.0.2".parse().unwrap());
        let s1 = p.try_acquire(a).unwrap();
        let _s2 = p.try_acquire(a).unwrap();
        assert!(p.try_acquire(a).is_none(), "third from one address");
        let _s3 = p.try_acquire(b).unwrap();
        assert!(p.try_acquire(b).is_none(), "total cap");
        s1.release();
        s1.release();
        assert_eq!(p.count(a), 1);
        drop(s1);
        assert_eq!(p.count(a), 1, "release then drop frees once");
        assert!(p.try_acquire(a).is_some());
    }

    #[test]
    fn failed_tokens_back_off_exponentially() {
        let t = TokenBackoff::default();
        let ip: IpAddr = "10.0.0.1".parse().unwrap();
        assert!(t.check(ip).is_ok());
        let waits: Vec<u128> = (0..7).map(|_| t.failed(ip).as_millis()).collect();
        assert_eq!(waits, [0, 0, 0, 500, 1000, 2000, 4000]);
        assert!(t.check(ip).is_err());
        assert_eq!(t.failed(ip), Duration::from_secs(8));
        for _ in 0..20 {
            t.failed(ip);
        }
        assert_eq!(t.failed(ip), BACKOFF_MAX);
        t.succeeded(ip);
        assert!(t.check(ip).is_ok());
    }
}
