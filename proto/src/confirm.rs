//! Client side: validating a response against the request that caused it
//! (libmodbus's `check_confirmation`, 3.1.12 semantics).

use crate::error::{Error, exception};
use crate::frame::{Framing, Layout, MsgKind, beyond_libmodbus, layout};
use crate::{Diag, fc};

/// Why a response was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// The server answered with an exception (or a malformed one): errno is set and
    /// libmodbus prints it with `_error_print`, but no error recovery follows.
    Exception(Error),
    /// The response does not belong to the request: with PROTOCOL error recovery the
    /// caller sleeps the response timeout and flushes.
    Mismatch(Error),
    /// The framing pre-check failed (TCP transaction or protocol id, RTU slave).
    /// libmodbus sets errno before its PROTOCOL-recovery flush here, so the flush may
    /// overwrite it (EAGAIN on TCP); the caller reproduces that order.
    Foreign(Error),
}

fn be16(b: &[u8], at: usize) -> i32 {
    ((b[at] as i32) << 8) | b[at + 1] as i32
}

/// Expected response length computed from the request, or `None` when it cannot be
/// known in advance (report slave id).
#[inline]
pub fn expected_length(framing: Framing, req: &[u8]) -> Option<usize> {
    let h = framing.header_length();
    let payload = match req[h] {
        fc::READ_COILS | fc::READ_DISCRETE_INPUTS => {
            let nb = be16(req, h + 3) as usize;
            2 + nb.div_ceil(8)
        }
        fc::READ_HOLDING_REGISTERS | fc::READ_INPUT_REGISTERS | fc::WRITE_AND_READ_REGISTERS => {
            2 + 2 * be16(req, h + 3) as usize
        }
        // libmodbus says 3 here, but never checks an FC 07 response; its answer is
        // the function code and one status byte.
        fc::READ_EXCEPTION_STATUS => 2,
        fc::REPORT_SLAVE_ID => return None,
        // Beyond libmodbus: as long as the table's fixed layout says, else unknown.
        f if beyond_libmodbus(f) => match layout(MsgKind::Confirmation, true, f) {
            Layout::Fixed(n) => 1 + n as usize,
            _ => return None,
        },
        fc::MASK_WRITE_REGISTER => 7,
        _ => 5,
    };
    Some(h + payload + framing.checksum_length())
}

