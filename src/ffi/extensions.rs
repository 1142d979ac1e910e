//! rsmodbus extensions: client calls for the function codes libmodbus lacks
//! (07, 08, 0B, 0C, 14, 15, 18, 2B/0E). Same conventions as libmodbus: `modbus_t *`
//! first, -1 with errno on failure (an exception answer gives `EMBX*`), counts as `int`.

use std::ffi::{c_char, c_int};
use std::slice;

use crate::engine::{self, AduBuf, Guard};
use crate::error::{Error, Result};
use crate::ffi::{Modbus, fail, with_ctx};
use crate::outstanding::{DecodeArgs, DecodeFn};
use crate::proto::decode;
use crate::proto::request::{
    MAX_DIAGNOSTICS_WORDS, MAX_FIFO_COUNT, MAX_FILE_READ_REGISTERS, MAX_FILE_RECORD, MAX_FILE_WRITE_REGISTERS, Request,
};

/// Sends `req`; returns the checked response from its PDU on (in `rsp`) and the
/// check's count.
fn exchange<'r>(g: &mut Guard<'_>, req: &Request<'_>, rsp: &'r mut AduBuf) -> Result<(&'r [u8], i32)> {
    let done = engine::exchange(g, req, rsp)?;
    Ok((&rsp[g.framing().header_length()..], done.count))
}

/// Copies `values` into the C array `dest` of room for them.
///
/// # Safety
/// `dest` must be valid for as many writes as `values` yields.
unsafe fn copy_words(values: impl Iterator<Item = u16>, dest: *mut u16) {
    for (i, v) in values.enumerate() {
        // SAFETY: guaranteed by the caller.
        unsafe { *dest.add(i) = v };
    }
}

/// A blocking call: `req`'s checked answer through `decode` (the decoder the call's
/// `_async` form runs when its answer comes).
///
/// # Safety
/// The pointers among `args` are valid for what `decode` writes.
unsafe fn blocking(g: &mut Guard<'_>, req: &Request<'_>, decode: DecodeFn, args: &DecodeArgs) -> Result<c_int> {
    let mut rsp = AduBuf::new();
    let (pdu, count) = exchange(g, req, &mut rsp)?;
    // SAFETY: forwarded caller contract.
    Ok(unsafe { decode(pdu, count, args) })
}

/// FC 07: `args[0]` the status byte. Returns 1.
///
/// # Safety
/// `args[0]` is a writable `uint8_t *`.
unsafe fn dec_exception_status(pdu: &[u8], _: c_int, args: &DecodeArgs) -> c_int {
    // SAFETY: guaranteed by the caller.
    unsafe { *(args[0] as *mut u8) = decode::exception_status(pdu) };
    1
}

/// The request of `modbus_diagnostics[_async]`, or `None` (EINVAL) for a
/// sub-function outside 16 bits, more than the data words a request holds, or a NULL
/// buffer with a count.
///
/// # Safety
/// `data` is valid for `nb` values for `'a` (when not NULL).
unsafe fn diagnostics_request<'a>(
    sub_function: c_int,
    data: *const u16,
    nb: c_int,
    dest: *mut u16,
    max_dest: c_int,
) -> Option<Request<'a>> {
    if !(0..=0xFFFF).contains(&sub_function)
        || !(0..=MAX_DIAGNOSTICS_WORDS).contains(&nb)
        || (nb > 0 && data.is_null())
        || max_dest < 0
        || (max_dest > 0 && dest.is_null())
    {
        return None;
    }
    // SAFETY: `data` is non-NULL and holds `nb` values when `nb` > 0 (contract).
    let data = if nb > 0 { unsafe { slice::from_raw_parts(data, nb as usize) } } else { &[] };
    Some(Request::Diagnostics { sub_function: sub_function as u16, data })
}

/// FC 08: up to `args[1]` data words to `args[0]`. Returns the words the answer has.
///
/// # Safety
/// `args[0]` is valid for `args[1]` values.
unsafe fn dec_diagnostics(pdu: &[u8], words: c_int, args: &DecodeArgs) -> c_int {
    let n = (words.max(0) as usize).min(args[1]);
    // SAFETY: guaranteed by the caller.
    unsafe { copy_words(decode::diagnostics_data(pdu, n), args[0] as *mut u16) };
    words
}

