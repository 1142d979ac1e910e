//! Serial lines: opening the device and setting termios exactly as libmodbus does,
//! restoring the old settings on close, RS-485 mode and the RTS line.

use std::mem::zeroed;

use crate::error::{Error, Result};
use crate::proto::Diag;
use crate::transport::link::{RTU_RS232, RTU_RS485, RtuLink};
use crate::transport::{close, last_error};

/// The termios speed for `baud`, or `None` when the rate is not in libmodbus's table
/// (it then falls back to 9600).
pub fn speed_for(baud: i32) -> Option<libc::speed_t> {
    Some(match baud {
        110 => libc::B110,
        300 => libc::B300,
        600 => libc::B600,
        1200 => libc::B1200,
        2400 => libc::B2400,
        4800 => libc::B4800,
        9600 => libc::B9600,
        19200 => libc::B19200,
        38400 => libc::B38400,
        57600 => libc::B57600,
        115200 => libc::B115200,
        230400 => libc::B230400,
        460800 => libc::B460800,
        500000 => libc::B500000,
        576000 => libc::B576000,
        921600 => libc::B921600,
        1000000 => libc::B1000000,
        1152000 => libc::B1152000,
        1500000 => libc::B1500000,
        2500000 => libc::B2500000,
        3000000 => libc::B3000000,
        3500000 => libc::B3500000,
        4000000 => libc::B4000000,
        _ => return None,
    })
}

/// The raw-mode termios libmodbus builds for these line settings (from all-zero).
pub fn raw_termios(speed: libc::speed_t, parity: u8, data_bit: i32, stop_bit: i32) -> libc::termios {
    // SAFETY: all-zero is a valid termios.
    let mut tios: libc::termios = unsafe { zeroed() };
    // What cfsetispeed/cfsetospeed do on Linux, written out: the libc crate binds
    // those two to versioned glibc symbols, which a fully static link cannot resolve.
    tios.c_cflag = (tios.c_cflag & !libc::CBAUD) | speed;
    tios.c_ispeed = speed;
    tios.c_ospeed = speed;
    tios.c_cflag |= libc::CREAD | libc::CLOCAL;
    tios.c_cflag &= !libc::CSIZE;
    tios.c_cflag |= match data_bit {
        5 => libc::CS5,
        6 => libc::CS6,
        7 => libc::CS7,
        _ => libc::CS8,
    };
    if stop_bit == 1 {
        tios.c_cflag &= !libc::CSTOPB;
    } else {
        tios.c_cflag |= libc::CSTOPB;
    }
    match parity {
        b'N' => tios.c_cflag &= !libc::PARENB,
        b'E' => {
            tios.c_cflag |= libc::PARENB;
            tios.c_cflag &= !libc::PARODD;
        }
        _ => tios.c_cflag |= libc::PARENB | libc::PARODD,
    }
    tios.c_lflag &= !(libc::ICANON | libc::ECHO | libc::ECHOE | libc::ISIG);
    if parity == b'N' {
        tios.c_iflag &= !libc::INPCK;
    } else {
        tios.c_iflag |= libc::INPCK;
    }
    tios.c_iflag &= !(libc::IXON | libc::IXOFF | libc::IXANY);
    tios.c_oflag &= !libc::OPOST;
    tios.c_cc[libc::VMIN] = 0;
    tios.c_cc[libc::VTIME] = 0;
    tios
}

/// `modbus_connect` for RTU, first half: open the device non-blocking (the message
/// libmodbus prints, and its error message).
pub fn open(link: &RtuLink, diag: &mut dyn Diag) -> Result<i32> {
    let dev = link.device.to_string_lossy().into_owned();
    diag.out(format_args!(
        "Opening {} at {} bauds ({}, {}, {})\n",
        dev, link.baud, link.parity as char, link.data_bit, link.stop_bit
    ));
    // O_EXCL follows 3.1.12 (dropped only after that release).
    let flags = libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_EXCL | libc::O_CLOEXEC;
    // SAFETY: the device name is a NUL-terminated CString.
    let fd = unsafe { libc::open(link.device.as_ptr(), flags) };
    if fd < 0 {
        let e = last_error();
        diag.err(format_args!("ERROR Can't open the device {} ({})\n", dev, crate::transport::describe(e.0)));
        return Err(e);
    }
    Ok(fd)
}

/// `modbus_connect` for RTU, second half: save the line's settings in
/// `link.saved_termios` (for close to restore) and set raw mode. On failure the
/// caller closes `fd`.
pub fn configure(fd: i32, link: &mut RtuLink, diag: &mut dyn Diag) -> Result<()> {
    // SAFETY: all-zero is a valid termios; tcgetattr fills it (its result is ignored,
    // as in libmodbus: on failure the zeroed settings are what close restores).
    let mut saved: libc::termios = unsafe { zeroed() };
    // SAFETY: `saved` is a live termios.
    unsafe { libc::tcgetattr(fd, &mut saved) };
    link.saved_termios = Some(Box::new(saved));
    let speed = speed_for(link.baud).unwrap_or_else(|| {
        diag.err(format_args!("WARNING Unknown baud rate {} (B9600 used)\n", link.baud));
        libc::B9600
    });
    let tios = raw_termios(speed, link.parity, link.data_bit, link.stop_bit);
    // SAFETY: `tios` is a fully initialised termios.
    if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &tios) } < 0 {
        return Err(last_error());
    }
    Ok(())
}