/// Checks `rsp` (a complete ADU as received) against `req` (the ADU sent, sealed).
/// On success returns libmodbus's "number of values" of the response: the count of
/// bits' bytes, registers, written items, or the report-slave-id byte count.
pub fn check(framing: Framing, req: &[u8], rsp: &[u8], diag: &mut dyn Diag) -> Result<i32, Rejection> {
    let h = framing.header_length();

    // Framing-specific pre-check.
    match framing {
        Framing::Tcp => {
            let (req_tid, rsp_tid) = (be16(req, 0), be16(rsp, 0));
            if req_tid != rsp_tid {
                diag.err(format_args!("Invalid transaction ID received 0x{rsp_tid:X} (not 0x{req_tid:X})\n"));
                return Err(Rejection::Foreign(Error::BAD_DATA));
            }
            let protocol = be16(rsp, 2);
            if protocol != 0 {
                diag.err(format_args!("Invalid protocol ID received 0x{protocol:X} (not 0x0)\n"));
                return Err(Rejection::Foreign(Error::BAD_DATA));
            }
        }
        Framing::Rtu | Framing::Ascii => {
            if req[0] != rsp[0] && req[0] != 0 {
                diag.err(format_args!("The responding slave {} isn't the requested slave {}\n", rsp[0], req[0]));
                return Err(Rejection::Foreign(Error::BAD_SLAVE));
            }
        }
    }

    // Every response has a function code and at least one byte after it. Frames
    // reach this point as long as their content says (the assembler reads them so,
    // and ASCII frames are checked against it); this guard keeps a frame that
    // escaped both from being read past its end.
    if rsp.len() < h + 2 + framing.checksum_length() {
        diag.err(format_args!(
            "Message length not corresponding to the computed length ({} != {})\n",
            rsp.len(),
            expected_length(framing, req).unwrap_or(h + 2 + framing.checksum_length())
        ));
        return Err(Rejection::Mismatch(Error::BAD_DATA));
    }
    let function = rsp[h];

    if function >= 0x80 {
        let well_formed = rsp.len() == h + 2 + framing.checksum_length() && req[h] == function.wrapping_sub(0x80);
        let error = match well_formed {
            true if rsp[h + 1] < exception::MAX => Error::from_exception(rsp[h + 1]),
            _ => Error::BAD_EXCEPTION,
        };
        return Err(Rejection::Exception(error));
    }

    if let Some(expected) = expected_length(framing, req)
        && rsp.len() != expected
    {
        diag.err(format_args!(
            "Message length not corresponding to the computed length ({} != {})\n",
            rsp.len(),
            expected
        ));
        return Err(Rejection::Mismatch(Error::BAD_DATA));
    }

    if function != req[h] {
        diag.err(format_args!(
            "Received function not corresponding to the request (0x{function:X} != 0x{:X})\n",
            req[h]
        ));
        return Err(Rejection::Mismatch(Error::BAD_DATA));
    }

    let (req_nb, rsp_nb, echo_ok) = match function {
        fc::READ_COILS | fc::READ_DISCRETE_INPUTS => {
            let nb = be16(req, h + 3);
            (nb / 8 + (nb % 8 != 0) as i32, rsp[h + 1] as i32, true)
        }
        fc::READ_HOLDING_REGISTERS | fc::READ_INPUT_REGISTERS | fc::WRITE_AND_READ_REGISTERS => {
            (be16(req, h + 3), rsp[h + 1] as i32 / 2, true)
        }
        fc::WRITE_MULTIPLE_COILS | fc::WRITE_MULTIPLE_REGISTERS => {
            (be16(req, h + 3), be16(rsp, h + 3), req[h + 1..h + 3] == rsp[h + 1..h + 3])
        }
        fc::WRITE_SINGLE_COIL | fc::WRITE_SINGLE_REGISTER => (1, 1, req[h + 1..h + 5] == rsp[h + 1..h + 5]),
        // The byte count must describe the frame (an ASCII frame ends at its
        // delimiter whatever the count says).
        fc::REPORT_SLAVE_ID => {
            let count = rsp[h + 1] as i32;
            let whole = rsp.len() == h + 2 + count as usize + framing.checksum_length();
            (count, if whole { count } else { rsp.len() as i32 - (h + 2 + framing.checksum_length()) as i32 }, true)
        }
        f if beyond_libmodbus(f) => {
            let body = &rsp[..rsp.len() - framing.checksum_length()];
            let req_body = &req[..req.len() - framing.checksum_length()];
            let (want, got) = match check_extended(h, req_body, body) {
                Ok(count) => return Ok(count),
                Err(pair) => pair,
            };
            (want, got, false)
        }
        _ => (1, 1, true),
    };
    if req_nb != rsp_nb || !echo_ok {
        diag.err(format_args!("Received data not corresponding to the request ({rsp_nb} != {req_nb})\n"));
        return Err(Rejection::Mismatch(Error::BAD_DATA));
    }
    Ok(rsp_nb)
}

