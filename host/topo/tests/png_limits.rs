//! Issue 23: a polarization mosaic PNG whose header declares 60000 x 60000 pixels (28.8 GB of
//! output buffer) is refused from its header, before anything is allocated.

use subnav_topo::polar_image::mosaic::Mosaic;

fn png_declaring(w: u32, h: u32) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
            }
        }
        !c
    }
    let mut v = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8], data: &[u8]| {
        v.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend_from_slice(data);
        v.extend_from_slice(&body);
        v.extend_from_slice(&crc32(&body).to_be_bytes());
    };
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[16, 0, 0, 0, 0]); // 16-bit grey
    chunk(b"IHDR", &ihdr);
    chunk(b"IDAT", &[0x78, 0x9c, 0x03, 0x00]); // the decoder reads the header up to here
    chunk(b"IEND", &[]);
    v
}

#[test]
fn a_mosaic_declaring_a_huge_size_is_refused_from_its_header() {
    let e = Mosaic::decode_png(&png_declaring(60_000, 60_000)[..]).unwrap_err();
    let msg = format!("{e:#}");
    assert!(msg.contains("60000 x 60000") && msg.contains("16384"), "{msg}");
}
