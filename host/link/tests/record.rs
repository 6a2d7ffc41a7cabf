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

/// Issue 23: one flipped bit anywhere in the header (magic, version, length, metadata or CRC)
/// costs only the header: every chunk after it is read, and the loss is reported.
#[test]
fn a_flipped_bit_in_the_header_costs_only_the_header() {
    let (bytes, chunks) = sample();
    let header_len = Reader::new(&bytes).unwrap().offset();
    for bit in 0..header_len * 8 {
        let mut b = bytes.clone();
        b[bit / 8] ^= 1 << (bit % 8);
        let l = read_bytes(&b).unwrap_or_else(|e| panic!("bit {bit}: {e}"));
        assert_eq!(l.chunks, chunks, "bit {bit}");
        assert!(l.header_error.is_some(), "bit {bit}");
        assert_eq!(l.damage.len(), 1, "bit {bit}: {:?}", l.damage);
        assert_eq!((l.damage[0].offset, l.damage[0].len), (MAGIC.len(), header_len - MAGIC.len()), "bit {bit}");
        assert!(l.damage[0].reason.contains("header"), "{:?}", l.damage);
    }
    // Not a recording at all, or of a newer version: still refused.
    assert_eq!(read_bytes(b"plain text, not a recording").err(), Some(RecordError::NotARecording));
}

/// The range CRC the resynchronisation uses equals the direct CRC on every range.
#[test]
fn range_crc_equals_the_direct_crc() {
    use subnav_link::record::reader::RangeCrc;
    let bytes: Vec<u8> = (0..3000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    let t = RangeCrc::new(&bytes);
    let crc = subnav_wire::frame::FRAME_CRC;
    for (s, e) in [(0, 0), (0, 1), (0, 3000), (1, 2999), (255, 257), (256, 512), (700, 701), (13, 2048), (2999, 3000)] {
        assert_eq!(t.crc(&bytes, s, e), crc.checksum(&bytes[s..e]), "{s}..{e}");
    }
}

/// Issue 23: a file of fake chunk headers, each claiming about half a megabyte, made the
/// resynchronisation quadratic (every candidate checksummed its claimed length: 1.3 MB took
/// 41 s in a release build). It must read in linear time: well under a second here, with
/// a bound loose enough for a loaded CI machine and a debug build.
#[test]
fn fake_chunk_headers_resync_in_linear_time() {
    let mut w = Writer::new(Vec::new(), &Meta::new("test")).unwrap();
    w.chunk(Stream::Uplink, 1, b"first").unwrap();
    let mut b = w.into_inner();
    let fake_len = 512 * 1024u32;
    while b.len() < 1_000_000 {
        b.extend_from_slice(&SYNC);
        b.push(0);
        b.extend_from_slice(&7u64.to_le_bytes());
        b.extend_from_slice(&fake_len.to_le_bytes());
    }
    let t0 = std::time::Instant::now();
    let l = read_bytes(&b).unwrap();
    let secs = t0.elapsed().as_secs_f64();
    assert_eq!(l.chunks.len(), 1);
    assert_eq!(l.stats.damaged_bytes as usize, b.len() - (Reader::new(&b).unwrap().offset() + CHUNK_OVERHEAD + 5));
    assert!(secs < 5.0, "reading {} bytes of fake chunk headers took {secs:.1} s", b.len());
}

/// Issue 23: a truth CSV with its columns in another order was read by position.
#[test]
fn truth_columns_are_read_by_name() {
    use subnav_link::record::session::parse_truth_csv;
    let (rows, bad) = parse_truth_csv("yaw_rad,t_s,d_m,e_m,n_m\n0.5,1,3,2,1\n");
    assert_eq!(bad, 0);
    assert_eq!((rows[0].t_s, rows[0].pos_ned_m, rows[0].yaw_rad), (1.0, [1.0, 2.0, 3.0], 0.5));
    let (rows, _) = parse_truth_csv("t_s,n_m,e_m,d_m,yaw_rad\n1,1,2,3,0.5\n");
    assert_eq!((rows[0].t_s, rows[0].pos_ned_m, rows[0].yaw_rad), (1.0, [1.0, 2.0, 3.0], 0.5));
    let (rows, _) = parse_truth_csv("1,1,2,3,0.5\n");
    assert_eq!(rows.len(), 1);
    let (rows, bad) = parse_truth_csv("t_s,north,east\n1,2,3\n");
    assert!(rows.is_empty() && bad > 0);
}