/// FC 0B: status and event counter to `args[0]`, `args[1]` (each may be NULL).
/// Returns 1.
///
/// # Safety
/// `args[0]`, `args[1]` are NULL or writable `uint16_t *`.
unsafe fn dec_comm_event_counter(pdu: &[u8], _: c_int, args: &DecodeArgs) -> c_int {
    let counter = decode::CommEventCounter::decode(pdu);
    for (p, v) in [(args[0], counter.status), (args[1], counter.event_count)] {
        // SAFETY: guaranteed by the caller.
        if let Some(p) = unsafe { (p as *mut u16).as_mut() } {
            *p = v;
        }
    }
    1
}

/// FC 0C's buffer: `max_events` >= 0, and a buffer when it is > 0.
fn events_room_ok(events: *mut u8, max_events: c_int) -> bool {
    max_events >= 0 && (max_events == 0 || !events.is_null())
}

/// FC 18's arguments: a pointer address of 16 bits and a buffer.
fn fifo_args_ok(addr: c_int, dest: *mut u16) -> bool {
    !dest.is_null() && (0..=0xFFFF).contains(&addr)
}

/// The arguments of FC 0C's decoder.
fn event_log_args(
    status: *mut u16,
    event_count: *mut u16,
    message_count: *mut u16,
    events: *mut u8,
    max_events: c_int,
) -> DecodeArgs {
    [status as usize, event_count as usize, message_count as usize, events as usize, max_events as usize, 0]
}

/// FC 0C: the three counters (each may be NULL) and up to `args[4]` events to
/// `args[3]`. Returns the number of events the device sent.
///
/// # Safety
/// The counter pointers NULL or writable; `args[3]` valid for `args[4]` bytes.
unsafe fn dec_comm_event_log(pdu: &[u8], n: c_int, args: &DecodeArgs) -> c_int {
    let log = decode::CommEventLog::decode(pdu, n as usize);
    for (p, v) in [(args[0], log.status), (args[1], log.event_count), (args[2], log.message_count)] {
        // SAFETY: guaranteed by the caller.
        if let Some(p) = unsafe { (p as *mut u16).as_mut() } {
            *p = v;
        }
    }
    let copy = (n.max(0) as usize).min(args[4]);
    if copy > 0 {
        // SAFETY: guaranteed by the caller.
        unsafe { slice::from_raw_parts_mut(args[3] as *mut u8, copy) }.copy_from_slice(&log.events[..copy]);
    }
    n
}

/// FC 14: the registers read to `args[0]`. Returns their number.
///
/// # Safety
/// `args[0]` is valid for the `nb` values requested (the check holds the count to it).
unsafe fn dec_file_record(pdu: &[u8], n: c_int, args: &DecodeArgs) -> c_int {
    // SAFETY: guaranteed by the caller.
    unsafe { copy_words(decode::file_record_data(pdu, n as usize), args[0] as *mut u16) };
    n
}

/// FC 18: the queue's values to `args[0]`. Returns their number.
///
/// # Safety
/// `args[0]` is valid for 31 values (the check holds the count to at most that).
unsafe fn dec_fifo(pdu: &[u8], n: c_int, args: &DecodeArgs) -> c_int {
    // SAFETY: guaranteed by the caller.
    unsafe { copy_words(decode::fifo_data(pdu, (n as usize).min(MAX_FIFO_COUNT)), args[0] as *mut u16) };
    n
}

/// Reads the eight exception status outputs of a serial device (FC 07) into
/// `*status`. Returns 1.
///
/// # Safety
/// `ctx` must be NULL or a live context; `status` NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_exception_status(ctx: *mut Modbus, status: *mut u8) -> c_int {
    if status.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract; `status` is non-NULL.
    unsafe {
        with_ctx(ctx, |g| {
            blocking(g, &Request::ReadExceptionStatus, dec_exception_status, &[status as usize, 0, 0, 0, 0, 0])
        })
    }
}

