//! The part of a long sequence still needed: items by their index in the whole,
//! with those before a point dropped (a job's blocks, plans and running sums, kept
//! from the first block not yet acknowledged on, so that a job's memory is bounded
//! by what is in flight and planned ahead, not by the program).

use std::ops::{Index, IndexMut};

/// Items `base..len()` of a sequence, by their index in the whole.
#[derive(Clone, Debug)]
pub(super) struct Trail<T> {
    base: usize,
    items: Vec<T>,
}

impl<T> Default for Trail<T> {
    fn default() -> Self {
        Self {
            base: 0,
            items: Vec::new(),
        }
    }
}

impl<T> Trail<T> {
    /// Items in the whole sequence, dropped ones included.
    pub(super) fn len(&self) -> usize {
        self.base + self.items.len()
    }

    /// The first item kept.
    pub(super) fn base(&self) -> usize {
        self.base
    }

    /// Item `i`, if kept.
    pub(super) fn get(&self, i: usize) -> Option<&T> {
        self.items.get(i.checked_sub(self.base)?)
    }

    /// Item `i`, if kept.
    pub(super) fn get_mut(&mut self, i: usize) -> Option<&mut T> {
        self.items.get_mut(i.checked_sub(self.base)?)
    }

    /// The last item, if kept.
    pub(super) fn last(&self) -> Option<&T> {
        self.items.last()
    }

    pub(super) fn push(&mut self, item: T) {
        self.items.push(item);
    }

    /// The items kept, the first being item [`Self::base`].
    pub(super) fn kept(&self) -> &[T] {
        &self.items
    }

    /// The items kept, the first being item [`Self::base`].
    pub(super) fn kept_mut(&mut self) -> &mut [T] {
        &mut self.items
    }

    /// Drops the items before `i`.
    pub(super) fn drop_before(&mut self, i: usize) {
        let n = i.saturating_sub(self.base).min(self.items.len());
        self.items.drain(..n);
        self.base += n;
    }
}

impl<T: Clone> Trail<T> {
    pub(super) fn extend_from_slice(&mut self, items: &[T]) {
        self.items.extend_from_slice(items);
    }
}

impl<T> Index<usize> for Trail<T> {
    type Output = T;
    fn index(&self, i: usize) -> &T {
        &self.items[i - self.base]
    }
}

impl<T> IndexMut<usize> for Trail<T> {
    fn index_mut(&mut self, i: usize) -> &mut T {
        &mut self.items[i - self.base]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn items_keep_their_index_once_those_before_are_dropped() {
        let mut t = Trail::default();
        for i in 0..10 {
            t.push(i * 10);
        }
        t.drop_before(4);
        assert_eq!((t.len(), t.base(), t[4], t[9]), (10, 4, 40, 90));
        assert_eq!((t.get(3), t.get(10), t.last()), (None, None, Some(&90)));
        t.drop_before(2);
        assert_eq!(t.base(), 4);
        t.drop_before(20);
        assert_eq!((t.len(), t.base(), t.kept().len()), (10, 10, 0));
    }
}
