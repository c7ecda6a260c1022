//! What `live` keeps of a stream: the newest records within a stated number of bytes, the
//! records that must outlive it (a vehicle's parameters, a CSV header), and what was dropped.
//!
//! The reader pushes and the fit takes snapshots; both hold the lock for a copy at most, so that
//! the reader never waits on a fit.

use std::collections::{BTreeMap, VecDeque};

/// Bytes counted per record besides its own: its place in the queue and its allocation.
const RECORD_OVERHEAD: usize = 48;

/// The records kept, in the order they arrived.
#[derive(Debug)]
pub struct Ring {
    records: VecDeque<(u64, Vec<u8>)>,
    /// Kept whatever the ring drops: the latest record per key, with its arrival number.
    pinned: BTreeMap<Vec<u8>, (u64, Vec<u8>)>,
    bytes: usize,
    capacity: usize,
    next: u64,
    /// Records dropped to stay within the capacity, oldest first.
    pub dropped: u64,
    /// Bumped by every record pushed: a snapshot of an unchanged generation is not refitted.
    pub generation: u64,
}

/// The most pinned records (a vehicle's parameter list holds at most 65,535).
pub const MAX_PINNED: usize = 1 << 16;

impl Ring {
    /// A ring of at most `capacity` bytes of records and pinned records together.
    pub fn new(capacity: usize) -> Self {
        Self {
            records: VecDeque::new(),
            pinned: BTreeMap::new(),
            bytes: 0,
            capacity,
            next: 0,
            dropped: 0,
            generation: 0,
        }
    }

    /// Bytes held, overhead included.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Records held, pinned ones included.
    pub fn len(&self) -> usize {
        self.records.len() + self.pinned.len()
    }

    /// Whether nothing is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Adds `record`, dropping the oldest records until it fits; with `pin`, it replaces the
    /// pinned record of that key instead of joining the queue (a key beyond [`MAX_PINNED`] joins
    /// the queue).
    pub fn push(&mut self, record: Vec<u8>, pin: Option<Vec<u8>>) {
        let n = self.next;
        self.next += 1;
        self.generation += 1;
        let size = record.len() + RECORD_OVERHEAD;
        match pin {
            Some(key) if self.pinned.len() < MAX_PINNED || self.pinned.contains_key(&key) => {
                if let Some((_, old)) = self.pinned.insert(key, (n, record)) {
                    self.bytes -= old.len() + RECORD_OVERHEAD;
                }
            }
            _ => self.records.push_back((n, record)),
        }
        self.bytes += size;
        while self.bytes > self.capacity {
            let Some((_, old)) = self.records.pop_front() else {
                break;
            };
            self.bytes -= old.len() + RECORD_OVERHEAD;
            self.dropped += 1;
        }
    }

    /// Every record held, pinned ones at their place in the arrival order, written after
    /// `head`.
    pub fn snapshot(&self, head: &[u8]) -> Vec<u8> {
        let mut pinned: Vec<&(u64, Vec<u8>)> = self.pinned.values().collect();
        pinned.sort_by_key(|p| p.0);
        let mut out = Vec::with_capacity(head.len() + self.bytes);
        out.extend_from_slice(head);
        let mut queue = self.records.iter().peekable();
        let mut pins = pinned.into_iter().peekable();
        loop {
            let take_pin = match (pins.peek(), queue.peek()) {
                (Some(p), Some(q)) => p.0 < q.0,
                (Some(_), None) => true,
                (None, Some(_)) => false,
                (None, None) => break,
            };
            let record = if take_pin {
                &pins.next().unwrap_or_else(|| unreachable!()).1
            } else {
                &queue.next().unwrap_or_else(|| unreachable!()).1
            };
            out.extend_from_slice(record);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_records_are_kept_within_the_capacity_and_the_pinned_in_arrival_order() {
        let mut ring = Ring::new(3 * (4 + RECORD_OVERHEAD));
        ring.push(b"p1;\n".to_vec(), Some(b"a".to_vec()));
        for r in [b"r1;\n", b"r2;\n", b"r3;\n"] {
            ring.push(r.to_vec(), None);
        }
        assert_eq!(ring.dropped, 1);
        assert_eq!(ring.snapshot(b"h\n"), b"h\np1;\nr2;\nr3;\n");
        // A new value of a pinned key replaces the old at its new place.
        ring.push(b"p2;\n".to_vec(), Some(b"a".to_vec()));
        assert_eq!(ring.dropped, 1);
        assert_eq!(ring.snapshot(b""), b"r2;\nr3;\np2;\n");
        assert_eq!(ring.bytes(), 3 * (4 + RECORD_OVERHEAD));
        assert_eq!(ring.len(), 3);
        assert_eq!(ring.generation, 5);
        ring.push(b"r4;\n".to_vec(), None);
        assert_eq!(ring.dropped, 2);
        assert_eq!(ring.snapshot(b""), b"r3;\np2;\nr4;\n");
    }
}