/// Value checks of the function codes beyond libmodbus, on header + PDU of the
/// request and the response. Returns the count the client call reports, or the
/// (expected, received) pair for the mismatch message.
fn check_extended(h: usize, req: &[u8], rsp: &[u8]) -> Result<i32, (i32, i32)> {
    let pdu = &rsp[h..];
    let req_pdu = &req[h..];
    let len = pdu.len() as i32;
    match pdu[0] {
        // Sub-function echoed; return query data echoes the data too.
        fc::DIAGNOSTICS => {
            if len < 3 || (len - 3) % 2 != 0 || pdu[1..3] != req_pdu[1..3] {
                return Err((req_pdu.len() as i32, len));
            }
            if req_pdu[1..3] == [0, 0] && pdu != req_pdu {
                return Err((req_pdu.len() as i32, len));
            }
            Ok((len - 3) / 2)
        }
        // Status, event count, message count, then the events.
        fc::GET_COMM_EVENT_LOG => {
            let count = pdu[1] as i32;
            if !(6..=6 + 64).contains(&count) || len != 2 + count {
                return Err((6, count));
            }
            Ok(count - 6)
        }
        // One sub-response: length, reference type, data.
        fc::READ_FILE_RECORD => {
            let nb = ((req_pdu[7] as i32) << 8) | req_pdu[8] as i32;
            let ok = len >= 4 && pdu[1] as i32 == len - 2 && pdu[2] as i32 == len - 3 && pdu[3] == 6;
            if !ok || (len - 4) != 2 * nb {
                return Err((nb, (len - 4).max(0) / 2));
            }
            Ok(nb)
        }
        // The whole request echoed.
        fc::WRITE_FILE_RECORD => {
            let nb = ((req_pdu[7] as i32) << 8) | req_pdu[8] as i32;
            if pdu != req_pdu {
                return Err((nb, (len - 9).max(0) / 2));
            }
            Ok(nb)
        }
        // Status and event count: nothing to compare with the request.
        fc::GET_COMM_EVENT_COUNTER => Ok(1),
        // Byte count, FIFO count, values; at most 31 values.
        fc::READ_FIFO_QUEUE => {
            if len < 5 {
                return Err((2, len - 1));
            }
            let bytes = ((pdu[1] as i32) << 8) | pdu[2] as i32;
            let count = ((pdu[3] as i32) << 8) | pdu[4] as i32;
            if bytes != 2 + 2 * count || count > 31 || len != 3 + bytes {
                return Err((2 + 2 * count, bytes));
            }
            Ok(count)
        }
        // MEI type and read code echoed; the number of objects.
        _ => {
            if len < 7 || pdu[1] != req_pdu[1] || pdu[2] != req_pdu[2] {
                return Err((req_pdu[2] as i32, if len > 2 { pdu[2] as i32 } else { -1 }));
            }
            // The objects must fill the frame exactly.
            let mut pos = 7usize;
            for _ in 0..pdu[6] {
                if pos + 2 > pdu.len() {
                    return Err((pdu[6] as i32, -1));
                }
                pos += 2 + pdu[pos + 1] as usize;
            }
            if pos != pdu.len() {
                return Err((pdu[6] as i32, -1));
            }
            Ok(pdu[6] as i32)
        }
    }
}

#[cfg(test)]
mod tests {
    /// Pseudo-random read requests and answers, valid and perturbed: every valid
    /// answer to a read is accepted with libmodbus's count (registers, or the bytes
    /// of bits), and no perturbed one makes the check misbehave.
    #[test]
    fn read_answers_are_accepted_with_their_count() {
        use super::*;
        let mut rng = crate::test_rng::XorShift::new(0xD1B5_4A32_D192_ED03);
        let mut next = || rng.next_u64();
        let mut accepted = 0;
        for round in 0..100_000 {
            let framing = [Framing::Rtu, Framing::Tcp, Framing::Ascii][round % 3];
            let h = framing.header_length();
            let function = [1u8, 2, 3, 4, 0x17, 5, 6, 0x0F, 0x10][(next() % 9) as usize];
            let nb = (next() % 130) as usize;
            let mut req = vec![0u8; h + 5 + 8];
            for b in req.iter_mut() {
                *b = next() as u8;
            }
            req[2] = 0;
            req[3] = 0;
            req[h] = function;
            req[h + 3..h + 5].copy_from_slice(&(nb as u16).to_be_bytes());
            let count = if function <= 2 { nb.div_ceil(8) } else { 2 * nb };
            let mut rsp = vec![0u8; h + 2 + count + framing.checksum_length()];
            rsp[..h].copy_from_slice(&req[..h]);
            rsp[h] = function;
            rsp[h + 1] = count as u8;
            let is_read = function <= 4 || function == 0x17;
            let expected = if function <= 2 { count } else { nb } as i32;
            if round % 2 == 0 {
                // Perturb one byte of the head or the length.
                match next() % 4 {
                    0 => {
                        let i = (next() as usize) % (h + 2);
                        rsp[i] ^= 1 << (next() % 8);
                    }
                    1 => rsp.truncate(rsp.len().saturating_sub(1 + (next() % 3) as usize)),
                    2 => rsp.push(0),
                    _ => req[h + 4] ^= 1,
                }
            }
            let got = check(framing, &req, &rsp, &mut crate::Silent);
            if round % 2 != 0 && is_read && nb > 0 && count <= 0xFF {
                accepted += 1;
                assert_eq!(got, Ok(expected), "{framing:?} req {req:02x?} rsp {rsp:02x?}");
            }
        }
        assert!(accepted > 20_000, "too few valid answers: {accepted}");
    }

