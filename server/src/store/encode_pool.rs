//! Where a store encodes a big batch's whole chunks in parallel.

use std::sync::{Arc, RwLock};

use rayon::prelude::*;

use super::PARALLEL_ENCODE_CHUNKS;

/// The engine's worker pool while it serves
/// ([`super::ChunkStore::encode_on`]), else whatever pool the caller runs
/// in. Only the encoding runs there: the commit's writes and fsync stay on
/// the commit thread, so no pool thread waits them out (the engine thread,
/// one of the pool's, may take a share of the encoding while it waits in
/// the pool; it waits out an fsync only when it commits itself, with no
/// commit thread).
#[derive(Debug, Default)]
pub struct EncodePool(RwLock<Option<Arc<rayon::ThreadPool>>>);

impl EncodePool {
    pub fn set(&self, pool: Option<Arc<rayon::ThreadPool>>) {
        *self.0.write().unwrap_or_else(|p| p.into_inner()) = pool;
    }

    /// `f` of each of `items`, in order: in parallel from
    /// [`PARALLEL_ENCODE_CHUNKS`] items on.
    pub fn map<I: Sync, T: Send>(&self, items: &[I], f: impl Fn(&I) -> T + Sync) -> Vec<T> {
        if items.len() < PARALLEL_ENCODE_CHUNKS {
            return items.iter().map(f).collect();
        }
        let pool = self.0.read().unwrap_or_else(|p| p.into_inner()).clone();
        let run = || items.par_iter().map(&f).collect();
        match pool {
            Some(pool) => pool.install(run),
            None => run(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_big_batch_is_encoded_on_the_pool_set_in_order() {
        let encode = EncodePool::default();
        let items: Vec<u32> = (0..64).collect();
        let on = |_: &u32| {
            let me = std::thread::current();
            me.name().is_some_and(|n| n.starts_with("encode-test"))
        };
        assert!(
            encode.map(&items[..2], on).iter().all(|x| !x),
            "a small one here"
        );
        let pool = Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .thread_name(|i| format!("encode-test-{i}"))
                .build()
                .unwrap(),
        );
        encode.set(Some(pool));
        assert!(
            encode.map(&items, on).iter().all(|x| *x),
            "a big one on the pool"
        );
        assert!(encode.map(&items[..2], on).iter().all(|x| !x));
        assert_eq!(
            encode.map(&items, |x| x * 2),
            (0..64).map(|x| x * 2).collect::<Vec<_>>()
        );
        encode.set(None);
        assert!(encode.map(&items, on).iter().all(|x| !x), "not on it again");
    }
}
