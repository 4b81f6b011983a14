//! scripts/slurm/train-task.sh, the job-array task, driven as SLURM drives
//! it (no SLURM daemon here: the scheduler's part is the environment it sets,
//! the SIGTERM it sends before the time limit, and running the task again
//! after `scontrol requeue`, which a stand-in on PATH records): a training
//! interrupted by SIGTERM requeues itself, and the rerun resumes and ends
//! bit-identical to an uninterrupted run; a rerun of a finished task leaves
//! it as it is; a task without a dataset line is refused.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/slurm/train-task.sh")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// The task command with SLURM's environment for array task 0 of job 77.
fn task(base: &Path, root: &str) -> Command {
    let mut c = Command::new("bash");
    c.arg(script()).arg(base.join("datasets.txt")).arg(base.join(root));
    c.args(["--stages", "I", "--quiet", "--set", "iterations=200", "--set", "test_interval=0", "--set", "checkpoint_interval=0"]);
    let path = format!("{}:{}", base.join("bin").display(), std::env::var("PATH").unwrap_or_default());
    c.env("TGS", env!("CARGO_BIN_EXE_tgs")).env("PATH", path).env("SLURM_ARRAY_TASK_ID", "0").env_remove("TGS_DEVICE");
    c
}

fn arrays(run: &Path) -> (u32, Vec<Vec<u32>>) {
    let (h, a) = tgs::train::checkpoint::read(&run.join("checkpoint.bin")).unwrap();
    (h.iteration, a.iter().map(|v| v.iter().map(|x| x.to_bits()).collect()).collect())
}

#[test]
fn a_requeued_task_resumes_and_ends_as_an_uninterrupted_one() {
    let base = std::env::temp_dir().join(format!("tgs-slurm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&base);
    std::fs::create_dir_all(base.join("bin")).unwrap();
    let scene = base.join("glass-tiny");
    let o = Command::new(env!("CARGO_BIN_EXE_tgs")).args(["scene", "make", "glass-tiny", "--out"]).arg(&scene).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    std::fs::write(base.join("datasets.txt"), format!("# one dataset per line\n\n{}\n", scene.display())).unwrap();
    // scontrol's stand-in: records the requeue.
    let log = base.join("scontrol.log");
    let fake = base.join("bin/scontrol");
    std::fs::write(&fake, format!("#!/bin/sh\necho \"$@\" >> '{}'\n", log.display())).unwrap();
    Command::new("chmod").arg("+x").arg(&fake).status().unwrap();

    // Uninterrupted.
    let o = task(&base, "a").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let (it, whole) = arrays(&base.join("a/glass-tiny"));
    assert_eq!(it, 200);

    // SIGTERM to the task (SLURM's --signal=B:TERM goes to the batch
    // shell) once 40 iterations are logged.
    let child = task(&base, "b").env("SLURM_JOB_ID", "78").env("SLURM_ARRAY_JOB_ID", "77").stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let run = base.join("b/glass-tiny");
    let t0 = std::time::Instant::now();
    while std::fs::read_to_string(run.join("log.jsonl")).map(|s| s.lines().count()).unwrap_or(0) < 40 {
        assert!(t0.elapsed().as_secs() < 300, "the task logged no iterations");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    let o = child.wait_with_output().unwrap();
    let t = text(&o);
    assert!(o.status.success(), "the interrupted task requeues itself and exits 0:\n{t}");
    assert!(t.contains("requeueing 77_0"), "{t}");
    assert_eq!(std::fs::read_to_string(&log).unwrap().trim(), "requeue 77_0");
    let (stopped, _) = arrays(&run);
    assert!(stopped > 0 && stopped < 200, "stopped at {stopped}");

    // The requeued task resumes and ends bit for bit as the uninterrupted run.
    let o = task(&base, "b").env("SLURM_JOB_ID", "78").env("SLURM_ARRAY_JOB_ID", "77").output().unwrap();
    assert!(o.status.success() && text(&o).contains("resuming"), "{}", text(&o));
    assert_eq!(arrays(&run), (200, whole.clone()), "the resumed run differs from the uninterrupted one");
    let lines = std::fs::read_to_string(run.join("log.jsonl")).unwrap();
    assert_eq!(lines.lines().filter(|l| l.contains("\"loss\"")).count(), 200, "each iteration logged once");

    // Run again after it finished: nothing trains, the checkpoint stays.
    let before = std::fs::read(run.join("checkpoint.bin")).unwrap();
    let o = task(&base, "b").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(std::fs::read(run.join("checkpoint.bin")).unwrap(), before);

    // Outside SLURM an interrupted task exits 130 and says how to go on.
    let child = task(&base, "c").stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let run_c = base.join("c/glass-tiny");
    while std::fs::read_to_string(run_c.join("log.jsonl")).map(|s| s.lines().count()).unwrap_or(0) < 10 {
        assert!(t0.elapsed().as_secs() < 600, "the task logged no iterations");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", text(&o));
    assert!(text(&o).contains("run this task again to resume"), "{}", text(&o));

    // A task past the list is refused, naming the list and the task.
    let o = task(&base, "d").env("SLURM_ARRAY_TASK_ID", "1").output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("datasets.txt has no dataset for array task 1"), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&base);
}
