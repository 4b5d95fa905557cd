#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_certs_fuzz::trust_store::run(data));