/// Sends a diagnostics request (FC 08) with sub-function `sub_function` and `nb`
/// data words from `data`, and copies at most `max_dest` data words of the answer
/// into `dest`. Returns the number of data words in the answer. Sub-function 0
/// (return query data) must come back identical. Sub-function 4 (force listen only
/// mode) gets no answer by definition: it returns 0 once sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; `data` valid for `nb` values (or NULL when
/// `nb` is 0), `dest` valid for `max_dest` values (or NULL when `max_dest` is 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_diagnostics(
    ctx: *mut Modbus,
    sub_function: c_int,
    data: *const u16,
    nb: c_int,
    dest: *mut u16,
    max_dest: c_int,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let Some(req) = (unsafe { diagnostics_request(sub_function, data, nb, dest, max_dest) }) else {
        return fail(Error::INVALID);
    };
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            if sub_function == 4 {
                let mut out = AduBuf::new();
                let n = engine::build_request(g, &req, &mut out);
                engine::send_msg(g, &mut out, n)?;
                return Ok(0);
            }
            blocking(g, &req, dec_diagnostics, &[dest as usize, max_dest as usize, 0, 0, 0, 0])
        })
    }
}

/// Reads the status word and event counter of a serial device (FC 0B).
/// Returns 1.
///
/// # Safety
/// `ctx` must be NULL or a live context; the pointers NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_comm_event_counter(
    ctx: *mut Modbus,
    status: *mut u16,
    event_count: *mut u16,
) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let args = [status as usize, event_count as usize, 0, 0, 0, 0];
            blocking(g, &Request::GetCommEventCounter, dec_comm_event_counter, &args)
        })
    }
}

/// Reads the communication event log of a serial device (FC 0C): status word,
/// event counter, message counter and up to 64 event bytes, newest first. Copies at
/// most `max_events` events into `events` and returns the number of events the
/// device sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; the counter pointers NULL or writable;
/// `events` valid for `max_events` bytes (or NULL when `max_events` is 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_comm_event_log(
    ctx: *mut Modbus,
    status: *mut u16,
    event_count: *mut u16,
    message_count: *mut u16,
    events: *mut u8,
    max_events: c_int,
) -> c_int {
    if !events_room_ok(events, max_events) {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let args = event_log_args(status, event_count, message_count, events, max_events);
            blocking(g, &Request::GetCommEventLog, dec_comm_event_log, &args)
        })
    }
}

fn check_file_args(file: c_int, record: c_int, nb: c_int, max: c_int) -> Result<()> {
    if !(1..=0xFFFF).contains(&file) || !(0..=MAX_FILE_RECORD).contains(&record) || !(1..=max).contains(&nb) {
        return Err(Error::INVALID);
    }
    Ok(())
}

/// Reads `nb` registers (1..124) from record `record` (0..9999) of file `file`
/// (1..65535) with one FC 14 sub-request. Returns `nb`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_file_record(
    ctx: *mut Modbus,
    file: c_int,
    record: c_int,
    nb: c_int,
    dest: *mut u16,
) -> c_int {
    if dest.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            check_file_args(file, record, nb, MAX_FILE_READ_REGISTERS)?;
            let req = Request::ReadFileRecord { file: file as u16, record: record as u16, nb: nb as u16 };
            blocking(g, &req, dec_file_record, &[dest as usize, 0, 0, 0, 0, 0])
        })
    }
}

/// Writes `nb` registers (1..122) from `src` to record `record` (0..9999) of file
/// `file` (1..65535) with one FC 15 sub-request. Returns `nb`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_file_record(
    ctx: *mut Modbus,
    file: c_int,
    record: c_int,
    nb: c_int,
    src: *const u16,
) -> c_int {
    if src.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            check_file_args(file, record, nb, MAX_FILE_WRITE_REGISTERS)?;
            let values = slice::from_raw_parts(src, nb as usize);
            let req = Request::WriteFileRecord { file: file as u16, record: record as u16, values };
            let mut rsp = AduBuf::new();
            exchange(g, &req, &mut rsp).map(|(_, n)| n)
        })
    }
}