    use super::*;
    use crate::Recorded;
    use crate::error::*;
    use crate::frame::MAX_ADU_LENGTH;
    use crate::request::Request;

    fn tcp_req(req: Request<'_>) -> Vec<u8> {
        let mut buf = [0u8; MAX_ADU_LENGTH];
        let n = req.encode(Framing::Tcp, 0xFF, 0x0102, &mut buf);
        let n = Framing::Tcp.seal(&mut buf, n);
        buf[..n].to_vec()
    }

    fn tcp_rsp(tid: u16, pdu: &[u8]) -> Vec<u8> {
        let mut v = tid.to_be_bytes().to_vec();
        v.extend([0, 0]);
        v.extend(((pdu.len() + 1) as u16).to_be_bytes());
        v.push(0xFF);
        v.extend(pdu);
        v
    }

    fn rtu(frame: &[u8]) -> Vec<u8> {
        let mut v = frame.to_vec();
        v.extend(crate::crc::crc16(frame).to_le_bytes());
        v
    }

    const READ3: Request<'static> = Request::ReadRegisters { function: 3, addr: 0x6B, nb: 3 };

    #[test]
    fn accepts_matching_read() {
        let req = tcp_req(READ3);
        let rsp = tcp_rsp(0x0102, &[3, 6, 0xAE, 0x41, 0x56, 0x52, 0x43, 0x40]);
        assert_eq!(check(Framing::Tcp, &req, &rsp, &mut Recorded::default()), Ok(3));
    }

    #[test]
    fn rejects_wrong_tid_and_protocol() {
        let req = tcp_req(READ3);
        let mut d = Recorded::default();
        let rsp = tcp_rsp(0x0103, &[3, 6, 0, 0, 0, 0, 0, 0]);
        assert_eq!(check(Framing::Tcp, &req, &rsp, &mut d), Err(Rejection::Foreign(Error::BAD_DATA)));
        assert_eq!(d.err, "Invalid transaction ID received 0x103 (not 0x102)\n");
        let mut rsp = tcp_rsp(0x0102, &[3, 6, 0, 0, 0, 0, 0, 0]);
        rsp[3] = 1; // 3.1.6 would accept a single non-zero byte; 3.1.12 does not.
        assert_eq!(check(Framing::Tcp, &req, &rsp, &mut d), Err(Rejection::Foreign(Error::BAD_DATA)));
    }

    #[test]
    fn rejects_other_slave_in_rtu() {
        let mut buf = [0u8; MAX_ADU_LENGTH];
        let n = READ3.encode(Framing::Rtu, 0x11, 0, &mut buf);
        let n = Framing::Rtu.seal(&mut buf, n);
        let rsp = rtu(&[0x12, 3, 6, 0, 0, 0, 0, 0, 0]);
        let mut d = Recorded::default();
        assert_eq!(check(Framing::Rtu, &buf[..n], &rsp, &mut d), Err(Rejection::Foreign(Error::BAD_SLAVE)));
        assert_eq!(d.err, "The responding slave 18 isn't the requested slave 17\n");
    }

