//! `tadgs view`, end to end on a tiny trained run: the server answers only its page, JSON and
//! frames; malformed, oversized and cross-site requests get a 4xx and the server goes on;
//! several sessions run at once and a closed one is freed; a frame has the pixels of
//! `tadgs render`; a headless Chromium, driven through the DevTools protocol, shows that
//! frame, follows the time slider and a mouse drag, and asks nothing of any other server; and
//! `tadgs train --view` serves the model as it trains.
//!
//! The browser test needs Chromium (the `chromium` package, or `TADGS_CHROMIUM`); without it
//! it skips with a message, and fails under `CI=true`. `TADGS_BLESS=1` saves its screenshot
//! as `docs/viewer.png`; `TADGS_VIEW_RUN=FOLDER` shows that run instead of the tiny one (for a
//! screenshot of a fully trained model).

#[path = "common/cdp.rs"]
mod cdp;
#[path = "common/cli.rs"]
mod tiny;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{Value, json};
use tiny::{tadgs, tiny_demo_scene};

fn check(out: Output) -> Output {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A run folder trained once per test process: the demo scene at 64×48 over 6 frames, 60
/// iterations (a few seconds).
fn tiny_run() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let dir = scratch("run");
        let scene = tiny_scene(&dir);
        let run = dir.join("run");
        check(tadgs(&[
            "-q",
            "train",
            scene.to_str().unwrap(),
            "--output",
            run.to_str().unwrap(),
            "--no-renders",
            "--no-report",
        ]));
        run
    })
}

/// A fresh folder `name` for this test process, in cargo's temporary folder for integration
/// tests.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("view-{}", std::process::id()))
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The demo scene at 64×48 over 6 frames, 60 iterations, written into `dir`.
fn tiny_scene(dir: &Path) -> PathBuf {
    tiny_demo_scene(dir, (64, 48), 400, 60, 20)
}

/// A `tadgs view` process, stopped when dropped.
struct Viewer {
    child: Child,
    url: String,
    /// host:port of the server.
    address: String,
}

impl Viewer {
    fn start(input: &Path, extra: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_tadgs"))
            .arg("view")
            .arg(input)
            .args(["--port", "0"])
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("tadgs view starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .expect("tadgs view prints its URL");
        let url = line.trim().to_string();
        assert!(url.starts_with("http://"), "no URL printed: {line:?}");
        let address = url
            .trim_start_matches("http://")
            .trim_end_matches('/')
            .to_string();
        Self {
            child,
            url,
            address,
        }
    }

    fn port(&self) -> u16 {
        self.address.rsplit(':').next().unwrap().parse().unwrap()
    }

    /// Sends `request` (raw bytes) and reads the whole response: status, headers, body.
    fn raw(&self, request: &[u8]) -> (u16, String, Vec<u8>) {
        let mut stream = TcpStream::connect(&self.address).expect("the viewer accepts");
        stream
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        // The server may answer and close before reading everything (e.g. a body too large),
        // so the request is written beside the reading.
        let mut writer = stream.try_clone().unwrap();
        let request = request.to_vec();
        let writing = std::thread::spawn(move || {
            let _ = writer.write_all(&request);
        });
        let mut response = Vec::new();
        let _ = stream.read_to_end(&mut response);
        let _ = writing.join();
        let split = response
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .unwrap_or_else(|| {
                panic!("no HTTP response: {:?}", String::from_utf8_lossy(&response))
            });
        let head = String::from_utf8_lossy(&response[..split]).to_string();
        let status = head
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("no status in {head:?}"));
        (status, head, response[split + 4..].to_vec())
    }

    fn get(&self, path: &str) -> (u16, String, Vec<u8>) {
        self.raw(
            format!(
                "GET {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
                self.address
            )
            .as_bytes(),
        )
    }

    fn post(&self, path: &str, content_type: &str, body: &[u8]) -> (u16, String, Vec<u8>) {
        let mut request = format!(
            "POST {path} HTTP/1.1\r\nHost: {}\r\nContent-Type: {content_type}\r\n\
             Content-Length: {}\r\nConnection: close\r\n\r\n",
            self.address,
            body.len()
        )
        .into_bytes();
        request.extend_from_slice(body);
        self.raw(&request)
    }

