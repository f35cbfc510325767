//! `ground demo`: the seed experiment simulated, run through the flight core and reported.

use crate::common::bar;
use anyhow::{Result, bail};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    out: PathBuf,
    /// Simulation seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Duration, hours (the seed experiment: 8).
    #[arg(long, default_value_t = 8.0)]
    hours: f64,
}

pub fn run(a: Args) -> Result<()> {
    use host_test::demo::{self, DemoOptions};
    if !(a.hours.is_finite() && a.hours > 0.0 && a.hours <= 100.0) {
        bail!("--hours must be in (0, 100]");
    }
    let opts = DemoOptions {
        seed: a.seed,
        hours: a.hours,
    };
    let pb = bar(0, "frames");
    let r = demo::run(opts, &a.out, |done, total| {
        pb.set_length(total);
        pb.set_position(done);
    })?;
    pb.finish_and_clear();
    print!("{}", demo::report(&r, opts));
    println!("\noutputs in {}", a.out.display());
    Ok(())
}
