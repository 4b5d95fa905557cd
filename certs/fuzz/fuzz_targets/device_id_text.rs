#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_certs_fuzz::device_id_text::run(data));
