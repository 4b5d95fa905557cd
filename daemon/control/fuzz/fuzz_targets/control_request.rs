#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| telextiles_control_fuzz::control_request::run(data));
