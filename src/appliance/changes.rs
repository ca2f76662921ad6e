//! The operator view's change counter: what the camera workers and enrolment bump so that the
//! page's live updates wait instead of polling.

use std::sync::Arc;

/// Bumped whenever something the operator view shows changes (a frame, a fault, a history
/// entry filed, a change made from the page): the page's live updates wait on it instead of
/// polling.
pub type Changes = Arc<tokio::sync::watch::Sender<u64>>;

/// Says that something changed.
pub fn bump(changes: &Changes) {
    changes.send_modify(|v| *v = v.wrapping_add(1));
}
