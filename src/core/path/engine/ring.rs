//! The fixed-capacity ring that holds the intake queue and the pieces: indices count up for ever
//! (u64), so a piece keeps its index while the window slides.

/// A fixed-capacity ring addressed by absolute indices.
pub(super) struct Ring<T: Copy> {
    items: Vec<T>,
    /// Index of the oldest item.
    pub(super) head: u64,
    /// One past the index of the newest item.
    pub(super) tail: u64,
}

impl<T: Copy> Ring<T> {
    pub(super) fn new(capacity: usize, fill: T) -> Self {
        Ring { items: vec![fill; capacity], head: 0, tail: 0 }
    }
    pub(super) fn len(&self) -> usize {
        (self.tail - self.head) as usize
    }
    pub(super) fn room(&self) -> usize {
        self.items.len() - self.len()
    }
    pub(super) fn get(&self, index: u64) -> &T {
        &self.items[(index % self.items.len() as u64) as usize]
    }
    pub(super) fn get_mut(&mut self, index: u64) -> &mut T {
        let n = self.items.len() as u64;
        &mut self.items[(index % n) as usize]
    }
    pub(super) fn push(&mut self, item: T) -> u64 {
        debug_assert!(self.room() > 0);
        let index = self.tail;
        *self.get_mut(index) = item;
        self.tail += 1;
        index
    }
    pub(super) fn pop(&mut self) -> Option<T> {
        (self.head < self.tail).then(|| {
            let item = *self.get(self.head);
            self.head += 1;
            item
        })
    }
}
