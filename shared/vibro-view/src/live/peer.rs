//! Whom a connection is from, for the share of the places one may hold.
//!
//! A remote peer is its address: an IPv4 address, or the /64 network of an IPv6 one (a
//! host is given a /64 and picks its addresses in it at will). A peer on this machine
//! is not: every address of 127.0.0.0/8 is any local user's to bind, so that one user
//! could hold all the places from as many addresses, while every client of a view on
//! 127.0.0.1 (the default) shares one. A local peer is therefore the user owning its
//! socket, which the kernel tells (sock_diag, as `ss -e` shows it: an exact lookup of
//! the peer's socket by its address and port and ours, `inet_diag_req_v2`), and which
//! no user can forge.

use std::fmt;
use std::net::{IpAddr, SocketAddr};

/// Whom a connection is from (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PeerKey {
    /// A socket of this machine, owned by this user.
    LocalUser(u32),
    /// A loopback peer whose socket was not found (gone already, or the lookup failed):
    /// all such share one key.
    LocalUnknown,
    /// A remote IPv4 address.
    V4([u8; 4]),
    /// A remote IPv6 /64 network (its first 8 bytes).
    V6Net([u8; 8]),
}

impl fmt::Display for PeerKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::LocalUser(uid) => write!(f, "local user {uid}"),
            Self::LocalUnknown => f.write_str("a local user not found"),
            Self::V4(a) => write!(f, "{}", std::net::Ipv4Addr::from(*a)),
            Self::V6Net(n) => {
                let mut a = [0; 16];
                a[..8].copy_from_slice(n);
                write!(f, "{}/64", std::net::Ipv6Addr::from(a))
            }
        }
    }
}

/// An address with an IPv4-mapped IPv6 address (a dual-stack listener's view of an IPv4
/// peer) as the IPv4 address it is.
fn canonical(a: SocketAddr) -> SocketAddr {
    match a.ip() {
        IpAddr::V6(v6) => v6
            .to_ipv4_mapped()
            .map_or(a, |v4| SocketAddr::new(v4.into(), a.port())),
        IpAddr::V4(_) => a,
    }
}

/// Whom the connection from `peer` to our `local` address is from.
pub fn key(peer: SocketAddr, local: SocketAddr) -> PeerKey {
    let (peer, local) = (canonical(peer), canonical(local));
    if let Some(uid) = socket_owner(peer, local) {
        return PeerKey::LocalUser(uid);
    }
    match peer.ip() {
        IpAddr::V4(a) if a.is_loopback() => PeerKey::LocalUnknown,
        IpAddr::V6(a) if a.is_loopback() => PeerKey::LocalUnknown,
        IpAddr::V4(a) => PeerKey::V4(a.octets()),
        IpAddr::V6(a) => {
            let mut n = [0; 8];
            n.copy_from_slice(&a.octets()[..8]);
            PeerKey::V6Net(n)
        }
    }
}

/// `SOCK_DIAG_BY_FAMILY` (linux/sock_diag.h).
const SOCK_DIAG_BY_FAMILY: u16 = 20;
/// `NLMSG_ERROR` (linux/netlink.h).
const NLMSG_ERROR: u16 = 2;
/// `TCP_LISTEN` (the kernel's socket states).
const TCP_LISTEN: u8 = 10;
/// `nlmsghdr` and `inet_diag_req_v2` (its `inet_diag_sockid` included), bytes.
const REQUEST_BYTES: usize = 16 + 8 + 48;
/// Where `idiag_uid` is in an answer: after `nlmsghdr` (16), `inet_diag_msg`'s family,
/// state, timer and retransmits (4), its `inet_diag_sockid` (48), expires, rqueue and
/// wqueue (12).
const UID_AT: usize = 16 + 4 + 48 + 12;

