//! The Foxglove server's port, open to the guard alone.
//!
//! The SDK (foxglove 0.30) serves on a TCP listener it binds itself: it takes no
//! listener, stream or Unix socket of ours. Its port (its log says which: "Started
//! server on 127.0.0.1:PORT") was open to every local user, past the guard: 20 frames
//! of 16 MiB took the view from 21.8 to 351 MB (issue 46, item 4). So the guard shuts
//! it with a socket filter (`SO_ATTACH_FILTER`, classic BPF, no privilege needed on a
//! socket of one's own) on the SDK's listening socket, which it finds among the
//! process's descriptors: a packet reaches the listener only if it comes from
//! 127.0.0.1 and from a port the guard holds, one bound by the guard's socket of each
//! connection to the SDK while it lives. Any other connection attempt is dropped at its
//! SYN (no connection, no request socket, nothing for the SDK to accept).
//!
//! Why no other local user gets past it: a port bound by one socket cannot be bound
//! by another without `SO_REUSEADDR` or `SO_REUSEPORT` on both (the guard sets
//! neither; `SO_REUSEPORT` also wants the same user), nor used by `connect`'s choice of
//! an ephemeral port, which passes over bound ports; other addresses of 127.0.0.0/8 do
//! not pass the address test; crafting a packet needs a raw socket (`CAP_NET_RAW`, in
//! this network namespace). A port leaves the filter before the guard's socket that
//! holds it closes ([`Hold`] keeps a duplicate of it for that). A connection accepted
//! by the SDK keeps the filter it was made with (its own port in it). Between the
//! SDK's `bind` and the filter, a few microseconds, a connection could get in: the
//! guard then looks for any (`/proc/net/tcp`: a connection to the port in a state
//! other than listening or closed) and, if there is one, stops that server and starts
//! another.

