//! [`serve_dir`]: a small static file server for the built page (`cargo xtask web --serve` and
//! the browser test). Native only. GET and HEAD of files under one folder, on 127.0.0.1, one
//! thread per connection; `application/wasm` for the module (streaming compilation needs it);
//! the cross-origin isolation headers, which give `performance.now()` its fine resolution.

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};

/// A server running on a background thread; it serves until the process ends.
#[derive(Debug)]
pub struct Server {
    addr: SocketAddr,
}

impl Server {
    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `http://127.0.0.1:<port>/`.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }
}

/// Serve the files under `root` on 127.0.0.1:`port` (0: any free port).
pub fn serve_dir(root: &Path, port: u16) -> std::io::Result<Server> {
    let root = root.canonicalize()?;
    let listener = TcpListener::bind(("127.0.0.1", port))?;
    let addr = listener.local_addr()?;
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let root = root.clone();
            std::thread::spawn(move || {
                // A client that hangs up mid-answer is its own business.
                let _ = answer(&root, stream);
            });
        }
    });
    Ok(Server { addr })
}

fn content_type(path: &Path) -> &'static str {
    match path.extension().and_then(|e| e.to_str()).unwrap_or("") {
        "html" => "text/html; charset=utf-8",
        "js" | "mjs" => "text/javascript; charset=utf-8",
        "css" => "text/css; charset=utf-8",
        "wasm" => "application/wasm",
        "json" => "application/json",
        "png" => "image/png",
        "txt" | "md" | "bvh" => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}

/// The file a request path names under `root`, if it is one (no `..`, no query).
fn resolve(root: &Path, target: &str) -> Option<PathBuf> {
    let path = target.split(['?', '#']).next().unwrap_or("");
    let mut file = root.to_path_buf();
    for part in path.split('/').filter(|p| !p.is_empty()) {
        if part == ".." || part == "." || part.contains('\\') {
            return None;
        }
        file.push(part);
    }
    if file.is_dir() {
        file.push("index.html");
    }
    let file = file.canonicalize().ok()?;
    (file.starts_with(root) && file.is_file()).then_some(file)
}

fn answer(root: &Path, stream: TcpStream) -> std::io::Result<()> {
    let mut reader = BufReader::new(stream.try_clone()?);
    let mut request = String::new();
    reader.read_line(&mut request)?;
    // Skip the headers.
    let mut line = String::new();
    while reader.read_line(&mut line)? > 2 {
        line.clear();
    }
    let mut parts = request.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or("/"));
    let mut out = stream;
    let (status, body, kind) = if method != "GET" && method != "HEAD" {
        ("405 Method Not Allowed", Vec::new(), "text/plain")
    } else {
        match resolve(root, target).map(|f| (std::fs::read(&f), f)) {
            Some((Ok(bytes), file)) => ("200 OK", bytes, content_type(&file)),
            _ => ("404 Not Found", b"not found".to_vec(), "text/plain"),
        }
    };
    write!(
        out,
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\n\
         Cache-Control: no-store\r\nCross-Origin-Opener-Policy: same-origin\r\n\
         Cross-Origin-Embedder-Policy: require-corp\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    if method != "HEAD" {
        out.write_all(&body)?;
    }
    out.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_stay_inside_the_root() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .canonicalize()
            .expect("dir");
        assert!(resolve(&root, "/Cargo.toml").is_some());
        assert!(resolve(&root, "/src/lib.rs?x=1").is_some());
        assert!(resolve(&root, "/../../Cargo.toml").is_none());
        assert!(resolve(&root, "/src/../Cargo.toml").is_none());
        assert!(resolve(&root, "/missing.js").is_none());
        assert_eq!(content_type(Path::new("a/b.wasm")), "application/wasm");
    }
}