/// The user owning the socket of this machine whose address is `peer` and whose peer is
/// `local` (the client's end of a connection we accepted), if there is one.
#[cfg(target_os = "linux")]
fn socket_owner(peer: SocketAddr, local: SocketAddr) -> Option<u32> {
    use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
    let (family, src, dst) = match (peer.ip(), local.ip()) {
        (IpAddr::V4(p), IpAddr::V4(l)) => {
            let (mut s, mut d) = ([0; 16], [0; 16]);
            s[..4].copy_from_slice(&p.octets());
            d[..4].copy_from_slice(&l.octets());
            (libc::AF_INET as u8, s, d)
        }
        (IpAddr::V6(p), IpAddr::V6(l)) => (libc::AF_INET6 as u8, p.octets(), l.octets()),
        _ => return None,
    };
    let mut req = Vec::with_capacity(REQUEST_BYTES);
    // nlmsghdr: length, type, flags (a request for one socket: no NLM_F_DUMP), seq, pid.
    req.extend_from_slice(&(REQUEST_BYTES as u32).to_ne_bytes());
    req.extend_from_slice(&SOCK_DIAG_BY_FAMILY.to_ne_bytes());
    req.extend_from_slice(&(libc::NLM_F_REQUEST as u16).to_ne_bytes());
    req.extend_from_slice(&1u32.to_ne_bytes());
    req.extend_from_slice(&0u32.to_ne_bytes());
    // inet_diag_req_v2: family, protocol, extensions, pad, states (all).
    req.extend_from_slice(&[family, libc::IPPROTO_TCP as u8, 0, 0]);
    req.extend_from_slice(&u32::MAX.to_ne_bytes());
    // inet_diag_sockid: the peer's socket seen from its side (ports and addresses in
    // network order), any interface, no cookie (INET_DIAG_NOCOOKIE).
    req.extend_from_slice(&peer.port().to_be_bytes());
    req.extend_from_slice(&local.port().to_be_bytes());
    req.extend_from_slice(&src);
    req.extend_from_slice(&dst);
    req.extend_from_slice(&0u32.to_ne_bytes());
    req.extend_from_slice(&[0xFF; 8]);
    debug_assert_eq!(req.len(), REQUEST_BYTES);

    // SAFETY: socket() takes no pointers; its result, when a descriptor, is owned here.
    let fd = unsafe {
        libc::socket(
            libc::AF_NETLINK,
            libc::SOCK_DGRAM | libc::SOCK_CLOEXEC,
            libc::NETLINK_SOCK_DIAG,
        )
    };
    if fd < 0 {
        return None;
    }
    // SAFETY: `fd` is a new descriptor that nothing else owns.
    let fd = unsafe { OwnedFd::from_raw_fd(fd) };
    // SAFETY: a zeroed sockaddr_nl is valid (pid 0: the kernel); the pointers and
    // lengths given describe `kernel` and `req`, alive for the call.
    let sent = unsafe {
        let mut kernel: libc::sockaddr_nl = std::mem::zeroed();
        kernel.nl_family = libc::AF_NETLINK as libc::sa_family_t;
        libc::sendto(
            fd.as_raw_fd(),
            req.as_ptr().cast(),
            req.len(),
            0,
            (&raw const kernel).cast(),
            std::mem::size_of::<libc::sockaddr_nl>() as libc::socklen_t,
        )
    };
    if sent != REQUEST_BYTES as isize {
        return None;
    }
    // The kernel answers within the send (sock_diag replies from the sender's context):
    // a receive that would wait means no answer.
    let mut answer = [0u8; 512];
    // SAFETY: the pointer and length describe `answer`, alive for the call.
    let n = unsafe {
        libc::recv(
            fd.as_raw_fd(),
            answer.as_mut_ptr().cast(),
            answer.len(),
            libc::MSG_DONTWAIT,
        )
    };
    let answer = &answer[..usize::try_from(n).ok()?];
    parse_owner(answer, peer.port(), local.port())
}

#[cfg(not(target_os = "linux"))]
fn socket_owner(_peer: SocketAddr, _local: SocketAddr) -> Option<u32> {
    None
}

