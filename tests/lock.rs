//! The context lock under threads: a callback that runs unlocked lets another thread
//! in, and many threads count exactly. (Integration tests: threads.)

use std::sync::Arc;

use modbus::lock::{OwnerGuard, OwnerMutex};

#[test]
fn unlocked_lets_another_thread_in() {
    let m = Arc::new(OwnerMutex::new(0u32));
    let mut g = m.lock();
    let m2 = Arc::clone(&m);
    OwnerGuard::unlocked(&mut g, move || {
        std::thread::spawn(move || *m2.lock() += 1).join().unwrap();
    });
    assert_eq!(*g, 1);
}

#[test]
fn many_threads_count_exactly() {
    let m = Arc::new(OwnerMutex::new(0u64));
    let threads: Vec<_> = (0..8)
        .map(|_| {
            let m = Arc::clone(&m);
            std::thread::spawn(move || {
                for _ in 0..20_000 {
                    let mut g = m.lock();
                    *g += 1;
                    if *g % 1000 == 0 {
                        std::thread::yield_now();
                    }
                }
            })
        })
        .collect();
    for t in threads {
        t.join().unwrap();
    }
    assert_eq!(*m.lock(), 160_000);
    assert_eq!(m.holder(), 0);
}
