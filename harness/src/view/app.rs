//! The viewer's window and event loop (winit): input to [`Action`]s, one
//! frame per redraw, the title as the status line.

use super::controls::Nav;
use super::gpu::{Gpu, Presented};
use super::input::{key_action, read_script, Action, HELP};
use super::motion::Motion;
use super::scene::Scene;
use super::{shot, ViewArgs};
use anyhow::{Context as _, Result};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tgs_engine::Buffer;
use tgs_train::train::live::{Handshake, Snapshot};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{ModifiersState, PhysicalKey};
use winit::window::{Window, WindowId};

/// Everything that lives while the window is open. Fields drop in this
/// order: tgs's buffers and scene before the device they live on, the
/// device before the window its surface belongs to.
struct Open {
    pixels: Option<Buffer<u32>>,
    scene: Scene,
    nav: Nav,
    gpu: Gpu,
    window: Window,
}

/// What the training thread tells the window (`tgs train --view`).
#[derive(Debug)]
pub enum LiveEvent {
    /// A new snapshot waits in the slot.
    Snapshot,
    /// Training ended (stopped by a signal: true).
    Done { interrupted: bool },
}

/// The latest snapshot of the run, replaced by each newer one.
pub type Slot = Arc<Mutex<Option<Snapshot>>>;

struct App<'a> {
    args: &'a ViewArgs,
    open: Option<Open>,
    /// A run still training: where its snapshots arrive; the window (and
    /// its device) until the first one came.
    live: Option<Slot>,
    /// Live: the window's word to the training that a snapshot is drawn.
    handshake: Option<Arc<Handshake>>,
    /// Live: the snapshot the next whole frame shows (told to the training once drawn).
    unshown: Option<u64>,
    early: Option<(Gpu, Window)>,
    error: Option<anyhow::Error>,
    script: Option<VecDeque<Action>>,
    /// A capture (script) or screenshot waiting for the next whole frame.
    capture: Option<PathBuf>,
    wait: u32,
    dirty: bool,
    drag: Option<(MouseButton, bool)>,
    cursor: Option<(f64, f64)>,
    modifiers: ModifiersState,
    /// Drawn frames and their seconds, for the summary at exit.
    frames: (u32, f64),
    last_ms: f64,
    /// The training thread ended (interrupted or not).
    done: Option<bool>,
    /// A script waits for the training to end.
    until_trained: bool,
    /// Left clicks mark the glass (key G), and the marks so far.
    marking: bool,
    marks: crate::marks::Marks,
    /// Smaller frames while the camera moves.
    motion: Motion,
}

/// The window's event loop (with the user events a live view sends).
pub fn event_loop() -> Result<EventLoop<LiveEvent>> {
    EventLoop::<LiveEvent>::with_user_event().build().context("opening the display for a window (`tgs render` writes the same images headless)")
}

pub fn run(args: &ViewArgs) -> Result<()> {
    run_on(event_loop()?, args, None)
}

/// Run the window on `el` until it closes: on `args.run`, or with `live`
/// on the snapshots of a run while it trains.
pub fn run_on(el: EventLoop<LiveEvent>, args: &ViewArgs, live: Option<(Slot, Arc<Handshake>)>) -> Result<()> {
    let (live, handshake) = live.unzip();
    let script = args.script.as_deref().map(read_script).transpose()?.map(VecDeque::from);
    let mut app = App {
        args,
        open: None,
        live,
        handshake,
        unshown: None,
        early: None,
        error: None,
        script,
        capture: None,
        wait: 0,
        dirty: true,
        drag: None,
        cursor: None,
        modifiers: ModifiersState::empty(),
        frames: (0, 0.0),
        last_ms: 0.0,
        done: None,
        until_trained: false,
        marking: false,
        marks: crate::marks::Marks { tolerance: args.mark_tolerance, ..Default::default() },
        motion: Motion::new(args.motion_fps),
    };
    el.run_app(&mut app).context("the window's event loop")?;
    drop(app.open.take());
    drop(app.early.take());
    if let Some(e) = app.error {
        return Err(e);
    }
    if app.frames.0 > 0 {
        let (n, s, scale) = app.motion.small;
        let small = if n > 0 { format!(" ({n} of them drawn at up to 1/{scale} size while moving, {:.1} ms on average)", 1e3 * s / n as f64) } else { String::new() };
        eprintln!("tgs view: {} frames, {:.1} ms a frame on average{small}", app.frames.0, 1e3 * app.frames.1 / app.frames.0 as f64);
    }
    Ok(())
}

