//! Stopping a long computation from outside: a [`Cancel`] token that the long loops poll (the renderer's
//! tiles, the energy and albedo integrals, the plot and accuracy sampling, the accuracy pass's search) and that
//! trips when its deadline passes or someone calls [`Cancel::cancel`]. A tripped computation returns
//! [`Cancelled`] instead of its result; it does not keep running in the background.
//!
//! The default token never trips and costs one branch per poll, so the CLI (which never cancels) passes
//! nothing. Polls are per tile, per row or per candidate, not per evaluation: a reading of the clock is
//! ~20 ns, so a poll every ~0.1 ms of work is free and stops a computation within milliseconds.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A cancellation token; clones share the flag. `Cancel::default()` never trips.
#[derive(Clone, Debug, Default)]
pub struct Cancel {
    inner: Option<Arc<Inner>>,
}

#[derive(Debug)]
struct Inner {
    flag: AtomicBool,
    deadline: Option<Instant>,
    /// A token this one also follows (a search's own time budget inside a request's deadline).
    parent: Option<Cancel>,
}

/// Why a computation stopped early: its [`Cancel`] tripped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cancelled;

impl std::fmt::Display for Cancelled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the computation was cancelled (its deadline passed)")
    }
}

impl std::error::Error for Cancelled {}

impl From<Cancelled> for super::diag::Diagnostic {
    fn from(c: Cancelled) -> super::diag::Diagnostic {
        super::diag::Diagnostic::error(c.to_string())
    }
}

/// Two tokens are equal when they are clones of one (options structs compare their settings).
impl PartialEq for Cancel {
    fn eq(&self, other: &Cancel) -> bool {
        match (&self.inner, &other.inner) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (a, b) => a.is_none() && b.is_none(),
        }
    }
}

impl Cancel {
    /// A token that never trips (the default).
    pub fn never() -> Cancel {
        Cancel::default()
    }

    /// A token that trips only when cancelled (a request's "the client has gone").
    pub fn untimed() -> Cancel {
        Cancel::at(None, None)
    }

    /// A token that trips `after` from now, or when cancelled.
    pub fn with_timeout(after: Duration) -> Cancel {
        Cancel::at(Instant::now().checked_add(after), None)
    }

    /// A token that trips when this one does, or `after` from now, whichever is first.
    pub fn child(&self, after: Duration) -> Cancel {
        Cancel::at(Instant::now().checked_add(after), Some(self.clone()).filter(|c| c.inner.is_some()))
    }

    fn at(deadline: Option<Instant>, parent: Option<Cancel>) -> Cancel {
        Cancel { inner: Some(Arc::new(Inner { flag: AtomicBool::new(false), deadline, parent })) }
    }

    /// Trips the token now (and every clone of it, and every child).
    pub fn cancel(&self) {
        if let Some(i) = &self.inner {
            i.flag.store(true, Ordering::Relaxed);
        }
    }

    /// Whether the token has tripped: cancelled, or past its deadline (or its parent's).
    pub fn is_cancelled(&self) -> bool {
        let Some(i) = &self.inner else { return false };
        if i.flag.load(Ordering::Relaxed) {
            return true;
        }
        let tripped = i.deadline.is_some_and(|d| Instant::now() >= d) || i.parent.as_ref().is_some_and(Cancel::is_cancelled);
        if tripped {
            i.flag.store(true, Ordering::Relaxed);
        }
        tripped
    }

    /// `Err(Cancelled)` once the token has tripped: `cancel.check()?` in a loop.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_cancelled() {
            Err(Cancelled)
        } else {
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_trip_by_flag_deadline_and_parent() {
        assert!(Cancel::never().check().is_ok());
        let never = Cancel::never();
        never.cancel();
        assert!(!never.is_cancelled(), "the default token ignores cancel()");
        let t = Cancel::with_timeout(Duration::from_secs(3600));
        let (clone, child) = (t.clone(), t.child(Duration::from_secs(3600)));
        assert!(t.check().is_ok() && child.check().is_ok());
        clone.cancel();
        assert_eq!(t.check(), Err(Cancelled));
        assert!(child.is_cancelled(), "a child follows its parent");
        let short = Cancel::with_timeout(Duration::ZERO);
        assert!(short.is_cancelled());
        let parent = Cancel::with_timeout(Duration::from_secs(3600));
        assert!(parent.child(Duration::ZERO).is_cancelled() && !parent.is_cancelled(), "a child's deadline is its own");
    }
}
