//! The priority of the threads that only serve people.

/// Nice value of the threads that only serve people (the operator view, its history): the
/// camera workers and the Modbus service (nice 0) get the CPU first.
pub const VIEW_NICE: i32 = 10;

/// Lowers the calling thread to [`VIEW_NICE`]; `what` names it in the log if that fails.
pub fn lower_priority(what: &str) {
    // SAFETY: plain system calls on the calling thread's own id; no memory is shared.
    let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, VIEW_NICE) };
    if rc != 0 {
        tracing::warn!("{what} keeps its priority: setpriority failed: {}", std::io::Error::last_os_error());
    }
}
