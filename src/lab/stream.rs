//! A camera's Motion-JPEG stream over HTTP, as IP cameras and `mjpg-streamer` serve one: `GET
//! /NAME.mjpg` answers `multipart/x-mixed-replace`, one JPEG part per frame from the moment the
//! client connects. Every client gets every frame published after it connected (a short
//! backlog is kept for a client that is a little behind; one further behind loses the oldest);
//! anything else is answered 404.

use std::collections::VecDeque;
use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Condvar, Mutex};

/// Frames kept for clients that have not sent them yet.
const BACKLOG: usize = 64;

/// What a client did, for the truth: when it connected (lab clock, s), the first frame it
/// was sent (the camera's count of published frames), how many it was sent.
#[derive(Clone, Debug, PartialEq)]
pub struct Client {
    pub connected_s: f64,
    pub first: u64,
    pub sent: u64,
}

#[derive(Default)]
struct State {
    /// The newest frames, and the number of the first of them.
    frames: VecDeque<Arc<Vec<u8>>>,
    first: u64,
    closed: bool,
    clients: Vec<Client>,
}

/// One camera's published frames and the clients reading them.
#[derive(Default)]
pub struct Stream {
    state: Mutex<State>,
    published: Condvar,
}

impl Stream {
    /// Publishes the next frame (number [`Stream::published`] before the call) to every client.
    pub fn publish(&self, jpeg: Vec<u8>) {
        let mut s = self.state.lock().expect("stream");
        s.frames.push_back(Arc::new(jpeg));
        if s.frames.len() > BACKLOG {
            s.frames.pop_front();
            s.first += 1;
        }
        self.published.notify_all();
    }

    /// How many frames have been published.
    pub fn published(&self) -> u64 {
        let s = self.state.lock().expect("stream");
        s.first + s.frames.len() as u64
    }

    /// Ends every client's stream.
    pub fn close(&self) {
        self.state.lock().expect("stream").closed = true;
        self.published.notify_all();
    }

    /// Every client so far.
    pub fn clients(&self) -> Vec<Client> {
        self.state.lock().expect("stream").clients.clone()
    }
}

/// Serves `stream` at `http://ADDR/NAME.mjpg` from `listener`, a thread per client, until the
/// stream is closed; `now_s` is the lab's clock.
pub fn serve(
    listener: TcpListener,
    name: String,
    stream: Arc<Stream>,
    now_s: impl Fn() -> f64 + Send + Sync + Clone + 'static,
) {
    std::thread::spawn(move || {
        for client in listener.incoming() {
            if stream.state.lock().expect("stream").closed {
                return;
            }
            let Ok(client) = client else { continue };
            let (name, stream, now_s) = (name.clone(), stream.clone(), now_s.clone());
            std::thread::spawn(move || answer(client, &name, &stream, &now_s));
        }
    });
}

fn answer(mut client: TcpStream, name: &str, stream: &Stream, now_s: &dyn Fn() -> f64) {
    if crate::http::requested(&mut client).as_deref() != Some(&format!("/{name}.mjpg")) {
        crate::http::not_found(&mut client);
        return;
    }
    let head = "HTTP/1.0 200 OK\r\nCache-Control: no-cache\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n\r\n";
    if client.write_all(head.as_bytes()).is_err() {
        return;
    }
    let _ = client.set_nodelay(true);
    let (me, mut next) = {
        let mut s = stream.state.lock().expect("stream");
        let next = s.first + s.frames.len() as u64;
        s.clients.push(Client {
            connected_s: now_s(),
            first: next,
            sent: 0,
        });
        (s.clients.len() - 1, next)
    };
    loop {
        let jpeg = {
            let mut s = stream.state.lock().expect("stream");
            while !s.closed && next >= s.first + s.frames.len() as u64 {
                s = stream.published.wait(s).expect("stream");
            }
            if s.closed {
                return;
            }
            // A client too far behind starts again from the oldest frame kept.
            next = next.max(s.first);
            s.frames[(next - s.first) as usize].clone()
        };
        let part = format!(
            "--frame\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\n\r\n",
            jpeg.len()
        );
        let sent = client
            .write_all(part.as_bytes())
            .and_then(|()| client.write_all(&jpeg))
            .and_then(|()| client.write_all(b"\r\n"));
        if sent.is_err() {
            return;
        }
        next += 1;
        stream.state.lock().expect("stream").clients[me].sent += 1;
    }
}
