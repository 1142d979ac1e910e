//! What a context holds for its event-driven client: the requests it was given
//! (`proto::session::pipeline`), the receive under way between two calls of
//! `modbus_process`, and the requests that completed and wait for their callback.
//! The driver is `crate::event`; the C side (`ffi/event.rs`) writes the values out
//! and calls the callbacks. Nothing here is made until the first asynchronous call,
//! so that a blocking context pays nothing for it.

use std::collections::{HashMap, VecDeque};
use std::ffi::{c_int, c_void};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering::SeqCst};

use crate::handle::lock::OwnerMutex;
use crate::transport::AduBuf;
use crate::transport::epoll::{Registered, WakeSet};

use crate::proto::frame::Framing;
use crate::proto::session::pipeline::Pipeline;
use crate::proto::session::receive::{Receiver, Settings, Step};

/// The application's callback as it is stored: `modbus_callback_t` with the context
/// as an untyped pointer (the C layer stores and calls it with `modbus_t *`).
pub type RawCallback = unsafe extern "C" fn(*mut c_void, c_int, c_int, c_int, *mut c_void);

/// Where the values of an answer go; the pointers are the application's, written by
/// the C layer only.
#[derive(Clone, Copy, Debug)]
pub enum Deliver {
    /// `nb` bits, one byte each (FC 01, 02); the call returns `nb`.
    Bits { dest: *mut u8, nb: c_int },
    /// The registers the answer counts (FC 03, 04, 17); the call returns the count.
    Registers { dest: *mut u16 },
    /// Nothing to copy: the call returns the count the server confirmed (writes).
    Count,
    /// Up to `max` bytes of the answer's data (FC 11); the call returns its byte count.
    Bytes { dest: *mut u8, max: c_int },
    /// The whole answer's ADU, as it came (header, PDU, checksum; exception answers
    /// too), to a buffer of `MODBUS_MAX_ADU_LENGTH` bytes; the call returns its length
    /// (`modbus_send_raw_request_async`).
    Raw { dest: *mut u8 },
    /// A raw request of the Rust API (`api::Modbus::send_raw`): the answer's PDU
    /// (function code first, no header or checksum; exception answers too) stays in
    /// [`Done::data`], for `api::Modbus::next_completion`; the call returns its
    /// length.
    Pdu,
    /// The answer's PDU handed to `decode` with the check's count and the call's
    /// arguments (the extensions' calls); it writes the values out and returns what
    /// the call returns.
    Decode { decode: DecodeFn, args: DecodeArgs },
    /// A call answered by several requests (device identification objects that
    /// "more follow"): each answer's PDU is handed to `decode`, which writes its
    /// values out and says whether the call is done or asks for the next request,
    /// which goes under the same id.
    Stream { decode: StreamFn, args: DecodeArgs },
}

/// A decoder of [`Deliver::Stream`]: `(pdu, count, args) -> what next`; it keeps
/// what the next round needs in `args`.
pub type StreamFn = unsafe fn(&[u8], c_int, &mut DecodeArgs) -> Streamed;