    #[test]
    fn exception_codes() {
        let req = tcp_req(READ3);
        let mut d = Recorded::default();
        for code in 0u8..=255 {
            let rsp = tcp_rsp(0x0102, &[0x83, code]);
            let want = if code < 12 { Error(MODBUS_ENOBASE + code as i32) } else { Error::BAD_EXCEPTION };
            assert_eq!(check(Framing::Tcp, &req, &rsp, &mut d), Err(Rejection::Exception(want)));
        }
        // An exception for another function, or with trailing bytes, is malformed.
        let rsp = tcp_rsp(0x0102, &[0x84, 2]);
        assert_eq!(check(Framing::Tcp, &req, &rsp, &mut d), Err(Rejection::Exception(Error::BAD_EXCEPTION)));
        let rsp = tcp_rsp(0x0102, &[0x83, 2, 0]);
        assert_eq!(check(Framing::Tcp, &req, &rsp, &mut d), Err(Rejection::Exception(Error::BAD_EXCEPTION)));
        assert_eq!(d.err, "");
    }

    #[test]
    fn length_function_and_count_mismatches() {
        let req = tcp_req(READ3);
        let mut d = Recorded::default();
        let short = tcp_rsp(0x0102, &[3, 4, 0, 0, 0, 0]);
        assert_eq!(check(Framing::Tcp, &req, &short, &mut d), Err(Rejection::Mismatch(Error::BAD_DATA)));
        assert_eq!(d.err, "Message length not corresponding to the computed length (13 != 15)\n");
        let mut d = Recorded::default();
        let wrong_fc = tcp_rsp(0x0102, &[4, 6, 0, 0, 0, 0, 0, 0]);
        assert_eq!(check(Framing::Tcp, &req, &wrong_fc, &mut d), Err(Rejection::Mismatch(Error::BAD_DATA)));
        assert_eq!(d.err, "Received function not corresponding to the request (0x4 != 0x3)\n");
        let mut d = Recorded::default();
        let wrong_count = tcp_rsp(0x0102, &[3, 4, 0, 0, 0, 0, 0, 0]);
        assert_eq!(check(Framing::Tcp, &req, &wrong_count, &mut d), Err(Rejection::Mismatch(Error::BAD_DATA)));
        assert_eq!(d.err, "Received data not corresponding to the request (2 != 3)\n");
    }

    #[test]
    fn write_echo_checks() {
        let req = tcp_req(Request::WriteRegister { addr: 1, value: 3 });
        let mut d = Recorded::default();
        assert_eq!(check(Framing::Tcp, &req, &tcp_rsp(0x0102, &[6, 0, 1, 0, 3]), &mut d), Ok(1));
        assert!(check(Framing::Tcp, &req, &tcp_rsp(0x0102, &[6, 0, 1, 0, 4]), &mut d).is_err());
        let req = tcp_req(Request::WriteRegisters { addr: 1, values: &[1, 2] });
        assert_eq!(check(Framing::Tcp, &req, &tcp_rsp(0x0102, &[0x10, 0, 1, 0, 2]), &mut d), Ok(2));
        assert!(check(Framing::Tcp, &req, &tcp_rsp(0x0102, &[0x10, 0, 2, 0, 2]), &mut d).is_err());
        let req = tcp_req(Request::ReadBits { function: 1, addr: 0, nb: 9 });
        assert_eq!(check(Framing::Tcp, &req, &tcp_rsp(0x0102, &[1, 2, 0xFF, 1]), &mut d), Ok(2));
    }

