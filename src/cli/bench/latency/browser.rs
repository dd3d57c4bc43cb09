//! The live page in headless Chromium (Debian's), driven over the DevTools protocol: the page
//! opened with `?latency=1` records when it first drew each pose, and the bench takes those
//! rows every quarter second (`window.lhmppTakeDraws()`).

use super::probe::{Sample, Stage};
use super::unix_ns;
use anyhow::{anyhow, bail, Context, Result};
use futures::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Whether `chromium` is on the PATH.
pub fn available() -> bool {
    std::env::var_os("PATH").is_some_and(|paths| {
        std::env::split_paths(&paths).any(|dir| dir.join("chromium").is_file())
    })
}

/// Chromium with the page open.
pub struct Page {
    chromium: Child,
    runtime: tokio::runtime::Runtime,
    ws: Socket,
    next: u64,
    session: String,
}

impl Page {
    /// Starts Chromium (profile in `profile`), opens the node's page on `port` and waits up to
    /// `timeout` for it to load.
    pub fn open(port: u16, profile: &Path, timeout: Duration) -> Result<Self> {
        let _ = std::fs::remove_dir_all(profile);
        let mut chromium = Command::new("chromium")
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--enable-unsafe-swiftshader",
                "--use-angle=swiftshader",
                "--remote-debugging-port=0",
                "--window-size=384,384",
                &format!("--user-data-dir={}", profile.display()),
                "about:blank",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .context("starting chromium")?;
        let mut lines = BufReader::new(chromium.stderr.take().expect("piped")).lines();
        let devtools = lines
            .by_ref()
            .map_while(Result::ok)
            .find_map(|l| {
                l.split_once("DevTools listening on ")
                    .map(|(_, u)| u.trim().to_owned())
            })
            .ok_or_else(|| anyhow!("chromium printed no DevTools address"))?;
        // Chromium keeps logging: its pipe is read to the end.
        std::thread::spawn(move || lines.for_each(drop));
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .context("tokio runtime")?;
        let ws = runtime
            .block_on(tokio_tungstenite::connect_async(devtools.as_str()))
            .context("connecting to chromium's DevTools")?
            .0;
        let mut page = Self {
            chromium,
            runtime,
            ws,
            next: 0,
            session: String::new(),
        };
        let target = page.call("Target.createTarget", json!({"url": "about:blank"}))?;
        let attached = page.call(
            "Target.attachToTarget",
            json!({"targetId": target["targetId"], "flatten": true}),
        )?;
        page.session = attached["sessionId"]
            .as_str()
            .ok_or_else(|| anyhow!("no DevTools session"))?
            .to_owned();
        page.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": 384, "height": 384, "deviceScaleFactor": 1, "mobile": false}),
        )?;
        let url = format!("http://127.0.0.1:{port}/?latency=1&bare=1");
        let deadline = Instant::now() + timeout;
        loop {
            page.call("Page.navigate", json!({"url": url}))?;
            std::thread::sleep(Duration::from_millis(500));
            if page.evaluate("typeof window.lhmppTakeDraws")? == json!("function") {
                return Ok(page);
            }
            if Instant::now() > deadline {
                bail!(
                    "the live page at {url} did not load in {} s",
                    timeout.as_secs()
                );
            }
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    /// The page's draws since the last call, as latencies from each pose's stamp.
    pub fn take_draws(&mut self) -> Result<Vec<Sample>> {
        let rows = self.evaluate("JSON.stringify(window.lhmppTakeDraws())")?;
        let rows: Vec<(String, f64, f64)> =
            serde_json::from_str(rows.as_str().unwrap_or("[]")).context("the page's draws")?;
        let now = unix_ns();
        Ok(rows
            .into_iter()
            // A stamp travels as a JS number (exact to 256 ns at today's epoch).
            .filter(|(_, stamp, _)| *stamp > 0.0 && (*stamp as i64) < now)
            .map(|(person, stamp, drawn_ms)| Sample {
                stage: Stage::Page,
                person,
                stamp_ns: stamp as i64,
                latency_ms: drawn_ms - stamp * 1e-6,
            })
            .collect())
    }

    fn evaluate(&mut self, expression: &str) -> Result<Value> {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true}),
        )?;
        Ok(r["result"]["value"].clone())
    }

    fn call(&mut self, method: &str, params: Value) -> Result<Value> {
        self.next += 1;
        let id = self.next;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if !self.session.is_empty() {
            msg["sessionId"] = json!(self.session);
        }
        let ws = &mut self.ws;
        self.runtime.block_on(async {
            ws.send(Message::Text(msg.to_string().into()))
                .await
                .with_context(|| format!("DevTools {method}"))?;
            loop {
                let reply = tokio::time::timeout(Duration::from_secs(30), ws.next())
                    .await
                    .map_err(|_| anyhow!("DevTools {method}: no reply in 30 s"))?
                    .ok_or_else(|| anyhow!("DevTools link closed"))??;
                let Message::Text(text) = reply else { continue };
                let v: Value = serde_json::from_str(&text)?;
                if v["id"] == json!(id) {
                    if let Some(e) = v.get("error") {
                        bail!("DevTools {method}: {e}");
                    }
                    return Ok(v["result"].clone());
                }
            }
        })
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        let _ = self.chromium.kill();
        let _ = self.chromium.wait();
    }
}
