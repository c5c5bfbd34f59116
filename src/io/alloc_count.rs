//! A global allocator that counts each thread's allocations, for proving that a path does not touch
//! the heap: the allocation tests and `strand-bench tick` install it with
//! `#[global_allocator] static GLOBAL: Counting = Counting;` and read [`allocations`] around the
//! code under test. Installing it costs one thread-local increment per allocation; the service does
//! not install it.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// The counting allocator: the system allocator plus a per-thread count.
pub struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: every call is forwarded to the system allocator unchanged; the count is a const-initialised
// thread-local Cell, which itself never allocates.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Allocations (and reallocations) made on this thread so far (count; only while [`Counting`] is
/// the global allocator).
pub fn allocations() -> usize {
    ALLOCATIONS.with(|c| c.get())
}
