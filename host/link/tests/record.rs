//! The recording format: lossless round trip, damage costs only the damaged chunk, header
//! errors are clear, hostile length fields are harmless.

use subnav_link::record::*;

fn sample() -> (Vec<u8>, Vec<Chunk>) {
    let mut w = Writer::new(Vec::new(), &Meta::new("test")).unwrap();
    let mut chunks = vec![];
    for i in 0..50u64 {
        let stream = Stream::ALL[(i % 4) as usize];
        let data: Vec<u8> = (0..(i as usize % 37 + 1)).map(|k| (k as u8).wrapping_mul(31).wrapping_add(i as u8)).collect();
        w.chunk(stream, 1_000 + i, &data).unwrap();
        chunks.push(Chunk { stream, t_host_us: 1_000 + i, data });
    }
    (w.into_inner(), chunks)
}

#[test]
fn roundtrip_keeps_every_byte_and_time() {
    let (bytes, chunks) = sample();
    let l = read_bytes(&bytes).unwrap();
    assert_eq!(l.meta.source, "test");
    assert_eq!(l.chunks, chunks);
    assert!(l.damage.is_empty());
}

#[test]
fn damage_costs_only_the_damaged_chunk() {
    let (bytes, chunks) = sample();
    let header_len = Reader::new(&bytes).unwrap().offset();
    // Flip one byte inside the data of chunk 10 (find it by walking sizes).
    let mut at = header_len;
    for c in &chunks[..10] {
        at += CHUNK_OVERHEAD + c.data.len();
    }
    let mut bad = bytes.clone();
    bad[at + 16] ^= 0x40;
    let l = read_bytes(&bad).unwrap();
    assert_eq!(l.damage.len(), 1);
    assert_eq!(l.damage[0].offset, at);
    assert_eq!(l.damage[0].reason, "chunk CRC mismatch");
    let mut expected = chunks.clone();
    expected.remove(10);
    assert_eq!(l.chunks, expected);
}

#[test]
fn a_cut_file_keeps_every_complete_chunk_and_says_so() {
    let (bytes, chunks) = sample();
    let cut = &bytes[..bytes.len() - 3];
    let l = read_bytes(cut).unwrap();
    assert_eq!(l.chunks, chunks[..chunks.len() - 1]);
    assert_eq!(l.damage.len(), 1);
    assert!(l.damage[0].reason.contains("truncated"), "{:?}", l.damage);
}

#[test]
fn header_errors_are_clear() {
    assert_eq!(Reader::new(b"").err(), Some(RecordError::NotARecording));
    assert_eq!(Reader::new(b"\x00\x01garbage").err(), Some(RecordError::NotARecording));
    assert_eq!(Reader::new(&MAGIC[..4]).err(), Some(RecordError::TruncatedHeader));
    let (bytes, _) = sample();
    assert_eq!(Reader::new(&bytes[..12]).err(), Some(RecordError::TruncatedHeader));
    let mut b = bytes.clone();
    b[MAGIC.len() + 8] ^= 1;
    assert_eq!(Reader::new(&b).err(), Some(RecordError::HeaderCrc));
}

#[test]
fn garbage_spliced_between_chunks_is_skipped() {
    let (bytes, chunks) = sample();
    let header_len = Reader::new(&bytes).unwrap().offset();
    let first = CHUNK_OVERHEAD + chunks[0].data.len();
    let mut b = bytes[..header_len + first].to_vec();
    b.extend_from_slice(&[0xA5, 0x5A, 0x07, 1, 2, 3, 0xA5, 0xA5, 0x5A, 0x00, 0xff]);
    b.extend_from_slice(&bytes[header_len + first..]);
    let l = read_bytes(&b).unwrap();
    assert_eq!(l.chunks, chunks);
    assert_eq!(l.stats.damaged_bytes, 11);
}

#[test]
fn huge_length_fields_do_not_allocate_or_panic() {
    let (bytes, _) = sample();
    let header_len = Reader::new(&bytes).unwrap().offset();
    let mut b = bytes.clone();
    b[header_len + 11..header_len + 15].copy_from_slice(&u32::MAX.to_le_bytes());
    let l = read_bytes(&b).unwrap();
    assert_eq!(l.chunks.len(), 49);
}
