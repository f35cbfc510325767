//! Against an f64 reference of the motion: classic coning and in-phase sculling, sampled at 604.8 frames/s and
//! integrated over 32-frame intervals, as the pipeline would.
use super::*;

extern crate std;
use std::vec::Vec;

type M3 = [[f64; 3]; 3];
type D3 = [f64; 3];

fn mul(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn t(a: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = a[j][i];
        }
    }
    c
}

fn mv(a: &M3, v: D3) -> D3 {
    [0, 1, 2].map(|i| (0..3).map(|k| a[i][k] * v[k]).sum())
}

/// Rotation by `x` rad about the coordinate axis `k` (0 = x, 2 = z).
fn rot(k: usize, x: f64) -> M3 {
    let (s, c) = x.sin_cos();
    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
    let mut m = [[0.0; 3]; 3];
    m[k][k] = 1.0;
    (m[i][i], m[i][j], m[j][i], m[j][j]) = (c, -s, s, c);
    m
}

fn rx(x: f64) -> M3 {
    rot(0, x)
}

fn rz(x: f64) -> M3 {
    rot(2, x)
}

/// exp of a rotation vector (Rodrigues).
fn exp(v: D3) -> M3 {
    let th = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let k = if th > 0.0 {
        v.map(|x| x / th)
    } else {
        [0.0; 3]
    };
    let kx: M3 = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let kx2 = mul(&kx, &kx);
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] =
                f64::from(u8::from(i == j)) + th.sin() * kx[i][j] + (1.0 - th.cos()) * kx2[i][j];
        }
    }
    r
}

/// Angle of a rotation matrix, rad.
fn angle(r: &M3) -> f64 {
    ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
}

const FPS: f64 = 604.8;
const PER_OUTPUT: usize = 32;

/// Classic coning, C(t) = Rz(Ωt)·Rx(a)·Rz(−Ωt) body-to-reference; body rate ω = Ω (Cᵀ e_z − e_z).
fn coning(a: f64, omega: f64, t_s: f64) -> (M3, D3) {
    let c = mul(&mul(&rz(omega * t_s), &rx(a)), &rz(-omega * t_s));
    let ez = mv(&t(&c), [0.0, 0.0, 1.0]);
    (c, [omega * ez[0], omega * ez[1], omega * (ez[2] - 1.0)])
}

/// The attitude error after `seconds` of coning when the attitude is composed from the integrator's ΔΘ.
fn coning_error(corrections: bool, a: f64, f_hz: f64, seconds: f64) -> f64 {
    let omega = 2.0 * core::f64::consts::PI * f_hz;
    let dt = 1.0 / FPS;
    let frames = (seconds * FPS).round() as usize;
    let mut nav = NavIntegrator::with_corrections(corrections);
    let mut c_est = coning(a, omega, 0.0).0;
    for j in 0..frames {
        // The frame's rate: the sample at the middle of its time step.
        let (_, w) = coning(a, omega, (j as f64 + 0.5) * dt);
        nav.add(w.map(|x| x as f32), [0.0; 3], dt as f32);
        if (j + 1) % PER_OUTPUT == 0 || j + 1 == frames {
            let inc = nav.take();
            c_est = mul(&c_est, &exp(inc.dtheta_rad.map(f64::from)));
        }
    }
    let c_true = coning(a, omega, frames as f64 * dt).0;
    angle(&mul(&t(&c_true), &c_est))
}

#[test]
fn coning_drift_is_removed() {
    // a = 1°, 2 Hz, 60 s (120 coning periods), 32-frame outputs: theory for plain sums of rate·dt,
    // ε = ½ a² Ω (1 − sin ΩT / ΩT) per second.
    let (a, f_hz, secs) = (1f64.to_radians(), 2.0, 60.0);
    let omega = 2.0 * core::f64::consts::PI * f_hz;
    let big_t = PER_OUTPUT as f64 / FPS;
    let theory = 0.5 * a * a * omega * (1.0 - (omega * big_t).sin() / (omega * big_t)) * secs;
    let plain = coning_error(false, a, f_hz, secs);
    let corrected = coning_error(true, a, f_hz, secs);
    std::eprintln!(
        "coning 60 s: theory {theory:.3e} rad, plain sums {plain:.3e}, corrected {corrected:.3e}"
    );
    assert!(
        (plain - theory).abs() < 0.05 * theory,
        "{plain} vs {theory}"
    );
    assert!(corrected < 0.05 * theory, "{corrected}");
}

