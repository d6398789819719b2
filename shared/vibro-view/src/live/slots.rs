//! The guard's places: every connection from its `accept` to the end of its task, with
//! whom it is from ([`PeerKey`]), how far it got, and whether it answers the guard's
//! pings; and whose place a new connection takes when all are held.
//!
//! At the cap, a new connection takes the place of, in this order:
//!
//! 1. the oldest connection still without its WebSocket request (it costs its client
//!    nothing to send it again);
//! 2. when the peer holding the most places holds at least two more than the
//!    newcomer's: that peer's connection that has owed a Pong the longest, else its
//!    oldest (one peer may hold every place only while no other wants one; the
//!    newcomer's peer never ends up with more than the one it displaced);
//! 3. a connection that has owed a Pong for at least the grace (a second at most):
//!    the biggest holder's first, then the one owing the longest. A client that reads
//!    what the view sends answers a ping within a round trip; one that holds its place
//!    without reading never does.
//!
//! Otherwise it is refused (503). So on a view that every client reaches from one peer
//! (127.0.0.1, one user), sixteen silent connections give their places to a client
//! that reads, and sixteen clients that read keep theirs; from another peer, a newcomer
//! gets a place from the one holding them all.

use super::peer::PeerKey;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;
use tokio::sync::oneshot;
use tokio::time::Instant;

/// Why a connection was closed to give its place to a newer one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Displacement {
    /// It had not sent its WebSocket request.
    NoRequest,
    /// It had not answered a ping sent this long ago.
    Unanswered(Duration),
    /// Its peer held `held` places, the most, and the newcomer's peer `theirs`.
    Share { held: usize, theirs: usize },
}

/// How far a connection got.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Waiting for its WebSocket request.
    Waiting,
    /// Its request passed on; the SDK's answer not yet.
    Upgrading,
    /// A WebSocket connection; since when it owes a Pong, if it does.
    Live { owes_since: Option<Instant> },
}

#[derive(Debug)]
struct Entry {
    peer: SocketAddr,
    key: PeerKey,
    stage: Stage,
    /// Closes the connection, saying why; `None` once it was told to close.
    close: Option<oneshot::Sender<Displacement>>,
}

/// The connections open, oldest first (by id).
#[derive(Debug, Default)]
pub(super) struct Slots {
    /// Connections whose task has not ended, those told to close included: their
    /// sockets are open until it has.
    open: usize,
    entries: BTreeMap<u64, Entry>,
    next_id: u64,
}

/// What [`Slots::admit`] decided.
#[derive(Debug)]
pub(super) enum Admission {
    /// A place, maybe another connection's (told to close), and the signal that closes
    /// this one.
    Admitted {
        id: u64,
        closed: oneshot::Receiver<Displacement>,
        displaced: Option<(SocketAddr, PeerKey, Displacement)>,
    },
    /// Every place is held by a connection that keeps it.
    Full,
}

impl Slots {
    /// Connections whose task has not ended.
    pub fn open(&self) -> usize {
        self.open
    }

    /// A place for a new connection from `peer` (`key`) among `max`, taken from
    /// another as the module docs say when all are held; `grace` is the time a Pong may
    /// be owed before the connection owing it gives its place.
    pub fn admit(
        &mut self,
        peer: SocketAddr,
        key: PeerKey,
        max: usize,
        now: Instant,
        grace: Duration,
    ) -> Admission {
        let mut displaced = None;
        if self.open >= max {
            let Some((id, why)) = self.victim(key, now, grace) else {
                return Admission::Full;
            };
            if let Some(e) = self.entries.get_mut(&id) {
                if let Some(close) = e.close.take() {
                    let _ = close.send(why);
                }
                displaced = Some((e.peer, e.key, why));
            }
        }
        self.open += 1;
        let id = self.next_id;
        self.next_id += 1;
        let (close, closed) = oneshot::channel();
        self.entries.insert(
            id,
            Entry {
                peer,
                key,
                stage: Stage::Waiting,
                close: Some(close),
            },
        );
        Admission::Admitted {
            id,
            closed,
            displaced,
        }
    }

    /// Closes the oldest connection still without its request (for a descriptor); which.
    pub fn evict_waiting(&mut self) -> Option<SocketAddr> {
        let e = self
            .entries
            .values_mut()
            .find(|e| e.stage == Stage::Waiting && e.close.is_some())?;
        if let Some(close) = e.close.take() {
            let _ = close.send(Displacement::NoRequest);
        }
        Some(e.peer)
    }

