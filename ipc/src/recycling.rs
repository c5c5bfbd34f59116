//! The iceoryx2 service flavour strand's ports use: `ipc::Service` with its per-sample bookkeeping
//! recycled instead of allocated, so a publish on the tick path does not touch the heap.
//!
//! Why this exists. iceoryx2 0.10 gives every loaned sample a small shared state (the chunk's offset
//! and a handle on the publisher), created with the service's `ArcThreadSafetyPolicy::new` in
//! `ChunkMutSharedState::new` and dropped at `send`. For `ipc::Service` that policy is an `Rc`, so
//! each publish is one `malloc` and one `free` of 48 bytes (0.9.3 kept no such state). glibc
//! serves that pair from its thread cache without a lock or a system call, but it is still the
//! allocator on the tick, and nothing bounds it but glibc's current implementation.
//!
//! The fix is upstream's own extension point, not a patch: a [`Service`] chooses how such state is
//! held (the *only* difference between iceoryx2's `ipc::Service` and `ipc_threadsafe::Service` is
//! this policy). [`Service`] here is `ipc::Service` type for type — the same shared memory,
//! connections, event mechanism and static storage, so it talks to `ipc::Service` peers, the Python
//! client included — with the state held in a [`Recycled`]: a single-threaded reference count like
//! `Rc`, whose memory goes back to a small per-thread free list when the last handle drops and is
//! taken from there by the next loan. A thread's first publish allocates one block; every later one
//! reuses it, as long as a sample is sent (or dropped) on the thread that loaned it — strand's ports
//! never leave their thread. The free list keeps blocks of at most [`LARGEST_KEPT`] bytes, at most
//! [`KEPT_PER_LAYOUT`] of each of [`LAYOUTS`] sizes per thread (beyond that, blocks go back to the
//! allocator), and returns what it keeps when the thread's locals are destroyed (a process's main
//! thread may simply exit with them).
//!
//! The same change upstream would be a per-publisher slab of `max_loaned_samples` states indexed by
//! the chunk, which needs no thread-local list; this flavour gets the same effect without forking.
//! `ipc/tests/ports.rs` counts allocations over steady-state publishes (0) and talks to a plain
//! `ipc::Service` peer through it.

use core::cell::{Cell, RefCell};
use core::fmt::Debug;
use core::marker::PhantomData;
use core::ops::Deref;
use core::ptr::NonNull;
use std::alloc::{self, Layout};

use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use iceoryx2_cal::arc_sync_policy::{ArcSyncPolicy, ArcSyncPolicyCreationError, LockGuard};
use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;
use iceoryx2_cal::*;

/// `iceoryx2::service::ipc::Service` with [`Recycled`] as its shared-state policy (see the module
/// doc). Every other associated type is `ipc::Service`'s, so the two are the same on the wire.
#[derive(Debug, Clone)]
pub struct Service {}

impl iceoryx2::service::Service for Service {
    type StaticStorage = static_storage::recommended::Ipc;
    type ConfigSerializer = serialize::recommended::Recommended;
    type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> = dynamic_storage::recommended::PersistentIpc<T>;
    type Bag = bag::recommended::Recommended;
    type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> = dynamic_storage::recommended::Ipc<T>;
    type ServiceNameHasher = hash::recommended::Recommended;
    type SharedMemory = shared_memory::recommended::Ipc<PoolAllocator>;
    type ResizableSharedMemory = resizable_shared_memory::recommended::Ipc<PoolAllocator>;
    type Connection = zero_copy_connection::recommended::Ipc;
    type Event = event::recommended::Ipc;
    type Monitoring = monitoring::recommended::Ipc;
    type Reactor = reactor::recommended::Ipc;
    type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> = Recycled<T>;
    type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> = dynamic_storage::recommended::Ipc<KeyType>;
    type BlackboardPayload = shared_memory::recommended::Ipc<BumpAllocator>;
    type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
}

// Every method of this trait has its default body; `ipc::Service` implements it the same way.
impl iceoryx2::service::internal::ServiceInternal<Service> for Service {}

/// Distinct block layouts the per-thread free list keeps (count). iceoryx2 uses the policy for a
/// handful of types per port kind; a thread that meets more simply allocates for the rest.
pub(crate) const LAYOUTS: usize = 8;
/// Blocks kept per layout and thread (count): more than the samples a publisher may hold on loan at
/// once in strand (one), and than the ports of one kind a thread opens.
pub(crate) const KEPT_PER_LAYOUT: usize = 64;
/// Largest block kept (bytes): the per-sample states (40 bytes) and their kind. A port's own state,
/// created once with the port, goes back to the allocator.
pub(crate) const LARGEST_KEPT: usize = 64;

/// The value and its handle count, in one block.
struct Shared<T> {
    handles: Cell<usize>,
    value: T,
}

/// A single-threaded shared handle (like `Rc<T>`, and like it neither `Send` nor `Sync`) whose block
/// is recycled through a per-thread free list. iceoryx2's `ArcSyncPolicy` for [`Service`].
pub struct Recycled<T: Send + Debug + Abandonable> {
    shared: NonNull<Shared<T>>,
    /// Owns a `Shared<T>`; `*const` keeps the handle on its thread, as `Rc` does.
    _owns: PhantomData<*const Shared<T>>,
}

