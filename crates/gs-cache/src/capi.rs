//! C ABI: next.
