//! Test support shared by the error tests of wire, core and firmware (std builds only): every
//! error's message is non-empty and names its variant uniquely; building the list checks that
//! each type coerces to `&dyn core::error::Error`.

pub fn assert_distinct_messages(what: &str, errors: &[&dyn core::error::Error]) {
    let messages: Vec<String> = errors.iter().map(|e| e.to_string()).collect();
    for (i, m) in messages.iter().enumerate() {
        assert!(!m.trim().is_empty(), "{what}: variant {i} ({:?}) has an empty message", errors[i]);
        for (j, other) in messages.iter().enumerate().skip(i + 1) {
            assert_ne!(m, other, "{what}: variants {i} and {j} share the message");
        }
    }
}
