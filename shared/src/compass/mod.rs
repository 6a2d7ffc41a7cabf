//! Polarization compass (work in progress, issue 3).
