//! A live view of a run while it trains (`tgs train --view`): the model as
//! a checkpoint would hold it, in memory, handed to a receiver (the
//! viewer's window) at most every so often, at each stage's start and at
//! the end. Taking it only reads the trainer's buffers, so the training is
//! the same with and without a view.

use super::checkpoint::{self, Header};
use super::trainer::Trainer;
use anyhow::Result;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The model at one iteration.
pub struct Snapshot {
    pub header: Header,
    pub arrays: Vec<Vec<f32>>,
    /// The schedule entry it trains ("I", "II", "III", ...) and the run's last iteration.
    pub label: String,
    pub total: u32,
}

/// Where snapshots go, and how often.
#[derive(Clone)]
pub struct LiveSink {
    pub every: Duration,
    pub send: Arc<dyn Fn(Snapshot) + Send + Sync>,
    /// False once nobody looks (the window closed): no more snapshots are taken.
    pub open: Arc<AtomicBool>,
    /// The receiver's pace in milliseconds: no snapshot sooner than this
    /// after the last, when longer than `every` (the viewer asks for nine
    /// times its frame time, so that drawing takes at most a tenth).
    pub pace_ms: Arc<AtomicU64>,
}

impl std::fmt::Debug for LiveSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LiveSink {{ every: {:?} }}", self.every)
    }
}

/// The training side: when the last snapshot went.
pub(crate) struct Live {
    sink: LiveSink,
    last: Option<Instant>,
}

impl Live {
    pub(crate) fn new(sink: &LiveSink) -> Live {
        Live { sink: sink.clone(), last: None }
    }

    /// Send a snapshot of `tr` if `every` has passed since the last (or `now`).
    pub(crate) fn offer(&mut self, tr: &Trainer, dataset: &str, label: &str, total: u32, now: bool) -> Result<()> {
        let gap = self.sink.every.max(Duration::from_millis(self.sink.pace_ms.load(Ordering::Relaxed)));
        if !self.sink.open.load(Ordering::Relaxed) || (!now && self.last.is_some_and(|t| t.elapsed() < gap)) {
            return Ok(());
        }
        let (header, arrays) = checkpoint::snapshot(tr, dataset)?;
        (self.sink.send)(Snapshot { header, arrays, label: label.to_string(), total });
        self.last = Some(Instant::now());
        Ok(())
    }
}
