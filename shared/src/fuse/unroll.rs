//! Per-group loops written out for the board's 16 groups.
//!
//! LLVM keeps a loop over 16 groups rolled when its body is long (the noise estimators' update: 27 Cortex-M4
//! instructions per group, of which the loop's counters, address arithmetic and a reloaded base pointer take
//! ≈ 10). Written out, every group's state sits at a fixed offset and every bit test has a constant shift.
//! Measured per use in `docs/performance.md`; other group counts take the plain loop.

/// Calls `f(g, &mut a[g], &b[g])` for every group g in order: written out for 16 groups, a loop otherwise.
#[inline(always)]
pub(super) fn zip_each<const G: usize, T, U>(
    a: &mut [T; G],
    b: &[U; G],
    mut f: impl FnMut(u32, &mut T, &U),
) {
    match (
        <&mut [T; 16]>::try_from(a.as_mut_slice()),
        <&[U; 16]>::try_from(b.as_slice()),
    ) {
        (
            Ok(
                [
                    a0,
                    a1,
                    a2,
                    a3,
                    a4,
                    a5,
                    a6,
                    a7,
                    a8,
                    a9,
                    a10,
                    a11,
                    a12,
                    a13,
                    a14,
                    a15,
                ],
            ),
            Ok(
                [
                    b0,
                    b1,
                    b2,
                    b3,
                    b4,
                    b5,
                    b6,
                    b7,
                    b8,
                    b9,
                    b10,
                    b11,
                    b12,
                    b13,
                    b14,
                    b15,
                ],
            ),
        ) => {
            f(0, a0, b0);
            f(1, a1, b1);
            f(2, a2, b2);
            f(3, a3, b3);
            f(4, a4, b4);
            f(5, a5, b5);
            f(6, a6, b6);
            f(7, a7, b7);
            f(8, a8, b8);
            f(9, a9, b9);
            f(10, a10, b10);
            f(11, a11, b11);
            f(12, a12, b12);
            f(13, a13, b13);
            f(14, a14, b14);
            f(15, a15, b15);
        }
        _ => {
            for (g, (x, y)) in (0u32..).zip(a.iter_mut().zip(b)) {
                f(g, x, y);
            }
        }
    }
}

/// Calls `f(g, b[g])` for every group g in order: written out for 16 groups, a loop otherwise.
#[inline(always)]
pub(super) fn each<const G: usize, U: Copy>(b: &[U; G], mut f: impl FnMut(u32, U)) {
    zip_each(&mut [(); G], b, |g, (), &v| f(g, v));
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::vec::Vec;

    /// Both paths visit every group once, in order, with its own elements, and write through.
    fn visits_in_order<const G: usize>() {
        let mut a: [u32; G] = core::array::from_fn(|g| g as u32 * 10);
        let b: [u32; G] = core::array::from_fn(|g| g as u32 * 100);
        let mut seen = Vec::new();
        zip_each(&mut a, &b, |g, x, &y| {
            seen.push((g, *x, y));
            *x += 1;
        });
        let expected: Vec<(u32, u32, u32)> = (0..G as u32).map(|g| (g, g * 10, g * 100)).collect();
        assert_eq!(seen, expected);
        assert!(a.iter().enumerate().all(|(g, &x)| x == g as u32 * 10 + 1));
        let mut seen = Vec::new();
        each(&b, |g, y| seen.push((g, y)));
        assert_eq!(
            seen,
            (0..G as u32).map(|g| (g, g * 100)).collect::<Vec<_>>()
        );
    }

    #[test]
    fn written_out_and_looped_paths_visit_every_group_in_order() {
        visits_in_order::<16>();
        visits_in_order::<1>();
        visits_in_order::<7>();
        visits_in_order::<32>();
    }
}
