//! Sums over a log's readings in fixed chunks: the chunks in parallel, their sums added in chunk
//! order, so that a sum has the same bits on one thread or many, and a log of at most [`CHUNK`]
//! readings is summed in one pass in reading order, as a plain loop would.
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

/// Readings per chunk: enough that a chunk's work (a few hundred microseconds at most) outweighs
/// handing it to a thread, few enough that a log of 10^4 readings already uses both cores of a
/// small machine.
pub const CHUNK: usize = 4096;

/// The sum over `items` of `each` applied to consecutive chunks of [`CHUNK`], the chunks in
/// parallel and their sums added in chunk order by `add`; for at most one chunk, `each(items)`.
pub fn sum_chunks<T: Sync, S: Send>(items: &[T], each: impl Fn(&[T]) -> S + Sync, add: impl Fn(&mut S, S)) -> S {
    if items.len() <= CHUNK {
        return each(items);
    }
    let mut parts = items.par_chunks(CHUNK).map(&each).collect::<Vec<S>>().into_iter();
    let mut total = parts.next().expect("more than one chunk");
    parts.for_each(|p| add(&mut total, p));
    total
}

/// The sum over `items` of `each`.
pub fn sum<T: Sync>(items: &[T], each: impl Fn(&T) -> f64 + Sync) -> f64 {
    sum_chunks(items, |chunk| chunk.iter().map(&each).sum::<f64>(), |t, p| *t += p)
}

/// `J^T J` (lower triangle filled) and `J^T r` of the residual `r` and gradient `g` that
/// `residual` gives for each item.
pub fn normal_equations<T: Sync, const N: usize>(
    items: &[T],
    residual: impl Fn(&T) -> (f64, [f64; N]) + Sync,
) -> ([[f64; N]; N], [f64; N]) {
    sum_chunks(
        items,
        |chunk| {
            let mut jtj = [[0.0; N]; N];
            let mut jtr = [0.0; N];
            for item in chunk {
                let (r, g) = residual(item);
                for i in 0..N {
                    jtr[i] += g[i] * r;
                    for j in 0..=i {
                        jtj[i][j] += g[i] * g[j];
                    }
                }
            }
            (jtj, jtr)
        },
        |(jtj, jtr), (a, b)| {
            for i in 0..N {
                jtr[i] += b[i];
                for j in 0..=i {
                    jtj[i][j] += a[i][j];
                }
            }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The chunked sums are the plain loop's for one chunk, and the same bits on one thread and
    /// on four for many.
    #[test]
    fn a_sum_has_the_same_bits_on_any_number_of_threads() {
        let items: Vec<f64> = (0..3 * CHUNK + 17)
            .map(|i| ((i as f64) * 0.7).sin() * 1e3 + 0.1)
            .collect();
        let residual = |x: &f64| (x.cos(), [x.sin(), x * 1e-3, 1.0]);
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
        let a = one.install(|| (sum(&items, |x| x * x), normal_equations(&items, residual)));
        let b = four.install(|| (sum(&items, |x| x * x), normal_equations(&items, residual)));
        assert_eq!(a.0.to_bits(), b.0.to_bits());
        assert_eq!(a.1, b.1);
        let few = &items[..CHUNK];
        assert_eq!(
            sum(few, |x| x * x).to_bits(),
            few.iter().map(|x| x * x).sum::<f64>().to_bits()
        );
        // Chunked, the sum is still the sum to rounding.
        let plain: f64 = items.iter().map(|x| x * x).sum();
        assert!(
            (a.0 - plain).abs() <= 1e-15 * items.len() as f64 * plain,
            "{} {plain}",
            a.0
        );
    }
}
