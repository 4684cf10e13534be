//! A thread's scheduling priority: the page's examiner below the session, the lab's simulated
//! hardware above whatever else the machine runs.

/// Sets the calling thread's `nice` (−20 to 19); `false` when not allowed (a lower one than it
/// has needs root or `CAP_SYS_NICE`).
pub fn set_thread_nice(nice: libc::c_int) -> bool {
    // SAFETY: setpriority on this thread's own id.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, nice) == 0
    }
}