use std::collections::BTreeSet;
use std::net::{Ipv4Addr, SocketAddr};
use std::os::fd::{AsFd, AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// Ports a filter lets through at most: its program has 2 instructions per port and
/// 5 more, within the kernel's 4,096 (`BPF_MAXINSNS`).
pub const MAX_HELD_PORTS: usize = 2000;

/// Why the guard could not open a connection to the SDK.
#[derive(Debug)]
pub(super) enum OpenError {
    /// The SDK's listener is closed (its accept loop ended): a new server is needed.
    Gone { port: u16 },
    /// A socket could not be made or the filter set (out of descriptors, mostly).
    Io(std::io::Error),
}

/// The SDK's listening socket: the descriptor number the SDK has for it and the socket's
/// inode, by which a duplicate of that number is known to still be it.
#[derive(Debug, Clone, Copy)]
struct Listener {
    fd: RawFd,
    inode: u64,
    port: u16,
}

/// The current SDK listener and the ports of the guard's connections to it.
#[derive(Debug, Default)]
pub(super) struct Gate {
    listener: Option<Listener>,
    held: BTreeSet<u16>,
}

fn lock(gate: &Mutex<Gate>) -> MutexGuard<'_, Gate> {
    gate.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A connection to the SDK about to be made: its socket, bound to a port that the
/// filter lets through, the SDK's address, the port's hold, and a duplicate of the
/// listener, which keeps it (and its port) from closing until the connection is made.
pub(super) struct Opening {
    pub socket: tokio::net::TcpSocket,
    pub addr: SocketAddr,
    pub hold: Hold,
    pub listener: OwnedFd,
}

/// The guard's hold on a port the filter lets through: dropped, it takes the port out
/// of the filter, then closes its duplicate of the socket bound to it (so that the port
/// is never free while the filter lets it through).
#[derive(Debug)]
pub(super) struct Hold {
    gate: Arc<Mutex<Gate>>,
    port: u16,
    socket: Option<OwnedFd>,
}

impl Drop for Hold {
    fn drop(&mut self) {
        {
            let mut g = lock(&self.gate);
            g.held.remove(&self.port);
            if let Some(l) = g.listener {
                // A listener gone needs no filter; one that fails to take the smaller
                // set keeps the larger, whose extra port is still bound here.
                if let Ok(fd) = l.duplicate() {
                    let _ = attach(&fd, &g.held);
                }
            }
        }
        drop(self.socket.take());
    }
}

impl Listener {
    /// A duplicate of the listener's descriptor if it is still the listener.
    fn duplicate(&self) -> Result<OwnedFd, OpenError> {
        let gone = OpenError::Gone { port: self.port };
        let fd = duplicate(self.fd).ok_or(gone)?;
        if inode(&fd) != Some(self.inode) {
            return Err(OpenError::Gone { port: self.port });
        }
        Ok(fd)
    }
}

impl Gate {
    /// Finds the SDK's listening socket on 127.0.0.1:`port` among this process's
    /// descriptors and shuts it to all but the guard's connections.
    pub fn adopt(gate: &Mutex<Gate>, port: u16) -> std::io::Result<()> {
        let mut g = lock(gate);
        let (listener, fd) = find_listener(port)?;
        attach(&fd, &g.held)?;
        g.listener = Some(listener);
        Ok(())
    }

    /// A socket bound to a port of 127.0.0.1 that the current listener's filter lets
    /// through, to connect to it.
    pub fn open(gate: &Arc<Mutex<Gate>>) -> Result<Opening, OpenError> {
        let mut g = lock(gate);
        let Some(l) = g.listener else {
            return Err(OpenError::Gone { port: 0 });
        };
        let listener = l.duplicate()?;
        if g.held.len() >= MAX_HELD_PORTS {
            return Err(OpenError::Io(std::io::Error::other(format!(
                "{MAX_HELD_PORTS} connections to the Foxglove server open, the most its \
                 port's filter lets through"
            ))));
        }
        let socket = tokio::net::TcpSocket::new_v4().map_err(OpenError::Io)?;
        socket
            .bind(SocketAddr::new(Ipv4Addr::LOCALHOST.into(), 0))
            .map_err(OpenError::Io)?;
        let port = socket.local_addr().map_err(OpenError::Io)?.port();
        let dup = socket.as_fd().try_clone_to_owned().map_err(OpenError::Io)?;
        g.held.insert(port);
        if let Err(e) = attach(&listener, &g.held) {
            g.held.remove(&port);
            return Err(OpenError::Io(e));
        }
        Ok(Opening {
            socket,
            addr: SocketAddr::new(Ipv4Addr::LOCALHOST.into(), l.port),
            hold: Hold {
                gate: Arc::clone(gate),
                port,
                socket: Some(dup),
            },
            listener,
        })
    }

    /// Ports held now (the guard's connections to the SDK).
    #[cfg(test)]
    pub fn held(gate: &Mutex<Gate>) -> usize {
        lock(gate).held.len()
    }
}

/// A duplicate of descriptor `fd`, if it is open.
fn duplicate(fd: RawFd) -> Option<OwnedFd> {
    // SAFETY: F_DUPFD_CLOEXEC takes no pointer; a closed `fd` fails with EBADF. The new
    // descriptor is owned by nothing else.
    let new = unsafe { libc::fcntl(fd, libc::F_DUPFD_CLOEXEC, 0) };
    // SAFETY: as above: `new` is a fresh descriptor.
    (new >= 0).then(|| unsafe { OwnedFd::from_raw_fd(new) })
}

/// The inode of the file `fd` refers to (a socket's, for a socket).
fn inode(fd: &OwnedFd) -> Option<u64> {
    // SAFETY: fstat writes the struct it is given, alive for the call.
    let mut st: libc::stat = unsafe { std::mem::zeroed() };
    let ok = unsafe { libc::fstat(fd.as_raw_fd(), &mut st) } == 0;
    // `ino_t` is u64 on Linux.
    #[allow(clippy::unnecessary_cast)]
    ok.then_some(st.st_ino as u64)
}

/// Whether `fd` is a listening socket (`SO_ACCEPTCONN`).
fn listening(fd: &OwnedFd) -> bool {
    let mut on: libc::c_int = 0;
    let mut len = std::mem::size_of::<libc::c_int>() as libc::socklen_t;
    // SAFETY: getsockopt writes at most `len` bytes into `on`, alive for the call.
    let r = unsafe {
        libc::getsockopt(
            fd.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_ACCEPTCONN,
            (&raw mut on).cast(),
            &mut len,
        )
    };
    r == 0 && on != 0
}

/// The listening socket of this process on 127.0.0.1:`port`, and a duplicate of it.
fn find_listener(port: u16) -> std::io::Result<(Listener, OwnedFd)> {
    let wanted = SocketAddr::new(Ipv4Addr::LOCALHOST.into(), port);
    for entry in std::fs::read_dir("/proc/self/fd")?.flatten() {
        let Some(fd) = entry
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<RawFd>().ok())
        else {
            continue;
        };
        let Ok(link) = std::fs::read_link(entry.path()) else {
            continue;
        };
        let Some(inode) = link
            .to_str()
            .and_then(|l| l.strip_prefix("socket:["))
            .and_then(|l| l.strip_suffix(']'))
            .and_then(|l| l.parse::<u64>().ok())
        else {
            continue;
        };
        let Some(dup) = duplicate(fd) else { continue };
        if self::inode(&dup) != Some(inode) || !listening(&dup) {
            continue;
        }
        // A non-IP socket has no such address: `local_addr` fails.
        let tcp = std::net::TcpListener::from(dup);
        if tcp.local_addr().ok() == Some(wanted) {
            return Ok((Listener { fd, inode, port }, OwnedFd::from(tcp)));
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::NotFound,
        format!("no listening socket on {wanted} among this process's descriptors"),
    ))
}