/// In-phase angular and linear oscillation: ω = A_ω sin Ωt about x, f = A_f sin Ωt along y (body): the classic
/// sculling motion, in which plain sums of f·dt rectify into a false, growing velocity. The reference integrates
/// C(t) f(t) in f64.
fn sculling_error(corrections: bool, seconds: f64) -> (f64, f64) {
    let (a_w, a_f, omega) = (0.05, 5.0, 2.0 * core::f64::consts::PI * 2.0);
    let theta = |t: f64| a_w / omega * (1.0 - (omega * t).cos());
    let dt = 1.0 / FPS;
    let frames = (seconds * FPS).round() as usize;
    let mut nav = NavIntegrator::with_corrections(corrections);
    let (mut v_ref, mut v_est) = ([0.0f64; 3], [0.0f64; 3]);
    let mut c_est = rx(0.0);
    for j in 0..frames {
        let tm = (j as f64 + 0.5) * dt;
        let s = (omega * tm).sin();
        nav.add(
            [(a_w * s) as f32, 0.0, 0.0],
            [0.0, (a_f * s) as f32, 0.0],
            dt as f32,
        );
        // Reference: ∫ C(t) f(t) dt over the step by Simpson's rule.
        let g = |t: f64| mv(&rx(theta(t)), [0.0, a_f * (omega * t).sin(), 0.0]);
        let (t0, t1) = (j as f64 * dt, (j + 1) as f64 * dt);
        let (g0, gm, g1) = (g(t0), g(0.5 * (t0 + t1)), g(t1));
        for k in 0..3 {
            v_ref[k] += dt / 6.0 * (g0[k] + 4.0 * gm[k] + g1[k]);
        }
        if (j + 1) % PER_OUTPUT == 0 || j + 1 == frames {
            let inc = nav.take();
            let dv = mv(&c_est, inc.dv_mps.map(f64::from));
            for k in 0..3 {
                v_est[k] += dv[k];
            }
            c_est = mul(&c_est, &exp(inc.dtheta_rad.map(f64::from)));
        }
    }
    let err: Vec<f64> = (0..3).map(|k| v_est[k] - v_ref[k]).collect();
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    (norm(&err), norm(&v_ref))
}

#[test]
fn sculling_rectification_is_kept() {
    let (plain, v) = sculling_error(false, 60.0);
    let (corrected, _) = sculling_error(true, 60.0);
    std::eprintln!(
        "sculling 60 s: |v| {v:.3} m/s, error plain sums {plain:.3e} m/s, corrected {corrected:.3e} m/s"
    );
    assert!(plain > 0.01, "plain sums drift: {plain}");
    assert!(corrected < 0.05 * plain, "{corrected} vs {plain}");
}

#[test]
fn static_gives_gravity_and_no_rotation_and_bridges_count() {
    let mut nav = NavIntegrator::new();
    let dt = (1.0 / FPS) as f32;
    for _ in 0..30 {
        nav.add([0.0; 3], [0.0, 0.0, -9.80665], dt);
    }
    nav.bridge(2, dt);
    let inc = nav.take();
    assert_eq!((inc.frames, inc.bridged), (32, 2));
    assert!((inc.dt_s - 32.0 * dt).abs() < 1e-6);
    assert_eq!(inc.dtheta_rad, [0.0; 3]);
    assert!(
        (inc.dv_mps[2] + 9.80665 * inc.dt_s).abs() < 1e-5,
        "{:?}",
        inc.dv_mps
    );
    let next = nav.take();
    assert_eq!((next.frames, next.bridged, next.dt_s), (0, 0, 0.0));
}

/// The closed-form bridge equals frame-by-frame integration with the held values.
#[test]
fn bridging_in_closed_form_equals_holding_frame_by_frame() {
    let dt = (1.0 / FPS) as f32;
    let start = |nav: &mut NavIntegrator| {
        nav.add([0.1, -0.2, 0.05], [0.3, 9.0, -1.0], dt);
        nav.add([0.12, -0.15, 0.07], [0.2, 9.1, -0.8], dt);
    };
    for n in [1u32, 2, 7, 100] {
        let (mut a, mut b) = (NavIntegrator::new(), NavIntegrator::new());
        start(&mut a);
        start(&mut b);
        a.bridge(n, dt);
        for _ in 0..n {
            b.add([0.12, -0.15, 0.07], [0.2, 9.1, -0.8], dt);
        }
        a.add([0.2, 0.1, 0.0], [1.0, 8.0, 0.5], dt);
        b.add([0.2, 0.1, 0.0], [1.0, 8.0, 0.5], dt);
        let (ia, ib) = (a.take(), b.take());
        assert_eq!((ia.frames, ia.bridged, ib.bridged), (n + 3, n, 0));
        for k in 0..3 {
            let tol = 1e-6 * (1.0 + ib.dtheta_rad[k].abs() + ib.dv_mps[k].abs());
            assert!(
                (ia.dtheta_rad[k] - ib.dtheta_rad[k]).abs() < tol,
                "{n}: {ia:?} {ib:?}"
            );
            assert!(
                (ia.dv_mps[k] - ib.dv_mps[k]).abs() < 10.0 * tol,
                "{n}: {ia:?} {ib:?}"
            );
        }
    }
}