    /// The place to take for a newcomer from `key`, and why.
    fn victim(&self, key: PeerKey, now: Instant, grace: Duration) -> Option<(u64, Displacement)> {
        let keeping = || self.entries.iter().filter(|(_, e)| e.close.is_some());
        if let Some((&id, _)) = keeping().find(|(_, e)| e.stage == Stage::Waiting) {
            return Some((id, Displacement::NoRequest));
        }
        let mut held: BTreeMap<PeerKey, usize> = BTreeMap::new();
        for (_, e) in keeping() {
            *held.entry(e.key).or_default() += 1;
        }
        let theirs = held.get(&key).copied().unwrap_or(0);
        let owes = |e: &Entry| match e.stage {
            Stage::Live { owes_since } => owes_since,
            _ => None,
        };
        let live = |e: &Entry| matches!(e.stage, Stage::Live { .. });
        // A newcomer whose socket's owner was not found claims no share: anyone's could
        // be, and a lookup failing (out of descriptors) must not displace live clients.
        let claims = key != PeerKey::LocalUnknown;
        if let Some((&top, &most)) = held.iter().max_by_key(|(_, n)| **n) {
            if claims && most >= theirs + 2 {
                // Its longest-owing connection, else its oldest.
                let pick = keeping()
                    .filter(|(_, e)| e.key == top && live(e))
                    .min_by_key(|(id, e)| (owes(e).is_none(), owes(e), **id));
                if let Some((&id, _)) = pick {
                    return Some((id, Displacement::Share { held: most, theirs }));
                }
            }
        }
        let since_limit = now.checked_sub(grace)?;
        keeping()
            .filter_map(|(&id, e)| Some((id, e, owes(e).filter(|s| *s <= since_limit)?)))
            .min_by_key(|(id, e, since)| {
                (
                    std::cmp::Reverse(held.get(&e.key).copied().unwrap_or(0)),
                    *since,
                    *id,
                )
            })
            .map(|(id, _, since)| (id, Displacement::Unanswered(now - since)))
    }

    fn set_stage(&mut self, id: u64, f: impl FnOnce(Stage) -> Stage) {
        if let Some(e) = self.entries.get_mut(&id) {
            e.stage = f(e.stage);
        }
    }

    fn leave(&mut self, id: u64) {
        self.open = self.open.saturating_sub(1);
        self.entries.remove(&id);
    }
}

pub(super) fn lock(slots: &Mutex<Slots>) -> MutexGuard<'_, Slots> {
    slots.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A connection's place, given back when its task ends (dropped).
#[derive(Debug)]
pub(super) struct Slot {
    pub id: u64,
    pub slots: Arc<Mutex<Slots>>,
}

impl Slot {
    /// Its request is whole: it no longer gives its place to a newer connection for
    /// want of one. False if it was told to close already (its request came as its place
    /// was given): then it is to close, not to go on.
    #[must_use]
    pub fn upgrading(&self) -> bool {
        let mut s = lock(&self.slots);
        match s.entries.get_mut(&self.id) {
            Some(e) if e.close.is_some() => {
                e.stage = Stage::Upgrading;
                true
            }
            _ => false,
        }
    }

    /// A WebSocket connection, owing nothing yet.
    pub fn live(&self) {
        lock(&self.slots).set_stage(self.id, |_| Stage::Live { owes_since: None });
    }

    /// It was sent a ping at `at` (it owes a Pong from then, unless it owes one already).
    pub fn pinged(&self, at: Instant) {
        lock(&self.slots).set_stage(self.id, |s| match s {
            Stage::Live { owes_since: None } => Stage::Live {
                owes_since: Some(at),
            },
            s => s,
        });
    }

