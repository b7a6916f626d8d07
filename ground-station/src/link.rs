//! The radio link's transports: a serial port (a SiK-type radio at 57600 baud, or the firmware's USART at
//! 115200, 8N1) or TCP (the virtual vehicle, QEMU), each as a byte stream the protocol's frames cross, with
//! the link's statistics.
use std::io::{Read, Write};
use std::time::Duration;

/// Where the link goes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LinkSpec {
    /// A serial device at a baud rate, 8N1.
    Serial {
        /// The device (`/dev/ttyUSB0`).
        device: String,
        /// Baud rate.
        baud: u32,
    },
    /// A TCP connection to `host:port`.
    Tcp(String),
}

impl LinkSpec {
    /// `serial:DEVICE:BAUD` or `tcp:HOST:PORT`.
    pub fn parse(s: &str) -> Result<Self, String> {
        if let Some(rest) = s.strip_prefix("serial:") {
            let (device, baud) = rest.rsplit_once(':').ok_or_else(|| {
                format!("`{s}`: serial:DEVICE:BAUD expected (e.g. serial:/dev/ttyUSB0:57600)")
            })?;
            let baud: u32 =
                baud.parse().map_err(|_| format!("`{s}`: the baud rate `{baud}` is not a number"))?;
            if !(1200..=4_000_000).contains(&baud) || device.is_empty() {
                return Err(format!("`{s}`: a device and a baud rate from 1200 to 4000000 expected"));
            }
            Ok(Self::Serial { device: device.to_string(), baud })
        } else if s.starts_with("tcp:") {
            Ok(Self::Tcp(tcp_address(s)?.to_string()))
        } else {
            Err(format!("`{s}`: serial:DEVICE:BAUD or tcp:HOST:PORT expected"))
        }
    }

    /// Bytes per second the link carries at most (a serial line: 10 bits per byte with 8N1).
    pub fn capacity_bytes_s(&self) -> Option<f64> {
        match self {
            Self::Serial { baud, .. } => Some(*baud as f64 / 10.0),
            Self::Tcp(_) => None,
        }
    }
}

/// The spec as `parse` reads it (`serial:DEVICE:BAUD`, `tcp:HOST:PORT`).
impl std::fmt::Display for LinkSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
            Self::Tcp(addr) => write!(f, "tcp:{addr}"),
        }
    }
}

/// The `HOST:PORT` of a `tcp:HOST:PORT` spec (the radio's, a camera stream's, a server's).
pub fn tcp_address(spec: &str) -> Result<&str, String> {
    match spec.strip_prefix("tcp:") {
        Some(addr)
            if addr.rsplit_once(':').is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok()) =>
        {
            Ok(addr)
        }
        _ => Err(format!("`{spec}`: tcp:HOST:PORT expected (e.g. tcp:127.0.0.1:5760)")),
    }
}

/// The address a listening endpoint binds (the virtual vehicle's radio and cameras): `tcp:PORT` binds the
/// loopback interface, 127.0.0.1, so that nothing off this machine reaches it unless an address is asked for
/// with `tcp:HOST:PORT` (`tcp:0.0.0.0:5760` for every interface).
pub fn listen_address(spec: &str) -> Result<String, String> {
    match spec.strip_prefix("tcp:") {
        Some(port) if port.parse::<u16>().is_ok() => Ok(format!("127.0.0.1:{port}")),
        _ => tcp_address(spec).map(str::to_string).map_err(|_| {
            format!("`{spec}`: tcp:PORT (on 127.0.0.1) or tcp:HOST:PORT expected (e.g. tcp:5760)")
        }),
    }
}

/// An open link: a reader (reads time out after `poll`, returning 0 bytes) and a writer.
pub struct Link {
    /// The read half.
    pub reader: Box<dyn Read + Send>,
    /// The write half.
    pub writer: Box<dyn Write + Send>,
}

/// Opens a link; reads return after at most `poll` with what arrived (possibly nothing).
pub fn open(spec: &LinkSpec, poll: Duration) -> Result<Link, String> {
    match spec {
        LinkSpec::Tcp(addr) => {
            let s = std::net::TcpStream::connect(addr)
                .map_err(|e| format!("cannot connect to tcp:{addr}: {e}"))?;
            s.set_nodelay(true).map_err(|e| e.to_string())?;
            s.set_read_timeout(Some(poll)).map_err(|e| e.to_string())?;
            let w = s.try_clone().map_err(|e| e.to_string())?;
            Ok(Link { reader: Box::new(TimeoutToZero(s)), writer: Box::new(w) })
        }
        LinkSpec::Serial { device, baud } => {
            let p = serialport::new(device, *baud)
                .data_bits(serialport::DataBits::Eight)
                .parity(serialport::Parity::None)
                .stop_bits(serialport::StopBits::One)
                .flow_control(serialport::FlowControl::None)
                .timeout(poll)
                .open()
                .map_err(|e| {
                    let hint = match e.kind() {
                        serialport::ErrorKind::NoDevice => " (is the radio plugged in? `ls /dev/tty*`)",
                        serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
                            " (permission denied: add yourself to the `dialout` group)"
                        }
                        _ => "",
                    };
                    format!("cannot open serial:{device}:{baud}: {e}{hint}")
                })?;
            let w = p.try_clone().map_err(|e| format!("cannot share serial:{device}: {e}"))?;
            Ok(Link { reader: Box::new(TimeoutToZero(p)), writer: Box::new(w) })
        }
    }
}

