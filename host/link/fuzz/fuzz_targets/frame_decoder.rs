//! The uplink/downlink frame decoders on arbitrary bytes: never panic; every delimiter gives a
//! message or a counted error; a message that decodes re-encodes to a frame that decodes to it.
#![no_main]
use libfuzzer_sys::fuzz_target;
use subnav_wire::*;

fuzz_target!(|data: &[u8]| {
    let mut up = FrameDecoder::<{ MAX_UPLINK_FRAME }>::new();
    let mut down = FrameDecoder::<{ MAX_DOWNLINK_FRAME }>::new();
    let delimiters = data.iter().filter(|b| **b == 0).count() as u64;
    for &b in data {
        if let Decoded::Message(m) = up.push::<Uplink>(b) {
            let mut buf = [0u8; MAX_UPLINK_FRAME];
            let f = encode(&m, &mut buf).expect("a decoded message re-encodes");
            let n = f.len() - 1;
            let back: Uplink = decode_in_place(&mut f[..n]).expect("a re-encoded message decodes");
            assert_eq!(format!("{back:?}"), format!("{m:?}"));
        }
        let _ = down.push::<Downlink>(b);
    }
    assert!(up.frames_ok + up.frames_bad <= delimiters);
    // The one-shot decoder on the whole input.
    let mut copy = data.to_vec();
    let _ = decode_in_place::<Uplink>(&mut copy);
    // The host's decoder with statistics.
    let mut dec = subnav_link::UplinkDecoder::new();
    dec.feed(data, |_| {});
    assert_eq!(dec.stats().bytes, data.len() as u64);
});
