//! Solar ephemeris (work in progress, issue 3).
