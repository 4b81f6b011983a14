//! What the viewer does on a key, a drag or a line of a `--script` file:
//! both come down to the same [`Action`]s, so a script drives exactly what
//! a user's keys and mouse do.

use anyhow::{bail, Context as _, Result};
use glam::DVec3;
use std::path::{Path, PathBuf};
use winit::keyboard::KeyCode;

#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    Orbit(f64, f64),
    Pan(f64, f64),
    Zoom(f64),
    /// Fly along the view's right, down and forward axes.
    Fly(DVec3),
    /// The next (+1) or previous (-1) dataset camera.
    Camera(i64),
    /// Switch between the test and the training cameras.
    CameraSet,
    /// Back to the current dataset camera.
    Reset,
    /// The next (+1) or previous (-1) layer.
    Layer(i64),
    /// The next checkpoint (Stage I, II, III).
    Checkpoint,
    /// Write what the window shows as a PNG (a new file in the shots directory).
    Screenshot,
    /// Marking the glass on or off (left clicks then outline it).
    MarkMode,
    /// A left click at window pixel coordinates (a mark while marking).
    Click(f64, f64),
    /// Take back the last mark.
    Unmark,
    /// The next clicks outline another piece of glass (another pane).
    NewRegion,
    /// The current piece of glass is a flat pane: its clicks are its corners.
    FlatPane,
    /// Write every training view's glass mask from the marks: into this
    /// new directory (script), else a new one in the run directory.
    WriteMarks(Option<PathBuf>),
    /// Print the keys.
    Help,
    Quit,
    /// Script only: ask the window for this size.
    Resize(u32, u32),
    /// Script only: write the next whole frame the window shows to this file.
    Capture(PathBuf),
    /// Script only: let this many frames pass.
    Wait(u32),
    /// Script only (`tgs train --view`): wait until the training has ended.
    Trained,
}

/// The keys, as `H` prints them.
pub const HELP: &str = "\
tgs view keys:
  left drag: orbit   right drag / shift+left drag: pan   wheel: zoom
  W A S D: fly forward, left, back, right   Q E: down, up
  N / P (or -> / <-): next / previous dataset camera   T: test or training cameras   R: back to the camera
  L / K: next / previous layer (final, normals, depth; after Stage I: scattering, reflection, R, F0, ...; gt: the photo)
  C: next checkpoint (Stage I, II, III)   F12 or O: screenshot   H: this help   Esc: quit
  G: mark the glass: left clicks around it (a pane's corners, a dome's outline) in two or more views
     B: the next clicks outline another piece of glass (each pane its own region)
     F: this piece is a flat pane: click its corners, in order round it, in two or more views
     U: take back a click   M: write every training view's glass mask (reflection.seed_masks)";

/// The action of a key press (with shift held or not).
pub fn key_action(key: KeyCode) -> Option<Action> {
    let fly = |x, y, z| Some(Action::Fly(DVec3::new(x, y, z)));
    match key {
        KeyCode::KeyW => fly(0.0, 0.0, 1.0),
        KeyCode::KeyS => fly(0.0, 0.0, -1.0),
        KeyCode::KeyA => fly(-1.0, 0.0, 0.0),
        KeyCode::KeyD => fly(1.0, 0.0, 0.0),
        KeyCode::KeyQ => fly(0.0, 1.0, 0.0),
        KeyCode::KeyE => fly(0.0, -1.0, 0.0),
        KeyCode::KeyN | KeyCode::ArrowRight => Some(Action::Camera(1)),
        KeyCode::KeyP | KeyCode::ArrowLeft => Some(Action::Camera(-1)),
        KeyCode::KeyT => Some(Action::CameraSet),
        KeyCode::KeyR => Some(Action::Reset),
        KeyCode::KeyL => Some(Action::Layer(1)),
        KeyCode::KeyK => Some(Action::Layer(-1)),
        KeyCode::KeyC => Some(Action::Checkpoint),
        KeyCode::F12 | KeyCode::KeyO => Some(Action::Screenshot),
        KeyCode::KeyH => Some(Action::Help),
        KeyCode::KeyG => Some(Action::MarkMode),
        KeyCode::KeyU => Some(Action::Unmark),
        KeyCode::KeyB => Some(Action::NewRegion),
        KeyCode::KeyF => Some(Action::FlatPane),
        KeyCode::KeyM => Some(Action::WriteMarks(None)),
        KeyCode::Escape => Some(Action::Quit),
        _ => None,
    }
}

