//! A sensor's bandwidth ([`Bandwidth`]): a single-pole low-pass response on a simulation's outputs, applied to
//! each chunk as the simulation streams ([`BandwidthFilter`]).

use crate::allan::noisefit::LowPass;
use crate::sim::{Axis, Chunk, GROUPS};

/// A sensor's bandwidth: the groups (all when `None`) and axes whose output passes a single-pole low-pass filter at
/// `cutoff_hz` (`--bandwidth-hz`).
#[derive(Clone, Debug, PartialEq)]
pub struct Bandwidth {
    /// Groups (all when `None`).
    pub groups: Option<Vec<usize>>,
    /// Axes.
    pub axes: Vec<Axis>,
    /// Cut-off, Hz.
    pub cutoff_hz: f64,
}

/// The single-pole low-pass filters of a simulation's outputs ([`Bandwidth`]), applied to each chunk's physical
/// values in place as the simulation streams (state kept across chunks; the first sample starts the filter at its
/// own value, so a static record has no transient).
#[derive(Clone, Debug)]
pub struct BandwidthFilter {
    /// (group, axis index 0..6, pole φ, state).
    taps: Vec<(usize, usize, f64, Option<f64>)>,
}

impl BandwidthFilter {
    /// The filters at output rate `rate_hz` (a later option for the same group and axis replaces an earlier one).
    pub fn new(bands: &[Bandwidth], rate_hz: f64) -> Self {
        let mut taps: Vec<(usize, usize, f64, Option<f64>)> = Vec::new();
        for b in bands {
            let phi = LowPass {
                cutoff_hz: b.cutoff_hz,
                tau0_s: 1.0 / rate_hz,
            }
            .pole();
            let groups: Vec<usize> = b.groups.clone().unwrap_or_else(|| (0..GROUPS).collect());
            for &g in &groups {
                for a in &b.axes {
                    let ai = a.index();
                    taps.retain(|t| !(t.0 == g && t.1 == ai));
                    taps.push((g, ai, phi, None));
                }
            }
        }
        Self { taps }
    }

    /// Filters the chunk's physical values in place.
    pub fn apply(&mut self, chunk: &mut Chunk) {
        let len = chunk.len.min(chunk.phys.len());
        for (g, a, phi, state) in &mut self.taps {
            if *g >= GROUPS || *a >= 6 {
                continue;
            }
            for row in &mut chunk.phys[..len] {
                row[*g][*a] = LowPass::step(*phi, state, row[*g][*a]);
            }
        }
    }
}