impl<T: Send + Debug + Abandonable> Recycled<T> {
    fn shared(&self) -> &Shared<T> {
        // SAFETY: the block lives while any handle does, and this is one.
        unsafe { self.shared.as_ref() }
    }
}

impl<T: Send + Debug + Abandonable> Debug for Recycled<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Recycled").field("handles", &self.shared().handles.get()).field("value", &self.shared().value).finish()
    }
}

impl<T: Send + Debug + Abandonable> Clone for Recycled<T> {
    fn clone(&self) -> Self {
        let handles = &self.shared().handles;
        // As `Rc`: a count that would wrap (only reachable by leaking handles) aborts rather than
        // let a later drop free a value still in use.
        handles.set(handles.get().checked_add(1).unwrap_or_else(|| std::process::abort()));
        Recycled { shared: self.shared, _owns: PhantomData }
    }
}

impl<T: Send + Debug + Abandonable> Drop for Recycled<T> {
    fn drop(&mut self) {
        let handles = &self.shared().handles;
        let left = handles.get() - 1;
        handles.set(left);
        if left == 0 {
            // SAFETY: the last handle: nobody else can see the value or the block any more.
            unsafe {
                core::ptr::drop_in_place(&mut (*self.shared.as_ptr()).value);
                release(self.shared.cast(), Layout::new::<Shared<T>>());
            }
        }
    }
}

impl<T: Send + Debug + Abandonable> Abandonable for Recycled<T> {
    // As iceoryx2's own single-threaded policy: the last handle abandons the value (and leaks its
    // block, as abandoning does); any other handle just lets go.
    unsafe fn abandon_in_place(mut this: NonNull<Self>) {
        let this = unsafe { this.as_mut() };
        if this.shared().handles.get() == 1 {
            unsafe { T::abandon_in_place(NonNull::from_mut(&mut (*this.shared.as_ptr()).value)) };
        } else {
            unsafe { core::ptr::drop_in_place(this) };
        }
    }
}

/// Read access to the value while the handle lives.
pub struct Guard<'parent, T> {
    value: &'parent T,
}

impl<T> Deref for Guard<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        self.value
    }
}

impl<'parent, T: Send + Abandonable> LockGuard<'parent, T> for Guard<'parent, T> {}

impl<T: Send + Debug + Abandonable> ArcSyncPolicy<T> for Recycled<T> {
    type LockGuard<'parent>
        = Guard<'parent, T>
    where
        Self: 'parent,
        T: 'parent;

    fn new(value: T) -> Result<Self, ArcSyncPolicyCreationError> {
        let layout = Layout::new::<Shared<T>>();
        let block = match reuse(layout) {
            Some(block) => block.cast::<Shared<T>>(),
            // SAFETY: `Shared<T>` has a non-zero size (it holds a `usize`).
            None => match NonNull::new(unsafe { alloc::alloc(layout) }) {
                Some(block) => block.cast::<Shared<T>>(),
                None => return Err(ArcSyncPolicyCreationError::InsufficientResources),
            },
        };
        // SAFETY: a block of `Shared<T>`'s layout, unused.
        unsafe { block.as_ptr().write(Shared { handles: Cell::new(1), value }) };
        Ok(Recycled { shared: block, _owns: PhantomData })
    }

    fn lock(&self) -> Self::LockGuard<'_> {
        Guard { value: &self.shared().value }
    }
}

/// A free block's first word: the next free block of its layout.
struct Link {
    next: *mut Link,
}

/// The free blocks of one layout.
#[derive(Clone, Copy)]
struct FreeList {
    layout: Option<Layout>,
    head: *mut Link,
    len: usize,
}

/// One thread's free lists.
struct Pool {
    lists: [FreeList; LAYOUTS],
}

impl Pool {
    const EMPTY: Pool = Pool { lists: [FreeList { layout: None, head: core::ptr::null_mut(), len: 0 }; LAYOUTS] };

    fn take(&mut self, layout: Layout) -> Option<NonNull<u8>> {
        let list = self.lists.iter_mut().find(|l| l.layout == Some(layout))?;
        let block = NonNull::new(list.head)?;
        // SAFETY: a block on the list holds a `Link` written by `keep`.
        list.head = unsafe { block.as_ref().next };
        list.len -= 1;
        Some(block.cast())
    }

