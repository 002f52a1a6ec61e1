//! A byte ring buffer that moves slices, not bytes: the controller's transmit buffer.
//!
//! `heapless::Deque<u8>` pushes and pops one byte at a time (a bounds check and an
//! index update per byte); a frame goes in, and the link's packets come out, as at most
//! two slice copies each. Invariant: `len ≤ N`, the bytes are `buf[head..]` then
//! `buf[..]` wrapping, oldest first.

/// A ring of `N` bytes.
#[derive(Clone, Debug)]
pub struct ByteRing<const N: usize> {
    buf: [u8; N],
    head: usize,
    len: usize,
}

impl<const N: usize> Default for ByteRing<N> {
    fn default() -> Self {
        Self {
            buf: [0; N],
            head: 0,
            len: 0,
        }
    }
}

impl<const N: usize> ByteRing<N> {
    /// Bytes held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Nothing held?
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Room left, bytes.
    pub fn free(&self) -> usize {
        N - self.len
    }

    /// Appends all of `bytes`, or nothing when they do not fit; returns whether they
    /// did.
    pub fn push_slice(&mut self, bytes: &[u8]) -> bool {
        if bytes.len() > self.free() {
            return false;
        }
        let tail = (self.head + self.len) % N;
        let first = bytes.len().min(N - tail);
        self.buf[tail..tail + first].copy_from_slice(&bytes[..first]);
        self.buf[..bytes.len() - first].copy_from_slice(&bytes[first..]);
        self.len += bytes.len();
        true
    }

    /// Moves the oldest bytes into `out`, as many as fit; returns how many. Emptied,
    /// the ring starts again at the front of its buffer (so that [`Self::tail_mut`]
    /// finds room in one piece).
    pub fn pop_into(&mut self, out: &mut [u8]) -> usize {
        let n = out.len().min(self.len);
        if n == 0 {
            // Nothing to move: the controller's transmit is called after every packet
            // and tick, mostly with nothing owed (two empty `memcpy` calls cost some 70
            // instructions on the M4).
            return 0;
        }
        let first = n.min(N - self.head);
        out[..first].copy_from_slice(&self.buf[self.head..self.head + first]);
        if first < n {
            out[first..n].copy_from_slice(&self.buf[..n - first]);
        }
        self.head = (self.head + n) % N;
        self.len -= n;
        if self.len == 0 {
            self.head = 0;
        }
        n
    }

    /// The free space after the held bytes when `M` bytes of it are in one piece, to
    /// write into directly; [`Self::commit`] then adds what was written.
    pub fn tail_mut<const M: usize>(&mut self) -> Option<&mut [u8; M]> {
        let end = self.head + self.len;
        // The free space runs to the end of the buffer, or (the held bytes wrapping)
        // to the oldest byte.
        let (tail, limit) = if end >= N {
            (end - N, self.head)
        } else {
            (end, N)
        };
        if tail + M <= limit {
            (&mut self.buf[tail..tail + M]).try_into().ok()
        } else {
            None
        }
    }

    /// Adds the first `n` bytes of the room [`Self::tail_mut`] gave.
    pub fn commit(&mut self, n: usize) {
        debug_assert!(n <= self.free());
        self.len += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_written_at_the_tail_come_out_after_the_others() {
        let mut r = ByteRing::<8>::default();
        let mut out = [0u8; 8];
        assert!(r.push_slice(&[1, 2, 3]));
        let room = r.tail_mut::<4>().unwrap();
        room[..2].copy_from_slice(&[4, 5]);
        r.commit(2);
        assert!(r.tail_mut::<4>().is_none(), "3 bytes left after the held 5");
        assert_eq!(r.pop_into(&mut out[..3]), 3);
        assert!(r.tail_mut::<4>().is_none(), "the free space wraps");
        assert_eq!(r.pop_into(&mut out), 2);
        assert_eq!(&out[..2], &[4, 5]);
        assert!(r.tail_mut::<8>().is_some(), "emptied: room from the front");
        // Held bytes that wrap: the room is between them.
        assert!(r.push_slice(&[1, 2, 3, 4, 5, 6]));
        assert_eq!(r.pop_into(&mut out[..5]), 5);
        assert!(r.push_slice(&[7, 8, 9]));
        let room = r.tail_mut::<3>().unwrap();
        room[0] = 10;
        r.commit(1);
        assert!(r.tail_mut::<3>().is_some());
        assert!(r.tail_mut::<4>().is_none());
        assert_eq!(r.pop_into(&mut out), 5);
        assert_eq!(&out[..5], &[6, 7, 8, 9, 10]);
    }

    #[test]
    fn bytes_come_out_in_order_across_the_wrap() {
        let mut r = ByteRing::<8>::default();
        let mut out = [0u8; 8];
        for round in 0..20u8 {
            let chunk = [round, round.wrapping_add(1), round.wrapping_add(2)];
            assert!(r.push_slice(&chunk));
            assert_eq!(r.pop_into(&mut out[..2]), 2);
            assert_eq!(&out[..2], &chunk[..2]);
            assert_eq!(r.pop_into(&mut out), 1);
            assert_eq!(out[0], chunk[2]);
            assert!(r.is_empty());
        }
    }

    #[test]
    fn a_slice_that_does_not_fit_is_refused_whole() {
        let mut r = ByteRing::<4>::default();
        assert!(r.push_slice(&[1, 2, 3]));
        assert!(!r.push_slice(&[4, 5]));
        assert_eq!(r.len(), 3);
        assert!(r.push_slice(&[4]));
        assert_eq!(r.free(), 0);
        let mut out = [0u8; 8];
        assert_eq!(r.pop_into(&mut out), 4);
        assert_eq!(&out[..4], &[1, 2, 3, 4]);
    }
}
