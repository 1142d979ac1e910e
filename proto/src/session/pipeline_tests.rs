use super::*;

const MS: Duration = Duration::from_millis(1);
const RESPONSE: Duration = Duration::from_millis(500);

fn tcp(depth: usize) -> Pipeline<&'static str> {
    let mut p = Pipeline::new(Framing::Tcp);
    assert!(p.set_max_in_flight(depth));
    p
}

/// A TCP request ADU with this transaction id (read 1 register at 0).
fn adu(tid: u16) -> [u8; 12] {
    let t = tid.to_be_bytes();
    [t[0], t[1], 0, 0, 0, 6, 1, 3, 0, 0, 0, 1]
}

fn submit(p: &mut Pipeline<&'static str>, tid: u16, what: &'static str) -> i32 {
    p.submit(&adu(tid), &[], tid, false, RESPONSE, what).expect("room")
}

fn of(a: Answer<&'static str>) -> &'static str {
    match a {
        Answer::Of(e) => e.payload,
        Answer::Stale => "stale",
        Answer::Unexpected => "unexpected",
    }
}

#[test]
fn depth_one_sends_one_request_at_a_time() {
    let mut p = tcp(1);
    let mut late = LateIds::default();
    submit(&mut p, 1, "a");
    submit(&mut p, 2, "b");
    assert_eq!(p.fill(Duration::ZERO, &mut late), 1);
    assert_eq!(p.output(), &adu(1));
    assert_eq!(p.fill(Duration::ZERO, &mut late), 0, "the depth is full");
    p.wrote(12);
    assert!(p.output().is_empty());
    assert_eq!(of(p.answer(Some(1), &mut late)), "a");
    assert_eq!(p.fill(MS, &mut late), 1);
    assert_eq!(p.output(), &adu(2));
    assert_eq!(p.pending(), 1);
}

#[test]
fn requests_queued_together_go_out_in_one_buffer_and_answers_match_in_any_order() {
    let mut p = tcp(16);
    let mut late = LateIds::default();
    for (tid, w) in [(7, "x"), (8, "y"), (9, "z")] {
        submit(&mut p, tid, w);
    }
    assert_eq!(p.fill(Duration::ZERO, &mut late), 3);
    let mut all = Vec::new();
    for t in [7, 8, 9] {
        all.extend_from_slice(&adu(t));
    }
    assert_eq!(p.output(), &all[..]);
    p.wrote(5);
    assert_eq!(p.output(), &all[5..], "a short write keeps the rest, in order");
    assert_eq!(of(p.answer(Some(9), &mut late)), "z");
    assert_eq!(of(p.answer(Some(7), &mut late)), "x");
    assert_eq!(of(p.answer(Some(42), &mut late)), "unexpected");
    assert_eq!(of(p.answer(Some(8), &mut late)), "y");
    assert!(p.is_empty());
}

#[test]
fn a_late_answer_is_dropped_never_handed_to_the_next_request() {
    let mut p = tcp(1);
    let mut late = LateIds::default();
    submit(&mut p, 1, "first");
    p.fill(Duration::ZERO, &mut late);
    assert_eq!(p.deadline(), Some(RESPONSE));
    assert!(p.due(RESPONSE - MS, &mut late).is_empty());
    let due = p.due(RESPONSE, &mut late);
    assert_eq!(due.len(), 1);
    assert!(matches!(due[0].1, End::TimedOut));
    submit(&mut p, 2, "second");
    assert_eq!(p.fill(RESPONSE, &mut late), 1);
    assert_eq!(p.deadline(), Some(2 * RESPONSE), "the timeout runs from the send");
    assert_eq!(of(p.answer(Some(1), &mut late)), "stale");
    assert_eq!(of(p.answer(Some(1), &mut late)), "unexpected", "a stale id is dropped once");
    assert_eq!(of(p.answer(Some(2), &mut late)), "second");
}

#[test]
fn each_request_in_flight_has_its_own_deadline() {
    let mut p = tcp(4);
    let mut late = LateIds::default();
    submit(&mut p, 1, "a");
    p.fill(Duration::ZERO, &mut late);
    submit(&mut p, 2, "b");
    p.fill(100 * MS, &mut late);
    let due = p.due(RESPONSE, &mut late);
    assert_eq!(due.iter().map(|(e, _)| e.payload).collect::<Vec<_>>(), ["a"]);
    assert_eq!(p.deadline(), Some(600 * MS));
    assert_eq!(p.answer_deadline(), Some(600 * MS));
}

#[test]
fn a_reused_transaction_id_belongs_to_the_new_request() {
    let mut p = tcp(1);
    let mut late = LateIds::default();
    submit(&mut p, 5, "old");
    p.fill(Duration::ZERO, &mut late);
    p.due(RESPONSE, &mut late);
    // 65536 requests later the id comes round again.
    submit(&mut p, 5, "new");
    p.fill(RESPONSE, &mut late);
    assert_eq!(of(p.answer(Some(5), &mut late)), "new");
}

#[test]
fn cancel_takes_a_request_from_the_queue_or_the_wire() {
    let mut p = tcp(1);
    let mut late = LateIds::default();
    let a = submit(&mut p, 1, "a");
    let b = submit(&mut p, 2, "b");
    p.fill(Duration::ZERO, &mut late);
    assert_eq!(p.cancel(b, &mut late).map(|e| e.payload), Some("b"));
    assert_eq!(p.cancel(a, &mut late).map(|e| e.payload), Some("a"));
    assert!(p.cancel(a, &mut late).is_none());
    assert_eq!(of(p.answer(Some(1), &mut late)), "stale", "the cancelled request's answer is dropped");
    assert!(p.is_empty());
}

#[test]
fn serial_lines_have_one_request_on_the_wire_and_no_transaction_ids() {
    let mut p: Pipeline<&str> = Pipeline::new(Framing::Rtu);
    let mut late = LateIds::default();
    assert!(p.set_max_in_flight(8));
    assert_eq!(p.max_in_flight(), 1);
    p.submit(&[1, 3, 0, 0, 0, 1, 0x84, 0x0A], &[], 0, false, RESPONSE, "a").unwrap();
    p.submit(&[1, 3, 0, 1, 0, 1, 0xD5, 0xCA], &[], 0, false, RESPONSE, "b").unwrap();
    assert_eq!(p.fill(Duration::ZERO, &mut late), 1);
    assert_eq!(of(p.answer(None, &mut late)), "a");
    assert_eq!(of(p.answer(None, &mut late)), "unexpected");
    // A timed-out request on a serial line leaves no id to recognise its answer by.
    p.fill(MS, &mut late);
    p.due(MS + RESPONSE, &mut late);
    assert_eq!(of(p.answer(None, &mut late)), "unexpected");
}

#[test]
fn a_broadcast_completes_after_the_turnaround_and_holds_the_line_until_then() {
    let mut p: Pipeline<&str> = Pipeline::new(Framing::Rtu);
    let mut late = LateIds::default();
    p.submit(&[0, 6, 0, 1, 0, 3, 0, 0], &[], 0, true, RESPONSE, "bc").unwrap();
    p.submit(&[1, 3, 0, 1, 0, 1, 0xD5, 0xCA], &[], 0, false, RESPONSE, "next").unwrap();
    assert_eq!(p.fill(Duration::ZERO, &mut late), 1);
    assert!(!p.awaits_answer());
    assert_eq!(p.deadline(), Some(TURNAROUND));
    assert_eq!(p.fill(MS, &mut late), 0);
    assert!(p.due(TURNAROUND - MS, &mut late).is_empty());
    let due = p.due(TURNAROUND, &mut late);
    assert!(matches!(due[0].1, End::Sent));
    assert_eq!(p.fill(TURNAROUND, &mut late), 1);
    assert!(p.awaits_answer());
}

#[test]
fn the_queue_is_bounded() {
    let mut p = tcp(1);
    for i in 0..MAX_PENDING {
        assert!(p.submit(&adu(i as u16), &[], i as u16, false, RESPONSE, "r").is_some());
    }
    assert!(p.submit(&adu(0), &[], 0, false, RESPONSE, "r").is_none());
    assert!(!p.set_max_in_flight(0));
    assert!(!p.set_max_in_flight(MAX_IN_FLIGHT + 1));
    let all = p.drain();
    assert_eq!(all.len(), MAX_PENDING);
    assert!(p.is_empty());
}

#[test]
fn ascii_requests_go_out_as_characters_and_are_checked_as_bytes() {
    let mut p: Pipeline<&str> = Pipeline::new(Framing::Ascii);
    let mut late = LateIds::default();
    p.submit(&[1, 3, 0, 0, 0, 1], b":010300000001FB\r\n", 0, false, RESPONSE, "a").unwrap();
    p.fill(Duration::ZERO, &mut late);
    assert_eq!(p.output(), b":010300000001FB\r\n");
    match p.answer(None, &mut late) {
        Answer::Of(e) => assert_eq!(e.adu(), &[1, 3, 0, 0, 0, 1]),
        _ => panic!("the request in flight"),
    }
}

#[test]
fn a_continued_request_keeps_its_id_and_goes_next() {
    let mut p = tcp(1);
    let mut late = LateIds::default();
    let first = submit(&mut p, 1, "stream");
    let other = submit(&mut p, 2, "other");
    assert_eq!(p.fill(Duration::ZERO, &mut late), 1);
    p.wrote(12);
    let Answer::Of(e) = p.answer(Some(1), &mut late) else { panic!("the answer of the first") };
    assert_eq!(e.id, first);
    // Its next round: same id, ahead of the request queued after it.
    assert_eq!(p.resubmit(first, &adu(3), &[], 3, RESPONSE, "stream, round 2"), Some(first));
    assert_eq!(p.ids().collect::<Vec<_>>(), vec![first, other]);
    assert_eq!(p.fill(MS, &mut late), 1);
    assert_eq!(p.output(), &adu(3));
    // Cancelled by its id in its second round.
    assert_eq!(p.cancel(first, &mut late).map(|e| e.payload), Some("stream, round 2"));
    assert_eq!(p.pending(), 1);
}

#[test]
fn a_write_that_took_time_restarts_the_clocks_of_the_requests_it_sent() {
    let mut p = tcp(2);
    let mut late = LateIds::default();
    submit(&mut p, 1, "a");
    assert_eq!(p.fill(Duration::ZERO, &mut late), 1);
    assert_eq!(p.deadline(), Some(RESPONSE));
    submit(&mut p, 2, "b");
    assert_eq!(p.fill(MS, &mut late), 1);
    // The second write took 300 ms (an RTS sequence on a slow line): its request's
    // timeout starts at its end; the first request's stays.
    p.restart_clocks(1, 301 * MS);
    assert_eq!(p.deadline(), Some(RESPONSE));
    assert!(p.due(RESPONSE + MS, &mut late).iter().map(|(e, _)| e.payload).eq(["a"]));
    assert_eq!(p.deadline(), Some(301 * MS + RESPONSE));
    assert!(p.due(300 * MS + RESPONSE, &mut late).is_empty(), "b still has its whole response timeout");
}

#[test]
fn each_request_keeps_the_timeout_it_was_queued_with_or_its_own() {
    let mut p = tcp(3);
    let mut late = LateIds::default();
    let a = submit(&mut p, 1, "a");
    let b = p.submit(&adu(2), &[], 2, false, 2 * RESPONSE, "b").expect("room");
    let c = submit(&mut p, 3, "c");
    // c's own timeout, set while queued: 100 ms from its send.
    assert!(p.set_timeout(c, 100 * MS));
    assert_eq!(p.fill(10 * MS, &mut late), 3);
    assert_eq!(p.deadline(), Some(110 * MS));
    assert!(p.due(110 * MS, &mut late).iter().map(|(e, _)| e.payload).eq(["c"]));
    // a's, changed on the wire: still counted from its send.
    assert!(p.set_timeout(a, 200 * MS));
    assert!(p.due(209 * MS, &mut late).is_empty());
    assert!(p.due(210 * MS, &mut late).iter().map(|(e, _)| e.payload).eq(["a"]));
    assert_eq!(p.deadline(), Some(10 * MS + 2 * RESPONSE), "b has the timeout it was queued with");
    assert!(!p.set_timeout(a, MS), "a is no longer pending");
    assert!(p.set_timeout(b, MS));
}