/// `modbus_close` for RTU: restore the settings found at connect, then close.
pub fn close_line(fd: i32, saved: Option<libc::termios>) {
    if let Some(saved) = saved {
        // SAFETY: `saved` is the termios read at connect time.
        unsafe { libc::tcsetattr(fd, libc::TCSANOW, &saved) };
    }
    close(fd);
}

/// Discards both directions of the line (`tcflush(TCIOFLUSH)`).
pub fn flush(fd: i32) -> Result<usize> {
    // SAFETY: plain system call with integer arguments.
    if unsafe { libc::tcflush(fd, libc::TCIOFLUSH) } < 0 { Err(last_error()) } else { Ok(0) }
}

/// `struct serial_rs485` of linux/serial.h.
#[repr(C)]
#[derive(Default)]
struct SerialRs485 {
    flags: u32,
    delay_rts_before_send: u32,
    delay_rts_after_send: u32,
    padding: [u32; 5],
}

const SER_RS485_ENABLED: u32 = 1;
const TIOCGRS485: libc::c_ulong = 0x542E;
const TIOCSRS485: libc::c_ulong = 0x542F;

/// `modbus_rtu_set_serial_mode` on Linux: flips SER_RS485_ENABLED, keeping the
/// driver's other RS-485 flags.
pub fn set_serial_mode(fd: i32, link: &mut RtuLink, mode: i32) -> Result<()> {
    if mode != RTU_RS485 && mode != RTU_RS232 {
        return Err(Error::INVALID);
    }
    if mode == RTU_RS232 && link.serial_mode != RTU_RS485 {
        link.serial_mode = RTU_RS232;
        return Ok(());
    }
    let mut conf = SerialRs485::default();
    // SAFETY: TIOCGRS485 fills a `struct serial_rs485`, which `conf` is.
    if unsafe { libc::ioctl(fd, TIOCGRS485, &mut conf as *mut SerialRs485) } < 0 {
        return Err(last_error());
    }
    if mode == RTU_RS485 {
        conf.flags |= SER_RS485_ENABLED;
    } else {
        conf.flags &= !SER_RS485_ENABLED;
    }
    // SAFETY: TIOCSRS485 reads a `struct serial_rs485`, which `conf` is.
    if unsafe { libc::ioctl(fd, TIOCSRS485, &conf as *const SerialRs485) } < 0 {
        return Err(last_error());
    }
    link.serial_mode = mode;
    Ok(())
}

/// The built-in RTS driver: raise or lower the RTS modem line. Errors are ignored,
/// as in libmodbus (a pty has no RTS line).
pub fn set_rts_line(fd: i32, on: bool) {
    let mut flags: libc::c_int = 0;
    // SAFETY: TIOCMGET/TIOCMSET read and write one c_int, which `flags` is.
    unsafe {
        libc::ioctl(fd, libc::TIOCMGET, &mut flags);
        if on {
            flags |= libc::TIOCM_RTS;
        } else {
            flags &= !libc::TIOCM_RTS;
        }
        libc::ioctl(fd, libc::TIOCMSET, &flags);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn baud_table_falls_back_to_9600() {
        assert_eq!(speed_for(115200), Some(libc::B115200));
        assert_eq!(speed_for(1800), None);
        assert_eq!(speed_for(2000000), None);
        assert_eq!(speed_for(14400), None);
    }

    #[test]
    fn termios_flags() {
        let t = raw_termios(libc::B9600, b'E', 7, 2);
        assert_eq!(t.c_cflag & libc::CSIZE, libc::CS7);
        assert_ne!(t.c_cflag & libc::CSTOPB, 0);
        assert_ne!(t.c_cflag & libc::PARENB, 0);
        assert_eq!(t.c_cflag & libc::PARODD, 0);
        assert_ne!(t.c_iflag & libc::INPCK, 0);
        assert_ne!(t.c_cflag & (libc::CREAD | libc::CLOCAL), 0);
        let t = raw_termios(libc::B115200, b'N', 8, 1);
        assert_eq!(t.c_cflag & libc::CSIZE, libc::CS8);
        assert_eq!(t.c_cflag & (libc::CSTOPB | libc::PARENB), 0);
        assert_eq!(t.c_lflag & libc::ICANON, 0);
        assert_eq!(t.c_oflag & libc::OPOST, 0);
        assert_eq!((t.c_cc[libc::VMIN], t.c_cc[libc::VTIME]), (0, 0));
        // SAFETY: reading the speed of a live termios.
        assert_eq!(unsafe { libc::cfgetospeed(&t) }, libc::B115200);
        let t = raw_termios(libc::B9600, b'O', 8, 1);
        assert_ne!(t.c_cflag & libc::PARODD, 0);
    }
}
