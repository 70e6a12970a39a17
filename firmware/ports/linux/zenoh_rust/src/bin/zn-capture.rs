//! zn-capture: the bench's Zenoh-side capture. Records every sample under a
//! key expression with its receive time and attachment, at rates a Python
//! subscriber cannot keep up with (one callback per sample, no interpreter).
//!
//!   zn-capture --connect tcp/router:7447 --key 'vehicle/can/**' \
//!              --ready-token bench/runs/<id>/capture/zenoh --out zenoh.tsv
//!
//! Output, one line per sample, flushed at least every 10 ms:
//!   <receive time, ns since the epoch>\t<key>\t<payload hex>\t<attachment hex or ->
//! The liveliness token is declared after the subscriber, on the same session,
//! so whoever sees the token knows the subscription is in place. Stops when
//! stdin reaches end of file (the orchestrator closes it), prints the sample
//! count on stderr. Multicast scouting is off; the endpoint is explicit.
//! --zenoh-config FILE: a Zenoh JSON5 config applied first (TLS, authentication: the
//! bench's capture identity, docs/access-control.md), as the bridge's --zenoh-config.
use std::fmt::Write as _;
use std::io::{Read, Write};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use zenoh::{Config, Wait};

const FLUSH_EVERY: Duration = Duration::from_millis(10);

struct Args {
    connect: String,
    mode: String,
    key: String,
    ready_token: Option<String>,
    out: String,
    zenoh_config: Option<String>,
}

fn usage() -> ! {
    eprintln!("usage: zn-capture --connect ENDPOINT [--mode client|peer] --key KEYEXPR [--ready-token KEY] --out FILE [--zenoh-config FILE]");
    std::process::exit(2);
}

fn parse_args() -> Args {
    let mut args = Args { connect: String::new(), mode: "client".into(), key: String::new(), ready_token: None, out: String::new(), zenoh_config: None };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().unwrap_or_else(|| usage());
        match flag.as_str() {
            "--connect" => args.connect = value,
            "--mode" => args.mode = value,
            "--key" => args.key = value,
            "--ready-token" => args.ready_token = Some(value),
            "--out" => args.out = value,
            "--zenoh-config" => args.zenoh_config = Some(value),
            _ => usage(),
        }
    }
    if args.connect.is_empty() || args.key.is_empty() || args.out.is_empty() {
        usage();
    }
    args
}

fn hex(out: &mut String, bytes: &[u8]) {
    for b in bytes {
        let _ = write!(out, "{b:02X}");
    }
}

fn main() {
    let args = parse_args();
    let mut config = match args.zenoh_config.as_deref() {
        Some(path) if !path.is_empty() => Config::from_file(path).unwrap_or_else(|e| {
            eprintln!("zn-capture: --zenoh-config {path}: {e}");
            std::process::exit(2)
        }),
        _ => Config::default(),
    };
    let set = |config: &mut Config, key: &str, value: String| {
        config.insert_json5(key, &value).unwrap_or_else(|e| {
            eprintln!("zn-capture: {key} = {value}: {e}");
            std::process::exit(2)
        })
    };
    set(&mut config, "mode", format!("{:?}", args.mode));
    set(&mut config, "scouting/multicast/enabled", "false".into());
    set(&mut config, "connect/endpoints", format!("[{:?}]", args.connect));
    if args.zenoh_config.as_deref().is_none_or(str::is_empty) {
        // a peer capture listens nowhere (Zenoh's default would be every interface): it connects out
        set(&mut config, "listen/endpoints", "[]".into());
    }
    // back within a second of a router restart (the bench's fault steps)
    set(&mut config, "connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}".into());
    let file = std::fs::File::create(&args.out).unwrap_or_else(|e| {
        eprintln!("zn-capture: {}: {e}", args.out);
        std::process::exit(2)
    });
    let writer = Arc::new(Mutex::new((std::io::BufWriter::with_capacity(1 << 20, file), 0u64)));
    let session = zenoh::open(config).wait().unwrap_or_else(|e| {
        eprintln!("zn-capture: cannot open a Zenoh session to {}: {e}", args.connect);
        std::process::exit(1)
    });
    let sink = writer.clone();
    let subscriber = session
        .declare_subscriber(args.key.clone())
        .callback(move |sample| {
            let t_ns = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
            let payload = sample.payload().to_bytes();
            let mut line = String::with_capacity(64 + 2 * payload.len());
            let _ = write!(line, "{t_ns}\t{}\t", sample.key_expr());
            hex(&mut line, &payload);
            line.push('\t');
            match sample.attachment() {
                Some(att) => hex(&mut line, &att.to_bytes()),
                None => line.push('-'),
            }
            line.push('\n');
            let mut w = sink.lock().unwrap();
            if w.0.write_all(line.as_bytes()).is_err() {
                eprintln!("zn-capture: write failed; stopping");
                std::process::exit(1);
            }
            w.1 += 1;
        })
        .wait()
        .unwrap_or_else(|e| {
            eprintln!("zn-capture: cannot subscribe to {}: {e}", args.key);
            std::process::exit(1)
        });
    let token = args.ready_token.as_ref().map(|key| {
        session.liveliness().declare_token(key.clone()).wait().unwrap_or_else(|e| {
            eprintln!("zn-capture: cannot declare token {key}: {e}");
            std::process::exit(1)
        })
    });
    let flusher = writer.clone();
    std::thread::spawn(move || loop {
        std::thread::sleep(FLUSH_EVERY);
        let _ = flusher.lock().unwrap().0.flush();
    });
    // runs until the orchestrator closes our stdin
    let mut sink_stdin = Vec::new();
    let _ = std::io::stdin().read_to_end(&mut sink_stdin);
    drop(token);
    let _ = subscriber.undeclare().wait();
    let mut w = writer.lock().unwrap();
    let _ = w.0.flush();
    eprintln!("zn-capture: {} samples on {}", w.1, args.key);
    let _ = session.close().wait();
}