/// What a [`StreamFn`] says after an answer.
pub enum Streamed {
    /// The call is done: what it returns.
    Done(c_int),
    /// The call goes on with this request.
    Next(crate::proto::request::Request<'static>),
}

/// A decoder of [`Deliver::Decode`]: `(pdu, count, args) -> rc`.
///
/// The C layer's: it writes to the pointers among `args`, valid per the call's
/// contract until the request completes.
pub type DecodeFn = unsafe fn(&[u8], c_int, &DecodeArgs) -> c_int;

/// A call's arguments kept for its decoder: pointers and counts, as integers.
pub type DecodeArgs = [usize; 6];

/// A request's payload in the pipeline: whom to tell, where its values go.
#[derive(Clone, Copy, Debug)]
pub struct Completion {
    pub callback: Option<RawCallback>,
    pub user_data: *mut c_void,
    pub deliver: Deliver,
}

// SAFETY: the pointers are the application's; the library only writes the values
// to them and passes them back, under the context's lock, on whichever thread runs
// `modbus_process` (the application's contract, as for the blocking calls' buffers).
unsafe impl Send for Completion {}

/// A request that completed: its result, and the values to copy out.
pub struct Done {
    pub id: c_int,
    /// Its response timeout (the next round of a call answered in several goes with
    /// it).
    pub timeout: std::time::Duration,
    pub completion: Completion,
    /// What the blocking call returns (>= 0), or the errno it sets.
    pub result: Result<c_int, i32>,
    /// The answer's data (packed bits, big-endian registers, bytes).
    pub data: Vec<u8>,
}

/// A completed request of a NULL callback, waiting for `modbus_completion_read` (or
/// `modbus_multi_completion_read`): what the callback would have been given.
#[derive(Clone, Copy, Debug)]
pub struct Ready {
    pub id: c_int,
    pub rc: c_int,
    pub error: c_int,
    pub user_data: *mut c_void,
}

// SAFETY: `user_data` is the application's, only handed back to it.
unsafe impl Send for Ready {}

/// A receive under way between two calls of `modbus_process`.
pub struct Receiving {
    pub machine: Receiver,
    /// The settings it runs with (the context's, with this receive's time limit).
    pub settings: Settings,
    pub step: Step,
    pub msg: AduBuf,
}

/// The event-driven client's state of one context.
pub struct Outstanding {
    pub pipeline: Pipeline<Completion>,
    /// Made when the answer's first bytes are there, dropped when it ends: a context
    /// waiting for its answer holds no receive buffer.
    pub receiving: Option<Box<Receiving>>,
    pub done: VecDeque<Done>,
    /// The completions of requests given without a callback, for
    /// `modbus_completion_read` (a context in a multi handle queues them there).
    pub ready: VecDeque<Ready>,
    /// When the connect under way gives up (the response timeout from its start;
    /// again for a TLS handshake that follows).
    pub connect_until: Option<std::time::Duration>,
    /// What a TLS handshake under way waits for (poll(2) events).
    pub handshake_wants: i16,
    /// A serial request timed out under LINK recovery: no request goes out before
    /// this time, then the line is flushed (the blocking calls sleep a response
    /// timeout and flush), so that a late answer is not taken for the next.
    pub quiet_until: Option<std::time::Duration>,
    /// The multi handle the context is in, if any, and the context's key in it (its
    /// handle's address).
    pub multi: Option<(Arc<Members>, usize)>,
    /// The context's own wake descriptor (`modbus_get_pollfd`), made by its first call.
    pub wake: Option<Box<Wake>>,
}

/// A context's wake descriptor: an epoll set of the line, an eventfd (a new request)
/// and a timerfd (the earliest deadline); see [`WakeSet`].
pub struct Wake {
    pub set: WakeSet,
    /// The line as registered in the set (key `epoll::KEY_LINE`).
    pub line: Registered,
}

/// The contexts of one multi handle (`modbus_multi_*`), shared by the handle and its
/// contexts, so that a context leaves it wherever it goes (removed, or freed).
pub struct Members {
    /// The multi handle's epoll set (`set.epfd`), with its eventfd (a request given
    /// to a member, `modbus_multi_wakeup`) and timerfd (the members' earliest
    /// deadline).
    pub set: WakeSet,
    /// By handle address: what is registered for each, and what it waits for.
    pub list: OwnerMutex<HashMap<usize, Member>>,
    /// The contexts whose interest may have changed since the handle last asked
    /// (a request given, processed, cancelled, a close): only these are asked again.
    pub dirty: OwnerMutex<Vec<usize>>,
    /// A context was closed (from a signal handler, maybe: no lock) with requests
    /// left to complete: every member is asked again.
    pub closed: AtomicBool,
    /// The completions of its contexts' requests given without a callback, with the
    /// context's key, for `modbus_multi_completion_read`.
    pub ready: OwnerMutex<VecDeque<(usize, Ready)>>,
}

/// What a multi handle registered for one context.
#[derive(Clone, Copy, Debug, Default)]
pub struct Member {
    /// Its line as registered in the handle's epoll set (under the context's key).
    pub line: Registered,
    /// When it is due without I/O, as last asked.
    pub until: Option<std::time::Duration>,
}

impl Members {
    /// A context closed with requests pending (see [`Members::closed`]).
    pub fn closed(&self) {
        self.closed.store(true, SeqCst);
    }

    /// The context `key` is to be asked again before the next wait.
    pub fn mark(&self, key: usize) {
        self.dirty.lock().push(key);
        // After the push: a wait that began before it (and took the list before it)
        // is woken.
        self.set.notify();
    }

    /// Takes the context of handle address `key` out (its registration with it: a
    /// descriptor still open stops reporting), and returns its completions not read
    /// yet.
    pub fn remove(&self, key: usize) -> Vec<Ready> {
        let mut ready = self.ready.lock();
        let mut own = Vec::new();
        ready.retain(|&(k, r)| {
            if k == key {
                own.push(r);
            }
            k != key
        });
        drop(ready);
        let mut list = self.list.lock();
        if let Some(m) = list.remove(&key) {
            if m.line.fd >= 0 && m.line.events != 0 {
                let _ = crate::transport::epoll::control(self.set.epfd, libc::EPOLL_CTL_DEL, m.line.fd, 0, 0);
            }
        }
        own
    }
}

impl Outstanding {
    pub fn new(framing: Framing) -> Self {
        Outstanding {
            pipeline: Pipeline::new(framing),
            receiving: None,
            done: VecDeque::new(),
            ready: VecDeque::new(),
            connect_until: None,
            handshake_wants: 0,
            quiet_until: None,
            multi: None,
            wake: None,
        }
    }

    /// Requests given and not completed yet (queued and in flight).
    pub fn pending(&self) -> usize {
        self.pipeline.pending()
    }

    /// Completes every request with `errno` (a close: ESHUTDOWN; a free: EIDRM; a
    /// lost line: its error); their callbacks run when the C layer next fires the
    /// completed ones.
    pub fn fail_all(&mut self, errno: i32) {
        self.receiving = None;
        self.connect_until = None;
        self.quiet_until = None;
        for e in self.pipeline.drain() {
            self.complete(Done {
                id: e.id,
                timeout: e.timeout,
                completion: e.payload,
                result: Err(errno),
                data: Vec::new(),
            });
        }
    }

    /// Queues a completed request for its callback. The queue grows one entry at a
    /// time at first (a deque's first growth makes room for four): a context polled
    /// with one request at a time holds room for one.
    pub fn complete(&mut self, done: Done) {
        if self.done.len() == self.done.capacity() && self.done.capacity() < 2 {
            self.done.reserve_exact(1);
        }
        self.done.push_back(done);
    }
}