/// A reader whose timeouts read as "nothing yet" (0 bytes would be end of stream on TCP: a closed peer
/// reads as an error instead, see [`Closed`]).
struct TimeoutToZero<R: Read>(R);

/// A link whose peer closed it.
#[derive(Debug)]
pub struct Closed;

impl std::fmt::Display for Closed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the link was closed by the other end")
    }
}

impl std::error::Error for Closed {}

impl<R: Read> Read for TimeoutToZero<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self.0.read(buf) {
            Ok(0) if !buf.is_empty() => {
                Err(std::io::Error::new(std::io::ErrorKind::ConnectionAborted, Closed))
            }
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => {
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }
}

/// The link's statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkStats {
    /// Bytes sent and received.
    pub bytes_up: u64,
    /// Bytes received.
    pub bytes_down: u64,
    /// The decoder's counts: frames delivered, and dropped by reason.
    pub decoder: protocol::frame::DecodeCounters,
    /// Messages received.
    pub messages_down: u64,
    /// Messages sent.
    pub messages_up: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_listening_endpoint_binds_the_loopback_unless_a_host_is_asked_for() {
        assert_eq!(listen_address("tcp:5760").as_deref(), Ok("127.0.0.1:5760"));
        assert_eq!(listen_address("tcp:0").as_deref(), Ok("127.0.0.1:0"));
        assert_eq!(listen_address("tcp:0.0.0.0:5760").as_deref(), Ok("0.0.0.0:5760"));
        assert_eq!(listen_address("tcp:[::1]:5760").as_deref(), Ok("[::1]:5760"));
        for bad in ["5760", "tcp:", "tcp:70000", "udp:5760", "tcp:host:"] {
            let e = listen_address(bad).unwrap_err();
            assert!(e.contains(bad) && e.contains("tcp:PORT"), "{e}");
        }
    }

    #[test]
    fn link_specs_parse_and_bad_ones_say_what_is_expected() {
        assert_eq!(
            LinkSpec::parse("serial:/dev/ttyUSB0:57600"),
            Ok(LinkSpec::Serial { device: "/dev/ttyUSB0".into(), baud: 57600 })
        );
        assert_eq!(LinkSpec::parse("tcp:127.0.0.1:5760"), Ok(LinkSpec::Tcp("127.0.0.1:5760".into())));
        assert_eq!(LinkSpec::parse("serial:/dev/ttyUSB0:57600").unwrap().capacity_bytes_s(), Some(5760.0));
        for spec in ["serial:/dev/ttyUSB0:57600", "tcp:127.0.0.1:5760"] {
            assert_eq!(LinkSpec::parse(spec).unwrap().to_string(), spec);
        }
        for bad in [
            "udp:1.2.3.4:5",
            "serial:/dev/ttyUSB0",
            "serial:/dev/x:fast",
            "serial::9600",
            "tcp:host",
            "tcp::80",
        ] {
            let e = LinkSpec::parse(bad).unwrap_err();
            assert!(e.contains(bad), "{e}");
        }
    }

    #[test]
    fn a_missing_serial_device_or_refused_connection_is_a_message() {
        let e =
            open(&LinkSpec::parse("serial:/dev/does-not-exist:57600").unwrap(), Duration::from_millis(10))
                .err()
                .unwrap();
        assert!(e.contains("/dev/does-not-exist"), "{e}");
        // A port nobody listens on (bound then released).
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let e = open(&LinkSpec::Tcp(format!("127.0.0.1:{port}")), Duration::from_millis(10)).err().unwrap();
        assert!(e.contains(&port.to_string()), "{e}");
    }

    #[test]
    fn tcp_reads_time_out_as_nothing_and_a_closed_peer_as_an_error() {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap().to_string();
        let t = std::thread::spawn(move || {
            let (mut s, _) = l.accept().unwrap();
            s.write_all(b"hi").unwrap();
            std::thread::sleep(Duration::from_millis(50));
        });
        let mut link = open(&LinkSpec::Tcp(addr), Duration::from_millis(10)).unwrap();
        let mut buf = [0u8; 8];
        let mut got = Vec::new();
        let mut closed = false;
        for _ in 0..100 {
            match link.reader.read(&mut buf) {
                Ok(n) => got.extend_from_slice(&buf[..n]),
                Err(e) => {
                    assert_eq!(e.kind(), std::io::ErrorKind::ConnectionAborted);
                    closed = true;
                    break;
                }
            }
        }
        t.join().unwrap();
        assert_eq!(got, b"hi");
        assert!(closed);
    }
}
