#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_proto_fuzz::latent_receive::run(data));
