#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_proto_fuzz::roller_decode::run(data));
