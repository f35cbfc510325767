//! `ground import`: a frame log, MIMU4444 stream or CSV to the interchange CSV.

use crate::common::{any_calib, millihz, print_loaded, spinner};
use anyhow::{Context, Result};
use host_test::load;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Input: FPGA frame log, MIMU4444 stream, interchange CSV or NumPy .npy array (t, then gx gy gz ax ay az per
    /// group).
    input: PathBuf,
    /// Output CSV.
    #[arg(long)]
    out: PathBuf,
    /// Calibration (.bin, .json or .toml; 16 groups for frame logs, 8 IMUs for MIMU4444 streams). Without it: the
    /// board's factory default, or the MIMU4444's nominal scales in each IMU's own frame.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// FPGA base rate before decimation, Hz (frame logs).
    #[arg(long, default_value_t = host_test::FPGA_BASE_RATE_HZ)]
    base_rate_hz: f64,
}

pub fn run(a: Args) -> Result<()> {
    let cal = any_calib(&a.calib)?;
    let pb = spinner("reading");
    let loaded = load::load_with(&a.input, cal.as_ref(), millihz(a.base_rate_hz)?)?;
    pb.set_message("writing");
    loaded
        .recording
        .write(&a.out)
        .with_context(|| format!("writing {}", a.out.display()))?;
    pb.finish_and_clear();
    print_loaded(&loaded);
    let r = &loaded.recording;
    println!(
        "{}: {} samples × {} columns, {:.1} s",
        a.out.display(),
        r.len(),
        r.columns.len(),
        r.t_s.last().unwrap_or(&0.0) - r.t_s.first().unwrap_or(&0.0)
    );
    Ok(())
}
