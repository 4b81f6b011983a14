//! What a training run tells its user while it runs: the progress bar on a
//! terminal (plain lines every 100 iterations otherwise, nothing with
//! `--quiet`), the messages between stages, the periodic test metrics,
//! and `RUN/log.jsonl`, one JSON line per iteration and per stage event.

use super::trainer::StepReport;
use crate::eval::Metrics;
use anyhow::{Context as _, Result};
use serde_json::{json, Value};
use std::fs::File;
use std::io::{IsTerminal, Write};
use std::path::Path;

pub struct Reporter {
    log: File,
    bar: Option<indicatif::ProgressBar>,
    quiet: bool,
}

impl Reporter {
    /// A reporter for a run of `total` iterations now at `position`, its
    /// log in `out` (appended to when `resume`, started afresh otherwise).
    pub fn open(out: &Path, resume: bool, quiet: bool, total: u32, position: u32) -> Result<Reporter> {
        let log = std::fs::OpenOptions::new().create(true).append(resume).write(true).truncate(!resume).open(out.join("log.jsonl")).context("opening log.jsonl")?;
        let tty = std::io::stderr().is_terminal() && !quiet;
        let bar = if tty {
            let b = indicatif::ProgressBar::new(total as u64);
            b.set_style(indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} [{elapsed_precise} < {eta}, {per_sec}]").unwrap());
            b.set_position(position as u64);
            Some(b)
        } else {
            None
        };
        Ok(Reporter { log, bar, quiet })
    }

    /// A line on stderr (above the bar), unless quiet.
    pub fn say(&self, msg: &str) {
        if let Some(b) = &self.bar {
            b.println(msg);
        } else if !self.quiet {
            eprintln!("{msg}");
        }
    }

    /// A stage began: its message, the log's event line, and the bar's new
    /// length (`total`: the schedule's, which a skipped stage shortens).
    pub fn stage_event(&mut self, msg: &str, event: Option<&Value>, total: u32) -> Result<()> {
        if let Some(b) = &self.bar {
            b.set_length(total as u64);
        }
        self.say(msg);
        if let Some(e) = event {
            writeln!(self.log, "{e}")?;
        }
        Ok(())
    }

    /// The log line of iteration `r` (of the schedule entry `label`):
    /// `its` iterations per second, `elapsed_s` the run's wall time,
    /// `phi_fraction` the share of pixels the light field ran on.
    pub fn iteration_line(r: &StepReport, label: &str, its: f64, elapsed_s: f64, phi_fraction: Option<f64>) -> Value {
        let mut line = json!({
            "iteration": r.iteration, "stage": label, "view": r.view, "loss": r.loss, "l1": r.values.l1, "ssim": r.values.ssim,
            "psnr": r.values.psnr(), "gaussians": r.gaussians, "it_per_s": its, "elapsed_s": elapsed_s,
        });
        if r.values.normal.is_finite() {
            line["normal"] = json!(r.values.normal);
        }
        if r.opacity_reset {
            line["opacity_reset"] = json!(true);
        }
        if let Some(f) = phi_fraction {
            line["phi_fraction"] = json!(f);
        }
        if let Some((b, a)) = r.densified {
            line["densified"] = json!({"before": b, "after": a});
        }
        line
    }

    /// The periodic test metrics `m` into the iteration's `line`, and on
    /// stderr when there is no bar.
    pub fn test_metrics(&self, line: &mut Value, iteration: u32, m: &Metrics) {
        line["test"] = json!({"psnr": m.psnr, "ssim": m.ssim, "lpips": m.lpips, "normal_mae_deg": m.normals.normal_mae_deg, "reflection_coverage": m.normals.reflection_coverage, "normal_mae_covered_deg": m.normals.normal_mae_covered_deg});
        if self.bar.is_none() && !self.quiet {
            eprintln!("[{iteration}] test PSNR {:.2} SSIM {:.4}{}", m.psnr, m.ssim, lpips_text(m.lpips));
        }
    }

    /// Iteration `r` of `total` done: its log `line`, and the bar or (every
    /// 100 iterations and at the end) a plain line.
    pub fn iteration(&mut self, r: &StepReport, line: &Value, total: u32, its: f64) -> Result<()> {
        writeln!(self.log, "{line}")?;
        let msg = format!("loss {:.4} PSNR {:.2} N {}", r.loss, r.values.psnr(), r.gaussians);
        if let Some(b) = &self.bar {
            b.set_position(r.iteration as u64);
            b.set_message(msg);
        } else if !self.quiet && (r.iteration.is_multiple_of(100) || r.iteration == total) {
            let eta = (total - r.iteration) as f64 / its.max(1e-9);
            eprintln!("[{}/{total}] {msg} {its:.2} it/s ETA {eta:.0}s", r.iteration);
        }
        Ok(())
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish();
        }
    }
}

/// ", LPIPS 0.123" (nothing without one).
pub fn lpips_text(l: Option<f64>) -> String {
    l.map(|v| format!(", LPIPS {v:.4}")).unwrap_or_default()
}
