//! Running the scenes of a benchmark on a few named threads, results in scene order.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Runs `work(0..count)` on `threads` threads named `<name>-<t>`, each taking the next index
/// until none is left; the results come back in index order whatever thread ran them.
pub fn in_order<T: Send>(
    count: usize,
    threads: usize,
    name: &str,
    work: &(dyn Fn(usize) -> Result<T, String> + Sync),
) -> Result<Vec<T>, String> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<T, String>>>> = Mutex::new((0..count).map(|_| None).collect());
    std::thread::scope(|scope| {
        let mut handles = Vec::new();
        for t in 0..threads.clamp(1, count.max(1)) {
            let (next, results) = (&next, &results);
            let spawned = std::thread::Builder::new().name(format!("{name}-{t}")).spawn_scoped(scope, move || {
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    if i >= count {
                        break;
                    }
                    let result = work(i);
                    results.lock().unwrap_or_else(std::sync::PoisonError::into_inner)[i] = Some(result);
                }
            });
            handles.push(spawned.map_err(|e| format!("cannot start a benchmark thread: {e}"))?);
        }
        for h in handles {
            h.join().map_err(|_| "a benchmark thread panicked".to_owned())?;
        }
        Ok::<(), String>(())
    })?;
    results
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .into_iter()
        .enumerate()
        .map(|(i, r)| r.unwrap_or_else(|| Err(format!("scene {i} was not run"))))
        .collect()
}
