//! Warm start: after a watchdog reset or a brown-out the head starts from its last solution
//! (a record the board keeps across the reset), not from the origin at rest.