/// Reads the FIFO queue whose pointer register is `addr` (FC 18) into `dest`, which
/// must hold 31 values. Returns the number of values.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` valid for 31 values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_fifo_queue(ctx: *mut Modbus, addr: c_int, dest: *mut u16) -> c_int {
    if !fifo_args_ok(addr, dest) {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            blocking(g, &Request::ReadFifoQueue { addr: addr as u16 }, dec_fifo, &[dest as usize, 0, 0, 0, 0, 0])
        })
    }
}

/// One device identification object (FC 2B / MEI 0E). `value` holds `length` bytes
/// followed by a NUL, so text objects can be printed directly.
#[repr(C)]
pub struct modbus_device_id_object_t {
    pub id: u8,
    pub length: u8,
    pub value: [c_char; 256],
}

/// `MODBUS_DEVICE_ID_*` read codes.
const READ_BASIC: c_int = 1;
const READ_SPECIFIC: c_int = 4;

/// Reads device identification objects (FC 2B / MEI 0E).
///
/// `read_code` 1 (basic), 2 (regular) or 3 (extended) is a stream access starting at
/// `object_id`: the "more follows" continuation is followed inside this call until
/// the device has sent every object, or `max_objects` are stored. `read_code` 4 reads
/// the single object `object_id`. The objects go to `objects[0..n]` in the order
/// received; `*conformity` (if not NULL) gets the device's conformity level.
/// Returns `n`, the number of objects stored.
///
/// # Safety
/// `ctx` must be NULL or a live context; `objects` valid for `max_objects` entries;
/// `conformity` NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_device_identification(
    ctx: *mut Modbus,
    read_code: c_int,
    object_id: c_int,
    objects: *mut modbus_device_id_object_t,
    max_objects: c_int,
    conformity: *mut c_int,
) -> c_int {
    if !device_id_args_ok(read_code, object_id, objects, max_objects) {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let out = slice::from_raw_parts_mut(objects, max_objects as usize);
            read_device_id(g, read_code as u8, object_id as u8, out, conformity.as_mut())
        })
    }
}

/// The arguments of `modbus_read_device_identification[_async]` are valid.
fn device_id_args_ok(read_code: c_int, object_id: c_int, objects: *mut modbus_device_id_object_t, max: c_int) -> bool {
    (READ_BASIC..=READ_SPECIFIC).contains(&read_code)
        && (0..=0xFF).contains(&object_id)
        && max >= 1
        && !objects.is_null()
}

fn read_device_id(
    g: &mut Guard<'_>,
    read_code: u8,
    mut object_id: u8,
    out: &mut [modbus_device_id_object_t],
    mut conformity: Option<&mut c_int>,
) -> Result<c_int> {
    let mut stored = 0usize;
    // Each round trip returns at least one object or ends the stream, so 256 rounds
    // cover every object id; the bound keeps a misbehaving device from looping us.
    for round in 0..DEVICE_ID_ROUNDS {
        let mut rsp = AduBuf::new();
        let (pdu, count) = exchange(g, &Request::ReadDeviceId { read_code, object_id }, &mut rsp)?;
        match device_id_round(pdu, count, out, conformity.as_deref_mut(), &mut stored, read_code, object_id) {
            Some(next) if round + 1 < DEVICE_ID_ROUNDS => object_id = next,
            _ => break,
        }
    }
    Ok(stored as c_int)
}

/// The most round trips of one device identification call.
const DEVICE_ID_ROUNDS: usize = 256;

/// One answer of a device identification stream: its objects go to `out[*stored..]`
/// (as many as there is room for), the conformity level to `conformity`. Returns the
/// object id the next request starts at, or `None` when the call is done (the
/// stream ended, or `out` is full).
fn device_id_round(
    pdu: &[u8],
    count: c_int,
    out: &mut [modbus_device_id_object_t],
    conformity: Option<&mut c_int>,
    stored: &mut usize,
    read_code: u8,
    object_id: u8,
) -> Option<u8> {
    let answer = decode::DeviceIdAnswer::decode(pdu, count as usize);
    if let Some(c) = conformity {
        *c = answer.conformity as c_int;
    }
    for (id, value) in answer.objects() {
        if *stored == out.len() {
            return None;
        }
        let slot = &mut out[*stored];
        slot.id = id;
        slot.length = value.len() as u8;
        for (dst, &src) in slot.value.iter_mut().zip(value) {
            *dst = src as c_char;
        }
        slot.value[value.len()] = 0;
        *stored += 1;
    }
    answer.next_request(read_code, object_id)
}

