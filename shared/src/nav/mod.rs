//! Navigation filter (work in progress, issue 4).