    #[test]
    fn extended_function_codes() {
        let mut d = Recorded::default();
        let t = Framing::Tcp;
        // Return query data: the echo must be exact.
        let req = tcp_req(Request::Diagnostics { sub_function: 0, data: &[0xA537, 1] });
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &[8, 0, 0, 0xA5, 0x37, 0, 1]), &mut d), Ok(2));
        assert!(check(t, &req, &tcp_rsp(0x0102, &[8, 0, 0, 0xA5, 0x37, 0, 2]), &mut d).is_err());
        // Counter sub-function: one word back.
        let req = tcp_req(Request::Diagnostics { sub_function: 0x0B, data: &[0] });
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &[8, 0, 0x0B, 0, 9]), &mut d), Ok(1));
        assert!(check(t, &req, &tcp_rsp(0x0102, &[8, 0, 0x0C, 0, 9]), &mut d).is_err());
        // Exception status and comm event counter have fixed lengths.
        let req = tcp_req(Request::ReadExceptionStatus);
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &[7, 0x6D]), &mut d), Ok(1));
        assert!(check(t, &req, &tcp_rsp(0x0102, &[7, 0x6D, 0]), &mut d).is_err());
        let req = tcp_req(Request::GetCommEventCounter);
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &[0x0B, 0xFF, 0xFF, 1, 8]), &mut d), Ok(1));
        // Comm event log: byte count 6 + events.
        let req = tcp_req(Request::GetCommEventLog);
        let rsp = tcp_rsp(0x0102, &[0x0C, 8, 0, 0, 1, 8, 1, 0x21, 0x20, 0]);
        assert_eq!(check(t, &req, &rsp, &mut d), Ok(2));
        // File records.
        let req = tcp_req(Request::ReadFileRecord { file: 4, record: 1, nb: 2 });
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &[0x14, 6, 5, 6, 0x0D, 0xFE, 0, 0x20]), &mut d), Ok(2));
        assert!(check(t, &req, &tcp_rsp(0x0102, &[0x14, 4, 3, 6, 0x0D, 0xFE]), &mut d).is_err());
        let req = tcp_req(Request::WriteFileRecord { file: 4, record: 7, values: &[0x06AF] });
        let echo = req[7..].to_vec();
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &echo), &mut d), Ok(1));
        // FIFO: byte count must match the count; at most 31 values.
        let req = tcp_req(Request::ReadFifoQueue { addr: 0x04DE });
        assert_eq!(check(t, &req, &tcp_rsp(0x0102, &[0x18, 0, 6, 0, 2, 1, 0xB8, 0x12, 0x84]), &mut d), Ok(2));
        assert!(check(t, &req, &tcp_rsp(0x0102, &[0x18, 0, 8, 0, 2, 1, 0xB8, 0x12, 0x84]), &mut d).is_err());
        // Device identification: read code echoed, number of objects returned.
        let req = tcp_req(Request::ReadDeviceId { read_code: 1, object_id: 0 });
        let rsp = tcp_rsp(0x0102, &[0x2B, 0x0E, 1, 1, 0, 0, 1, 0, 1, b'A']);
        assert_eq!(check(t, &req, &rsp, &mut d), Ok(1));
        let rsp = tcp_rsp(0x0102, &[0x2B, 0x0E, 2, 1, 0, 0, 1, 0, 1, b'A']);
        assert!(check(t, &req, &rsp, &mut d).is_err());
    }

    #[test]
    fn frames_shorter_than_any_answer_are_refused_not_read() {
        // Fuzz finding F4 (ASCII): two decoded bytes, the second being the LRC.
        let mut d = Recorded::default();
        let req = [0xEF, 0x11, 0x00];
        assert!(check(Framing::Ascii, &req, &[0xEF, 0x11], &mut d).is_err());
        let req = [0xF8, 0x08, 0x00, 0x00, 0x00];
        assert!(check(Framing::Ascii, &req, &[0xF8, 0x08], &mut d).is_err());
        let req = tcp_req(READ3);
        assert!(check(Framing::Tcp, &req, &req[..8], &mut d).is_err());
    }

    #[test]
    fn counts_must_describe_the_frame() {
        // Fuzz finding F3 (ASCII): byte count 0xFF with 11 bytes in the frame.
        let req = [0x11, 0x11, 0xDE];
        let mut rsp = vec![0x11, 0x11, 0xFF, 0xB4, 0xFF, b'L', b'M', b'B', b'3', b'.', b'1', b'.', b'1', b'2'];
        rsp.push(crate::ascii::lrc(&rsp));
        let refused = check(Framing::Ascii, &req, &rsp, &mut Recorded::default());
        assert_eq!(refused, Err(Rejection::Mismatch(Error::BAD_DATA)));
        rsp[2] = 11;
        assert_eq!(check(Framing::Ascii, &req, &rsp, &mut Recorded::default()), Ok(11));
    }

    #[test]
    fn report_slave_id_has_no_fixed_length() {
        let req = tcp_req(Request::ReportSlaveId);
        let rsp = tcp_rsp(0x0102, &[0x11, 5, 0xB4, 0xFF, b'L', b'M', b'B']);
        assert_eq!(check(Framing::Tcp, &req, &rsp, &mut Recorded::default()), Ok(5));
    }
}
