//! `ground tradeoff`: the seed paper's Figures 9–10 from a recording (`host_test::tradeoff`).

use crate::common::spinner;
use anyhow::Result;
use host_test::load;
use shared::wire::clock::FPGA_BASE_RATE_MILLIHZ;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The recording to place (any format the other commands read).
    rec: PathBuf,
    /// A board: `seed` (the paper's board with its Raspberry Pi), `ours` (with the STM32F405) or a board TOML file;
    /// repeat for several (default: seed and ours).
    #[arg(long)]
    board: Vec<String>,
    /// The IMU catalogue (default: data/imus.toml as built in).
    #[arg(long)]
    catalogue: Option<PathBuf>,
    /// mcu-bench's report (default: docs/mcu-bench.json as built in).
    #[arg(long)]
    mcu_bench: Option<PathBuf>,
    /// Directory for tradeoff_mass.png, tradeoff_power.png, tradeoff.md and tradeoff.json.
    #[arg(long, default_value = "tradeoff-out")]
    out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let pb = spinner("reading");
    let rec = load::load_with(&a.rec, None, FPGA_BASE_RATE_MILLIHZ)?.recording;
    pb.set_message("Allan deviations, budgets, plots");
    let inputs = host_test::tradeoff::Inputs {
        catalogue: a.catalogue,
        boards: a.board,
        mcu_bench: a.mcu_bench,
    };
    let t = host_test::tradeoff::run(&rec, &a.rec.display().to_string(), &inputs, &a.out)?;
    pb.finish_and_clear();
    print!("{}", host_test::tradeoff::render::summary(&t));
    println!("outputs in {}", a.out.display());
    Ok(())
}
