//! Helpers shared by the `nerf` and `nsff` command-line tests. Integration tests of one crate
//! cannot import another's, so both `crates/*/tests/cli.rs` include this file with `#[path]`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `cmd` and returns its output, failing the test with both streams if it failed.
pub fn run(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("spawn");
    assert!(
        out.status.success(),
        "{:?} failed\nstdout:\n{}\nstderr:\n{}",
        cmd,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A fresh, empty directory `<tmp>/<prefix>-<name>-<pid>`.
pub fn temp(prefix: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("{prefix}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The value after `mean_psnr` on the last line of stdout.
pub fn mean_psnr(out: &Output) -> f64 {
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or_default();
    last.strip_prefix("mean_psnr ")
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("last line: {last}"))
}

/// PSNR of rendered PNGs (`renders/0000.png`, … in file order) against the scene's test PNGs
/// composited on white, computed here independently of the program's own evaluation.
pub fn score_pngs(renders: &Path, data: &Path) -> f64 {
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("transforms_test.json")).unwrap()).unwrap();
    let frames = json["frames"].as_array().unwrap();
    let mut total = 0.0;
    for (k, f) in frames.iter().enumerate() {
        let file = f["file_path"].as_str().unwrap().trim_start_matches("./");
        let gt = image::open(data.join(format!("{file}.png")))
            .unwrap()
            .to_rgba32f();
        let ours = image::open(renders.join(format!("{k:04}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!(gt.dimensions(), ours.dimensions());
        let mut se = 0.0f64;
        for (g, o) in gt.pixels().zip(ours.pixels()) {
            let a = g[3];
            for c in 0..3 {
                let want = g[c] * a + (1.0 - a);
                se += (want as f64 - o[c] as f64 / 255.0).powi(2);
            }
        }
        let mse = se / (3 * gt.width() * gt.height()) as f64;
        total += -10.0 * mse.log10();
    }
    total / frames.len() as f64
}

/// Trains `data` with `bin train … args` twice under `dir`: once uninterrupted, once killed
/// (SIGKILL) after `kill_after` logged steps and a checkpoint, then `--resume`d. Returns the
/// evaluated PSNR of both and the resumed run's stderr.
pub fn kill_and_resume(
    bin: &str,
    data: &Path,
    dir: &Path,
    args: &[&str],
    kill_after: usize,
) -> (f64, f64, String) {
    let train = |out: &Path| {
        let mut cmd = Command::new(bin);
        cmd.arg("train").arg(data).arg("--out").arg(out);
        cmd
    };
    let eval = |out: &Path| mean_psnr(&run(Command::new(bin).arg("eval").arg(out)));
    let reference = dir.join("reference");
    run(train(&reference).args(args));
    let want = eval(&reference);

    let killed = dir.join("killed");
    let mut child = train(&killed).args(args).spawn().unwrap();
    let metrics = killed.join("metrics.jsonl");
    let start = std::time::Instant::now();
    loop {
        let steps = std::fs::read_to_string(&metrics)
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if steps >= kill_after && killed.join("checkpoint.bin").exists() {
            break;
        }
        assert!(start.elapsed().as_secs() < 300, "training did not progress");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL on Unix
    child.wait().unwrap();
    let out = run(train(&killed).arg("--resume").arg("--no-render"));
    let got = eval(&killed);
    eprintln!("uninterrupted {want:.3} dB, killed and resumed {got:.3} dB");
    (want, got, String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A PLY file as a generic reader sees it (written here from the format's specification, not
/// from the writer): per element, its name, and per record its scalar properties (as f64) and
/// list properties.
#[derive(Debug, Default)]
pub struct Ply {
    pub elements: Vec<PlyElement>,
}

#[derive(Debug, Default)]
pub struct PlyElement {
    pub name: String,
    /// Scalar property names, in order.
    pub scalars: Vec<String>,
    /// Per record: scalar values, then the lists.
    pub records: Vec<(Vec<f64>, Vec<Vec<i64>>)>,
}

impl Ply {
    pub fn element(&self, name: &str) -> &PlyElement {
        self.elements
            .iter()
            .find(|e| e.name == name)
            .unwrap_or_else(|| panic!("no element {name}"))
    }
}

impl PlyElement {
    pub fn column(&self, name: &str) -> Vec<f64> {
        let k = self
            .scalars
            .iter()
            .position(|s| s == name)
            .unwrap_or_else(|| panic!("no property {name}"));
        self.records.iter().map(|r| r.0[k]).collect()
    }
}

/// A property in a PLY header: name, value type, and for a list the type of its count.
type PlyProperty = (String, String, Option<String>);

/// Reads a `binary_little_endian 1.0` PLY; panics (failing the test) on anything malformed,
/// including bytes left over after the last element.
pub fn read_ply(path: &Path) -> Ply {
    let bytes = std::fs::read(path).unwrap();
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .expect("end_header")
        + end.len();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    let mut lines = header.lines();
    assert_eq!(lines.next(), Some("ply"));
    assert_eq!(lines.next(), Some("format binary_little_endian 1.0"));
    let mut layout: Vec<(String, usize, Vec<PlyProperty>)> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["comment", ..] | ["end_header"] => {}
            ["element", name, n] => layout.push((name.to_string(), n.parse().unwrap(), Vec::new())),
            ["property", "list", count, ty, name] => {
                layout
                    .last_mut()
                    .unwrap()
                    .2
                    .push((name.to_string(), ty.to_string(), Some(count.to_string())))
            }
            ["property", ty, name] => {
                layout
                    .last_mut()
                    .unwrap()
                    .2
                    .push((name.to_string(), ty.to_string(), None))
            }
            _ => panic!("bad header line {line:?}"),
        }
    }
    let mut pos = at;
    let mut read = |ty: &str| -> f64 {
        let size = match ty {
            "char" | "uchar" | "int8" | "uint8" => 1,
            "short" | "ushort" | "int16" | "uint16" => 2,
            "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
            "double" | "float64" => 8,
            _ => panic!("unknown type {ty}"),
        };
        let b = &bytes[pos..pos + size];
        pos += size;
        match ty {
            "uchar" | "uint8" => b[0] as f64,
            "char" | "int8" => b[0] as i8 as f64,
            "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
            "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
            "int" | "int32" => i32::from_le_bytes(b.try_into().unwrap()) as f64,
            "uint" | "uint32" => u32::from_le_bytes(b.try_into().unwrap()) as f64,
            "float" | "float32" => f32::from_le_bytes(b.try_into().unwrap()) as f64,
            _ => f64::from_le_bytes(b.try_into().unwrap()),
        }
    };
    let mut ply = Ply::default();
    for (name, n, props) in &layout {
        let mut el = PlyElement {
            name: name.clone(),
            scalars: props
                .iter()
                .filter(|p| p.2.is_none())
                .map(|p| p.0.clone())
                .collect(),
            records: Vec::with_capacity(*n),
        };
        for _ in 0..*n {
            let (mut scalars, mut lists) = (Vec::new(), Vec::new());
            for (_, ty, count) in props {
                match count {
                    None => scalars.push(read(ty)),
                    Some(ct) => {
                        let len = read(ct) as usize;
                        lists.push((0..len).map(|_| read(ty) as i64).collect());
                    }
                }
            }
            el.records.push((scalars, lists));
        }
        ply.elements.push(el);
    }
    assert_eq!(pos, bytes.len(), "bytes after the last element");
    ply
}

/// Checks an exported mesh or point cloud: finite positions inside `aabb` (with a margin),
/// faces that index existing vertices, colours that are not all the same. Returns (vertices, faces).
pub fn check_ply(path: &Path, aabb: [[f64; 3]; 2]) -> (usize, usize) {
    let ply = read_ply(path);
    let v = ply.element("vertex");
    let xyz = ["x", "y", "z"].map(|c| v.column(c));
    for k in 0..v.records.len() {
        for d in 0..3 {
            let x = xyz[d][k];
            let margin = 0.01 * (aabb[1][d] - aabb[0][d]);
            assert!(
                x.is_finite() && x >= aabb[0][d] - margin && x <= aabb[1][d] + margin,
                "vertex {k}: {x}"
            );
        }
    }
    let red = v.column("red");
    assert!(red.iter().all(|&c| (0.0..=255.0).contains(&c)));
    assert!(
        red.iter().any(|&c| c != red[0]),
        "every vertex has the same colour"
    );
    let faces = ply.elements.iter().find(|e| e.name == "face").map_or(0, |f| {
        for (_, lists) in &f.records {
            assert_eq!(lists[0].len(), 3);
            assert!(lists[0].iter().all(|&i| i >= 0 && (i as usize) < v.records.len()));
        }
        f.records.len()
    });
    (v.records.len(), faces)
}

/// One HTTP/1.1 request to `addr` (host:port) over a plain socket: (status, headers, body).
pub fn http(addr: &str, method: &str, path: &str) -> (u16, String, Vec<u8>) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(120)))
        .unwrap();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: 0\r\n\r\n"
    )
    .unwrap();
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).unwrap();
    let split = bytes
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("end of headers");
    let head = String::from_utf8_lossy(&bytes[..split]).into_owned();
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .expect("status code");
    (status, head, bytes[split + 4..].to_vec())
}

/// Starts `bin view RUN_DIR --port 0` and returns the child and the host:port it printed.
pub fn start_viewer(
    bin: &str,
    run_dir: &Path,
) -> (
    std::process::Child,
    String,
    std::io::BufReader<std::process::ChildStdout>,
) {
    use std::io::BufRead;
    let mut child = Command::new(bin)
        .arg("view")
        .arg(run_dir)
        .args(["--port", "0"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|r| r.split('/').next())
        .unwrap_or_else(|| panic!("no URL in {line:?}"))
        .to_string();
    (child, addr, out)
}

/// Checks the viewer's HTTP API as a browser would use it, then stops it with SIGINT (Ctrl-C)
/// and checks that it exits cleanly. `channels` are those the run must offer.
pub fn check_viewer(bin: &str, run_dir: &Path, channels: &[&str], has_time: bool) {
    use std::io::Read;
    let (mut child, addr, mut out) = start_viewer(bin, run_dir);
    let (status, head, body) = http(&addr, "GET", "/");
    let page = String::from_utf8_lossy(&body);
    assert!(status == 200 && head.contains("text/html"), "{head}");
    assert!(
        page.contains("id=\"view\"") && !page.contains("<script src"),
        "the page loads nothing from elsewhere"
    );

    let (status, _, body) = http(&addr, "GET", "/info");
    assert_eq!(status, 200);
    let info: serde_json::Value = serde_json::from_slice(&body).unwrap();
    let offered: Vec<&str> = info["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap())
        .collect();
    assert_eq!(offered, channels);
    assert_eq!(!info["times"].as_array().unwrap().is_empty(), has_time);
    let start = &info["start"];
    let cam = format!(
        "azimuth={}&elevation={}&distance={}",
        start["azimuth"], start["elevation"], start["distance"]
    );

    for (k, channel) in channels.iter().enumerate() {
        let t0 = std::time::Instant::now();
        let (w, h) = (40 + 8 * k as u32, 30);
        let (status, head, body) = http(
            &addr,
            "GET",
            &format!("/frame?{cam}&width={w}&height={h}&channel={channel}&time=0.5"),
        );
        assert!(
            status == 200 && head.contains("image/png"),
            "{channel}: {status} {head}"
        );
        let img = image::load_from_memory(&body).unwrap();
        assert_eq!((img.width(), img.height()), (w, h), "{channel}");
        eprintln!(
            "viewer {channel} {w}x{h}: {:.0} ms",
            t0.elapsed().as_secs_f64() * 1e3
        );
    }
    for (method, path, want) in [
        ("GET", format!("/frame?{cam}&width=abc&height=30"), 400),
        (
            "GET",
            format!("/frame?{cam}&width=40&height=30&channel=nope"),
            400,
        ),
        ("GET", format!("/frame?{cam}&width=40&height=30&time=7"), 400),
        ("GET", "/frame".to_string(), 400),
        ("GET", "/frame?%ZZ=&&&=".to_string(), 400),
        ("GET", "/no/such/page".to_string(), 404),
        ("POST", "/".to_string(), 405),
    ] {
        let (status, _, body) = http(&addr, method, &path);
        assert_eq!(
            status,
            want,
            "{method} {path}: {}",
            String::from_utf8_lossy(&body)
        );
    }

    // Ctrl-C stops it cleanly.
    let ok = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let status = child.wait().unwrap();
    let mut rest = String::new();
    out.read_to_string(&mut rest).unwrap();
    assert!(
        status.success() && rest.contains("viewer stopped"),
        "{status:?} {rest}"
    );
}
