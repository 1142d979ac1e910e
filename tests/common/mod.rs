//! What the tests of the Rust API share.

use std::time::{Duration, Instant};

use modbus::api::{Completion, Modbus, PollFd, poll};

/// Polls and processes `m` until a completion comes (5 s at most); `between` runs
/// after each round (at most 20 ms apart).
pub fn wait_completion(m: &mut Modbus, mut between: impl FnMut()) -> Completion {
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        if let Some(c) = m.next_completion() {
            return c;
        }
        assert!(Instant::now() < end, "no completion");
        let (fd, until) = m.poll_fd().unwrap();
        let mut fds = [PollFd { fd, events: libc::POLLIN, revents: 0 }];
        poll(&mut fds, Some(until.unwrap_or(Duration::MAX).min(Duration::from_millis(20)))).unwrap();
        m.process_events(fds[0].revents).unwrap();
        between();
    }
}
