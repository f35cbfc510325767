//! Navigation increments: the angle and velocity increments ΔΘ and ΔV over an output interval, integrated at the
//! frame rate from the fused angular rate and specific force, with the coning and sculling corrections a strapdown
//! navigation filter needs (Savage, *Strapdown Analytics*, §7.1.1.1 and §7.2.2.2; the two-sample "previous
//! interval" form of the coning term is also what PX4's `IntegratorConing` uses).
//!
//! Per frame j (incremental angle α_j = ω_j·dt_j, incremental velocity υ_j = f_j·dt_j; α, υ the sums so far in the
//! interval; α_p, υ_p the previous frame's increments, across interval boundaries):
//!
//! ```text
//! coning    β += ½ (α + α_p/6) × α_j
//! sculling  s += ½ [(α + α_p/6) × υ_j + (υ + υ_p/6) × α_j]
//! then      α += α_j,  υ += υ_j
//! interval  ΔΘ = α + β,   ΔV = υ + ½ α × υ + s        (½ α × υ: the rotation compensation)
//! ```
//!
//! Arithmetic in `f32` (the Cortex-M4F has an FPU): the increments of one interval are small (≤ 4096 frames), and the
//! tests bound the error against an `f64` reference of the motion. A frame that was lost is bridged by holding the
//! last rate and specific force over its time step, counted in [`Increments::bridged`], so the interval's `dt`
//! never silently shortens.

/// A 3-vector.
pub type V3 = [f32; 3];

fn cross(a: V3, b: V3) -> V3 {
    let [ax, ay, az] = a;
    let [bx, by, bz] = b;
    [ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx]
}

fn add(a: V3, b: V3) -> V3 {
    let [ax, ay, az] = a;
    let [bx, by, bz] = b;
    [ax + bx, ay + by, az + bz]
}

fn scale(a: V3, k: f32) -> V3 {
    let [x, y, z] = a;
    [x * k, y * k, z * k]
}

/// The increments of one output interval.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Increments {
    /// Angle increment ΔΘ (rotation vector, body frame), rad.
    pub dtheta_rad: V3,
    /// Velocity increment ΔV (specific force integrated, body frame at the interval's end), m/s.
    pub dv_mps: V3,
    /// Length of the interval, s.
    pub dt_s: f32,
    /// Frames integrated (bridged ones included).
    pub frames: u32,
    /// Frames bridged (lost, filled with the last rate and specific force).
    pub bridged: u32,
}

/// The integrator (see the module documentation).
#[derive(Clone, Copy, Debug, Default)]
pub struct NavIntegrator {
    alpha: V3,
    beta: V3,
    nu: V3,
    scul: V3,
    alpha_prev: V3,
    nu_prev: V3,
    last_rate: V3,
    last_force: V3,
    dt_s: f32,
    frames: u32,
    bridged: u32,
    corrections: bool,
}

impl NavIntegrator {
    /// An integrator with the coning and sculling corrections on.
    pub const fn new() -> Self {
        Self::with_corrections(true)
    }

    /// An integrator with the corrections on or off (off: plain sums of rate·dt and force·dt, for comparison).
    pub const fn with_corrections(corrections: bool) -> Self {
        Self {
            alpha: [0.0; 3],
            beta: [0.0; 3],
            nu: [0.0; 3],
            scul: [0.0; 3],
            alpha_prev: [0.0; 3],
            nu_prev: [0.0; 3],
            last_rate: [0.0; 3],
            last_force: [0.0; 3],
            dt_s: 0.0,
            frames: 0,
            bridged: 0,
            corrections,
        }
    }

    /// One frame: angular rate (rad/s) and specific force (m/s²) over its time step `dt_s`.
    pub fn add(&mut self, rate_rps: V3, force_mps2: V3, dt_s: f32) {
        let (a, v) = (scale(rate_rps, dt_s), scale(force_mps2, dt_s));
        if self.corrections {
            let ap = add(self.alpha, scale(self.alpha_prev, 1.0 / 6.0));
            let vp = add(self.nu, scale(self.nu_prev, 1.0 / 6.0));
            self.beta = add(self.beta, scale(cross(ap, a), 0.5));
            self.scul = add(self.scul, scale(add(cross(ap, v), cross(vp, a)), 0.5));
        }
        self.alpha = add(self.alpha, a);
        self.nu = add(self.nu, v);
        (self.alpha_prev, self.nu_prev) = (a, v);
        (self.last_rate, self.last_force) = (rate_rps, force_mps2);
        self.dt_s += dt_s;
        self.frames = self.frames.saturating_add(1);
    }

    /// `n` lost frames of `dt_s` each: bridged with the last rate and specific force, in closed form (the same as
    /// `n` calls of [`Self::add`] with those values, at any `n`). With a constant increment a (and v) every
    /// correction term but the first frame's is α₀ × a, α₀ the angle before the bridge:
    /// β += ½ n α₀ × a + (1/12) α_p × a, s += ½ n (α₀ × v + υ₀ × a) + (1/12)(α_p × v + υ_p × a).
    pub fn bridge(&mut self, n: u32, dt_s: f32) {
        if n == 0 {
            return;
        }
        let nf = n as f32;
        let (a, v) = (scale(self.last_rate, dt_s), scale(self.last_force, dt_s));
        if self.corrections {
            let (a0, v0) = (self.alpha, self.nu);
            let beta = add(
                scale(cross(a0, a), 0.5 * nf),
                scale(cross(self.alpha_prev, a), 1.0 / 12.0),
            );
            let scul = add(
                scale(add(cross(a0, v), cross(v0, a)), 0.5 * nf),
                scale(
                    add(cross(self.alpha_prev, v), cross(self.nu_prev, a)),
                    1.0 / 12.0,
                ),
            );
            self.beta = add(self.beta, beta);
            self.scul = add(self.scul, scul);
        }
        self.alpha = add(self.alpha, scale(a, nf));
        self.nu = add(self.nu, scale(v, nf));
        (self.alpha_prev, self.nu_prev) = (a, v);
        self.dt_s += dt_s * nf;
        self.frames = self.frames.saturating_add(n);
        self.bridged = self.bridged.saturating_add(n);
    }

    /// The increments since the last call; starts the next interval (the previous frame's increments stay, for the
    /// next interval's first correction terms).
    pub fn take(&mut self) -> Increments {
        let dv = if self.corrections {
            add(
                add(self.nu, scale(cross(self.alpha, self.nu), 0.5)),
                self.scul,
            )
        } else {
            self.nu
        };
        let out = Increments {
            dtheta_rad: add(self.alpha, self.beta),
            dv_mps: dv,
            dt_s: self.dt_s,
            frames: self.frames,
            bridged: self.bridged,
        };
        *self = Self {
            alpha_prev: self.alpha_prev,
            nu_prev: self.nu_prev,
            last_rate: self.last_rate,
            last_force: self.last_force,
            ..Self::with_corrections(self.corrections)
        };
        out
    }
}

#[cfg(test)]
mod tests;
