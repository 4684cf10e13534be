//! Camera URLs: their parts, shown without the password, and what an HTTP camera's server
//! answers when OpenCV cannot open its stream (FFmpeg does not say: a wrong path, wrong
//! credentials and a page that is not a stream all end in "cannot open").

use std::io::{Read, Write};
use std::time::Duration;

/// How long the server's answer is waited for (s).
pub const ANSWER_S: f64 = 2.0;

/// A URL's parts: `scheme://[user[:password]@]host[:port][/path…]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Url<'a> {
    pub scheme: &'a str,
    pub user: Option<&'a str>,
    pub password: Option<&'a str>,
    /// Host and port, as written.
    pub authority: &'a str,
    /// From the first `/`, `?` or `#` on (`""` when none).
    pub path: &'a str,
}

impl<'a> Url<'a> {
    /// The parts of `source`, or `None` when it is no URL (a device, a file).
    pub fn parse(source: &'a str) -> Option<Self> {
        let (scheme, rest) = source.split_once("://")?;
        let end = rest.find(['/', '?', '#']).unwrap_or(rest.len());
        let (authority, path) = rest.split_at(end);
        let (credentials, authority) = match authority.rsplit_once('@') {
            Some((c, a)) => (Some(c), a),
            None => (None, authority),
        };
        let (user, password) = match credentials.map(|c| c.split_once(':')) {
            Some(Some((u, p))) => (Some(u), Some(p)),
            Some(None) => (credentials, None),
            None => (None, None),
        };
        Some(Url {
            scheme,
            user,
            password,
            authority,
            path,
        })
    }
}

/// Query parameters and pipeline properties whose value is a secret (compared without case;
/// a GStreamer property ending in `-pw` is one too).
const SECRET_NAMES: [&str; 14] = [
    "password",
    "passwd",
    "pass",
    "pwd",
    "token",
    "access_token",
    "auth",
    "key",
    "apikey",
    "api_key",
    "secret",
    "signature",
    "sig",
    "credentials",
];

/// `source` as it may be shown and written, its secrets as `***`: a URL's credentials (a
/// password, and a user part without one, which cameras take as a token), secret query
/// parameters (`?password=…`, `&token=…`), and in a GStreamer pipeline the secret properties
/// (`user-pw=…`, `proxy-pw=…`) and every URL. The user of `user:password` stays shown.
pub fn redact(source: &str) -> String {
    let mut out = String::with_capacity(source.len());
    let mut rest = source;
    while !rest.is_empty() {
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        let (word, after) = rest.split_at(end);
        out.push_str(&redact_word(word));
        let space = after.len() - after.trim_start().len();
        out.push_str(&after[..space]);
        rest = &after[space..];
    }
    out
}

/// One word of a source: a URL, a `property=value` of a pipeline, or neither.
fn redact_word(word: &str) -> String {
    if let Some((name, value)) = word.split_once('=') {
        if !name.contains("://") && !name.contains(['?', '&']) {
            let value = match is_secret(name) || name.to_ascii_lowercase().ends_with("-pw") {
                true => "***".to_string(),
                false => redact_word(value),
            };
            return format!("{name}={value}");
        }
    }
    let quote = word.find(|c| c != '"' && c != '\'').unwrap_or(0);
    let (quotes, word) = word.split_at(quote);
    let (scheme, after) = match word.split_once("://") {
        Some(parts) => parts,
        None => return format!("{quotes}{word}"),
    };
    // The credentials end at the last `@` (a raw `/`, `?` or `#` in a password or token ends a
    // URL's authority early, so no parser finds them: all of it up to that `@` is hidden).
    let after = match after.rsplit_once('@') {
        Some((credentials, host)) => match Url::parse(word) {
            Some(u) if u.password.is_some() && !credentials.contains(['/', '?', '#']) => {
                format!("{}:***@{host}", u.user.unwrap_or(""))
            }
            _ => format!("***@{host}"),
        },
        None => after.to_string(),
    };
    format!("{quotes}{scheme}://{}", redact_query(&after))
}

