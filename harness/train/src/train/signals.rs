//! Stopping a training from outside: Ctrl-C, SIGTERM and SIGHUP (counted
//! per process, never reset) and [`request_stop`] from the same process.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};

static INTERRUPTED: AtomicBool = AtomicBool::new(false);
/// Signals received by this process: never reset, so that a caller
/// running several trainings (a sweep) sees a signal that arrived while
/// none was in its loop, and a second signal aborts whatever runs.
static SIGNALS: AtomicU32 = AtomicU32::new(0);

/// Ctrl-C (SIGINT), SIGTERM (what batch schedulers send before killing a
/// job) and SIGHUP all stop training at the end of the iteration with a
/// checkpoint (a sweep: at the next safe point); a second one exits at
/// once. Installed once per process; later calls do nothing.
pub fn install_signal_handler() {
    // A second installation in one process (tests) fails harmlessly.
    let _ = ctrlc::set_handler(|| {
        INTERRUPTED.store(true, Ordering::SeqCst);
        if SIGNALS.fetch_add(1, Ordering::SeqCst) >= 1 {
            eprintln!("\nsecond interrupt: exiting at once");
            std::process::exit(130);
        }
        eprintln!("\ninterrupted (Ctrl-C or SIGTERM): stopping at the next safe point with a checkpoint (interrupt again to abort)");
    });
}

/// Signals this process has received so far (see [`install_signal_handler`]).
pub fn signals_received() -> u32 {
    SIGNALS.load(Ordering::SeqCst)
}

/// Ask a running `train` in this process to stop at the next iteration (as Ctrl-C does).
pub fn request_stop() {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// Arm the stop flag for a training that began when `signals_at_start`
/// signals had arrived: a request_stop() of an earlier training in this
/// process is spent; a signal that arrived since this one started is not.
pub(crate) fn arm(signals_at_start: u32) {
    INTERRUPTED.store(signals_received() > signals_at_start, Ordering::SeqCst);
}

/// Whether a stop was asked for (a signal or [`request_stop`]).
pub(crate) fn stop_requested() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}
