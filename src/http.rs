//! The little HTTP/1.0 a local page or stream needs: a request's path read, an answer written.
//! Only `GET` is answered; each connection carries one request.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;

/// The path of a `GET` request, from a head read within 2 s (at most 8 kB); `None` for
/// anything else.
pub fn requested(client: &mut TcpStream) -> Option<String> {
    client.set_read_timeout(Some(Duration::from_secs(2))).ok()?;
    let mut head = Vec::new();
    let mut buf = [0u8; 1024];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") && head.len() < 8192 {
        let n = client.read(&mut buf).ok().filter(|&n| n > 0)?;
        head.extend_from_slice(&buf[..n]);
    }
    let line = String::from_utf8_lossy(&head);
    let mut words = line.lines().next()?.split_whitespace();
    (words.next()? == "GET").then(|| words.next().map(str::to_string))?
}

/// Answers `200 OK` with `body` of type `content_type`, never cached.
pub fn ok(client: &mut TcpStream, content_type: &str, body: &[u8]) {
    let head = format!(
        "HTTP/1.0 200 OK\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-store\r\n\r\n",
        body.len()
    );
    let _ = client
        .write_all(head.as_bytes())
        .and_then(|()| client.write_all(body));
}

/// Answers `404 Not Found`, empty.
pub fn not_found(client: &mut TcpStream) {
    let _ = client.write_all(b"HTTP/1.0 404 Not Found\r\nContent-Length: 0\r\n\r\n");
}
