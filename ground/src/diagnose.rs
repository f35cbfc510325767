//! `ground diagnose`: the sim-to-real diagnosis of a static cluster recording.

use crate::common::{any_calib, apply_window, print_loaded, spinner};
use anyhow::{Context, Result};
use clap::ValueEnum;
use host_test::load;
use shared::wire::clock::FPGA_BASE_RATE_MILLIHZ;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
enum WeightsArg {
    /// Equal weights (the seed's mean).
    Equal,
    /// Inverse white-noise variance.
    InverseVariance,
}

#[derive(clap::Args)]
pub struct Args {
    /// Static recording: interchange CSV, NumPy .npy array, FPGA frame log or MIMU4444 stream.
    recording: PathBuf,
    /// Time window START:END in seconds.
    #[arg(long)]
    window: Option<String>,
    /// Output folder for report.txt and diagnose.png.
    #[arg(long, default_value = "diagnose-out")]
    out: PathBuf,
    /// JSON result file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also write the fitted cluster model (the twin: `docs/twin.md`) to this TOML file, for `ground simulate
    /// --model`.
    #[arg(long)]
    model: Option<PathBuf>,
    /// With --model: check the fit against N records played from the fitted model, diagnosed and fitted the same
    /// way: how many octave τ the terms leave outside the record's 68 % interval, beside what records of exactly
    /// this model score, and the Monte Carlo p-value (a parametric bootstrap; docs/twin.md). Each replica costs
    /// about one diagnosis and one fit.
    #[arg(long, requires = "model", value_name = "N")]
    check_fit: Option<usize>,
    /// Weights of the cluster mean.
    #[arg(long, value_enum, default_value = "equal")]
    weights: WeightsArg,
    /// Override: leave out octave tau whose half holds fewer averaging blocks (default: every tau down to 4 blocks,
    /// each with its own EDF).
    #[arg(long)]
    min_blocks: Option<usize>,
    /// MIMU4444 stream: diagnose the longest static interval (found as `calibrate --static` finds poses), or its
    /// longest quiet part when shared disturbances (transients every sensor saw: docs/diagnose.md) lie inside it.
    #[arg(long, conflicts_with = "window")]
    longest_static: bool,
    /// With --longest-static: keep the whole interval, shared disturbances included.
    #[arg(long, requires = "longest_static")]
    keep_disturbances: bool,
    /// Calibration table (.bin) for raw inputs.
    #[arg(long)]
    calib: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    use host_test::diagnose::{self, Options, WeightRule, report};
    let cal = any_calib(&a.calib)?;
    let pb = spinner("reading");
    let mut loaded = load::load_with(&a.recording, cal.as_ref(), FPGA_BASE_RATE_MILLIHZ)?;
    // Through `suspend`: the spinner's own `println` prints nothing when stderr is not a terminal.
    pb.suspend(|| print_loaded(&loaded));
    if let Some(w) = &a.window {
        apply_window(&mut loaded.recording, w)?;
    }
    if a.longest_static {
        let m = host_test::formats::mimu::read(&a.recording)
            .map_err(|e| anyhow::anyhow!("--longest-static needs a MIMU4444 stream: {e}"))?;
        let p_false = Options::default().p_false;
        let ls = diagnose::quiet::longest_static(&m, &loaded.recording, p_false)
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .context("no static interval found")?;
        // Through `suspend`: `pb.println` prints nothing when stderr is not a terminal.
        pb.suspend(|| {
            println!(
                "longest static interval: {:.3} … {:.3} s ({:.1} s of {} poses)",
                ls.start_s,
                ls.end_s,
                ls.end_s - ls.start_s,
                ls.poses
            )
        });
        let (quiet, found) = (ls.quiet, ls.disturbances);
        if found.is_empty() {
            loaded.recording = quiet;
        } else if a.keep_disturbances {
            loaded.recording = diagnose::quiet::interval(&loaded.recording, ls.start_s, ls.end_s);
        } else {
            let (t0, t1) = (
                quiet.t_s.first().copied().unwrap_or(f64::NAN),
                quiet.t_s.last().copied().unwrap_or(f64::NAN),
            );
            pb.suspend(|| {
                for d in &found {
                    println!(
                        "shared disturbance: {} {} at {:.3} … {:.3} s, variance ×{:.1} (threshold ×{:.2})",
                        d.sensor,
                        d.axis,
                        ls.start_s + d.start_s,
                        ls.start_s + d.end_s,
                        d.variance_ratio,
                        d.threshold
                    );
                }
                println!(
                    "diagnosing its longest quiet part: {t0:.3} … {t1:.3} s ({:.1} s; --keep-disturbances for all)",
                    t1 - t0
                )
            });
            loaded.recording = quiet;
        }
    }
    pb.set_message("fitting noise models and effects");
    let opts = Options {
        weights: match a.weights {
            WeightsArg::Equal => WeightRule::Equal,
            WeightsArg::InverseVariance => WeightRule::InverseVariance,
        },
        min_blocks: a.min_blocks.unwrap_or(Options::default().min_blocks),
        ..Options::default()
    };
    let r = diagnose::diagnose(&loaded.recording, &opts)?;
    pb.finish_and_clear();
    let source = a.recording.display().to_string();
    let text = report::write(&r, &a.out, &source)?;
    print!("{text}");
    println!(
        "\nreport: {}, plot: {}",
        a.out.join(report::TEXT_FILE).display(),
        a.out.join(report::PLOT_FILE).display()
    );
    if let Some(j) = &a.json {
        std::fs::write(j, serde_json::to_string_pretty(&r)?)
            .with_context(|| format!("writing {}", j.display()))?;
        println!("json: {}", j.display());
    }
    if let Some(m) = &a.model {
        let model = host_test::twin::fit(&loaded.recording, &r, &source)?;
        model.save(m)?;
        println!(
            "model: {} ({} axes, {} shared processes, temperature {})",
            m.display(),
            model.axes.len(),
            model.axes.iter().map(|x| x.shared.len()).sum::<usize>(),
            if model.temperature.is_some() {
                "modelled"
            } else {
                "absent"
            }
        );
        for axis in &model.axes {
            if let Some(c) = &axis.coverage {
                println!("  {}: {}", axis.axis, c.summary());
            }
        }
        let seeds: Vec<u64> = (1..=a.check_fit.unwrap_or(0) as u64).collect();
        let pb = spinner("checking the fit");
        let check = host_test::twin::coverage::check(&model, &seeds, &opts)?;
        pb.finish_and_clear();
        println!("fit: the terms are {}", check.summary());
    }
    Ok(())
}