    fn json(&self, path: &str) -> Value {
        let (status, _, body) = self.get(path);
        assert_eq!(status, 200, "{path}");
        serde_json::from_slice(&body).expect("JSON")
    }

    /// One frame through `POST /api/frame`, decoded.
    fn frame(&self, request: &Value) -> image::RgbImage {
        let (status, head, body) = self.post(
            "/api/frame",
            "application/json",
            request.to_string().as_bytes(),
        );
        assert_eq!(status, 200, "{head}\n{}", String::from_utf8_lossy(&body));
        image::load_from_memory(&body).expect("a PNG").to_rgb8()
    }

    /// The server still answers.
    fn alive(&self) {
        assert_eq!(
            self.get("/api/status").0,
            200,
            "the server stopped answering"
        );
    }

    fn websocket(&self) -> tungstenite::WebSocket<TcpStream> {
        let stream = TcpStream::connect(&self.address).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        tungstenite::client(format!("ws://{}/ws", self.address), stream)
            .expect("WebSocket handshake")
            .0
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `tadgs render` of the camera in the RON `camera` at `time`, as 8-bit RGB.
fn rendered(run: &Path, camera: &str, time: f32) -> image::RgbImage {
    let dir = tempfile::tempdir().unwrap();
    let ron = dir.path().join("view.ron");
    std::fs::write(&ron, camera).unwrap();
    let png = dir.path().join("view.png");
    let time = time.to_string();
    check(tadgs(&[
        "-q",
        "render",
        run.to_str().unwrap(),
        "--camera",
        ron.to_str().unwrap(),
        "--time",
        &time,
        "--frames",
        "1",
        "-o",
        png.to_str().unwrap(),
    ]));
    image::open(&png).unwrap().to_rgb8()
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (255.0f64.powi(2) / mse).log10()
}

/// The home camera of `/api/info` as a frame request at frame `frame`.
fn home_request(info: &Value, frame: usize) -> Value {
    json!({ "camera": info["home"], "frame": frame })
}

/// The server binds 127.0.0.1, serves its page (with a policy that loads nothing from
/// elsewhere), its JSON and frames, and nothing else: no path reaches the file system.
#[test]
fn serves_only_its_page_json_and_frames() {
    let run = tiny_run();
    let viewer = Viewer::start(run, &[]);
    assert!(
        viewer.url.starts_with("http://127.0.0.1:"),
        "{}",
        viewer.url
    );

    let (status, head, body) = viewer.get("/");
    assert_eq!(status, 200);
    let head = head.to_ascii_lowercase();
    assert!(head.contains("content-type: text/html"), "{head}");
    assert!(
        head.contains("content-security-policy: default-src 'none'"),
        "{head}"
    );
    let page = String::from_utf8(body).unwrap();
    assert_eq!(page, tadgs::view::PAGE);
    // Nothing in the page points outside its own server.
    for outside in ["http://", "https://", "//cdn", "src=\"http"] {
        assert!(!page.contains(outside), "the page mentions {outside}");
    }

    let info = viewer.json("/api/info");
    assert_eq!(info["frames"], 6);
    assert!(info["gaussians"].as_u64().unwrap() > 0);
    let cameras = info["cameras"].as_array().unwrap();
    // The demo's ring of 16 cameras, one held out.
    assert_eq!(cameras.len(), 16, "{info}");
    assert_eq!(
        cameras.iter().filter(|c| c["heldout"] == true).count(),
        1,
        "one held-out camera"
    );
    let status = viewer.json("/api/status");
    assert_eq!(status["sessions"], 0);

    for path in [
        "/scene.ron",
        "/model.safetensors",
        "/../scene.ron",
        "/%2e%2e/scene.ron",
        "/..%2fscene.ron",
        "/api/../../etc/passwd",
        "//etc/passwd",
        "/page.html",
        "/src/view/page.html",
        "/api/info/../../Cargo.toml",
        "/ws/../../run/model.safetensors",
    ] {
        let (status, _, body) = viewer.get(path);
        assert_eq!(status, 404, "{path}");
        assert!(body.len() < 100, "{path} answered {} bytes", body.len());
    }
    // A model file starts too: the input is what render takes.
    let model = run.join("model.safetensors");
    let by_file = Viewer::start(&model, &[]);
    let info = by_file.json("/api/info");
    assert_eq!(info["cameras"].as_array().unwrap().len(), 0);
    assert_eq!(info["frames"], 6);
    by_file.frame(&home_request(&info, 2));
    // And a static splat PLY: one frame, time-invariant.
    let ply = scratch("ply");
    check(tadgs(&[
        "-q",
        "export",
        run.to_str().unwrap(),
        "--frames",
        "3",
        "-o",
        ply.to_str().unwrap(),
    ]));
    let by_ply = Viewer::start(&ply.join("frame_0003.ply"), &[]);
    let info = by_ply.json("/api/info");
    assert_eq!(info["frames"], 1);
    by_ply.frame(&home_request(&info, 0));
}

/// Malformed, oversized, cross-site and misdirected requests are answered with a 4xx, and the
/// server answers the next request as before.
#[test]
fn bad_requests_get_4xx_and_the_server_goes_on() {
    let run = tiny_run();
    let viewer = Viewer::start(run, &[]);
    let info = viewer.json("/api/info");
    let good = home_request(&info, 0).to_string();
    let host = viewer.address.clone();
    let huge_header = format!(
        "GET / HTTP/1.1\r\nHost: {host}\r\nX-Padding: {}\r\nConnection: close\r\n\r\n",
        "a".repeat(1 << 20)
    );
    let raw_cases: Vec<(&str, Vec<u8>, &[u16])> = vec![
        ("not HTTP", b"HELLO THERE\r\n\r\n".to_vec(), &[400]),
        ("binary garbage", vec![0xFF, 0x00, 0x13, 0x37, b'\r', b'\n', b'\r', b'\n'], &[400]),
        ("1 MiB header", huge_header.into_bytes(), &[431, 400]),
        (
            "no Host",
            b"GET / HTTP/1.1\r\nConnection: close\r\n\r\n".to_vec(),
            &[400],
        ),
        (
            "another Host (DNS rebinding)",
            b"GET /api/info HTTP/1.1\r\nHost: attacker.example:80\r\nConnection: close\r\n\r\n"
                .to_vec(),
            &[403],
        ),
        (
            "a post from another site",
            format!(
                "POST /api/frame HTTP/1.1\r\nHost: {host}\r\nOrigin: http://attacker.example\r\n\
                 Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{good}",
                good.len()
            )
            .into_bytes(),
            &[403],
        ),
        (
            "a WebSocket from another site",
            format!(
                "GET /ws HTTP/1.1\r\nHost: {host}\r\nOrigin: http://attacker.example\r\n\
                 Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n\
                 Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
            )
            .into_bytes(),
            &[403],
        ),
        (
            "a WebSocket path without the upgrade",
            format!("GET /ws HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n").into_bytes(),
            &[400, 426],
        ),
        (
            "a method the page does not use",
            format!("DELETE / HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n").into_bytes(),
            &[405],
        ),
        (
            "a body larger than announced limits",
            format!(
                "POST /api/frame HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\n\
                 Content-Length: 100000000\r\nConnection: close\r\n\r\n{{"
            )
            .into_bytes(),
            &[413],
        ),
    ];
    for (what, request, expected) in raw_cases {
        let (status, head, _) = viewer.raw(&request);
        assert!(expected.contains(&status), "{what}: {head}");
        viewer.alive();
    }

    let mut too_large = home_request(&info, 0);
    too_large["camera"]["width"] = json!(100_000);
    let mut not_rigid = home_request(&info, 0);
    not_rigid["camera"]["world_to_camera"][0][0] = json!(3.0);
    let mut late = home_request(&info, 0);
    late["frame"] = json!(6);
    let mut nan_time = json!({ "camera": info["home"], "time": 2.0 });
    nan_time["camera"]["fx"] = json!(-1.0);
    let body_cases: Vec<(&str, &str, Vec<u8>, u16)> = vec![
        (
            "truncated JSON",
            "application/json",
            good.as_bytes()[..20].to_vec(),
            400,
        ),
        (
            "not JSON",
            "application/json",
            b"camera please".to_vec(),
            400,
        ),
        (
            "unknown field",
            "application/json",
            br#"{"camera":{},"zoom":1}"#.to_vec(),
            400,
        ),
        (
            "too large a frame",
            "application/json",
            too_large.to_string().into_bytes(),
            400,
        ),
        (
            "not a rigid camera",
            "application/json",
            not_rigid.to_string().into_bytes(),
            400,
        ),
        (
            "a frame past the end",
            "application/json",
            late.to_string().into_bytes(),
            400,
        ),
        (
            "bad intrinsics",
            "application/json",
            nan_time.to_string().into_bytes(),
            400,
        ),
        (
            "not JSON content",
            "text/plain",
            good.clone().into_bytes(),
            415,
        ),
        ("a 1 MiB body", "application/json", vec![b' '; 1 << 20], 413),
    ];
    for (what, content_type, body, expected) in body_cases {
        let (status, head, answer) = viewer.post("/api/frame", content_type, &body);
        assert_eq!(
            status,
            expected,
            "{what}: {head}\n{}",
            String::from_utf8_lossy(&answer)
        );
        viewer.alive();
    }
    // And a good request still renders.
    viewer.frame(&home_request(&info, 0));
}

/// A frame from the viewer has exactly the pixels `tadgs render` writes for the same camera
/// and time: at the home view, and at a dataset camera at a given frame (whose time the viewer
/// computes as the dataset does, so it equals `render --heldout`'s frame).
#[test]
fn frames_are_the_pixels_of_tadgs_render() {
    let run = tiny_run();
    let viewer = Viewer::start(run, &[]);
    let info = viewer.json("/api/info");
    for (request, time) in [
        (json!({ "camera": info["home"], "time": 0.3 }), 0.3f32),
        (home_request(&info, 0), 0.0),
    ] {
        let shown = viewer.frame(&request);
        let spec: tadgs::io::camera_path::CameraSpec =
            serde_json::from_value(request["camera"].clone()).unwrap();
        let camera = ron::to_string(&spec).unwrap();
        assert_eq!(shown, rendered(run, &camera, time), "t = {time}");
    }

    let heldout = info["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["heldout"] == true)
        .unwrap()
        .clone();
    let index = heldout["index"].as_u64().unwrap().to_string();
    let dir = tempfile::tempdir().unwrap();
    check(tadgs(&[
        "-q",
        "render",
        run.to_str().unwrap(),
        "--heldout",
        &index,
        "-o",
        dir.path().to_str().unwrap(),
    ]));
    for frame in [0usize, 4] {
        let shown = viewer.frame(&json!({ "camera": heldout["camera"], "frame": frame }));
        let expected = image::open(dir.path().join(format!("frame_{frame:04}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!(shown, expected, "held-out camera {index}, frame {frame}");
    }
}

/// Reads one binary frame reply (little-endian header length, JSON header, PNG) or an error.
fn read_reply(socket: &mut tungstenite::WebSocket<TcpStream>) -> Result<(Value, Vec<u8>), Value> {
    loop {
        match socket.read().expect("a reply") {
            tungstenite::Message::Binary(bytes) => {
                let length = u32::from_le_bytes(bytes[..4].try_into().unwrap()) as usize;
                let header: Value = serde_json::from_slice(&bytes[4..4 + length]).unwrap();
                return Ok((header, bytes[4 + length..].to_vec()));
            }
            tungstenite::Message::Text(text) => return Err(serde_json::from_str(&text).unwrap()),
            _ => continue,
        }
    }
}

/// Several pages at once each get their own frames; a malformed message is answered with an
/// error and the session goes on; an oversized one ends that session only; a closed session
/// is freed (the server's session count falls back to 0).
#[test]
fn sessions_run_side_by_side_and_closing_frees_them() {
    let run = tiny_run();
    let viewer = Viewer::start(run, &[]);
    let info = viewer.json("/api/info");
    let mut sockets: Vec<_> = (0..3).map(|_| viewer.websocket()).collect();
    assert_eq!(viewer.json("/api/status")["sessions"], 3);
    // Each asks for another frame; all ask before any reads, so they are served side by side.
    for (k, socket) in sockets.iter_mut().enumerate() {
        let mut request = home_request(&info, k);
        request["id"] = json!(100 + k);
        socket
            .send(tungstenite::Message::text(request.to_string()))
            .unwrap();
    }
    for (k, socket) in sockets.iter_mut().enumerate() {
        let (header, png) = read_reply(socket).expect("a frame");
        assert_eq!(
            (header["id"].as_u64(), header["frame"].as_u64()),
            (Some(100 + k as u64), Some(k as u64))
        );
        let image = image::load_from_memory(&png).unwrap();
        assert_eq!(
            (image.width() as u64, image.height() as u64),
            (
                info["home"]["width"].as_u64().unwrap(),
                info["home"]["height"].as_u64().unwrap()
            )
        );
        assert!(
            header["camera_ron"]
                .as_str()
                .unwrap()
                .contains("world_to_camera")
        );
        assert!(header["total"].as_u64().unwrap() >= header["alive"].as_u64().unwrap());
    }

    // Malformed: answered, and the session still renders.
    let first = &mut sockets[0];
    for bad in [
        "{",
        r#"{"camera":{"width":1}}"#,
        r#"{"camera":null,"time":0}"#,
    ] {
        first.send(tungstenite::Message::text(bad)).unwrap();
        let error = read_reply(first).expect_err("an error reply");
        assert!(
            error["error"].as_str().is_some_and(|e| !e.is_empty()),
            "{error}"
        );
    }
    let mut bad_camera = home_request(&info, 0);
    bad_camera["id"] = json!(7);
    bad_camera["camera"]["height"] = json!(0);
    first
        .send(tungstenite::Message::text(bad_camera.to_string()))
        .unwrap();
    let error = read_reply(first).expect_err("an error reply");
    assert_eq!(error["id"], 7, "{error}");
    first
        .send(tungstenite::Message::binary(vec![1, 2, 3]))
        .unwrap();
    assert!(read_reply(first).is_err());
    first
        .send(tungstenite::Message::text(
            home_request(&info, 1).to_string(),
        ))
        .unwrap();
    assert!(read_reply(first).is_ok());

    // Oversized: that session ends, the others go on.
    let second = &mut sockets[1];
    let _ = second.send(tungstenite::Message::text(format!(
        "\"{}\"",
        "x".repeat(1 << 20)
    )));
    let closed = loop {
        match second.read() {
            Ok(tungstenite::Message::Close(_)) | Err(_) => break true,
            Ok(_) => continue,
        }
    };
    assert!(closed);
    let third = &mut sockets[2];
    third
        .send(tungstenite::Message::text(
            home_request(&info, 5).to_string(),
        ))
        .unwrap();
    assert!(read_reply(third).is_ok());

    // Closing pages frees their sessions.
    for mut socket in sockets {
        let _ = socket.close(None);
        let _ = socket.flush();
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while viewer.json("/api/status")["sessions"] != 0 {
        assert!(
            Instant::now() < deadline,
            "sessions left open: {}",
            viewer.json("/api/status")
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    viewer.alive();
}

/// The PNG inside a `data:` URL.
fn data_url_image(url: &Value) -> image::RgbImage {
    let url = url.as_str().expect("a data URL");
    let encoded = url.split_once(',').expect("data URL").1;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(encoded)
        .expect("base64");
    image::load_from_memory(&bytes).unwrap().to_rgb8()
}

/// A real browser: the page's first frame is `tadgs render`'s at the same camera and time
/// (PSNR ≥ 40 dB), dragging the time slider to the end shows the last frame, dragging on the
/// image orbits the camera, and every request the page made went to the viewer's server.
#[test]
fn browser_shows_what_tadgs_render_draws() {
    let Some(chromium) = cdp::find_chromium() else {
        return;
    };
    let run = match std::env::var_os("TADGS_VIEW_RUN") {
        Some(run) => PathBuf::from(run),
        None => tiny_run().to_path_buf(),
    };
    let viewer = Viewer::start(&run, &[]);
    let mut browser = cdp::Browser::start(&chromium, 1100, 700);
    browser.call("Page.navigate", json!({ "url": viewer.url }));
    let resting = "(() => { const s = window.viewer && viewer.status(); return !!s && s.connected && s.resting; })()";
    browser.wait_for(resting, 60);
    let status = browser.eval("viewer.status()");
    let header = &status["header"];
    assert_eq!(header["frame"], 0, "{status}");

    // The first frame: the home camera at time 0, as `tadgs render` draws it.
    let first = data_url_image(&browser.eval("viewer.canvas.toDataURL('image/png')"));
    let camera = browser
        .eval("viewer.cameraRon()")
        .as_str()
        .unwrap()
        .to_string();
    let time = header["time"].as_f64().unwrap() as f32;
    let expected = rendered(&run, &camera, time);
    let quality = psnr(&first, &expected);
    assert!(
        quality >= 40.0,
        "first frame: PSNR {quality:.1} dB against tadgs render"
    );
    let readout = browser.eval("document.getElementById('readout').textContent");
    for word in ["FPS", "render", "ms", "Gaussians"] {
        assert!(
            readout.as_str().unwrap().contains(word),
            "readout lacks {word}: {readout}"
        );
    }

    // Drag the time slider's thumb to its right end: the last frame, as rendered.
    let frames = browser
        .eval("Number(document.getElementById('time').max)")
        .as_u64()
        .unwrap();
    let rect = browser.eval(
        "(() => { const r = document.getElementById('time').getBoundingClientRect(); \
         return [r.left, r.top, r.width, r.height]; })()",
    );
    let r: Vec<f64> = rect
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let y = r[1] + r[3] / 2.0;
    browser.drag((r[0] + 3.0, y), (r[0] + r[2] + 20.0, y), 8);
    browser.wait_for(
        &format!("(() => {{ const s = viewer.status(); return s.resting && s.header.frame === {frames}; }})()"),
        60,
    );
    let last = data_url_image(&browser.eval("viewer.canvas.toDataURL('image/png')"));
    assert_ne!(last, first, "the time slider changed nothing");
    let header = browser.eval("viewer.status().header");
    assert_eq!(header["frame"], frames);
    let shown_time = header["time"].as_f64().unwrap() as f32;
    assert_eq!(shown_time, 1.0);
    let expected = rendered(&run, &camera, shown_time);
    let quality = psnr(&last, &expected);
    assert!(
        quality >= 40.0,
        "last frame: PSNR {quality:.1} dB against tadgs render"
    );
    // The same camera; only the comment's `--time` changed.
    let uncommented = |ron: &str| -> String {
        ron.lines()
            .filter(|l| !l.starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    let now = browser
        .eval("viewer.cameraRon()")
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(uncommented(&now), uncommented(&camera));
    assert!(now.contains("--time 1.0 "), "{now}");

    // Drag across the image: the camera orbits, and the new view is rendered as tadgs would.
    let rect = browser.eval(
        "(() => { const r = viewer.canvas.getBoundingClientRect(); \
         return [r.left, r.top, r.width, r.height]; })()",
    );
    let r: Vec<f64> = rect
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let centre = (r[0] + r[2] / 2.0, r[1] + r[3] / 2.0);
    browser.drag(centre, (centre.0 + r[2] / 5.0, centre.1 + r[3] / 10.0), 10);
    browser.wait_for(resting, 60);
    let orbited = browser
        .eval("viewer.cameraRon()")
        .as_str()
        .unwrap()
        .to_string();
    assert_ne!(orbited, camera, "dragging did not move the camera");
    let moved = data_url_image(&browser.eval("viewer.canvas.toDataURL('image/png')"));
    assert_ne!(moved, last, "the orbited view shows the same image");
    let quality = psnr(&moved, &rendered(&run, &orbited, shown_time));
    assert!(
        quality >= 40.0,
        "orbited frame: PSNR {quality:.1} dB against tadgs render"
    );

    // A dataset camera from the list, then the screenshot of the whole page.
    let heldout = browser.eval(
        "(() => { const o = [...document.querySelectorAll('#cameras optgroup[label^=held] option')]; \
         if (!o.length) return null; const s = document.getElementById('cameras'); \
         s.value = o[0].value; s.dispatchEvent(new Event('change')); return Number(o[0].value); })()",
    );
    if !heldout.is_null() {
        browser.wait_for(resting, 60);
        let ron = browser
            .eval("viewer.cameraRon()")
            .as_str()
            .unwrap()
            .to_string();
        let dataset =
            viewer.json("/api/info")["cameras"][heldout.as_u64().unwrap() as usize]["camera"]
                .clone();
        let spec: tadgs::io::camera_path::CameraSpec = serde_json::from_value(dataset).unwrap();
        let file = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(file.path(), &ron).unwrap();
        let loaded = tadgs::io::camera_path::load_camera(file.path()).unwrap();
        assert_eq!(
            loaded,
            spec.to_camera().unwrap(),
            "the held-out camera is shown as it is"
        );
    }
    let shot = browser.call("Page.captureScreenshot", json!({ "format": "png" }));
    let png = base64::engine::general_purpose::STANDARD
        .decode(shot["data"].as_str().unwrap())
        .unwrap();
    image::load_from_memory(&png).expect("a screenshot");
    if std::env::var_os("TADGS_BLESS").is_some_and(|v| v == "1") {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/viewer.png");
        std::fs::write(&path, &png).unwrap();
        eprintln!("screenshot written to {}", path.display());
    }

    // Every request went to the viewer itself.
    let urls = browser.requested_urls();
    let origin = format!("127.0.0.1:{}", viewer.port());
    for path in ["/", "/api/info", "/ws"] {
        assert!(
            urls.iter().any(|u| u.ends_with(&format!("{origin}{path}"))),
            "no request for {path}: {urls:?}"
        );
    }
    for url in &urls {
        let local = url.starts_with(&format!("http://{origin}/"))
            || url.starts_with(&format!("ws://{origin}/"))
            || url.starts_with("data:")
            || url.starts_with("blob:");
        assert!(local, "the page requested {url}");
    }
    let errors = browser.page_errors();
    assert!(errors.is_empty(), "the page reported errors: {errors:?}");
}

/// `tadgs train --view` serves the model while it trains: the status shows the iteration,
/// loss and PSNR going on, and with a page open the model shown is replaced about once a
/// second (its version and iteration advance, and a frame shows the newer model).
#[test]
fn train_view_follows_training() {
    let dir = scratch("live");
    let scene = tiny_scene(&dir);
    let mut child = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["-q", "train"])
        .arg(&scene)
        .args([
            "--iterations",
            "5000",
            "--no-renders",
            "--no-report",
            "--view",
        ])
        .arg("--output")
        .arg(dir.join("run"))
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("tadgs train starts");
    let mut stderr = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    let url = loop {
        line.clear();
        let read = stderr.read_line(&mut line).unwrap();
        assert!(read > 0, "tadgs train --view printed no viewer URL");
        if let Some(url) = line.split_whitespace().find(|w| w.starts_with("http://")) {
            break url.to_string();
        }
    };
    // Keep draining stderr so the run never blocks on a full pipe.
    std::thread::spawn(move || std::io::copy(&mut stderr, &mut std::io::sink()));
    let viewer = Viewer {
        address: url
            .trim_start_matches("http://")
            .trim_end_matches('/')
            .to_string(),
        url,
        child,
    };
    let info = viewer.json("/api/info");
    let mut socket = viewer.websocket();
    let mut request = home_request(&info, 3);
    socket
        .send(tungstenite::Message::text(request.to_string()))
        .unwrap();
    let (first, first_png) = read_reply(&mut socket).expect("a frame");
    let version = |status: &Value| status["version"].as_u64().unwrap();

    // Within a few seconds the model shown is replaced, and a frame shows the newer one.
    let deadline = Instant::now() + Duration::from_secs(20);
    let later = loop {
        let status = viewer.json("/api/status");
        if version(&status) > first["version"].as_u64().unwrap() {
            break status;
        }
        assert!(
            Instant::now() < deadline,
            "the model shown was never updated: {status}"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let training = &later["training"];
    assert_eq!(training["iterations"], 5000, "{later}");
    assert!(training["iteration"].as_u64().unwrap() >= 1, "{later}");
    assert!(
        training["shown_iteration"].as_u64().unwrap() >= 1,
        "{later}"
    );
    assert!(
        training["loss"].as_f64().is_some_and(|l| l > 0.0),
        "{later}"
    );
    assert!(
        training["psnr"].as_f64().is_some_and(|p| p > 0.0),
        "{later}"
    );
    request["id"] = json!(2);
    socket
        .send(tungstenite::Message::text(request.to_string()))
        .unwrap();
    let (second, second_png) = read_reply(&mut socket).expect("a frame");
    assert!(second["version"].as_u64() > first["version"].as_u64());
    assert_ne!(first_png, second_png, "the newer model looks the same");
    // And again: updates keep coming while the page is open.
    let deadline = Instant::now() + Duration::from_secs(20);
    while version(&viewer.json("/api/status")) <= version(&later) {
        assert!(Instant::now() < deadline, "no second update");
        std::thread::sleep(Duration::from_millis(100));
    }
}
