#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_certs_fuzz::identity_pem::run(data));
