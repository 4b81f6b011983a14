//! Smaller frames while the camera moves, as nerfstudio's viewer draws
//! them: where a full-size frame takes longer than the frame rate asked for
//! motion (`tgs view --motion-fps`), the frames of an orbit, pan, zoom or
//! flight are rendered `scale` times smaller on each side and enlarged;
//! once the camera has rested a moment the frame is drawn at full size.
//! Screenshots, captures and layers other than the final image are always
//! full size.

use std::time::{Duration, Instant};

/// The frame rate kept while moving unless `--motion-fps` says otherwise.
pub const DEFAULT_FPS: f32 = 10.0;
/// How long the camera rests before a smaller frame is drawn again at full size.
pub const REST: Duration = Duration::from_millis(150);
/// The smallest frame: 1/4 of the window on each side.
pub const MAX_SCALE: u32 = 4;

#[derive(Debug)]
pub struct Motion {
    /// Frames a second to keep while moving (0: always full size).
    fps: f32,
    /// The camera moved since the last frame, and when it last did.
    moving: bool,
    last_move: Option<Instant>,
    /// The last full-size frame's milliseconds (0 before the first).
    full_ms: f64,
    /// A smaller frame is on screen.
    small_shown: bool,
    /// Smaller frames drawn: count, seconds, the largest scale.
    pub small: (u32, f64, u32),
}

impl Motion {
    pub fn new(fps: f32) -> Motion {
        Motion { fps: fps.max(0.0), moving: false, last_move: None, full_ms: 0.0, small_shown: false, small: (0, 0.0, 1) }
    }

    /// The camera moved (orbit, pan, zoom, fly).
    pub fn moved(&mut self, now: Instant) {
        self.moving = true;
        self.last_move = Some(now);
    }

    /// The scale of the next frame: 1 unless the camera moves and the last
    /// full-size frame was slower than the motion frame rate; else the
    /// smallest integer whose frame (about full / scale² as long) keeps
    /// that rate, at most [`MAX_SCALE`]. `full` forces 1.
    pub fn scale(&self, full: bool) -> u32 {
        if full || !self.moving || self.fps <= 0.0 || self.full_ms <= 0.0 {
            return 1;
        }
        let target = 1e3 / self.fps as f64;
        if self.full_ms <= target {
            return 1;
        }
        ((self.full_ms / target).sqrt().ceil() as u32).clamp(1, MAX_SCALE)
    }

    /// A frame at `scale` took `ms`.
    pub fn drawn(&mut self, scale: u32, ms: f64) {
        self.moving = false;
        self.small_shown = scale > 1;
        if scale > 1 {
            self.small = (self.small.0 + 1, self.small.1 + ms / 1e3, self.small.2.max(scale));
        } else {
            self.full_ms = ms;
        }
    }

    /// With a smaller frame on screen: when to draw it at full size (the
    /// camera then rested [`REST`]); `None` when nothing waits.
    pub fn refine_at(&self) -> Option<Instant> {
        self.small_shown.then(|| self.last_move.map_or_else(Instant::now, |t| t + REST))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_frames_shrink_only_when_a_full_frame_is_too_slow() {
        let t0 = Instant::now();
        let mut m = Motion::new(5.0);
        m.moved(t0);
        assert_eq!(m.scale(false), 1, "before any full frame: full size");
        m.drawn(1, 320.0);
        assert_eq!((m.scale(false), m.refine_at()), (1, None), "resting: full size");
        m.moved(t0);
        // 320 ms against 200: 1/2 on each side (about 80 ms).
        assert_eq!(m.scale(false), 2);
        assert_eq!(m.scale(true), 1, "a capture is full size");
        m.drawn(2, 80.0);
        assert_eq!(m.refine_at(), Some(t0 + REST), "the full frame waits for the camera to rest");
        m.moved(t0 + Duration::from_millis(50));
        assert_eq!(m.refine_at(), Some(t0 + Duration::from_millis(50) + REST));
        m.drawn(2, 80.0);
        m.drawn(1, 330.0);
        assert_eq!((m.refine_at(), m.small), (None, (2, 0.16, 2)));
        // Far too slow: at most 1/4; fast enough or off: full size.
        m.drawn(1, 10_000.0);
        m.moved(t0);
        assert_eq!(m.scale(false), MAX_SCALE);
        m.drawn(1, 150.0);
        m.moved(t0);
        assert_eq!(m.scale(false), 1);
        let mut off = Motion::new(0.0);
        off.drawn(1, 10_000.0);
        off.moved(t0);
        assert_eq!(off.scale(false), 1);
    }
}
