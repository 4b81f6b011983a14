//! A live view of a run while it trains (`tgs train --view`): the model as
//! a checkpoint would hold it, in memory, handed to a receiver (the
//! viewer's window) at most every so often, at each stage's start and at
//! the end, the training waiting while the window draws it. Taking it only
//! reads the trainer's buffers, so the training is the same with and
//! without a view.

use super::checkpoint::{self, Header};
use super::trainer::Trainer;
use anyhow::Result;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// The model at one iteration.
pub struct Snapshot {
    pub header: Header,
    pub arrays: Vec<Vec<f32>>,
    /// The schedule entry it trains ("I", "II", "III", ...) and the run's last iteration.
    pub label: String,
    pub total: u32,
    /// Its number in the run (1, 2, ...), for [`Handshake::drawn`].
    pub seq: u64,
}

/// The share of the training's time a live view may take: the training
/// waits while the window draws each model ([`Handshake`]), so that the
/// two never run at once, and takes the next no sooner than [`gap_after`]
/// that wait.
pub const DRAW_SHARE: f64 = 0.05;

/// The time to train on after a model whose drawing the training waited
/// `waited` for: a wait each gap plus a wait is at most [`DRAW_SHARE`].
pub fn gap_after(waited: Duration) -> Duration {
    waited.mul_f64(1.0 / DRAW_SHARE - 1.0)
}

/// The longest the training waits for one model to be drawn: twice the
/// last wait, at least a second (a window that stopped drawing, or a frame
/// far slower than the last, holds the training up no longer).
pub fn wait_limit(last_wait: Duration) -> Duration {
    (2 * last_wait).max(Duration::from_secs(1))
}

/// Which snapshot the window has drawn, shared by the window and the
/// training. The training waits for each snapshot to be drawn before it
/// goes on: on a CPU device a frame drawn beside the training slowed it by
/// more than the frame's own time (their threads take turns on the same
/// cores; perf/journal, sixty-eighth entry).
#[derive(Debug, Default)]
pub struct Handshake {
    sent: AtomicU64,
    drawn: Mutex<u64>,
    shown: Condvar,
    /// Snapshots not drawn within the wait's limit, and the nanoseconds
    /// the training waited for the window, over the run.
    late: AtomicU64,
    waited_ns: AtomicU64,
}

impl Handshake {
    /// The window: snapshot `seq` ([`Snapshot::seq`]) is on screen, or will
    /// not be drawn (nothing to draw on); older ones count as drawn too.
    pub fn drawn(&self, seq: u64) {
        let mut d = self.drawn.lock().unwrap_or_else(|e| e.into_inner());
        *d = (*d).max(seq);
        self.shown.notify_all();
    }

    /// The training: wait until snapshot `seq` has been drawn, the window
    /// closed (`open` false) or `limit` passed; whether it was drawn.
    pub fn wait_drawn(&self, seq: u64, limit: Duration, open: &AtomicBool) -> bool {
        let t0 = Instant::now();
        let mut d = self.drawn.lock().unwrap_or_else(|e| e.into_inner());
        let drawn = loop {
            let left = limit.saturating_sub(t0.elapsed());
            if *d >= seq || !open.load(Ordering::Relaxed) || left.is_zero() {
                break *d >= seq;
            }
            // Woken by `drawn`; the closed window is polled.
            d = self.shown.wait_timeout(d, left.min(Duration::from_millis(50))).unwrap_or_else(|e| e.into_inner()).0;
        };
        self.waited_ns.fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.late.fetch_add(u64::from(!drawn), Ordering::Relaxed);
        drawn
    }

    /// Snapshots sent, those not drawn within the limit, and the seconds
    /// the training waited for them.
    pub fn totals(&self) -> (u64, u64, f64) {
        let n = |a: &AtomicU64| a.load(Ordering::Relaxed);
        (n(&self.sent), n(&self.late), n(&self.waited_ns) as f64 * 1e-9)
    }
}

/// Where snapshots go, and how often.
#[derive(Clone)]
pub struct LiveSink {
    /// The shortest time between two snapshots (`--view-every`).
    pub every: Duration,
    pub send: Arc<dyn Fn(Snapshot) + Send + Sync>,
    /// False once nobody looks (the window closed): no more snapshots are taken.
    pub open: Arc<AtomicBool>,
    /// The window's word that a snapshot is drawn.
    pub handshake: Arc<Handshake>,
}