// ---------------------------------------------------------------- the _async forms
// The requests above queued for the event-driven client (see modbus_process(3)):
// the same argument checks, the same decoders when the answer comes; `rc` of the
// callback is what the blocking call returns.

use crate::ffi::event::{Callback, submit, submit_expecting};
use crate::outstanding::{Deliver, Streamed};
use std::ffi::c_void;

/// `modbus_read_exception_status` without waiting (FC 07): `*status` is written
/// before the callback, which gets `rc` 1.
///
/// # Safety
/// `ctx` must be NULL or a live context; `status` NULL or writable until the request
/// completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_exception_status_async(
    ctx: *mut Modbus,
    status: *mut u8,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if status.is_null() {
        return fail(Error::INVALID);
    }
    let deliver = Deliver::Decode { decode: dec_exception_status, args: [status as usize, 0, 0, 0, 0, 0] };
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, deliver, |_| Ok(Request::ReadExceptionStatus)) }
}

/// `modbus_diagnostics` without waiting (FC 08): `rc` is the number of data words
/// the answer has (at most `max_dest` go to `dest`); Force Listen Only Mode (04)
/// completes once sent, with 0.
///
/// # Safety
/// `ctx` must be NULL or a live context; `data` valid for `nb` values; `dest` for
/// `max_dest` values until the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_diagnostics_async(
    ctx: *mut Modbus,
    sub_function: c_int,
    data: *const u16,
    nb: c_int,
    dest: *mut u16,
    max_dest: c_int,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let Some(req) = (unsafe { diagnostics_request(sub_function, data, nb, dest, max_dest) }) else {
        return fail(Error::INVALID);
    };
    let deliver = Deliver::Decode { decode: dec_diagnostics, args: [dest as usize, max_dest as usize, 0, 0, 0, 0] };
    // SAFETY: forwarded caller contract.
    unsafe { submit_expecting(ctx, cb, user_data, deliver, sub_function != 4, |_| Ok(req)) }
}

/// `modbus_get_comm_event_counter` without waiting (FC 0B): `rc` 1.
///
/// # Safety
/// `ctx` must be NULL or a live context; the pointers NULL or writable until the
/// request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_comm_event_counter_async(
    ctx: *mut Modbus,
    status: *mut u16,
    event_count: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    let args = [status as usize, event_count as usize, 0, 0, 0, 0];
    let deliver = Deliver::Decode { decode: dec_comm_event_counter, args };
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, deliver, |_| Ok(Request::GetCommEventCounter)) }
}

/// `modbus_get_comm_event_log` without waiting (FC 0C): `rc` is the number of
/// events the device sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; the counter pointers NULL or writable,
/// `events` valid for `max_events` bytes, until the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_comm_event_log_async(
    ctx: *mut Modbus,
    status: *mut u16,
    event_count: *mut u16,
    message_count: *mut u16,
    events: *mut u8,
    max_events: c_int,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if !events_room_ok(events, max_events) {
        return fail(Error::INVALID);
    }
    let args = event_log_args(status, event_count, message_count, events, max_events);
    let deliver = Deliver::Decode { decode: dec_comm_event_log, args };
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, deliver, |_| Ok(Request::GetCommEventLog)) }
}

/// `modbus_read_file_record` without waiting (FC 14): `rc` is `nb`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` valid for `nb` values until the
/// request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_file_record_async(
    ctx: *mut Modbus,
    file: c_int,
    record: c_int,
    nb: c_int,
    dest: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if dest.is_null() {
        return fail(Error::INVALID);
    }
    let deliver = Deliver::Decode { decode: dec_file_record, args: [dest as usize, 0, 0, 0, 0, 0] };
    // SAFETY: forwarded caller contract.
    unsafe {
        submit(ctx, cb, user_data, deliver, |_| {
            check_file_args(file, record, nb, MAX_FILE_READ_REGISTERS)?;
            Ok(Request::ReadFileRecord { file: file as u16, record: record as u16, nb: nb as u16 })
        })
    }
}

