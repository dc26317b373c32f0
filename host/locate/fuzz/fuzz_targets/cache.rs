//! Fuzz the reading of the cold start's cached database (`locate-KEY.db`): a database whose
//! every entry is usable, or a `CacheError` (the file is then rebuilt). Each input is tried
//! twice: as the whole file (header checks), and as a body behind a valid header with its
//! length and CRC-32, so that the body's decoding and the entries' checks are reached too. The
//! cache is at most 1 GiB; the fuzzer's inputs are far smaller, so any allocation over 64 MiB
//! aborts.
#![no_main]

use fuzz_support::LimitAlloc;
use libfuzzer_sys::fuzz_target;
use locate::database::{Database, FORMAT_VERSION, HEADER_LEN};

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

const KEY: u64 = 0x5eed_cafe;

fuzz_target!(|data: &[u8]| {
    let _ = Database::from_bytes(data, KEY);
    let mut file = Vec::with_capacity(HEADER_LEN + data.len());
    file.extend_from_slice(b"HVLOCDB");
    file.push(FORMAT_VERSION);
    file.extend_from_slice(&KEY.to_le_bytes());
    file.extend_from_slice(&(data.len() as u64).to_le_bytes());
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(data);
    file.extend_from_slice(&crc.to_le_bytes());
    file.extend_from_slice(data);
    if let Ok(db) = Database::from_bytes(&file, KEY) {
        // What was accepted writes back to a file that reads as the same database.
        let bytes = db.to_bytes().unwrap();
        let again = Database::from_bytes(&bytes, KEY).unwrap();
        assert_eq!(again.to_bytes().unwrap(), bytes);
    }
});
