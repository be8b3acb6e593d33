//! Request bodies → the JSON types the API deserializes them into (submit by
//! path, move, start, resume, jog), the way its handlers do. The first byte
//! picks the call, so each type's corpus stays its own.
#![no_main]

use laserd::daemon::api::{JogBody, MoveTo, ResumeBody, StartBody, SubmitPath};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&which, body)) = data.split_first() else { return };
    match which % 5 {
        0 => {
            let _ = serde_json::from_slice::<SubmitPath>(body);
        }
        1 => {
            let _ = serde_json::from_slice::<MoveTo>(body);
        }
        2 => {
            // An empty body is the default start.
            if !body.is_empty() {
                let _ = serde_json::from_slice::<StartBody>(body);
            }
        }
        3 => {
            let _ = serde_json::from_slice::<ResumeBody>(body);
        }
        _ => {
            let _ = serde_json::from_slice::<JogBody>(body);
        }
    }
});
