//! Fuzzing of what the viewer parses from the network: the HTTP request head
//! (request line, headers, percent-encoded path and query) and the run
//! settings of `POST /api/run` (JSON). Mutated requests give a request or a
//! refusal with a 4xx/5xx status, never a panic, a hang or a huge
//! allocation. See `colslam_testutil::fuzz`; the long run is in
//! docs/benchmarks.md ("Fuzzing").

use colslam_testutil::fuzz::{Corpus, fuzz};
use colslam_viewer::{RunSettings, parse_request_head};

colslam_testutil::fuzz_allocator!();

/// Inputs in the default test run.
const CI_ITERS: u64 = 6_000;

#[test]
fn fuzz_request_head() {
    let corpus = Corpus::single("head")
        .sample("GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nAccept: text/html\r\n\r\n")
        .sample(
            "POST /api/run HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nOrigin: http://127.0.0.1:8765\r\n\
             Content-Type: application/json\r\nContent-Length: 120\r\n\r\n",
        )
        .sample("GET /api/frame.png?v=12&kind=current%20frame HTTP/1.1\nHost: localhost:8765\nCookie: colslam_token_8765=ab%2Fcd\n\n")
        .sample("GET /events?token=00ff HTTP/1.0\r\nAuthorization: Bearer 0123456789abcdef\r\n\r\n")
        .words(["%", "%zz", "%ff", "?", "&", "=", ":", "Content-Length", "\r\n", "HTTP/1.1", "HTTP/2"]);
    fuzz("http-request-head", &corpus, CI_ITERS, |parts| match parse_request_head(&parts[0]) {
        Ok(req) => {
            assert!(!req.method.is_empty(), "accepted a request without a method");
            Ok(req.path.len())
        }
        Err(e) => {
            assert!((400..600).contains(&e.status), "refusal with status {}", e.status);
            Err(e)
        }
    });
}

#[test]
fn fuzz_run_settings() {
    let corpus = Corpus::single("settings.json")
        .sample(
            r#"{"input":"/data/seq","output":"/tmp/out","skip":2,"max_frames":null,"init_frames":20,"flow_threshold":0.05,"extractor":"orb","matcher":"nn"}"#,
        )
        .sample(
            r#"{"input":"video.mp4","output":"out","skip":1,"max_frames":300,"init_frames":10,"flow_threshold":0.0,"extractor":"xfeat","matcher":"lighterglue"}"#,
        )
        .words(["null", "-1", "1e999", "9223372036854775808", "\"\\u0000\"", "[]", "{}", "\"orb\"", "true"]);
    fuzz("run-settings-json", &corpus, CI_ITERS, |parts| {
        let settings = RunSettings::from_json(&parts[0])?;
        // Accepted settings must make a valid run.
        settings.validate().unwrap_or_else(|e| panic!("accepted settings do not validate: {e}"));
        Ok::<_, colslam_viewer::SettingsError>(settings.skip_usize())
    });
}
