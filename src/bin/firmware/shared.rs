//! Data shared by the interpolation tick and the thread-mode tasks, locked by priority
//! ceiling rather than by disabling every interrupt.
//!
//! A global critical section (`critical_section::with`) masks every interrupt,
//! including the 10 kHz servo interrupt, for as long as it lasts; the controller's
//! tick and a received packet's processing take far longer than a servo period. So
//! what the tick shares with the tasks (the controller, the tick's I/O) is guarded by
//! raising BASEPRI to the tick's priority ([`board::TICK_PRIORITY`]) instead: that
//! masks the tick and every less urgent interrupt (USB, the time base) and leaves the
//! servo interrupt running.
//!
//! Soundness: (1) every access to the data happens inside [`TickShared::lock`], which
//! runs with BASEPRI at the ceiling, so while one context holds the lock no context
//! at the ceiling priority or below (the tick, USB, the time base, thread mode) can
//! run; (2) the only more urgent context, the servo interrupt, never calls `lock`
//! (it exchanges data with the tick through short critical sections instead). So no
//! two contexts are ever inside `lock` on the same data at once. A nested `lock` of the
//! same data in one context is caught by the `RefCell` and returns `None`.

use core::cell::RefCell;
use core::sync::atomic::{compiler_fence, Ordering};

use cortex_m::register::{basepri, basepri_max};

use crate::board;

/// Data owned jointly by the tick and thread-mode tasks. See the module docs.
pub struct TickShared<T> {
    data: RefCell<T>,
}

// SAFETY: the data is only reached through `lock`, whose priority ceiling excludes
// every other context that uses it (module docs); `T: Send` because it is handed
// between the tick interrupt and thread mode.
unsafe impl<T: Send> Sync for TickShared<T> {}

impl<T> TickShared<T> {
    /// Shared `data`.
    pub const fn new(data: T) -> Self {
        Self {
            data: RefCell::new(data),
        }
    }

    /// Runs `f` on the data with the tick and every less urgent interrupt masked; `None`
    /// if the data is already borrowed (a nested call). Never call from the servo
    /// interrupt.
    pub fn lock<R>(&self, f: impl FnOnce(&mut T) -> R) -> Option<R> {
        let previous = mask_to_tick();
        let result = self.data.try_borrow_mut().ok().map(|mut data| f(&mut data));
        // SAFETY: the mask `mask_to_tick` found, in the same context.
        unsafe { unmask(previous) };
        result
    }
}

/// Masks the tick and every less urgent interrupt (BASEPRI raised to
/// [`board::TICK_PRIORITY`], never lowered); the servo interrupt stays unmasked. Returns
/// the BASEPRI found, for [`unmask`].
pub fn mask_to_tick() -> u8 {
    let previous = basepri::read();
    basepri_max::write(board::TICK_PRIORITY as u8);
    compiler_fence(Ordering::SeqCst);
    previous
}

/// Puts back the BASEPRI that [`mask_to_tick`] returned.
///
/// # Safety
/// `previous` must be what `mask_to_tick` returned in this context, and nothing that
/// relies on the mask may run after it: no lock relies on a lower one.
pub unsafe fn unmask(previous: u8) {
    compiler_fence(Ordering::SeqCst);
    // SAFETY: the caller's own mask (above).
    unsafe { basepri::write(previous) };
}
