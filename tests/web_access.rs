//! Who gets the live page (`outputs.web`): a server on all interfaces without a token is
//! refused at startup; with a token, a request reaching it through another interface than
//! loopback without the token (or with a wrong one) is refused with 401, with it the page is
//! served; a WebSocket upgrade from another origin is refused with 403. The refusals are
//! printed.

use lhmpp::web::{LiveState, WebServer};
use std::io::{Read, Write};
use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpStream, UdpSocket};
use std::sync::Arc;
use std::time::Duration;

/// This host's address on its default route (no packet is sent), else loopback.
fn other_interface() -> IpAddr {
    UdpSocket::bind("0.0.0.0:0")
        .and_then(|s| {
            s.connect("192.0.2.1:9")?;
            s.local_addr()
        })
        .map(|a| a.ip())
        .ok()
        .filter(|ip| !ip.is_loopback() && !ip.is_unspecified())
        .unwrap_or(IpAddr::V4(Ipv4Addr::LOCALHOST))
}

/// The status line and body of a GET of `path` on `addr` with extra headers.
fn get(addr: SocketAddr, path: &str, headers: &[(&str, &str)]) -> (String, String) {
    let mut stream = TcpStream::connect_timeout(&addr, Duration::from_secs(5)).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut request = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n");
    if !headers.iter().any(|(n, _)| *n == "Connection") {
        request.push_str("Connection: close\r\n");
    }
    for (name, value) in headers {
        request.push_str(&format!("{name}: {value}\r\n"));
    }
    request.push_str("\r\n");
    stream.write_all(request.as_bytes()).unwrap();
    let mut response = Vec::new();
    let _ = stream.read_to_end(&mut response);
    let text = String::from_utf8_lossy(&response).into_owned();
    let status = text.lines().next().unwrap_or("").to_owned();
    let body = text.split("\r\n\r\n").nth(1).unwrap_or("").to_owned();
    (status, body)
}

#[test]
fn another_interface_without_the_token_is_refused_and_cross_origin_upgrades_too() {
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let state = Arc::new(LiveState::default());
    let any: SocketAddr = "0.0.0.0:0".parse().unwrap();
    let refused = WebServer::start(any, None, state.clone(), runtime.handle())
        .err()
        .expect("all interfaces without a token is refused");
    println!("start on 0.0.0.0 without a token: {refused}");
    assert!(refused.to_string().contains("--web-token"));

    let server = WebServer::start(any, Some("t0ken".into()), state, runtime.handle()).unwrap();
    let ip = other_interface();
    let addr = SocketAddr::new(ip, server.local_addr().port());
    println!("reaching the page through {ip}");

    let (status, body) = get(addr, "/", &[]);
    println!("GET / without the token: {status}: {body}");
    assert!(status.contains("401"), "{status}");
    assert!(body.contains("--web-token"), "{body}");
    let (status, body) = get(addr, "/?token=wrong", &[]);
    println!("GET / with a wrong token: {status}: {body}");
    assert!(
        status.contains("401") && body.contains("wrong token"),
        "{status} {body}"
    );
    let upgrade = [
        ("Upgrade", "websocket"),
        ("Connection", "Upgrade"),
        ("Sec-WebSocket-Version", "13"),
        ("Sec-WebSocket-Key", "dGhlIHNhbXBsZSBub25jZQ=="),
    ];
    let (status, body) = get(addr, "/ws", &upgrade);
    println!("WebSocket upgrade without the token: {status}: {body}");
    assert!(status.contains("401"), "{status}");

    let (status, body) = get(addr, "/?token=t0ken", &[]);
    assert!(status.contains("200"), "{status}");
    assert!(body.contains("lhmpp live avatars"));
    let mut cross = upgrade.to_vec();
    cross.push(("Origin", "http://evil.example"));
    let (status, body) = get(addr, "/ws?token=t0ken", &cross);
    println!("WebSocket upgrade from http://evil.example: {status}: {body}");
    assert!(
        status.contains("403") && body.contains("cross-origin"),
        "{status} {body}"
    );
    let origin = format!("http://{addr}");
    let mut same = upgrade.to_vec();
    same.push(("Origin", origin.as_str()));
    let (status, _) = get(addr, "/ws?token=t0ken", &same);
    assert!(status.contains("101"), "same-origin upgrade: {status}");
    // The libraries hold no personal data: served without the token.
    let (status, _) = get(addr, "/vendor/spark/LICENSE", &[]);
    assert!(status.contains("200"), "{status}");
    drop(server);
}

#[test]
fn the_node_refuses_a_non_loopback_page_without_a_token() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["run", "--config", "launch_configs/demo.yaml"])
        .args(["--set", "outputs.web=0.0.0.0:0", "--set", "outputs.dir=''"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("lhmpp run with outputs.web 0.0.0.0:0 and no --web-token: {stderr}");
    assert!(!out.status.success());
    assert!(stderr.contains("--web-token"), "{stderr}");
}