/// The filter's program: from 127.0.0.1 and from one of `ports`, else dropped. It runs
/// with the packet's TCP header at offset 0 (the source port, `ldh [0]`) and its IP
/// header at `SKF_NET_OFF` (the source address at +12).
fn program(ports: &BTreeSet<u16>) -> Vec<libc::sock_filter> {
    let op = |code: u32, jt: u8, jf: u8, k: u32| libc::sock_filter {
        code: code as u16,
        jt,
        jf,
        k,
    };
    const ACCEPT: u32 = u32::MAX;
    let mut p = vec![
        op(
            libc::BPF_LD | libc::BPF_W | libc::BPF_ABS,
            0,
            0,
            (libc::SKF_NET_OFF + 12) as u32,
        ),
        op(
            libc::BPF_JMP | libc::BPF_JEQ | libc::BPF_K,
            1,
            0,
            u32::from(Ipv4Addr::LOCALHOST),
        ),
        op(libc::BPF_RET | libc::BPF_K, 0, 0, 0),
        op(libc::BPF_LD | libc::BPF_H | libc::BPF_ABS, 0, 0, 0),
    ];
    for &port in ports {
        p.push(op(
            libc::BPF_JMP | libc::BPF_JEQ | libc::BPF_K,
            0,
            1,
            u32::from(port),
        ));
        p.push(op(libc::BPF_RET | libc::BPF_K, 0, 0, ACCEPT));
    }
    p.push(op(libc::BPF_RET | libc::BPF_K, 0, 0, 0));
    p
}