/// The key a script line `key NAME` names (the letters, digits, arrows,
/// F12 and Escape the viewer knows).
fn key_named(name: &str) -> Option<KeyCode> {
    let k = match name.to_ascii_lowercase().as_str() {
        "right" => KeyCode::ArrowRight,
        "left" => KeyCode::ArrowLeft,
        "escape" | "esc" => KeyCode::Escape,
        "f12" => KeyCode::F12,
        s if s.len() == 1 => match s.as_bytes()[0] {
            b'w' => KeyCode::KeyW,
            b'a' => KeyCode::KeyA,
            b's' => KeyCode::KeyS,
            b'd' => KeyCode::KeyD,
            b'q' => KeyCode::KeyQ,
            b'e' => KeyCode::KeyE,
            b'n' => KeyCode::KeyN,
            b'p' => KeyCode::KeyP,
            b't' => KeyCode::KeyT,
            b'r' => KeyCode::KeyR,
            b'l' => KeyCode::KeyL,
            b'k' => KeyCode::KeyK,
            b'c' => KeyCode::KeyC,
            b'o' => KeyCode::KeyO,
            b'h' => KeyCode::KeyH,
            b'g' => KeyCode::KeyG,
            b'u' => KeyCode::KeyU,
            b'b' => KeyCode::KeyB,
            b'f' => KeyCode::KeyF,
            b'm' => KeyCode::KeyM,
            _ => return None,
        },
        _ => return None,
    };
    Some(k)
}

/// A `--script` file: one action a line, `#` comments.
///
/// ```text
/// key N            # a key press, as the keyboard's (N, Right, L, C, O, Escape, ...)
/// orbit DX DY      # a left drag of DX, DY pixels
/// pan DX DY        # a right drag
/// zoom STEPS       # wheel steps (negative: out)
/// resize W H       # ask the window for W x H
/// capture FILE     # write the next whole frame the window shows (PNG)
/// click X Y        # a left click at window pixel (X, Y) (a mark after key G)
/// marks DIR        # write the glass masks of the marks into the new directory DIR
/// wait FRAMES
/// trained          # (tgs train --view) wait until the training has ended
/// quit
/// ```
///
/// Relative files are relative to the script's directory.
pub fn read_script(path: &Path) -> Result<Vec<Action>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading the script {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        out.push(parse_line(line, base).with_context(|| format!("{}:{}: '{line}'", path.display(), i + 1))?);
    }
    Ok(out)
}

fn parse_line(line: &str, base: &Path) -> Result<Action> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let num = |i: usize| -> Result<f64> {
        let w = words.get(i).context("a number is missing")?;
        w.parse::<f64>().ok().filter(|v| v.is_finite()).with_context(|| format!("'{w}' is not a number"))
    };
    let size = |i: usize| -> Result<u32> {
        let v = num(i)?;
        if !(1.0..=16384.0).contains(&v) || v.fract() != 0.0 {
            bail!("{v} is not a size from 1 to 16384");
        }
        Ok(v as u32)
    };
    let want = |n: usize| if words.len() == n { Ok(()) } else { Err(anyhow::anyhow!("'{}' takes {} argument(s)", words[0], n - 1)) };
    Ok(match words[0] {
        "key" => {
            want(2)?;
            key_named(words[1]).and_then(key_action).with_context(|| format!("no key '{}' (see `tgs view --help`)", words[1]))?
        }
        "orbit" => {
            want(3)?;
            Action::Orbit(num(1)?, num(2)?)
        }
        "pan" => {
            want(3)?;
            Action::Pan(num(1)?, num(2)?)
        }
        "zoom" => {
            want(2)?;
            Action::Zoom(num(1)?)
        }
        "resize" => {
            want(3)?;
            Action::Resize(size(1)?, size(2)?)
        }
        "capture" => {
            want(2)?;
            Action::Capture(base.join(words[1]))
        }
        "click" => {
            want(3)?;
            Action::Click(num(1)?, num(2)?)
        }
        "marks" => {
            want(2)?;
            Action::WriteMarks(Some(base.join(words[1])))
        }
        "wait" => {
            want(2)?;
            Action::Wait(size(1)?)
        }
        "quit" => {
            want(1)?;
            Action::Quit
        }
        "trained" => {
            want(1)?;
            Action::Trained
        }
        w => bail!("unknown action '{w}' (key, orbit, pan, zoom, resize, capture, click, marks, wait, trained, quit)"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn script_lines_become_the_keys_actions() {
        let dir = std::env::temp_dir().join(format!("tgs-view-script-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("s.txt");
        std::fs::write(&p, "# a path\nkey N\norbit 10 -5\n\nzoom -2 # out\nresize 1 1\ncapture a.png\nwait 3\nkey g\nclick 3 4.5\nmarks m\nkey escape\n").unwrap();
        let a = read_script(&p).unwrap();
        assert_eq!(
            a,
            vec![
                Action::Camera(1),
                Action::Orbit(10.0, -5.0),
                Action::Zoom(-2.0),
                Action::Resize(1, 1),
                Action::Capture(dir.join("a.png")),
                Action::Wait(3),
                Action::MarkMode,
                Action::Click(3.0, 4.5),
                Action::WriteMarks(Some(dir.join("m"))),
                Action::Quit
            ]
        );
        for (bad, what) in [("key Z", "no key 'Z'"), ("orbit 1", "takes 2 argument"), ("resize 0 4", "not a size"), ("zoom nan", "not a number"), ("jump", "unknown action")] {
            std::fs::write(&p, format!("key N\n{bad}\n")).unwrap();
            let e = format!("{:#}", read_script(&p).unwrap_err());
            assert!(e.contains(":2:") && e.contains(what), "{bad}: {e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
