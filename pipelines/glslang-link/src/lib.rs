//! Link-only crate: see build.rs.

/// Referenced by users so that this crate (and its link directives) is linked.
pub fn linked() -> bool {
    true
}
