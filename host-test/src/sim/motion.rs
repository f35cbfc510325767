//! Motions of the board for the navigation increments (`shared::nav`): classic coning and in-phase sculling, each
//! with its true attitude and the body rate and specific force its sensors measure.
//!
//! - `coning:half_angle_deg=A,freq_hz=F`: body-to-reference attitude C(t) = Rz(Ωt)·Rx(a)·Rz(−Ωt), Ω = 2πF; body
//!   rate ω = Ω (Cᵀ e_z − e_z) (from Cᵀ Ċ = Ω (Cᵀ \[e_z\]× C − \[e_z\]×)).
//! - `sculling:angle_amp_deg=A,accel_amp_g=B,freq_hz=F`: C(t) = Rx(θ), θ = A sin Ωt, ω = (A Ω cos Ωt, 0, 0), and a
//!   linear acceleration B sin Ωt along the body y axis, in phase with the angle.
//!
//! In both the static specific force (the simulator's `accel_g`, e.g. 1 g up) is fixed in the reference frame and
//! seen through Cᵀ. Rates in °/s and specific force in g, as the simulator's sensors take them.

/// A 3 × 3 matrix, rows.
pub type M3 = [[f64; 3]; 3];

/// A board motion (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// Classic coning.
    Coning {
        /// Half-angle a, rad.
        half_angle_rad: f64,
        /// Coning frequency, Hz.
        freq_hz: f64,
    },
    /// In-phase angular and linear oscillation.
    Sculling {
        /// Angle amplitude A, rad.
        angle_amp_rad: f64,
        /// Linear acceleration amplitude B, g.
        accel_amp_g: f64,
        /// Frequency, Hz.
        freq_hz: f64,
    },
}

/// `a b`.
pub fn mul(a: &M3, b: &M3) -> M3 {
    core::array::from_fn(|i| core::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// `aᵀ v`.
pub fn mul_t(a: &M3, v: [f64; 3]) -> [f64; 3] {
    core::array::from_fn(|i| (0..3).map(|k| a[k][i] * v[k]).sum())
}

fn rx(x: f64) -> M3 {
    let (s, c) = x.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

fn rz(x: f64) -> M3 {
    let (s, c) = x.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

impl Motion {
    /// Parses `coning:half_angle_deg=A,freq_hz=F` or `sculling:angle_amp_deg=A,accel_amp_g=B,freq_hz=F`.
    pub fn parse(s: &str) -> Result<Self, super::SimError> {
        let (kind, rest) = s.split_once(':').unwrap_or((s, ""));
        let get = {
            let pairs: Vec<(&str, &str)> =
                rest.split(',').filter_map(|p| p.split_once('=')).collect();
            move |key: &str| -> Result<f64, super::SimError> {
                let v = pairs
                    .iter()
                    .find(|(k, _)| k.trim() == key)
                    .ok_or_else(|| {
                        super::SimError::Syntax(format!("--motion {kind}: missing {key}=…"))
                    })?
                    .1;
                let x: f64 = v.trim().parse().map_err(|_| {
                    super::SimError::Syntax(format!("--motion {kind}: {key}={v} is not a number"))
                })?;
                if x.is_finite() && x > 0.0 {
                    Ok(x)
                } else {
                    Err(super::SimError::Syntax(format!(
                        "--motion {kind}: {key} must be a positive number, found {v}"
                    )))
                }
            }
        };
        match kind {
            "coning" => Ok(Self::Coning {
                half_angle_rad: get("half_angle_deg")?.to_radians(),
                freq_hz: get("freq_hz")?,
            }),
            "sculling" => Ok(Self::Sculling {
                angle_amp_rad: get("angle_amp_deg")?.to_radians(),
                accel_amp_g: get("accel_amp_g")?,
                freq_hz: get("freq_hz")?,
            }),
            _ => Err(super::SimError::Syntax(format!(
                "--motion: expected coning:half_angle_deg=A,freq_hz=F or \
                 sculling:angle_amp_deg=A,accel_amp_g=B,freq_hz=F, found {s}"
            ))),
        }
    }

    /// The body-to-reference attitude at `t_s`.
    pub fn attitude(&self, t_s: f64) -> M3 {
        match *self {
            Self::Coning {
                half_angle_rad,
                freq_hz,
            } => {
                let w = 2.0 * core::f64::consts::PI * freq_hz;
                mul(&mul(&rz(w * t_s), &rx(half_angle_rad)), &rz(-w * t_s))
            }
            Self::Sculling {
                angle_amp_rad,
                freq_hz,
                ..
            } => rx(angle_amp_rad * (2.0 * core::f64::consts::PI * freq_hz * t_s).sin()),
        }
    }

    /// (body rate °/s, specific force g) at `t_s`, with `f_ref_g` the static specific force in the reference frame.
    pub fn at(&self, t_s: f64, f_ref_g: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let c = self.attitude(t_s);
        let f_static = mul_t(&c, f_ref_g);
        match *self {
            Self::Coning { freq_hz, .. } => {
                let w = 2.0 * core::f64::consts::PI * freq_hz;
                let ez = mul_t(&c, [0.0, 0.0, 1.0]);
                let rate = [ez[0], ez[1], ez[2] - 1.0].map(|x| (w * x).to_degrees());
                (rate, f_static)
            }
            Self::Sculling {
                angle_amp_rad,
                accel_amp_g,
                freq_hz,
            } => {
                let w = 2.0 * core::f64::consts::PI * freq_hz;
                let (s, co) = (w * t_s).sin_cos();
                let rate = [(angle_amp_rad * w * co).to_degrees(), 0.0, 0.0];
                (
                    rate,
                    [f_static[0], f_static[1] + accel_amp_g * s, f_static[2]],
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The body rate `at` gives equals the one differentiated numerically from the attitude: [ω]× = Cᵀ Ċ.
    #[test]
    fn body_rates_match_the_attitudes_derivative() {
        for m in [
            Motion::parse("coning:half_angle_deg=1,freq_hz=2").unwrap(),
            Motion::parse("coning:half_angle_deg=20,freq_hz=0.7").unwrap(),
            Motion::parse("sculling:angle_amp_deg=3,accel_amp_g=0.5,freq_hz=5").unwrap(),
        ] {
            for k in 0..50 {
                let t = 0.0137 * f64::from(k);
                let h = 1e-5;
                let (c0, c1, c) = (m.attitude(t - h), m.attitude(t + h), m.attitude(t));
                let dc: M3 = core::array::from_fn(|i| {
                    core::array::from_fn(|j| (c1[i][j] - c0[i][j]) / (2.0 * h))
                });
                let s: M3 = core::array::from_fn(|i| {
                    core::array::from_fn(|j| (0..3).map(|k| c[k][i] * dc[k][j]).sum())
                });
                let w_num = [s[2][1], s[0][2], s[1][0]].map(f64::to_degrees);
                let (w, _) = m.at(t, [0.0, 0.0, 1.0]);
                for i in 0..3 {
                    assert!(
                        (w[i] - w_num[i]).abs() < 1e-5 * (1.0 + w[i].abs()),
                        "{m:?} t={t}: {w:?} vs {w_num:?}"
                    );
                }
            }
        }
        assert!(Motion::parse("coning:half_angle_deg=1").is_err());
        assert!(Motion::parse("wobble:x=1").is_err());
        assert!(Motion::parse("coning:half_angle_deg=-1,freq_hz=2").is_err());
    }
}