    /// Keeps `block` for reuse; false when it is larger than [`LARGEST_KEPT`] bytes, its layout's
    /// list is full, or no list is free for it (an empty list is free for any layout).
    fn keep(&mut self, block: NonNull<u8>, layout: Layout) -> bool {
        if layout.size() < size_of::<Link>() || layout.size() > LARGEST_KEPT || layout.align() < align_of::<Link>() {
            return false;
        }
        let index = match self.lists.iter().position(|l| l.layout == Some(layout)) {
            Some(i) => i,
            None => match self.lists.iter().position(|l| l.layout.is_none() || l.len == 0) {
                Some(i) => {
                    self.lists[i].layout = Some(layout);
                    i
                }
                None => return false,
            },
        };
        let list = &mut self.lists[index];
        if list.len >= KEPT_PER_LAYOUT {
            return false;
        }
        let link = block.cast::<Link>();
        // SAFETY: the block is free, large and aligned enough for a `Link`.
        unsafe { link.as_ptr().write(Link { next: list.head }) };
        list.head = link.as_ptr();
        list.len += 1;
        true
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        for list in &mut self.lists {
            let Some(layout) = list.layout else { continue };
            while let Some(block) = NonNull::new(list.head) {
                // SAFETY: as in `take`; the block came from the global allocator with `layout`.
                unsafe {
                    list.head = block.as_ref().next;
                    alloc::dealloc(block.as_ptr().cast(), layout);
                }
            }
            list.len = 0;
        }
    }
}

thread_local! {
    static POOL: RefCell<Pool> = const { RefCell::new(Pool::EMPTY) };
}

/// A kept block of `layout`, if this thread has one.
fn reuse(layout: Layout) -> Option<NonNull<u8>> {
    POOL.try_with(|pool| pool.try_borrow_mut().ok().and_then(|mut pool| pool.take(layout))).ok().flatten()
}

/// Returns a block to this thread's free list, or to the allocator when the list is full (or the
/// thread is ending).
///
/// # Safety
/// `block` came from the global allocator with `layout` and nothing uses it any more.
unsafe fn release(block: NonNull<u8>, layout: Layout) {
    let kept = POOL.try_with(|pool| pool.try_borrow_mut().map(|mut pool| pool.keep(block, layout)).unwrap_or(false)).unwrap_or(false);
    if !kept {
        unsafe { alloc::dealloc(block.as_ptr(), layout) };
    }
}

/// Blocks this thread keeps for reuse (count), over all layouts. For tests and diagnostics.
pub fn kept_blocks() -> usize {
    POOL.try_with(|pool| pool.try_borrow().map(|p| p.lists.iter().map(|l| l.len).sum()).unwrap_or(0)).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Probe<'a>(&'a Cell<usize>, u64);
    impl Drop for Probe<'_> {
        fn drop(&mut self) {
            self.0.set(self.0.get() + 1);
        }
    }
    impl Abandonable for Probe<'_> {
        unsafe fn abandon_in_place(_this: NonNull<Self>) {}
    }
    // SAFETY (test only): the probe stays on its thread.
    unsafe impl Send for Probe<'_> {}

    #[test]
    fn a_handle_drops_its_value_once_and_the_next_one_reuses_the_block() {
        let drops = Cell::new(0);
        let kept_before = kept_blocks();
        let first = Recycled::new(Probe(&drops, 7)).unwrap();
        let address = first.shared.as_ptr() as usize;
        let second = first.clone();
        assert_eq!(second.lock().1, 7);
        drop(first);
        assert_eq!(drops.get(), 0, "a clone still holds the value");
        drop(second);
        assert_eq!(drops.get(), 1);
        assert_eq!(kept_blocks(), kept_before + 1);
        let again = Recycled::new(Probe(&drops, 8)).unwrap();
        assert_eq!(again.shared.as_ptr() as usize, address, "the freed block is reused");
        assert_eq!(kept_blocks(), kept_before);
        assert_eq!(again.lock().1, 8);
    }

    /// An emptied list takes another layout, so layouts seen once (ports opened and closed) cannot
    /// use up the lists and leave the per-sample states to the allocator; large blocks are not kept.
    #[test]
    fn emptied_lists_take_other_layouts_and_large_blocks_are_not_kept() {
        let mut pool = Pool::EMPTY;
        let block = |size: usize| {
            let layout = Layout::from_size_align(size, 8).unwrap();
            (NonNull::new(unsafe { alloc::alloc(layout) }).unwrap(), layout)
        };
        for size in (0..LAYOUTS).map(|k| 8 + 8 * k) {
            let (b, layout) = block(size);
            assert!(pool.keep(b, layout), "{size} bytes");
            assert_eq!(pool.take(layout), Some(b));
            unsafe { alloc::dealloc(b.as_ptr(), layout) };
        }
        let (b, layout) = block(40);
        assert!(pool.keep(b, layout), "a ninth layout after eight emptied lists");
        let (big, big_layout) = block(LARGEST_KEPT + 8);
        assert!(!pool.keep(big, big_layout));
        unsafe { alloc::dealloc(big.as_ptr(), big_layout) };
        drop(pool); // gives the kept 40-byte block back
    }

    #[test]
    fn the_free_list_is_bounded() {
        let drops = Cell::new(0);
        let handles: Vec<_> = (0..KEPT_PER_LAYOUT as u64 + 10).map(|i| Recycled::new(Probe(&drops, i)).unwrap()).collect();
        drop(handles);
        assert_eq!(drops.get(), KEPT_PER_LAYOUT + 10);
        assert!(kept_blocks() <= KEPT_PER_LAYOUT, "kept {}", kept_blocks());
    }
}
