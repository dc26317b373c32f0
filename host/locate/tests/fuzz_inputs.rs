//! The cold start's cache file (`locate-KEY.db`) on truncated, foreign, wrong-version, flipped
//! and arbitrary bytes (issue 40): read back whole and checked, or refused with the reason
//! (the caller then rebuilds the database); never a panic.

use locate::database::{CacheError, Database, Entry, FORMAT_VERSION, HEADER_LEN, View};
use proptest::prelude::*;

const KEY: u64 = 0x1234_5678_9abc_def0;

fn database() -> Database {
    Database {
        key: KEY,
        views: vec![
            View {
                q_cw: [1.0, 0.0, 0.0, 0.0],
                c_w: [0.0, 0.0, 1.0],
            },
            View {
                q_cw: [0.0, 1.0, 0.0, 0.0],
                c_w: [0.5, -0.25, 2.0],
            },
        ],
        entries: (0..5u16)
            .map(|i| Entry {
                descriptor: [u64::from(i) * 0x0101_0101, !0, 7, 1 << 63],
                point: [f32::from(i), -0.5, 0.125],
                view: i % 2,
            })
            .collect(),
    }
}

#[test]
fn a_cache_file_reads_back_whole() {
    let db = database();
    let bytes = db.to_bytes().unwrap();
    assert_eq!(Database::from_bytes(&bytes, KEY).unwrap(), db);
}

#[test]
fn every_truncation_is_refused_as_truncated() {
    let bytes = database().to_bytes().unwrap();
    for len in 0..bytes.len() {
        match Database::from_bytes(&bytes[..len], KEY) {
            Err(CacheError::Truncated { found, .. }) => assert_eq!(found, len as u64),
            other => panic!("{len} bytes: {other:?}"),
        }
    }
}

#[test]
fn foreign_files_are_refused() {
    for bytes in [
        &b"not a database at all, but long enough for a header"[..],
        b"{}",
        b"\x89PNG",
    ] {
        let e = Database::from_bytes(bytes, KEY).unwrap_err();
        assert_eq!(e, CacheError::Foreign);
        assert!(e.to_string().contains("foreign"), "{e}");
    }
}

#[test]
fn other_versions_keys_lengths_and_checksums_are_refused() {
    let bytes = database().to_bytes().unwrap();
    // Version 1 (the postcard body alone) and a future one.
    for v in [b'1', b'3'] {
        let mut old = bytes.clone();
        old[7] = v;
        let e = Database::from_bytes(&old, KEY).unwrap_err();
        assert!(matches!(e, CacheError::Version { .. }), "{e:?}");
        assert!(
            e.to_string()
                .contains(&format!("reads version {}", char::from(FORMAT_VERSION)))
        );
    }
    assert!(matches!(
        Database::from_bytes(&bytes, KEY ^ 1),
        Err(CacheError::OtherKey { .. })
    ));
    let mut longer = bytes.clone();
    longer.push(0);
    assert_eq!(
        Database::from_bytes(&longer, KEY),
        Err(CacheError::TrailingBytes { extra: 1 })
    );
    // Every single bit flip in the body is caught by the checksum.
    for i in HEADER_LEN..bytes.len() {
        let mut flipped = bytes.clone();
        flipped[i] ^= 0x10;
        let e = Database::from_bytes(&flipped, KEY).unwrap_err();
        assert!(matches!(e, CacheError::Checksum { .. }), "byte {i}: {e:?}");
    }
}

/// A body with a correct checksum that lies (an entry of a view that does not exist) is still
/// refused: the checksum guards against damage, not against a wrong writer.
#[test]
fn a_consistent_file_of_impossible_entries_is_corrupt() {
    let mut db = database();
    db.entries[0].view = 9;
    let e = Database::from_bytes(&db.to_bytes().unwrap(), KEY).unwrap_err();
    assert!(matches!(e, CacheError::Corrupt(_)), "{e:?}");
    let mut db = database();
    db.entries.clear();
    let e = Database::from_bytes(&db.to_bytes().unwrap(), KEY).unwrap_err();
    assert!(matches!(e, CacheError::Corrupt(_)), "{e:?}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        let _ = Database::from_bytes(&bytes, KEY);
    }

    /// Mutations of a real file whose header is then made consistent again (length and
    /// checksum): the body decoder itself on damaged input.
    #[test]
    fn mutated_bodies_with_fixed_headers_never_panic(
        ops in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..6)
    ) {
        let bytes = database().to_bytes().unwrap();
        let mut body = bytes[HEADER_LEN..].to_vec();
        for (at, byte, kind) in ops {
            let i = at.index(body.len() + 1);
            match kind {
                0 if i < body.len() => body[i] = byte,
                1 => body.truncate(i),
                _ => body.insert(i, byte),
            }
        }
        let mut file = bytes[..16].to_vec();
        file.extend_from_slice(&(body.len() as u64).to_le_bytes());
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&body);
        file.extend_from_slice(&crc.to_le_bytes());
        file.extend_from_slice(&body);
        if let Ok(db) = Database::from_bytes(&file, KEY) {
            prop_assert!(db.entries.iter().all(|e| usize::from(e.view) < db.views.len()));
        }
    }
}