/// The owner in a sock_diag answer about the socket at `sport` whose peer is at
/// `dport`; `None` for an error (ENOENT: no such socket), a listener, or another socket.
fn parse_owner(answer: &[u8], sport: u16, dport: u16) -> Option<u32> {
    let u16_at = |i: usize| Some(u16::from_ne_bytes(answer.get(i..i + 2)?.try_into().ok()?));
    let u32_at = |i: usize| Some(u32::from_ne_bytes(answer.get(i..i + 4)?.try_into().ok()?));
    let kind = u16_at(4)?;
    // NLMSG_ERROR carries the lookup's error (ENOENT: no such socket).
    if kind == NLMSG_ERROR || kind != SOCK_DIAG_BY_FAMILY {
        return None;
    }
    let state = *answer.get(16 + 1)?;
    let id = 16 + 4;
    let ports = (
        u16::from_be_bytes(answer.get(id..id + 2)?.try_into().ok()?),
        u16::from_be_bytes(answer.get(id + 2..id + 4)?.try_into().ok()?),
    );
    (state != TCP_LISTEN && ports == (sport, dport))
        .then(|| u32_at(UID_AT))
        .flatten()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::{TcpListener, TcpStream};

    /// A connection to a listener of this process: the peer is the user running the
    /// test (`getuid`, not the lookup); a remote-looking key for other addresses.
    #[test]
    fn a_local_peer_is_the_user_owning_its_socket() {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let _c = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let (s, peer) = l.accept().unwrap();
        let local = s.local_addr().unwrap();
        // SAFETY: getuid has no preconditions.
        let uid = unsafe { libc::getuid() };
        assert_eq!(key(peer, local), PeerKey::LocalUser(uid));
        // The same peer seen by a dual-stack listener.
        let mapped = |a: SocketAddr| match a.ip() {
            IpAddr::V4(v4) => SocketAddr::new(v4.to_ipv6_mapped().into(), a.port()),
            IpAddr::V6(_) => a,
        };
        assert_eq!(key(mapped(peer), mapped(local)), PeerKey::LocalUser(uid));
        // A loopback peer whose socket is not there.
        let gone: SocketAddr = "127.0.0.9:1".parse().unwrap();
        assert_eq!(key(gone, local), PeerKey::LocalUnknown);
        let remote: SocketAddr = "192.0.2.7:40000".parse().unwrap();
        assert_eq!(key(remote, local), PeerKey::V4([192, 0, 2, 7]));
        let remote6: SocketAddr = "[2001:db8:1:2:aaaa::1]:40000".parse().unwrap();
        let k = key(remote6, "[::1]:1".parse().unwrap());
        assert_eq!(k, PeerKey::V6Net([0x20, 0x01, 0x0d, 0xb8, 0, 1, 0, 2]));
        assert_eq!(k.to_string(), "2001:db8:1:2::/64");
    }

    /// A socket made by another user (as root: the thread's filesystem uid, which the
    /// kernel gives a new socket) is that user's.
    #[test]
    fn a_socket_made_by_another_user_is_that_users() {
        const OTHER: u32 = 65534;
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let to = l.local_addr().unwrap();
        let c = std::thread::spawn(move || {
            // SAFETY: setfsuid changes this thread's filesystem uid only, set back below.
            let before = unsafe { libc::setfsuid(OTHER) };
            let now = unsafe { libc::setfsuid(OTHER) };
            let c = (now as u32 == OTHER).then(|| TcpStream::connect(to).unwrap());
            unsafe { libc::setfsuid(before as u32) };
            c
        })
        .join()
        .unwrap();
        let Some(_c) = c else {
            eprintln!("SKIPPED: not root, so no socket of another user can be made");
            return;
        };
        let (s, peer) = l.accept().unwrap();
        assert_eq!(
            key(peer, s.local_addr().unwrap()),
            PeerKey::LocalUser(OTHER)
        );
    }

    #[test]
    fn an_answer_about_another_socket_or_an_error_names_no_owner() {
        let mut a = vec![0u8; UID_AT + 4];
        a[4..6].copy_from_slice(&SOCK_DIAG_BY_FAMILY.to_ne_bytes());
        a[17] = 1; // ESTABLISHED
        a[20..22].copy_from_slice(&5000u16.to_be_bytes());
        a[22..24].copy_from_slice(&8765u16.to_be_bytes());
        a[UID_AT..].copy_from_slice(&1000u32.to_ne_bytes());
        assert_eq!(parse_owner(&a, 5000, 8765), Some(1000));
        assert_eq!(parse_owner(&a, 5001, 8765), None);
        assert_eq!(parse_owner(&a[..UID_AT], 5000, 8765), None);
        a[17] = TCP_LISTEN;
        assert_eq!(parse_owner(&a, 5000, 8765), None);
        a[4..6].copy_from_slice(&NLMSG_ERROR.to_ne_bytes());
        assert_eq!(parse_owner(&a, 5000, 8765), None);
    }
}
