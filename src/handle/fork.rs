//! `fork()` while another thread is inside a call on a handle: the child has one
//! thread, the forking one, and the lock word still names the thread whose call held
//! it, which does not exist in the child. libmodbus has no lock, so its child simply
//! goes on with the context as that call left it; so does ours: a `pthread_atfork`
//! child handler frees every lock held by a thread other than the forking one
//! (`OwnerMutex::forget_dead_holder`), and forgets the stops and waits of those
//! threads (`Stop::after_fork_in_child`).
//!
//! To find the handles, every live one is registered here (at creation, removed
//! before it is freed): a map from the handle's address to the function that resets
//! it, behind a lock that the prepare handler takes before the fork, so that no
//! thread is changing the map at the instant of the fork, and that the parent and
//! child handlers release. The cost is at creation and freeing only; a call pays
//! nothing.

use std::collections::BTreeMap;
use std::sync::Once;
use std::sync::atomic::{AtomicBool, Ordering::SeqCst};

use super::lock::{Entry, OwnerMutex};

/// Live handles: address → what resets it in a fork child.
type Handles = BTreeMap<usize, unsafe fn(usize)>;

static HANDLES: OwnerMutex<Handles> = OwnerMutex::new(BTreeMap::new());
static HANDLERS: Once = Once::new();
/// The forking thread took the map's lock in [`prepare`] (not when it held it
/// already: a fork from a signal handler that interrupted a registration).
static PREPARED: AtomicBool = AtomicBool::new(false);

/// Registers the live handle at `addr`; `reset` is what a fork child does to it
/// (called with `addr`, in the child, with the map locked).
pub(super) fn register(addr: usize, reset: unsafe fn(usize)) {
    HANDLERS.call_once(|| {
        // SAFETY: the three handlers are `extern "C" fn()` of this library, valid for
        // as long as it is loaded (glibc drops them if the library is unloaded).
        // A failure (ENOMEM) leaves fork children without the reset: their calls on
        // a handle another thread held would wait for ever, as before this module.
        unsafe { libc::pthread_atfork(Some(prepare), Some(parent), Some(child)) };
    });
    HANDLES.lock().insert(addr, reset);
}

/// The handle at `addr` is about to be freed.
pub(super) fn unregister(addr: usize) {
    HANDLES.lock().remove(&addr);
}

/// Before `fork`: the map is locked, so that the child finds it whole.
extern "C" fn prepare() {
    if let Entry::Locked(g) = HANDLES.enter() {
        std::mem::forget(g);
        PREPARED.store(true, SeqCst);
    }
}

/// After `fork`, in the parent: the map is released.
extern "C" fn parent() {
    if PREPARED.swap(false, SeqCst) {
        // SAFETY: `prepare`, on this thread, took the lock and forgot its guard.
        drop(unsafe { HANDLES.adopt() });
    }
}

/// After `fork`, in the child (one thread: this one): every handle is reset, then
/// the map released.
extern "C" fn child() {
    if PREPARED.swap(false, SeqCst) {
        // SAFETY: `prepare`, on this thread (the forking thread, the child's only
        // one), took the lock and forgot its guard.
        let handles = unsafe { HANDLES.adopt() };
        for (&addr, &reset) in handles.iter() {
            // SAFETY: a registered handle is live: it is unregistered, under this
            // lock, before it is freed; `reset` was registered for its type.
            unsafe { reset(addr) };
        }
    }
}