/// A URL's tail with its secret query parameters' values as `***`.
fn redact_query(url: &str) -> String {
    let Some((head, query)) = url.split_once('?') else {
        return url.to_string();
    };
    let (query, fragment) = query.split_at(query.find('#').unwrap_or(query.len()));
    let pairs: Vec<String> = query
        .split('&')
        .map(|pair| match pair.split_once('=') {
            Some((name, _)) if is_secret(name) => format!("{name}=***"),
            _ => pair.to_string(),
        })
        .collect();
    format!("{head}?{}{fragment}", pairs.join("&"))
}

/// Whether a parameter named `name` holds a secret ([`SECRET_NAMES`]).
fn is_secret(name: &str) -> bool {
    SECRET_NAMES.iter().any(|s| s.eq_ignore_ascii_case(name))
}

/// A URL whose credentials hold a raw `/`, `?` or `#` (`http://lab:pa/ss@host/…`): its scheme
/// and what follows the last `@`. `None` when there is no such shape.
fn mangled_credentials(source: &str) -> Option<(&str, &str)> {
    let (scheme, rest) = source.split_once("://")?;
    let (credentials, after) = rest.rsplit_once('@')?;
    (credentials.contains(':') && credentials.contains(['/', '?', '#'])).then_some((scheme, after))
}

/// What to do about a camera URL whose password holds a character that ends a URL's host
/// part: percent-encode it. `None` for any other source.
pub fn credentials_hint(source: &str) -> Option<&'static str> {
    mangled_credentials(source)
        .map(|_| "a password holding /, ? or # must be percent-encoded in the URL (%2F, %3F, %23)")
}

