//! Building large values in place: the controller's queue and executor are tens of
//! kilobytes, too large for a temporary on the MCU's stack, so each has an
//! `init_at(p, ..)` that writes its fields into a slot; on the host, [`built`] turns
//! that into an ordinary constructor.

use core::mem::MaybeUninit;

/// The value `init` writes into a fresh slot.
///
/// # Safety
/// `init` must write every field of the slot it is given before it returns.
pub unsafe fn built<T>(init: impl FnOnce(*mut T)) -> T {
    let mut slot = MaybeUninit::<T>::uninit();
    init(slot.as_mut_ptr());
    // SAFETY: the caller's promise: `init` wrote every field.
    unsafe { slot.assume_init() }
}
