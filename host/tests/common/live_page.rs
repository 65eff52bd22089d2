//! The live page's test harness (`live_view.rs`): `magcomp monitor --web` started on a free
//! port, its websocket, and the page in headless Chromium driven over the DevTools protocol.

use super::common::chromium_command;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Starts `magcomp monitor --web` on a free port; returns it and the page's address.
pub fn start_server(args: &[&str]) -> (Killed, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["monitor", "--web", "--listen", "127.0.0.1:0"])
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start magcomp monitor --web");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    let url = first
        .split_whitespace()
        .find(|w| w.starts_with("http://"))
        .unwrap_or_else(|| panic!("no address in {first:?}"))
        .to_string();
    (Killed(child), url)
}

/// `None` while the browser's DevTools server is not answering yet. HTTP/1.1 with the body
/// read to its `Content-Length`: that server does not answer HTTP/1.0 and keeps the
/// connection open.
pub fn http_get(host_port: &str, path: &str) -> Option<String> {
    let mut s = TcpStream::connect(host_port).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET {path} HTTP/1.1\r\nHost: {host_port}\r\n\r\n").ok()?;
    let mut r = BufReader::new(s);
    let mut len = 0;
    loop {
        let mut h = String::new();
        r.read_line(&mut h).ok()?;
        let h = h.trim_end();
        if h.is_empty() {
            break;
        }
        if let Some((k, v)) = h.split_once(':') {
            if k.eq_ignore_ascii_case("content-length") {
                len = v.trim().parse().ok()?;
            }
        }
    }
    let mut body = vec![0u8; len];
    r.read_exact(&mut body).ok()?;
    String::from_utf8(body).ok()
}

/// A child process killed when the test ends, passed or not (a failing assertion must not
/// leave a server or a browser running).
pub struct Killed(pub Child);
impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub type Ws = tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>;

pub fn ws_connect(url: &str) -> Ws {
    let (ws, _) = tungstenite::connect(url).unwrap();
    if let tungstenite::stream::MaybeTlsStream::Plain(s) = ws.get_ref() {
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    }
    ws
}

/// The page in Chromium, driven over the DevTools protocol.
pub struct Page {
    pub ws: Ws,
    next_id: u64,
    /// Console errors and uncaught exceptions the browser reported.
    pub console_errors: Vec<String>,
}

impl Page {
    pub fn open(url: &str, profile: &Path) -> (Killed, Page) {
        let chrome = chromium_command(profile)
            .args(["--remote-debugging-port=0", "--window-size=1200,1400", url])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromium");
        let chrome = Killed(chrome);
        let port_file = profile.join("DevToolsActivePort");
        let start = Instant::now();
        let port = loop {
            if let Some(p) = std::fs::read_to_string(&port_file)
                .ok()
                .and_then(|t| t.lines().next().map(String::from))
                .filter(|p| !p.is_empty())
            {
                break p;
            }
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "no DevTools port"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        let target = loop {
            let list: Value = http_get(&format!("127.0.0.1:{port}"), "/json/list")
                .and_then(|b| serde_json::from_str(&b).ok())
                .unwrap_or(Value::Null);
            let page = list.as_array().and_then(|a| {
                a.iter()
                    .find(|t| t["type"] == "page" && t["url"].as_str() == Some(url))
                    .and_then(|t| t["webSocketDebuggerUrl"].as_str().map(String::from))
            });
            if let Some(p) = page {
                break p;
            }
            assert!(start.elapsed() < Duration::from_secs(20), "no page target");
            std::thread::sleep(Duration::from_millis(50));
        };
        let mut page = Page {
            ws: ws_connect(&target),
            next_id: 1,
            console_errors: Vec::new(),
        };
        page.call("Runtime.enable", json!({}));
        (chrome, page)
    }

    /// Sends a command and returns its result, noting console events met on the way.
    pub fn call(&mut self, method: &str, params: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        let msg = json!({"id": id, "method": method, "params": params}).to_string();
        self.ws.send(tungstenite::Message::text(msg)).unwrap();
        loop {
            let m = self.ws.read().unwrap();
            let Ok(text) = m.to_text() else { continue };
            let v: Value = serde_json::from_str(text).unwrap();
            match v["method"].as_str() {
                Some("Runtime.consoleAPICalled") if v["params"]["type"] == "error" => {
                    self.console_errors.push(v["params"]["args"].to_string())
                }
                Some("Runtime.exceptionThrown") => self
                    .console_errors
                    .push(v["params"]["exceptionDetails"].to_string()),
                _ => {}
            }
            if v["id"] == id {
                return v["result"].clone();
            }
        }
    }

    /// The page's `#plotted` element, parsed (`Null` before the first draw).
    pub fn plotted(&mut self) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": "document.getElementById('plotted').textContent",
                   "returnByValue": true}),
        );
        serde_json::from_str(r["result"]["value"].as_str().unwrap_or("")).unwrap_or(Value::Null)
    }

    pub fn text_of(&mut self, id: &str) -> String {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": format!("document.getElementById('{id}').textContent"),
                   "returnByValue": true}),
        );
        r["result"]["value"].as_str().unwrap_or("").to_string()
    }
}

pub fn numbers(v: &Value) -> Vec<Option<f64>> {
    v.as_array()
        .map(|a| a.iter().map(Value::as_f64).collect())
        .unwrap_or_default()
}

/// Reads websocket messages until `stop` says so (or 10 s pass).
pub fn read_until(ws: &mut Ws, mut stop: impl FnMut(&Value) -> bool) -> Vec<Value> {
    let start = Instant::now();
    let mut got = Vec::new();
    while start.elapsed() < Duration::from_secs(10) {
        let m = ws.read().unwrap();
        let Ok(t) = m.to_text() else { continue };
        let v: Value = serde_json::from_str(t).unwrap();
        // A backlog (what was sent before this client subscribed) is its messages.
        let batch = match v["messages"].as_array() {
            Some(b) if v["kind"] == "backlog" => b.clone(),
            _ => vec![v],
        };
        for v in batch {
            let done = stop(&v);
            got.push(v);
            if done {
                return got;
            }
        }
    }
    got
}
