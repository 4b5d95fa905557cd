#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_proto_fuzz::peer_decode::run(data));
