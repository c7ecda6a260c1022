//! Seeded, portable random streams.
//!
//! magcal never draws from OS entropy or a thread-local generator. Every random draw takes an RNG
//! argument; the runner derives one independent ChaCha8 stream per trial and per optimiser run from
//! (scenario seed, stream id), so that a trial's numbers do not depend on which thread ran it.

use rand::SeedableRng;
pub use rand::rngs::ChaCha8Rng;

/// The generator used throughout magcal: ChaCha8, portable across platforms and versions of rand
/// (unlike `StdRng`, whose algorithm is not guaranteed).
pub type MagcalRng = ChaCha8Rng;

/// The generator for `stream` of `seed`: ChaCha8 keyed by `seed` with its 64-bit stream id set to
/// `stream`. Distinct streams of one seed are independent sequences.
pub fn stream_rng(seed: u64, stream: u64) -> MagcalRng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

/// A stream id from up to four indices (design, noise level, trial, ...), each below 2^16 except the
/// last, which may use the remaining bits: `((a * 2^16 + b) * 2^16 + c) ...`. Distinct index tuples
/// of the same length give distinct ids while every index is within its range.
///
/// # Panics
/// When an index other than the last is 2^16 or more, or the last does not fit (a caller bug).
#[track_caller]
pub fn stream_id(indices: &[u64]) -> u64 {
    let (last, head) = indices.split_last().expect("stream_id: at least one index");
    let mut id: u64 = 0;
    for &i in head {
        assert!(i < 1 << 16, "stream_id: index {i} too large");
        id = (id << 16) | i;
    }
    let shift = 64 - 16 * head.len() as u32;
    assert!(
        shift == 64 || *last < 1u64 << shift,
        "stream_id: last index {last} too large"
    );
    if shift == 64 { *last } else { (id << shift) | last }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<u64> = (0..4).map(|_| stream_rng(1, 5).random()).collect();
        let mut r = stream_rng(1, 5);
        let b: Vec<u64> = (0..4).map(|_| r.random()).collect();
        assert_eq!(a[0], b[0]);
        let c: u64 = stream_rng(1, 6).random();
        let d: u64 = stream_rng(2, 5).random();
        assert_ne!(b[0], c);
        assert_ne!(b[0], d);
        assert_ne!(b[0], b[1]);
    }

    #[test]
    fn stream_ids_are_distinct() {
        let mut seen = std::collections::HashSet::new();
        for a in 0..4 {
            for b in 0..4 {
                for c in 0..100 {
                    assert!(seen.insert(stream_id(&[a, b, c])));
                }
            }
        }
        assert_eq!(stream_id(&[7]), 7);
        assert_eq!(stream_id(&[1, 2]), (1 << 48) | 2);
    }
}
