//! The estimator's worker pool, as its stages use it: a list mapped side by side on the pool
//! when there is one and more than one item, else on the calling thread; the results in the
//! items' order either way, so that one thread and two give the same estimate.

use rayon::prelude::*;

/// `f` of each item, in the items' order.
pub fn each<T: Sync, R: Send>(pool: Option<&rayon::ThreadPool>, items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    match pool {
        Some(pool) if items.len() > 1 => pool.install(|| items.par_iter().map(&f).collect()),
        _ => items.iter().map(f).collect(),
    }
}
