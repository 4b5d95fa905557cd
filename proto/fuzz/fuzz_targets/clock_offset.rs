#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_proto_fuzz::clock_offset::run(data));
