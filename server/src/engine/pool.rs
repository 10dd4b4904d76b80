//! The engine's worker pool.

/// The engine's worker pool of `workers` threads. With `with_engine`
/// (called on the engine thread, `workers` 2 or more) the calling thread
/// is one of them (`use_current_thread`): a tick's parallel work (apply,
/// sight checks, fan-out) starts on it instead of waking a worker and
/// waiting, and it takes its share; `workers - 1` threads of their own run
/// the rest and what is spawned (the tick's meshes, which the engine helps
/// build while it waits for them; a job it spawned may so run on it, as
/// may a share of a big batch's encoding while it waits in the pool). That halved the
/// server's thread switches per edit (BENCHMARKS.md, session 50). With
/// one worker, the engine only waits for it: some thread of the pool must
/// run spawned jobs while the engine serves commands.
pub(super) fn build(workers: usize, with_engine: bool) -> std::io::Result<rayon::ThreadPool> {
    let builder = rayon::ThreadPoolBuilder::new()
        .num_threads(workers)
        .thread_name(|i| format!("strata-worker-{i}"));
    let builder = if with_engine && workers >= 2 {
        builder.use_current_thread()
    } else {
        builder
    };
    builder.build().map_err(std::io::Error::other)
}

/// Waits for `rx`, running the pool's pending jobs meanwhile when the
/// calling thread is one of its threads (the engine thread, from two
/// workers on): the tick's meshes, spawned from there, may still wait for
/// a free worker, so the engine builds them too instead of idling.
pub(super) fn help_until<T>(
    rx: &std::sync::mpsc::Receiver<T>,
) -> Result<T, std::sync::mpsc::RecvError> {
    loop {
        match rx.try_recv() {
            Ok(v) => return Ok(v),
            Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                return Err(std::sync::mpsc::RecvError)
            }
            Err(std::sync::mpsc::TryRecvError::Empty) => {}
        }
        if rayon::yield_now() != Some(rayon::Yield::Executed) {
            return rx.recv();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::thread;

    #[test]
    fn with_two_workers_or_more_the_engine_thread_is_one() {
        thread::spawn(|| {
            let me = thread::current().id();
            let pool = build(2, true).unwrap();
            assert_eq!(pool.current_num_threads(), 2);
            assert_eq!(pool.install(|| thread::current().id()), me);
            // The other runs what is spawned while this one waits.
            let (tx, rx) = std::sync::mpsc::channel();
            pool.spawn(move || tx.send(thread::current().id()).unwrap());
            assert_ne!(rx.recv().unwrap(), me);
            // With the other worker held, a job spawned from here waits
            // for a worker: waiting for it runs it here.
            let (hold, held) = std::sync::mpsc::channel::<()>();
            let (busy, is_busy) = std::sync::mpsc::channel();
            pool.spawn(move || {
                busy.send(()).unwrap();
                let _ = held.recv_timeout(std::time::Duration::from_secs(10));
            });
            is_busy.recv().unwrap();
            let (tx, rx) = std::sync::mpsc::channel();
            pool.spawn(move || tx.send(thread::current().id()).unwrap());
            assert_eq!(help_until(&rx), Ok(me));
            hold.send(()).unwrap();
        })
        .join()
        .unwrap();
        thread::spawn(|| {
            let me = thread::current().id();
            let one = build(1, true).unwrap();
            assert_ne!(one.install(|| thread::current().id()), me);
            let apart = build(2, false).unwrap();
            assert_ne!(apart.install(|| thread::current().id()), me);
        })
        .join()
        .unwrap();
    }
}
