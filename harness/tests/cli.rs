//! The `tgs` command line as a user types it: options that were ignored or
//! accepted with nonsense values before are now honoured or refused with a
//! message, before any work or allocation.

use std::process::{Command, Output};

fn tgs(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tgs")).args(args).env_remove("TGS_DEVICE").output().expect("running tgs")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Fails with a message holding every needle.
fn refused(args: &[&str], needles: &[&str]) {
    let o = tgs(args);
    let t = text(&o);
    assert!(!o.status.success(), "tgs {args:?} should fail:\n{t}");
    assert!(o.status.code().is_some(), "tgs {args:?} ended by a signal (an abort?):\n{t}");
    for n in needles {
        assert!(t.contains(n), "tgs {args:?}: '{n}' missing from:\n{t}");
    }
    assert!(!t.contains("panicked") && !t.contains("memory allocation"), "tgs {args:?}:\n{t}");
}

#[test]
fn render_frames_are_bounded() {
    // Before: --frames 0 rendered one frame, 4294967295 aborted allocating 309 GB.
    refused(&["render", "no-such-run", "--cameras", "orbit", "--frames", "0"], &["--frames", "0"]);
    refused(&["render", "no-such-run", "--cameras", "orbit", "--frames", "4294967295"], &["--frames"]);
}

#[test]
fn sweep_print_grid_needs_no_out() {
    let o = tgs(&["sweep", "--print-grid"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("[knobs]"));
    refused(&["sweep"], &["--out"]);
}

#[test]
fn devices_honours_device() {
    let all = tgs(&["devices", "--json"]);
    assert!(all.status.success(), "{}", text(&all));
    let list: serde_json::Value = serde_json::from_slice(&all.stdout).unwrap();
    let n = list.as_array().unwrap().len();
    refused(&["devices", "--device", "7"], &["--device 7", "no such Vulkan device"]);
    refused(&["devices", "--device", "no-such-gpu-name"], &["no-such-gpu-name"]);
    if n > 0 {
        let one = tgs(&["devices", "--json", "--device", "0"]);
        let v: serde_json::Value = serde_json::from_slice(&one.stdout).unwrap();
        assert_eq!(v.as_array().unwrap().len(), 1);
        assert_eq!(v[0]["index"], 0);
    }
}

#[test]
fn benches_refuse_sizes_that_cannot_run() {
    // Before: 19 GB of host memory and no output; an error after 45 s; -inf and NaN rates.
    refused(&["bench", "raster", "--n", "2147483648"], &["--n 2147483648", "MiB"]);
    refused(&["bench", "sort", "--n", "4294967295"], &["--n 4294967295"]);
    refused(&["bench", "sort", "--reps", "0"], &["--reps"]);
    refused(&["bench", "scan", "--reps", "0"], &["--reps"]);
    refused(&["bench", "mlp", "--n", "0"], &["--n 0"]);
    refused(&["bench", "mlp", "--reps", "0", "--preset", "small"], &["--reps"]);
    refused(&["bench", "train", "--light-field", "large"], &["--light-field", "large"]);
    refused(&["bench", "train", "--light-field", "small", "--from", "run"], &["--light-field"]);
    refused(&["bench", "raster", "--width", "0"], &["--width"]);
}