impl App<'_> {
    fn start(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let window = el.create_window(Window::default_attributes().with_title("tgs view").with_visible(true)).context("creating the window")?;
        let gpu = Gpu::new(&window, &self.args.device)?;
        if self.live.is_some() {
            window.set_title("tgs view · waiting for the run's first model");
            self.early = Some((gpu, window));
            return self.take_snapshot();
        }
        let scene = Scene::open(gpu.ctx(), &self.args.run)?;
        self.show(scene, gpu, window)
    }

    /// The latest snapshot of a run while it trains, into the scene (the
    /// first one opens it).
    fn take_snapshot(&mut self) -> Result<()> {
        // Before the window exists a snapshot stays in the slot: `start`
        // takes it (it was taken and dropped, and the window waited for the next).
        if self.open.is_none() && self.early.is_none() {
            return Ok(());
        }
        let Some(snap) = self.live.as_ref().and_then(|s| s.lock().ok().and_then(|mut g| g.take())) else { return Ok(()) };
        self.dirty = true;
        self.unshown = Some(snap.seq);
        if let Some(o) = self.open.as_mut() {
            return o.scene.update(snap);
        }
        let Some((gpu, window)) = self.early.take() else { return Ok(()) };
        let scene = Scene::live(gpu.ctx(), snap)?;
        self.show(scene, gpu, window)
    }

    fn show(&mut self, mut scene: Scene, gpu: Gpu, window: Window) -> Result<()> {
        if self.args.train {
            scene.switch_set();
        }
        let n = scene.cameras().len();
        if self.args.camera >= n {
            anyhow::bail!("--camera {}: the run has {n} {} cameras", self.args.camera, if scene.train_set { "training" } else { "test" });
        }
        scene.camera = self.args.camera;
        let cam = scene.dataset_camera().1;
        let size = self.args.size.unwrap_or_else(|| {
            let k = 400u32.div_ceil(cam.width).max(1);
            (cam.width * k, cam.height * k)
        });
        let _ = window.request_inner_size(PhysicalSize::new(size.0, size.1));
        let nav = Nav::at(&cam, scene.target, scene.up);
        eprintln!("tgs view: {} on {}; press H for the keys", self.args.run.display(), gpu.device_name);
        self.open = Some(Open { pixels: None, scene, nav, gpu, window });
        Ok(())
    }

    fn apply(&mut self, a: Action, el: &ActiveEventLoop) -> Result<()> {
        let Some(o) = self.open.as_mut() else { return Ok(()) };
        let reset = |o: &mut Open| o.nav = Nav::at(&o.scene.dataset_camera().1, o.scene.target, o.scene.up);
        if matches!(a, Action::Orbit(..) | Action::Pan(..) | Action::Zoom(_) | Action::Fly(_)) {
            self.motion.moved(Instant::now());
        }
        match a {
            Action::Orbit(dx, dy) => o.nav.orbit(dx, dy),
            Action::Pan(dx, dy) => o.nav.pan(dx, dy),
            Action::Zoom(s) => o.nav.zoom(s),
            Action::Fly(d) => o.nav.fly(d),
            Action::Camera(by) => {
                o.scene.step_camera(by);
                reset(o);
            }
            Action::CameraSet => {
                o.scene.switch_set();
                reset(o);
            }
            Action::Reset => reset(o),
            Action::Layer(by) => o.scene.step_layer(by),
            Action::Checkpoint => o.scene.next_checkpoint()?,
            Action::Screenshot => {
                let dir = self.args.shots.clone().unwrap_or_else(|| self.args.run.join("screenshots"));
                let (name, _) = o.scene.dataset_camera();
                let stem = format!("{}{}_{}_stage{}", name, if o.nav.unmoved().is_some() { "" } else { "_moved" }, o.scene.layer_name(), o.scene.stage());
                self.capture = Some(shot::fresh_name(&dir, &stem));
            }
            Action::MarkMode => {
                self.marking = !self.marking;
                // One marks what the photo shows; the marked region is tinted on it.
                if self.marking {
                    o.scene.show_layer("gt");
                }
                eprintln!(
                    "tgs view: marking the glass {}",
                    if self.marking { "on: left clicks around it, in two or more views; U takes one back, M writes the masks" } else { "off" }
                );
            }
            Action::Click(x, y) => {
                let size = o.window.inner_size();
                if let (true, Some((w, h))) = (self.marking, o.gpu.extent((size.width, size.height))?) {
                    // Window pixels span [x, x + 1): their centres are the camera's integers.
                    self.marks.click(&o.nav.camera(w, h), x - 0.5, y - 0.5);
                }
            }
            Action::Unmark => self.marks.undo(),
            Action::NewRegion => self.marks.new_region(),
            Action::FlatPane => self.marks.flat(),
            Action::WriteMarks(dir) => {
                let dir = dir.unwrap_or_else(|| shot::unused_path(&self.args.run, "glass-marks", ""));
                match self.marks.write(&o.scene.data.train, &dir) {
                    Ok(n) => eprintln!(
                        "tgs view: {} training views' glass masks in {} ({n} with glass); train on them with\n  tgs train --from {} --stages II,III --set reflection.seed_masks={} --out NEW_RUN",
                        o.scene.data.train.len(),
                        dir.display(),
                        self.args.run.display(),
                        dir.display()
                    ),
                    // A script stops on it; a user reads it and marks on.
                    Err(e) if self.script.is_some() => return Err(e),
                    Err(e) => eprintln!("tgs view: {e:#}"),
                }
            }
            Action::Help => println!("{HELP}"),
            Action::Quit => el.exit(),
            Action::Resize(w, h) => {
                let _ = o.window.request_inner_size(PhysicalSize::new(w, h));
            }
            Action::Capture(p) => self.capture = Some(p),
            Action::Wait(n) => self.wait = n,
            Action::Trained => self.until_trained = self.live.is_some(),
        }
        self.dirty = true;
        Ok(())
    }

    /// Draw one frame; whether it was whole (else draw again). A live
    /// snapshot counts as shown after a whole frame, or when there is
    /// nothing to draw on (a minimised window): the training waits till then.
    fn draw(&mut self) -> Result<bool> {
        let whole = self.draw_frame();
        if !matches!(whole, Ok(false)) {
            if let (Some(seq), Some(hs)) = (self.unshown.take(), &self.handshake) {
                hs.drawn(seq);
            }
        }
        whole
    }

    fn draw_frame(&mut self) -> Result<bool> {
        let Some(o) = self.open.as_mut() else { return Ok(true) };
        let size = o.window.inner_size();
        let Some((w, h)) = o.gpu.extent((size.width, size.height))? else { return Ok(true) };
        let t0 = Instant::now();
        let cam = o.nav.camera(w, h);
        let n = (w * h) as usize;
        if o.pixels.as_ref().is_none_or(|p| p.len() != n) {
            // Every pixel is written (by the pack kernel or the upload) before the copy reads it.
            o.pixels = Some(Buffer::uninit(o.gpu.ctx(), "view.pixels", n)?);
        }
        let pixels = o.pixels.as_ref().expect("made above");
        let order = o.gpu.order;
        // What the marks cover in this view (tinted on the photo, counted in the title).
        let marked = if self.marking || self.marks.clicks() > 0 { self.marks.mask_if_ready(&cam) } else { None };
        if o.scene.layer != 0 {
            let mut px = o.scene.host_layer(&cam, o.nav.unmoved(), order)?;
            if let Some(m) = marked.as_ref().filter(|_| self.marking && o.scene.layer_name() == "gt") {
                tint(&mut px, m);
            }
            pixels.upload(&px)?;
        }
        // A moving camera's frame may be drawn smaller (a capture or another layer never is).
        let scale = self.motion.scale(self.capture.is_some() || o.scene.layer != 0);
        let drawn = if scale > 1 { o.nav.camera(w.div_ceil(scale), h.div_ceil(scale)) } else { cam };
        let scene = &mut o.scene;
        let shown = o.gpu.present(pixels, self.capture.is_some(), |rec| scene.record_final_scaled(rec, &drawn, (w, h, scale), order, pixels).map(|_| ()))?;
        let whole = o.scene.complete(&drawn)?;
        let captured = match shown {
            Presented::Hidden => return Ok(true),
            Presented::Stale => return Ok(false),
            Presented::Shown(c) => c,
        };
        if !whole {
            return Ok(false);
        }
        let dt = t0.elapsed().as_secs_f64();
        self.frames = (self.frames.0 + 1, self.frames.1 + dt);
        self.last_ms = 1e3 * dt;
        self.motion.drawn(scale, self.last_ms);
        if let (Some(px), Some(path)) = (captured, self.capture.take()) {
            shot::write_new(&path, &px, (w, h), order)?;
            eprintln!("tgs view: wrote {}", path.display());
        }
        let (name, _) = o.scene.dataset_camera();
        let set = if o.scene.train_set { "training" } else { "test" };
        let training = match (o.scene.training(), self.done) {
            (_, Some(true)) => " (training stopped)".to_string(),
            (Some(("done", ..)), _) | (_, Some(false)) => " (trained)".to_string(),
            (Some((label, it, total)), None) => format!(" (training {label}: iteration {it} of {total})"),
            (None, _) => String::new(),
        };
        let title = format!(
            "tgs view · Stage {}{training} · {set} camera {}/{} '{name}'{} · {} · {w}x{h}{} · {:.1} ms · {} + {} Gaussians",
            o.scene.stage(),
            o.scene.camera + 1,
            o.scene.cameras().len(),
            if o.nav.unmoved().is_some() { "" } else { " (moved)" },
            o.scene.layer_name(),
            if scale > 1 { format!(" (1/{scale} while moving)") } else { String::new() },
            self.last_ms,
            o.scene.counts.0,
            o.scene.counts.1,
        ) + &marking_status(self.marking, &self.marks, marked.as_deref());
        o.window.set_title(&title);
        Ok(true)
    }

    fn fail(&mut self, e: anyhow::Error, el: &ActiveEventLoop) {
        self.error.get_or_insert(e);
        el.exit();
    }
}

