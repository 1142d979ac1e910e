//! The context lock under threads: a callback that runs unlocked lets another thread
//! in (and the lock is back when it panics), and many threads count exactly.
//! (Integration tests: threads, unwinding.)

use std::panic::{AssertUnwindSafe, catch_unwind};
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
fn unlocked_takes_the_lock_back_when_the_callback_panics() {
    let m = Arc::new(OwnerMutex::new(0u32));
    let mut g = m.lock();
    let m2 = Arc::clone(&m);
    let caught = catch_unwind(AssertUnwindSafe(|| {
        OwnerGuard::unlocked(&mut g, || {
            // Unlocked here: another thread gets in.
            std::thread::spawn(move || *m2.lock() += 1).join().unwrap();
            panic!("callback fails");
        })
    }));
    assert!(caught.is_err());
    // The guard holds the lock again: this thread is the holder, another thread
    // cannot take it, and the value is reached through the guard.
    assert_eq!(m.holder(), modbus::lock::current_thread());
    let m3 = Arc::clone(&m);
    assert!(std::thread::spawn(move || m3.try_lock().is_none()).join().unwrap());
    *g += 1;
    // Released properly when the guard goes: another thread takes it at once.
    drop(g);
    assert_eq!(m.holder(), 0);
    let m4 = Arc::clone(&m);
    assert_eq!(std::thread::spawn(move || *m4.try_lock().expect("free")).join().unwrap(), 2);
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
