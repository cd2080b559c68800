//! The CSV fields the reports write: a budget as its kind and value, and text quoted where it
//! must be.

use crate::records::Budget;

/// A budget as its CSV kind (`spp` or `seconds`) and value.
pub fn budget_fields(b: Budget) -> (&'static str, String) {
    match b {
        Budget::Spp(s) => ("spp", s.to_string()),
        Budget::Seconds(s) => ("seconds", s.to_string()),
    }
}

/// A string as a CSV field (quoted when it holds a comma or quote).
pub fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