    /// It answered its ping.
    pub fn answered(&self) {
        lock(&self.slots).set_stage(self.id, |s| match s {
            Stage::Live { .. } => Stage::Live { owes_since: None },
            s => s,
        });
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        lock(&self.slots).leave(self.id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: PeerKey = PeerKey::LocalUser(1000);
    const B: PeerKey = PeerKey::LocalUser(1001);
    const GRACE: Duration = Duration::from_secs(1);

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    /// `n` connections from `key`, live and owing nothing; their close signals.
    fn fill(
        s: &mut Slots,
        key: PeerKey,
        n: usize,
        now: Instant,
    ) -> Vec<(u64, oneshot::Receiver<Displacement>)> {
        (0..n)
            .map(
                |i| match s.admit(addr(1000 + i as u16), key, usize::MAX, now, GRACE) {
                    Admission::Admitted { id, closed, .. } => {
                        s.set_stage(id, |_| Stage::Live { owes_since: None });
                        (id, closed)
                    }
                    Admission::Full => unreachable!(),
                },
            )
            .collect()
    }

    fn displaced(a: &Admission) -> Option<(SocketAddr, PeerKey, Displacement)> {
        match a {
            Admission::Admitted { displaced, .. } => *displaced,
            Admission::Full => None,
        }
    }

    /// One peer, every place live and answering: a newcomer from it is refused; one
    /// connection that owes a Pong past the grace gives its place (the longest-owing
    /// first), one owing it for less does not.
    #[test]
    fn on_one_peer_only_a_connection_owing_a_pong_gives_its_place() {
        let t0 = Instant::now();
        let mut s = Slots::default();
        let mut conns = fill(&mut s, A, 4, t0);
        assert_eq!(conns.len(), 4);
        let now = t0 + Duration::from_secs(10);
        assert!(matches!(
            s.admit(addr(1), A, 4, now, GRACE),
            Admission::Full
        ));
        s.set_stage(conns[2].0, |_| Stage::Live {
            owes_since: Some(now - Duration::from_millis(500)),
        });
        assert!(matches!(
            s.admit(addr(1), A, 4, now, GRACE),
            Admission::Full
        ));
        s.set_stage(conns[1].0, |_| Stage::Live {
            owes_since: Some(now - Duration::from_secs(3)),
        });
        let later = now + Duration::from_secs(1);
        let a = s.admit(addr(1), A, 4, later, GRACE);
        assert_eq!(
            displaced(&a),
            Some((
                addr(1001),
                A,
                Displacement::Unanswered(Duration::from_secs(4))
            ))
        );
        assert!(conns[1].1.try_recv().is_ok(), "told to close");
        assert!(conns[2].1.try_recv().is_err());
        // It counts until its task ends.
        assert_eq!(s.open(), 5);
        s.leave(conns[1].0);
        if let Admission::Admitted { id, .. } = a {
            s.set_stage(id, |_| Stage::Live { owes_since: None });
        }
        // Now the one owing for 1.5 s goes.
        let a = s.admit(addr(2), A, 4, later, GRACE);
        assert_eq!(
            displaced(&a).map(|d| d.0),
            Some(addr(1002)),
            "{:?}",
            displaced(&a)
        );
    }

    /// Another peer's newcomer takes a place from the peer holding them all, its
    /// longest-owing connection, else its oldest; once the two peers hold as many
    /// as each other (or one fewer), nobody's is taken.
    #[test]
    fn a_newcomer_of_another_peer_takes_a_place_from_the_biggest_holder() {
        let t0 = Instant::now();
        let mut s = Slots::default();
        let conns = fill(&mut s, A, 4, t0);
        let a = s.admit(addr(1), B, 4, t0, GRACE);
        assert_eq!(
            displaced(&a),
            Some((addr(1000), A, Displacement::Share { held: 4, theirs: 0 }))
        );
        s.leave(conns[0].0);
        if let Admission::Admitted { id, .. } = a {
            s.set_stage(id, |_| Stage::Live { owes_since: None });
        }
        s.set_stage(conns[3].0, |_| Stage::Live {
            owes_since: Some(t0),
        });
        let a = s.admit(addr(2), B, 4, t0, GRACE);
        assert_eq!(
            displaced(&a),
            Some((addr(1003), A, Displacement::Share { held: 3, theirs: 1 }))
        );
        s.leave(conns[3].0);
        if let Admission::Admitted { id, .. } = a {
            s.set_stage(id, |_| Stage::Live { owes_since: None });
        }
        // A: 2, B: 2.
        assert!(matches!(s.admit(addr(3), B, 4, t0, GRACE), Admission::Full));
        assert!(matches!(s.admit(addr(3), A, 4, t0, GRACE), Admission::Full));
        // A peer not found claims no share, though it holds none.
        let c = PeerKey::LocalUnknown;
        assert!(matches!(s.admit(addr(4), c, 4, t0, GRACE), Admission::Full));
    }

    /// A connection still without its request gives its place first, whoever holds
    /// the most; one upgrading is never taken.
    #[test]
    fn a_connection_without_its_request_gives_its_place_first() {
        let t0 = Instant::now();
        let mut s = Slots::default();
        fill(&mut s, A, 3, t0);
        let Admission::Admitted { id, .. } = s.admit(addr(7), B, 4, t0, GRACE) else {
            panic!()
        };
        let a = s.admit(addr(8), A, 4, t0, GRACE);
        assert_eq!(displaced(&a), Some((addr(7), B, Displacement::NoRequest)));
        s.leave(id);
        let Admission::Admitted { id, .. } = a else {
            panic!()
        };
        s.set_stage(id, |_| Stage::Upgrading);
        assert!(matches!(s.admit(addr(9), A, 4, t0, GRACE), Admission::Full));
        assert_eq!(s.evict_waiting(), None);
    }
}
