//! The local web server of the live view: one page, the vendored uPlot, and a websocket
//! that pushes every record as JSON. A page opened late first gets the last
//! [`BACKLOG`] messages so its strips start full, and each stream's latest FOM table
//! (however long ago it was computed).

use super::feed::Message;
use super::source::{follow, Input};
use anyhow::{Context, Result};
use axum::extract::ws::{self, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use tokio::sync::broadcast;

/// Messages kept per stream for a page that connects late: two minutes at the board's 10 Hz.
pub const BACKLOG: usize = 1200;
/// Messages queued per page before a slow one skips ahead (it is told by a gap in `seq`).
const QUEUE: usize = 4096;

const PAGE: &str = include_str!("../../assets/live.html");
const UPLOT_JS: &str = include_str!("../../assets/uplot/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("../../assets/uplot/uPlot.min.css");

/// Settings of the page.
#[derive(Clone, Debug)]
pub struct PageSettings {
    /// Acceptance band of the 4th difference (± nT).
    pub d4_band_nt: f64,
    /// Records kept on the strips.
    pub window_records: usize,
}

struct Shared {
    page: String,
    tx: broadcast::Sender<Arc<str>>,
    backlog: Mutex<VecDeque<Arc<str>>>,
    /// Messages kept: [`BACKLOG`] per stream.
    backlog_len: usize,
    /// Each stream's latest FOM table message: kept apart from the backlog, which a table
    /// computed more than [`BACKLOG`] records ago has left.
    fom: Mutex<Vec<Option<Arc<str>>>>,
}

/// The page with its settings and the streams' names filled in.
pub fn page_html(s: &PageSettings, names: &[&str]) -> String {
    // `<` escaped so no name can close the page's script element.
    let names = serde_json::to_string(names)
        .unwrap_or_else(|_| "[]".into())
        .replace('<', "\\u003c");
    let flags = serde_json::to_string(&crate::board::flag_names::FLAG_NAMES)
        .unwrap_or_else(|_| "[]".into());
    PAGE.replace("__D4_BAND_NT__", &format!("{}", s.d4_band_nt))
        .replace("__FLAG_NAMES__", &flags)
        .replace("__WINDOW_RECORDS__", &s.window_records.to_string())
        .replace("__STREAMS__", &names)
}

/// A message and the input (sensor) it came from, as sent to the page.
#[derive(serde::Serialize)]
struct Tagged<'a> {
    stream: usize,
    #[serde(flatten)]
    message: &'a Message,
}

/// Serves the live view of `inputs` (one board output each: several sensors) on `listen`
/// until the process is stopped. Prints the address it listens on
/// (`live view: http://…/`) once bound, so a caller that asked for port 0 learns which
/// port it got.
/// `save` receives the first input's records as `monitor --save` writes them.
pub fn serve(
    inputs: Vec<Input>,
    mut save: Option<Box<dyn std::io::Write + Send>>,
    listen: &str,
    settings: &PageSettings,
) -> Result<()> {
    anyhow::ensure!(!inputs.is_empty(), "no input to follow");
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the web server's runtime")?;
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .with_context(|| format!("listening on {listen}"))?;
        let addr = listener.local_addr()?;
        let names: Vec<&str> = inputs.iter().map(|i| i.name.as_str()).collect();
        crate::outln!(
            "live view: http://{addr}/  (following {})",
            names.join(", ")
        );
        use std::io::Write;
        std::io::stdout().flush()?;
        let (tx, _) = broadcast::channel(QUEUE);
        let shared = Arc::new(Shared {
            page: page_html(settings, &names),
            tx,
            backlog: Mutex::new(VecDeque::with_capacity(BACKLOG * inputs.len())),
            backlog_len: BACKLOG * inputs.len(),
            fom: Mutex::new(vec![None; inputs.len()]),
        });
        for (stream, input) in inputs.into_iter().enumerate() {
            let feeder = shared.clone();
            // A port is read with blocking calls (a serial device is a file): its own thread.
            let save = save.take();
            std::thread::spawn(move || follow(&input, save, |m| publish(&feeder, stream, &m)));
        }
        let app = Router::new()
            .route("/", get(index))
            .route("/uPlot.iife.min.js", get(uplot_js))
            .route("/uPlot.min.css", get(uplot_css))
            .route("/ws", get(upgrade))
            .with_state(shared);
        axum::serve(listener, app).await.context("web server")
    })
}

fn publish(shared: &Shared, stream: usize, message: &Message) {
    let Ok(json) = serde_json::to_string(&Tagged { stream, message }) else {
        return;
    };
    let json: Arc<str> = json.into();
    if matches!(message, Message::Fom(_)) {
        let mut f = shared.fom.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(slot) = f.get_mut(stream) {
            *slot = Some(json.clone());
        }
    }
    // Under the backlog's lock, so a page connecting now gets each message once: in its
    // backlog or from its subscription, never both, never neither.
    let mut b = shared.backlog.lock().unwrap_or_else(|p| p.into_inner());
    if b.len() >= shared.backlog_len {
        b.pop_front();
    }
    b.push_back(json.clone());
    // No page open is not an error.
    let _ = shared.tx.send(json);
}

async fn index(State(s): State<Arc<Shared>>) -> Html<String> {
    Html(s.page.clone())
}

async fn uplot_js() -> Response {
    ([(header::CONTENT_TYPE, "text/javascript")], UPLOT_JS).into_response()
}

async fn uplot_css() -> Response {
    ([(header::CONTENT_TYPE, "text/css")], UPLOT_CSS).into_response()
}

async fn upgrade(ws: WebSocketUpgrade, State(s): State<Arc<Shared>>) -> Response {
    ws.on_upgrade(move |socket| push(socket, s))
}

/// Sends the backlog, then every new message, until the page goes away.
async fn push(mut socket: WebSocket, s: Arc<Shared>) {
    let (backlog, mut rx) = {
        let b = s.backlog.lock().unwrap_or_else(|p| p.into_inner());
        let f = s.fom.lock().unwrap_or_else(|p| p.into_inner());
        // The latest tables first: a copy still in the backlog comes again later and the
        // page shows the latest it has got either way.
        let joined: Vec<&str> = f.iter().flatten().chain(b.iter()).map(|m| &**m).collect();
        (
            format!(
                "{{\"kind\":\"backlog\",\"messages\":[{}]}}",
                joined.join(",")
            ),
            s.tx.subscribe(),
        )
    };
    if socket
        .send(ws::Message::Text(backlog.into()))
        .await
        .is_err()
    {
        return;
    }
    loop {
        tokio::select! {
            m = rx.recv() => match m {
                Ok(json) => {
                    let text: &str = &json;
                    if socket.send(ws::Message::Text(text.into())).await.is_err() {
                        return;
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return,
            },
            // The page closed (or sent something: it has nothing to say, ignored).
            r = socket.recv() => if matches!(r, None | Some(Err(_)) | Some(Ok(ws::Message::Close(_)))) {
                return;
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_gets_every_setting_and_the_flag_names_from_the_one_list() {
        let s = PageSettings {
            d4_band_nt: 0.5,
            window_records: 600,
        };
        let page = page_html(&s, &["board </script>"]);
        assert!(!page.contains("__"), "a placeholder is left");
        let names = serde_json::to_string(&crate::board::flag_names::FLAG_NAMES).unwrap();
        assert!(page.contains(&format!("const FLAG_NAMES = {names};")));
        assert!(
            page.contains("board \\u003c/script>"),
            "a name closes the script"
        );
    }
}