/// Sets the filter letting `ports` through on the socket `fd` (replacing any).
fn attach(fd: &OwnedFd, ports: &BTreeSet<u16>) -> std::io::Result<()> {
    let mut prog = program(ports);
    let fprog = libc::sock_fprog {
        len: prog.len() as libc::c_ushort,
        filter: prog.as_mut_ptr(),
    };
    // SAFETY: `fprog` points at `prog`, both alive for the call; the kernel copies them.
    let r = unsafe {
        libc::setsockopt(
            fd.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_ATTACH_FILTER,
            (&raw const fprog).cast(),
            std::mem::size_of::<libc::sock_fprog>() as libc::socklen_t,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// Connections to 127.0.0.1:`port` in `/proc/net/tcp` that are neither listening nor
/// closed (established, half-open, closing: any that got in).
pub(super) fn intruders(port: u16) -> std::io::Result<usize> {
    let table = std::fs::read_to_string("/proc/net/tcp")?;
    Ok(count_connections(&table, port))
}

/// [`intruders`] in the text of `/proc/net/tcp`.
fn count_connections(table: &str, port: u16) -> usize {
    // The address as the kernel prints it: the 32-bit word in memory order, as hex.
    let local = format!(
        "{:08X}:{port:04X}",
        u32::from_ne_bytes(Ipv4Addr::LOCALHOST.octets())
    );
    table
        .lines()
        .skip(1)
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            let (addr, state) = (f.nth(1)?, f.nth(1)?);
            Some((addr, state))
        })
        // 0A: listening; 06: TIME_WAIT; 07: CLOSE.
        .filter(|(addr, state)| {
            addr.eq_ignore_ascii_case(&local) && !matches!(*state, "0A" | "06" | "07")
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};
    use std::net::{TcpListener, TcpStream};
    use std::time::Duration;

    /// A listener of this process, found and shut: a connection from a port the gate
    /// holds is made and carries bytes (also after the gate took that port out again);
    /// one from any other port, or from another loopback address with a held port's
    /// number, never connects; a socket of this process cannot bind a held port.
    #[test]
    fn only_connections_from_held_ports_reach_the_listener() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        let gate = Arc::new(Mutex::new(Gate::default()));
        Gate::adopt(&gate, port).unwrap();
        let opening = Gate::open(&gate).unwrap();
        assert_eq!(Gate::held(&gate), 1);
        let held = opening.socket.local_addr().unwrap().port();
        let mut guard = rt
            .block_on(opening.socket.connect(opening.addr))
            .unwrap()
            .into_std()
            .unwrap();
        guard.set_nonblocking(false).unwrap();
        drop(opening.listener);
        let (mut inner, from) = l.accept().unwrap();
        assert_eq!(from.port(), held);
        guard.write_all(b"through").unwrap();
        let mut got = [0; 7];
        inner.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"through");
        let stranger = TcpStream::connect_timeout(&l.local_addr().unwrap(), Duration::from_secs(1));
        assert!(stranger.is_err(), "{stranger:?}");
        let same_number = std::net::SocketAddr::from(([127, 0, 0, 2], held));
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.bind(same_number).unwrap();
        let r = rt.block_on(async {
            tokio::time::timeout(
                Duration::from_secs(1),
                sock.connect(l.local_addr().unwrap()),
            )
            .await
        });
        assert!(!matches!(r, Ok(Ok(_))), "{r:?}");
        let squatter = TcpListener::bind(("127.0.0.1", held));
        assert!(squatter.is_err(), "bound a held port: {squatter:?}");
        assert_eq!(
            count_connections(&std::fs::read_to_string("/proc/net/tcp").unwrap(), port),
            1
        );
        drop(opening.hold);
        assert_eq!(Gate::held(&gate), 0);
        guard.write_all(b"still").unwrap();
        let mut got = [0; 5];
        inner.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"still");
    }

    /// The listener closed: the gate says so instead of giving a socket.
    #[test]
    fn a_closed_listener_is_gone() {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        let gate = Arc::new(Mutex::new(Gate::default()));
        Gate::adopt(&gate, port).unwrap();
        drop(l);
        assert!(matches!(Gate::open(&gate), Err(OpenError::Gone { port: p }) if p == port));
        assert!(Gate::adopt(&gate, port).is_err());
    }

    #[test]
    fn the_table_counts_connections_to_the_port_but_not_the_listener() {
        let table = "  sl  local_address rem_address   st tx_queue rx_queue\n\
   0: 0100007F:1F90 00000000:0000 0A 00000000:00000000\n\
   1: 0100007F:1F90 0100007F:A000 01 00000000:00000000\n\
   2: 0100007F:1F90 0100007F:A001 06 00000000:00000000\n\
   3: 0100007F:1F91 0100007F:A002 01 00000000:00000000\n\
   4: 0100007F:1F90 0100007F:A003 03 00000000:00000000\n";
        if cfg!(target_endian = "little") {
            assert_eq!(count_connections(table, 0x1F90), 2);
        }
        assert_eq!(count_connections(table, 0x1F92), 0);
    }
}