impl ApplicationHandler<LiveEvent> for App<'_> {
    fn user_event(&mut self, el: &ActiveEventLoop, event: LiveEvent) {
        match event {
            LiveEvent::Snapshot => {
                if let Err(e) = self.take_snapshot() {
                    self.fail(e, el);
                }
            }
            LiveEvent::Done { interrupted } => {
                self.done = Some(interrupted);
                self.dirty = true;
                // Stopped (Ctrl-C): the window goes too; trained: it stays until closed.
                if interrupted {
                    el.exit();
                }
            }
        }
    }

    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.open.is_none() {
            if let Err(e) = self.start(el) {
                self.fail(e, el);
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let r = match event {
            WindowEvent::CloseRequested => {
                el.exit();
                Ok(())
            }
            WindowEvent::Resized(_) => {
                self.dirty = true;
                Ok(())
            }
            WindowEvent::RedrawRequested => match self.draw() {
                Ok(whole) => {
                    self.dirty = !whole;
                    Ok(())
                }
                Err(e) => Err(e),
            },
            WindowEvent::ModifiersChanged(m) => {
                self.modifiers = m.state();
                Ok(())
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => match event.physical_key {
                PhysicalKey::Code(k) => key_action(k).map_or(Ok(()), |a| self.apply(a, el)),
                _ => Ok(()),
            },
            WindowEvent::MouseInput { state, button, .. } => match (self.marking, state, button, self.cursor) {
                // Marking: a left click marks (no orbit); the right button still pans.
                (true, ElementState::Pressed, MouseButton::Left, Some((x, y))) => {
                    self.drag = None;
                    self.apply(Action::Click(x, y), el)
                }
                (true, _, MouseButton::Left, _) => Ok(()),
                _ => {
                    self.drag = (state == ElementState::Pressed).then_some((button, self.modifiers.shift_key()));
                    Ok(())
                }
            },
            WindowEvent::CursorMoved { position, .. } => {
                let last = self.cursor.replace((position.x, position.y));
                match (self.drag, last) {
                    (Some((MouseButton::Left, false)), Some((x, y))) => self.apply(Action::Orbit(position.x - x, position.y - y), el),
                    (Some((MouseButton::Left, true) | (MouseButton::Right, _)), Some((x, y))) => self.apply(Action::Pan(position.x - x, position.y - y), el),
                    _ => Ok(()),
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 50.0,
                };
                self.apply(Action::Zoom(steps), el)
            }
            _ => Ok(()),
        };
        if let Err(e) = r {
            self.fail(e, el);
        }
    }

    fn about_to_wait(&mut self, el: &ActiveEventLoop) {
        // A script moves on only after a whole frame of the last action
        // (and, live, once the run's first model is shown).
        let waits = self.open.is_none() || (self.until_trained && self.done.is_none());
        // A smaller frame on screen: full size once the camera rests.
        el.set_control_flow(ControlFlow::Wait);
        if let (false, Some(at)) = (self.dirty, self.motion.refine_at()) {
            if Instant::now() >= at {
                self.dirty = true;
            } else {
                el.set_control_flow(ControlFlow::WaitUntil(at));
            }
        }
        if !self.dirty && self.capture.is_none() && !waits {
            self.until_trained = false;
            if self.wait > 0 {
                self.wait -= 1;
                self.dirty = true;
            } else if let Some(script) = self.script.as_mut() {
                match script.pop_front() {
                    Some(a) => {
                        if let Err(e) = self.apply(a, el) {
                            self.fail(e, el);
                        }
                    }
                    None => el.exit(),
                }
            }
        }
        if self.dirty || self.capture.is_some() {
            if let Some(o) = &self.open {
                o.window.request_redraw();
            }
        }
    }
}

/// The title's marking part: the clicks so far and how much of this view
/// they mark (`marked`, once they describe a region).
fn marking_status(on: bool, marks: &crate::marks::Marks, marked: Option<&[bool]>) -> String {
    if !on && marks.clicks() == 0 {
        return String::new();
    }
    let share = marked.map_or_else(String::new, |m| format!(", {:.0}% of this view", 100.0 * m.iter().filter(|&&b| b).count() as f64 / m.len().max(1) as f64));
    let pieces = marks.regions.iter().filter(|r| !r.outlines.is_empty()).count();
    let regions = if pieces > 1 { format!(" ({pieces} pieces of glass)") } else { String::new() };
    let pending = marks.pending().map(|p| format!(" · this piece: {p}")).unwrap_or_default();
    format!(" · marking{}: {} clicks in {} views{regions}{share}{pending}", if on { "" } else { " (off)" }, marks.clicks(), marks.outlines())
}

/// Tint the marked pixels magenta (half way), in either byte order.
fn tint(px: &mut [u32], mask: &[bool]) {
    for (p, _) in px.iter_mut().zip(mask).filter(|(_, &m)| m) {
        let [a, g, b, x] = p.to_le_bytes();
        *p = u32::from_le_bytes([a / 2 + 128, g / 2, b / 2 + 128, x]);
    }
}