/// `modbus_write_file_record` without waiting (FC 15; the values are copied at
/// once): `rc` is `nb`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `src` valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_write_file_record_async(
    ctx: *mut Modbus,
    file: c_int,
    record: c_int,
    nb: c_int,
    src: *const u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if src.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract; `src` holds `nb` (checked) values.
    unsafe {
        submit(ctx, cb, user_data, Deliver::Count, |_| {
            check_file_args(file, record, nb, MAX_FILE_WRITE_REGISTERS)?;
            let values = slice::from_raw_parts(src, nb as usize);
            Ok(Request::WriteFileRecord { file: file as u16, record: record as u16, values })
        })
    }
}

/// `modbus_read_fifo_queue` without waiting (FC 18): `rc` is the number of values.
///
/// # Safety
/// `ctx` must be NULL or a live context; `dest` valid for 31 values until the request
/// completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_fifo_queue_async(
    ctx: *mut Modbus,
    addr: c_int,
    dest: *mut u16,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if !fifo_args_ok(addr, dest) {
        return fail(Error::INVALID);
    }
    let deliver = Deliver::Decode { decode: dec_fifo, args: [dest as usize, 0, 0, 0, 0, 0] };
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, deliver, |_| Ok(Request::ReadFifoQueue { addr: addr as u16 })) }
}

/// `modbus_read_device_identification` without waiting (FC 2B / MEI 0E): a stream
/// access follows the device's "more follows" with the next requests under the same
/// request id (`modbus_cancel` of that id stops it between rounds); the callback runs
/// once, at the end, with the number of objects stored. `objects` and `conformity`
/// are written as the answers come.
///
/// # Safety
/// `ctx` must be NULL or a live context; `objects` valid for `max_objects` entries and
/// `conformity` NULL or writable, until the request completes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_read_device_identification_async(
    ctx: *mut Modbus,
    read_code: c_int,
    object_id: c_int,
    objects: *mut modbus_device_id_object_t,
    max_objects: c_int,
    conformity: *mut c_int,
    cb: Callback,
    user_data: *mut c_void,
) -> c_int {
    if !device_id_args_ok(read_code, object_id, objects, max_objects) {
        return fail(Error::INVALID);
    }
    // args: objects, max_objects, conformity, objects stored so far, read code, and
    // the object id this round asked from, with the rounds made (<< 8).
    let args = [objects as usize, max_objects as usize, conformity as usize, 0, read_code as usize, object_id as usize];
    let deliver = Deliver::Stream { decode: dec_device_id, args };
    let (read_code, object_id) = (read_code as u8, object_id as u8);
    // SAFETY: forwarded caller contract.
    unsafe { submit(ctx, cb, user_data, deliver, move |_| Ok(Request::ReadDeviceId { read_code, object_id })) }
}

/// A round of [`modbus_read_device_identification_async`] (see its `args`).
///
/// # Safety
/// `args[0]` valid for `args[1]` objects; `args[2]` NULL or a writable `int *`.
unsafe fn dec_device_id(pdu: &[u8], count: c_int, args: &mut DecodeArgs) -> Streamed {
    // SAFETY: guaranteed by the caller.
    let out = unsafe { slice::from_raw_parts_mut(args[0] as *mut modbus_device_id_object_t, args[1]) };
    // SAFETY: as above.
    let conformity = unsafe { (args[2] as *mut c_int).as_mut() };
    let read_code = args[4] as u8;
    let (object_id, rounds) = (args[5] as u8, args[5] >> 8);
    let mut stored = args[3];
    let next = device_id_round(pdu, count, out, conformity, &mut stored, read_code, object_id);
    args[3] = stored;
    match next {
        Some(next) if rounds + 1 < DEVICE_ID_ROUNDS => {
            args[5] = usize::from(next) | (rounds + 1) << 8;
            Streamed::Next(Request::ReadDeviceId { read_code, object_id: next })
        }
        _ => Streamed::Done(stored as c_int),
    }
}
