//! Where the MIMU4444 recordings and the small test fixture are.

use std::path::PathBuf;

/// The directory with `exp_1/data.bin` … `exp_6/data.bin`: `$MIMU4444_DIR` if set (and only it, so that
/// `MIMU4444_DIR=/nonexistent` forces the skip), else `shared/data/mimu4444` beside the repository
/// (`<repo>/../shared/data/mimu4444`), else `/work/shared/data/mimu4444`. `None` when it does not hold
/// `exp_1/data.bin` (tests on the real data then skip).
pub fn mimu4444_dir() -> Option<PathBuf> {
    let mut candidates = Vec::new();
    if let Some(d) = std::env::var_os("MIMU4444_DIR") {
        let d = PathBuf::from(d);
        return d.join("exp_1/data.bin").is_file().then_some(d);
    }
    candidates.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/mimu4444"));
    candidates.push(PathBuf::from("/work/shared/data/mimu4444"));
    candidates
        .into_iter()
        .find(|d| d.join("exp_1/data.bin").is_file())
}

/// The excerpt of exp_1 kept in the repository (`testdata/mimu4444/exp1_excerpt.bin`, MIT licence, see the
/// README beside it): the acknowledgement, then 12 slices of 150 frames (2.4 s) from 12 static poses.
pub fn fixture_excerpt() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../testdata/mimu4444/exp1_excerpt.bin")
}