impl std::fmt::Debug for LiveSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LiveSink {{ every: {:?} }}", self.every)
    }
}

/// The training side: when the last snapshot went, the gap to the next,
/// and how long the last regular one (not a stage's first or the last)
/// was waited for.
pub(crate) struct Live {
    sink: LiveSink,
    last: Option<Instant>,
    gap: Duration,
    waited: Duration,
}

impl Live {
    pub(crate) fn new(sink: &LiveSink) -> Live {
        Live { sink: sink.clone(), last: None, gap: sink.every, waited: Duration::ZERO }
    }

    /// Send a snapshot of `tr` if the gap has passed since the last (or
    /// `now`), and wait while the window draws it. A regular snapshot's
    /// wait sets the gap to the next ([`gap_after`], at least `every`); the
    /// ones sent `now` (a stage's start, with the window's new kernels, and
    /// the end) leave it.
    pub(crate) fn offer(&mut self, tr: &Trainer, dataset: &str, label: &str, total: u32, now: bool) -> Result<()> {
        if !self.sink.open.load(Ordering::Relaxed) || (!now && self.last.is_some_and(|t| t.elapsed() < self.gap)) {
            return Ok(());
        }
        let (header, arrays) = checkpoint::snapshot(tr, dataset)?;
        let hs = &self.sink.handshake;
        let seq = hs.sent.fetch_add(1, Ordering::Relaxed) + 1;
        (self.sink.send)(Snapshot { header, arrays, label: label.to_string(), total, seq });
        let t0 = Instant::now();
        hs.wait_drawn(seq, wait_limit(self.waited), &self.sink.open);
        if !now {
            self.waited = t0.elapsed();
            self.gap = self.sink.every.max(gap_after(self.waited));
        }
        self.last = Some(Instant::now());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_at_the_gap_take_at_most_their_share() {
        for ms in [0.5, 3.0, 265.4, 467.0, 1e4] {
            let wait = Duration::from_secs_f64(ms * 1e-3);
            let gap = gap_after(wait).as_secs_f64();
            let share = wait.as_secs_f64() / (wait.as_secs_f64() + gap);
            assert!((DRAW_SHARE - 1e-6..=DRAW_SHARE + 1e-9).contains(&share), "{ms} ms waits, gap {gap} s: share {share}");
        }
        assert_eq!(gap_after(Duration::ZERO), Duration::ZERO);
    }

    #[test]
    fn the_training_waits_for_the_window_to_draw_and_no_longer() {
        let open = Arc::new(AtomicBool::new(true));
        let hs = Arc::new(Handshake::default());
        // Drawn 100 ms later: the wait ends then, and is counted.
        let window = {
            let hs = hs.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(100));
                hs.drawn(1);
            })
        };
        let t0 = Instant::now();
        assert!(hs.wait_drawn(1, Duration::from_secs(20), &open));
        let waited = t0.elapsed();
        window.join().unwrap();
        assert!(waited >= Duration::from_millis(100) && waited < Duration::from_secs(10), "{waited:?}");
        assert!(hs.totals().2 >= 0.1);
        // A later snapshot drawn counts for the earlier ones.
        hs.drawn(3);
        assert!(hs.wait_drawn(2, Duration::ZERO, &open));
        // Never drawn: the limit ends the wait.
        let t0 = Instant::now();
        assert!(!hs.wait_drawn(4, Duration::from_millis(200), &open));
        assert!(t0.elapsed() >= Duration::from_millis(200));
        // The window closed: no wait.
        open.store(false, Ordering::Relaxed);
        let t0 = Instant::now();
        assert!(!hs.wait_drawn(4, Duration::from_secs(20), &open));
        assert!(t0.elapsed() < Duration::from_secs(5));
        assert_eq!(hs.totals().1, 2, "the two waits that ended undrawn");
        // The limit: twice the last wait, at least a second.
        assert_eq!(wait_limit(Duration::from_millis(300)), Duration::from_secs(1));
        assert_eq!(wait_limit(Duration::from_secs(2)), Duration::from_secs(4));
    }
}
