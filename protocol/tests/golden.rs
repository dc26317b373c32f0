//! The worked byte examples of `PROTOCOL.md` are golden vectors: every sample message must
//! have one, encode to exactly those bytes, and decode from them.
//!
//! To print the vectors after a deliberate change of the wire format (which needs a new major
//! version): `PRINT_GOLDEN=1 cargo test -p protocol --test golden -- --nocapture`.

use protocol::{CoreToHost, Decoder, HostToCore, MAX_FRAME_LEN, encode_frame, samples};

const DOC: &str = include_str!("../PROTOCOL.md");

/// `(direction, name) → bytes` from `<!-- golden DIR: NAME -->` markers, each followed by a
/// fenced block of hex bytes.
fn vectors() -> Vec<(String, String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut lines = DOC.lines();
    while let Some(line) = lines.next() {
        let Some(rest) = line.trim().strip_prefix("<!-- golden ") else {
            continue;
        };
        let rest = rest
            .strip_suffix("-->")
            .expect("marker ends with -->")
            .trim();
        let (dir, name) = rest.split_once(':').expect("marker is `DIR: NAME`");
        assert!(
            lines.next().expect("fence").starts_with("```"),
            "fence after {rest}"
        );
        let mut bytes = Vec::new();
        for l in lines.by_ref() {
            if l.starts_with("```") {
                break;
            }
            for tok in l.split_whitespace() {
                bytes.push(u8::from_str_radix(tok, 16).unwrap_or_else(|_| panic!("hex {tok}")));
            }
        }
        out.push((dir.trim().to_string(), name.trim().to_string(), bytes));
    }
    out
}

fn frame<T: serde::Serialize>(msg: &T) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    encode_frame(msg, &mut buf).unwrap().to_vec()
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .chunks(16)
        .map(|c| {
            c.iter()
                .map(|b| format!("{b:02x}"))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn lookup<'a>(v: &'a [(String, String, Vec<u8>)], dir: &str, name: &str) -> &'a [u8] {
    &v.iter()
        .find(|(d, n, _)| d == dir && n == name)
        .unwrap_or_else(|| panic!("PROTOCOL.md has no golden vector for {dir}: {name}"))
        .2
}

#[test]
fn protocol_md_byte_examples_match_the_encoder_and_decoder() {
    if std::env::var_os("PRINT_GOLDEN").is_some() {
        for (name, m) in samples::host_messages() {
            println!(
                "<!-- golden host: {name} -->\n```text\n{}\n```\n",
                hex(&frame(&m))
            );
        }
        for (name, m) in samples::core_messages() {
            println!(
                "<!-- golden core: {name} -->\n```text\n{}\n```\n",
                hex(&frame(&m))
            );
        }
    }
    let v = vectors();
    assert_eq!(
        v.len(),
        samples::host_messages().len() + samples::core_messages().len(),
        "one vector per sample"
    );
    for (name, msg) in samples::host_messages() {
        let bytes = lookup(&v, "host", name);
        assert_eq!(hex(&frame(&msg)), hex(bytes), "host: {name}");
        let got: Vec<_> = Decoder::new().feed::<HostToCore>(bytes).collect();
        assert_eq!(got, vec![Ok(msg)], "host: {name}");
    }
    for (name, msg) in samples::core_messages() {
        let bytes = lookup(&v, "core", name);
        assert_eq!(hex(&frame(&msg)), hex(bytes), "core: {name}");
        let got: Vec<_> = Decoder::new().feed::<CoreToHost>(bytes).collect();
        assert_eq!(got, vec![Ok(msg)], "core: {name}");
    }
}
