//! The device catalogue's TOML: `cathlab_physics::Catalogue::from_toml_str` (the input as
//! UTF-8 text; other bytes are skipped, as a file read to a string would fail first).
#![no_main]

use cathlab_physics::Catalogue;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cathlab_fuzz::start();
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let result = Catalogue::from_toml_str(text);
    cathlab_fuzz::report("devices", &result);
    if let Ok(catalogue) = result {
        for entry in catalogue.entries() {
            let _ = catalogue.device(&entry.id);
        }
    }
});
