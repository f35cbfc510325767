//! `ground compare`: the sim-to-real gap measured directly between two recordings (`host_test::twin::compare`).

use crate::common::spinner;
use anyhow::{Context, Result};
use host_test::load;
use host_test::twin::compare::{P_FALSE, TOLERANCE};
use shared::wire::clock::FPGA_BASE_RATE_MILLIHZ;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The real recording (any format the other commands read).
    real: PathBuf,
    /// The simulated one (e.g. `ground simulate --model`).
    sim: PathBuf,
    /// Directory for compare.json and compare.png.
    #[arg(long, default_value = "compare-out")]
    out: PathBuf,
    /// False-alarm probability of the verdict per axis.
    #[arg(long, default_value_t = P_FALSE)]
    p_false: f64,
    /// Model tolerance, ln deviation (a simulation within it at a τ is not told apart there).
    #[arg(long, default_value_t = TOLERANCE)]
    tolerance: f64,
    /// SIM was played from a model fitted on another record than REAL (of the same length): count that record's
    /// estimation error too.
    #[arg(long)]
    fitted_elsewhere: bool,
}

pub fn run(a: Args) -> Result<()> {
    let pb = spinner("reading");
    let real = load::load_with(&a.real, None, FPGA_BASE_RATE_MILLIHZ)?.recording;
    let sim = load::load_with(&a.sim, None, FPGA_BASE_RATE_MILLIHZ)?.recording;
    pb.set_message("Allan deviations and verdicts");
    let c = host_test::twin::compare(
        &real,
        &sim,
        &host_test::twin::CompareOptions {
            p_false: a.p_false,
            tolerance: a.tolerance,
            fitted_elsewhere: a.fitted_elsewhere,
        },
    )?;
    pb.finish_and_clear();
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let json = a.out.join("compare.json");
    std::fs::write(&json, serde_json::to_string_pretty(&c)?)
        .with_context(|| format!("writing {}", json.display()))?;
    let png = a.out.join("compare.png");
    c.plot(
        &png,
        &format!("{} vs {}", a.real.display(), a.sim.display()),
    )?;
    print!("{}", c.summary());
    println!("json: {}, plot: {}", json.display(), png.display());
    Ok(())
}
