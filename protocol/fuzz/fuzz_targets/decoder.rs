//! Fuzz the streaming decoder: arbitrary bytes, in chunks whose sizes the input also chooses,
//! through both directions' decoders. Every accepted message must re-encode to a frame that
//! decodes to the same bytes again, and validation must never panic.
//!
//! Random bytes almost never carry a valid CRC, so half of the inputs (first byte odd) are
//! taken as a message body and wrapped in a correct frame first: that reaches the message
//! deserialiser with arbitrary bodies.
//!
//! Run: `cd protocol/fuzz && RUSTC_BOOTSTRAP=1 cargo fuzz run decoder -- -max_total_time=600`
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::{CoreToHost, Decoder, HostToCore, MAX_FRAME_LEN, encode_frame};

fn check<T>(decoder: &mut Decoder, data: &[u8], chunk: usize)
where
    T: serde::Serialize + serde::de::DeserializeOwned,
{
    let mut buf = [0u8; MAX_FRAME_LEN];
    for piece in data.chunks(chunk) {
        let msgs: Vec<T> = decoder.feed::<T>(piece).filter_map(Result::ok).collect();
        for msg in msgs {
            let frame = encode_frame(&msg, &mut buf).expect("decoded message re-encodes").to_vec();
            let again: Vec<_> = Decoder::new().feed::<T>(&frame).collect();
            assert_eq!(again.len(), 1);
            let mut buf2 = [0u8; MAX_FRAME_LEN];
            let frame2 = encode_frame(again[0].as_ref().unwrap(), &mut buf2).unwrap();
            assert_eq!(frame, frame2);
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let chunk = 1 + (first >> 1) as usize;
    let framed;
    let bytes = if first & 1 == 1 {
        let mut raw = rest.to_vec();
        raw.extend(protocol::crc32c(rest).to_le_bytes());
        let mut f = vec![0u8];
        f.extend(cobs::encode_vec(&raw));
        f.push(0);
        framed = f;
        &framed[..]
    } else {
        rest
    };
    check::<HostToCore>(&mut Decoder::new(), bytes, chunk);
    check::<CoreToHost>(&mut Decoder::new(), bytes, chunk);
    let mut dec = Decoder::new();
    for msg in dec.feed::<HostToCore>(bytes).filter_map(Result::ok) {
        let _ = msg.validate();
    }
});
