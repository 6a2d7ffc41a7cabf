//! The recording reader on arbitrary bytes (raw, and behind a valid header so that the chunk
//! parser and resynchronisation are reached): never panics, accounts for every byte, and the
//! decoded session never panics either.
#![no_main]
use libfuzzer_sys::fuzz_target;
use subnav_link::record::{Item, Meta, Reader, Writer, read_bytes, session::Session};

fuzz_target!(|data: &[u8]| {
    if let Ok(l) = read_bytes(data) {
        let _ = Session::decode(&l, None);
    }
    let mut with_header = Writer::new(Vec::new(), &Meta::default()).expect("header").into_inner();
    let start = with_header.len();
    with_header.extend_from_slice(data);
    let mut r = Reader::new(&with_header).expect("a valid header");
    let mut covered = 0usize;
    for item in r.by_ref() {
        covered += match item {
            Item::Chunk(c) => c.data.len() + subnav_link::record::CHUNK_OVERHEAD,
            Item::Damage(d) => d.len,
        };
    }
    assert_eq!(covered, data.len(), "every byte is either in a chunk or in a reported damaged region");
    let l = read_bytes(&with_header).expect("a valid header");
    let _ = Session::decode(&l, None);
});