/// What the server of an `http://` camera URL answers a GET of its path (with its credentials,
/// as HTTP basic authentication): its status line and content type, or why there is no answer.
/// `None` for other schemes.
pub fn answer(source: &str) -> Option<String> {
    let url = Url::parse(source).filter(|u| u.scheme.eq_ignore_ascii_case("http"))?;
    let address = if url.authority.contains(':') {
        url.authority.to_string()
    } else {
        format!("{}:80", url.authority)
    };
    let wait = Duration::from_secs_f64(ANSWER_S);
    let resolved = match std::net::ToSocketAddrs::to_socket_addrs(&address) {
        Ok(mut a) => a.next(),
        Err(e) => return Some(format!("{} cannot be resolved ({e})", url.authority)),
    };
    let Some(resolved) = resolved else {
        return Some(format!("{} cannot be resolved", url.authority));
    };
    let mut stream = match std::net::TcpStream::connect_timeout(&resolved, wait) {
        Ok(s) => s,
        Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
            return Some(format!(
                "nothing listens at {} (connection refused)",
                url.authority
            ))
        }
        Err(e) => return Some(format!("{} cannot be reached ({e})", url.authority)),
    };
    let path = if url.path.starts_with('/') {
        url.path
    } else {
        "/"
    };
    let auth = match url.user {
        Some(user) => format!(
            "Authorization: Basic {}\r\n",
            base64::Engine::encode(
                &base64::engine::general_purpose::STANDARD,
                format!("{user}:{}", url.password.unwrap_or("")).as_bytes()
            )
        ),
        None => String::new(),
    };
    let request = format!(
        "GET {path} HTTP/1.0\r\nHost: {}\r\n{auth}\r\n",
        url.authority
    );
    let _ = stream.set_read_timeout(Some(wait));
    if stream.write_all(request.as_bytes()).is_err() {
        return Some(format!("{} closed the connection", url.authority));
    }
    // The head: up to the blank line, or what came within the wait.
    let mut head = Vec::new();
    let mut buf = [0u8; 512];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") && head.len() < 8192 {
        match stream.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => head.extend_from_slice(&buf[..n]),
        }
    }
    let head = String::from_utf8_lossy(&head);
    let mut lines = head.lines();
    let Some(status) = lines.next().filter(|l| l.starts_with("HTTP/")) else {
        return Some(format!(
            "{} gave no HTTP answer within {ANSWER_S} s",
            url.authority
        ));
    };
    let status = status.split_once(' ').map_or(status, |(_, s)| s).trim();
    let content = lines
        .filter_map(|l| l.split_once(':'))
        .find(|(k, _)| k.trim().eq_ignore_ascii_case("content-type"))
        .map(|(_, v)| v.trim().to_string());
    Some(match content {
        Some(c) => format!("the server answers {status} ({c})"),
        None => format!("the server answers {status}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_split_into_their_parts() {
        let u = Url::parse("http://admin:s3cr:et@10.0.0.5:8080/video?x=1").unwrap();
        assert_eq!(
            (u.user, u.password, u.authority, u.path),
            (
                Some("admin"),
                Some("s3cr:et"),
                "10.0.0.5:8080",
                "/video?x=1"
            )
        );
        assert!(Url::parse("0").is_none());
    }

    /// Issue 44, item 11: a raw `/`, `?` or `#` in the password ends the authority early; the
    /// password is hidden all the same, and the hint says to percent-encode it.
    #[test]
    fn a_password_holding_a_slash_question_mark_or_hash_is_hidden() {
        for (url, shown) in [
            (
                "http://lab:pa/ss@host/left.mjpg",
                "http://***@host/left.mjpg",
            ),
            (
                "http://lab:pa?ss@host:81/left.mjpg",
                "http://***@host:81/left.mjpg",
            ),
            ("rtsp://admin:a#b/c@cam/live", "rtsp://***@cam/live"),
        ] {
            assert_eq!(redact(url), shown);
            assert!(!redact(url).contains("ss") || !url.contains("pa/ss"));
            assert!(credentials_hint(url).unwrap().contains("percent-encoded"));
        }
        assert_eq!(credentials_hint("http://lab:s3cret@cam/v"), None);
    }

    #[test]
    fn passwords_in_camera_urls_are_hidden_and_nothing_else_changes() {
        assert_eq!(
            redact("http://lab:s3cret@10.0.0.7:8080/stream.mjpg?x=1"),
            "http://lab:***@10.0.0.7:8080/stream.mjpg?x=1"
        );
        assert_eq!(
            redact("rtsp://admin:p@ss@cam/live"),
            "rtsp://admin:***@cam/live"
        );
        assert_eq!(credentials_hint("http://cam/a@b"), None);
        for plain in ["0", "/dev/video2", "left.avi", "http://cam:8080/video"] {
            assert_eq!(redact(plain), plain);
        }
    }

    /// Hostile probe 6 (issue 61): a token as the URL's user part (with or without a `/`), a
    /// `?password=…` and GStreamer's `user-pw=` were written to `capture.json` and printed.
    #[test]
    fn hostile_camera_secrets_are_never_written() {
        for (source, shown) in [
            ("http://tok3n@cam/v", "http://***@cam/v"),
            ("http://ab/cd+ef@cam:81/v", "http://***@cam:81/v"),
            (
                "http://cam/v.mjpg?user=lab&password=s3cret&fps=30",
                "http://cam/v.mjpg?user=lab&password=***&fps=30",
            ),
            ("http://cam/v?Token=abc#top", "http://cam/v?Token=***#top"),
            (
                "rtspsrc location=rtsp://cam/live user-id=lab user-pw=s3cret ! decodebin ! appsink",
                "rtspsrc location=rtsp://cam/live user-id=lab user-pw=*** ! decodebin ! appsink",
            ),
            (
                "souphttpsrc location=\"http://lab:s3cret@cam/v\" ! jpegdec ! appsink",
                "souphttpsrc location=\"http://lab:***@cam/v\" ! jpegdec ! appsink",
            ),
        ] {
            assert_eq!(redact(source), shown);
            for secret in ["tok3n", "cd+ef", "s3cret", "abc"] {
                assert!(!redact(source).contains(secret), "{source}");
            }
        }
    }
}
