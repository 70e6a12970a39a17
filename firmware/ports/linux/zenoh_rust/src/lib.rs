//! Zenoh port of zenoh-node for Linux: implements the C contract of
//! `firmware/ports/include/zn_port_zenoh.h` over the official `zenoh` crate.
//! Handles are boxed Rust objects behind opaque C pointers; every function
//! returns 0 on success and a negative value on failure, never panics across
//! the FFI boundary (panic = "abort" in the release profile as a backstop).

use std::cell::RefCell;
use std::collections::HashMap;
use std::ffi::{c_char, c_int, c_void, CStr};
use std::ptr;
use std::slice;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use zenoh::bytes::ZBytes;
use zenoh::key_expr::KeyExpr;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority, Reliability};
use zenoh::query::Queryable;
use zenoh::sample::{Locality, SampleKind};
use zenoh::session::{Transport, ZenohId};
use zenoh::{Config, Session, Wait};
use zenoh_buffers::ZBuf;

const ERR: c_int = -1;
/// zn_open's result for a configuration that cannot work (ZN_PORT_ERR_CONFIG).
const ERR_CONFIG: c_int = -2;
/// zn_put's result for a sample put while the session had no connection (ZN_PORT_UNROUTED).
const UNROUTED: c_int = 1;

/// A session's connections (Zenoh transports) to routers and peers, from its transport and link
/// events: Zenoh's put returns Ok whether or not one is open, and a connection closed and replaced
/// within milliseconds is seen by no poll of the routers.
/// One entry per peer: a transport seen at the start and in a live Put (opened as the listener was
/// declared) is one. A replaced transport's Delete comes before its successor's Put (zenoh 1.10.2:
/// the old one's closed() is called before it leaves the manager's table, and until then no new
/// transport to that peer is made).
/// A transport is told before the runtime has accepted it, and one it then refuses (a client's
/// second router, a client dialing a client) or one closed while it was being set up gets no
/// Delete: its manager closes it before it has a callback to call closed() on. An accepted one
/// tells its first link right after, a refused one never (zenoh-transport unicast/manager.rs,
/// init_new_transport_unicast: new_unicast(), whose handlers tell the Put before the runtime's
/// checks, then set_callback, then the link). So a transport counts from its Put, as a put it may
/// carry is never said lost, and one still without a link at two polls of the monitor in a row
/// (zn_poll_connections, 500 ms apart) is dropped.
#[derive(Default)]
struct Connections {
    peers: Mutex<HashMap<ZenohId, Seen>>,
    open: AtomicUsize, // the entries, read by every put without the lock
    closed: AtomicU64, // since the session opened
}

/// What the events told of a peer's transport.
#[derive(Clone, Copy, PartialEq)]
enum Seen {
    Told,     // its Put, no link yet
    Unlinked, // still no link at a poll: dropped at the next one
    Linked,   // accepted (or there at the start): open until its Delete
}

impl Connections {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<ZenohId, Seen>> {
        self.peers.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn event(&self, kind: SampleKind, transport: &Transport) {
        let mut peers = self.lock();
        if kind == SampleKind::Delete {
            peers.remove(transport.zid());
            self.closed.fetch_add(1, Ordering::Relaxed);
        } else {
            // a multicast group's peers tell no link
            peers.insert(*transport.zid(), if transport.is_multicast() { Seen::Linked } else { Seen::Told });
        }
        self.open.store(peers.len(), Ordering::Relaxed);
    }

    /// A link added: its transport is accepted. One of a transport no longer here (closed before
    /// its link was told, or dropped) is not taken for a new one.
    fn link(&self, kind: SampleKind, peer: &ZenohId) {
        if kind == SampleKind::Put {
            if let Some(seen) = self.lock().get_mut(peer) {
                *seen = Seen::Linked;
            }
        }
    }

    /// The monitor's poll: drops the transports that told no link since the poll before.
    fn poll(&self) {
        let mut peers = self.lock();
        peers.retain(|_, seen| *seen != Seen::Unlinked);
        for seen in peers.values_mut().filter(|seen| **seen == Seen::Told) {
            *seen = Seen::Unlinked;
        }
        self.open.store(peers.len(), Ordering::Relaxed);
    }

    /// The peers already connected when the listeners were declared. Not the listener's history:
    /// it lists them through each transport's links, which the low-latency transport reads with
    /// Tokio's current runtime (none on a C thread: zenoh-transport panics).
    fn seed(&self, peers: impl Iterator<Item = ZenohId>) {
        let mut set = self.lock();
        for peer in peers {
            set.entry(peer).or_insert(Seen::Linked); // one told meanwhile waits for its link
        }
        self.open.store(set.len(), Ordering::Relaxed);
    }

    fn none_open(&self) -> bool {
        self.open.load(Ordering::Relaxed) == 0
    }

    #[cfg(test)]
    fn holds(&self, peer: &ZenohId) -> bool {
        self.lock().contains_key(peer)
    }
}

pub struct ZnSession(Session, Arc<Connections>);
pub struct ZnPublisher(Publisher<'static>, Arc<Connections>);
pub struct ZnSubscriber(Subscriber<()>);
pub struct ZnToken(LivelinessToken);
pub struct ZnQueryable(Queryable<()>);

#[repr(C)]
pub struct ZnSessionConfig {
    mode: c_int,
    connect: *const c_char,
    listen: *const c_char,
    config_file: *const c_char,
    compression: c_int,
    rx_message_max: usize,
    low_latency: c_int,
}

#[repr(C)]
pub struct ZnQos {
    priority: u8,
    congestion: c_int,
    express: u8,
    best_effort: u8,
}

type SampleCb = extern "C" fn(*const u8, usize, *const u8, usize, u64, *mut c_void);
type QueryCb = extern "C" fn(*mut c_char, usize, *mut c_void) -> usize;

/// The C side's context pointer; the C code synchronises its own state.
#[derive(Clone, Copy)]
struct Ctx(*mut c_void);
unsafe impl Send for Ctx {}
unsafe impl Sync for Ctx {}

/// A reply's first buffer: one bus's stats take about 1.2 KiB; more grow it (reply_text).
const STATS_REPLY_FIRST: usize = 4096;
/// A bound on a reply's buffer (the stats of 8 buses with 8 QoS classes each are 12-18 KiB).
const STATS_REPLY_MAX: usize = 1 << 20;
const OPEN_RETRY_MIN: std::time::Duration = std::time::Duration::from_millis(250);
const OPEN_RETRY_MAX: std::time::Duration = std::time::Duration::from_millis(4000);

/// Zenoh's thread pools for the bridge unless the user set ZENOH_RUNTIME (zenoh-runtime reads it
/// once, at its first use). A tokio socket belongs to the runtime whose context created it:
/// the router link is opened inside zn_open's `.wait()` (the app runtime) and reopened after a
/// router restart on the net runtime, so without this every sample woke app-0 (or net-0) in
/// epoll_wait, which woke an rx worker through the rx runtime's inject queue, which woke the
/// other rx worker (tokio: the last searching worker wakes another). With app, net and acc
/// handed over to rx, the link's events reach the rx worker that then reads it itself.
/// tx stays apart (a callback's reply never waits for its own thread).
const ZENOH_RUNTIME_DEFAULT: &str = "(app: (handover: rx), net: (handover: rx), acc: (handover: rx))";

fn c_str<'a>(p: *const c_char) -> Option<&'a str> {
    if p.is_null() {
        return None;
    }
    unsafe { CStr::from_ptr(p) }.to_str().ok()
}

fn endpoints_json(list: &str) -> String {
    let items: Vec<String> = list
        .split(',')
        .map(str::trim)
        .filter(|e| !e.is_empty())
        .map(|e| format!("{e:?}"))
        .collect();
    format!("[{}]", items.join(","))
}

fn build_config(cfg: &ZnSessionConfig) -> Result<Config, String> {
    let mut config = match c_str(cfg.config_file) {
        Some(path) if !path.is_empty() => Config::from_file(path).map_err(|e| format!("{path}: {e}"))?,
        _ => Config::default(),
    };
    let mode = match cfg.mode {
        0 => "client",
        1 => "peer",
        2 => "router",
        m => return Err(format!("mode {m} is not 0, 1 or 2")),
    };
    let mut set = |key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .map_err(|e| format!("{key} = {value}: {e}"))
    };
    set("mode", format!("{mode:?}"))?;
    // Network safety: no multicast discovery, ever; endpoints are explicit.
    set("scouting/multicast/enabled", "false".into())?;
    if let Some(connect) = c_str(cfg.connect).filter(|s| !s.trim().is_empty()) {
        set("connect/endpoints", endpoints_json(connect))?;
    }
    if let Some(listen) = c_str(cfg.listen).filter(|s| !s.trim().is_empty()) {
        set("listen/endpoints", endpoints_json(listen))?;
    } else if c_str(cfg.config_file).is_none_or(str::is_empty) {
        // Network safety: a peer or router listens only where it is told (--listen, or the user's
        // config file); Zenoh's default would be every interface (tcp/[::]:0, tcp/[::]:7447)
        set("listen/endpoints", "[]".into())?;
    }
    if cfg.compression != 0 {
        set("transport/unicast/compression/enabled", "true".into())?;
    }
    // Zenoh's low-latency transport writes each sample from the caller's thread: no transmit
    // task to wake per put (docs/bridge.md). It has no QoS, and Zenoh refuses both at once.
    // Negotiated: with a router that does not enable it too, the link is the universal one.
    if cfg.low_latency != 0 {
        set("transport/unicast/lowlatency", "true".into())?;
        set("transport/unicast/qos/enabled", "false".into())?;
    }
    // A fragmented message larger than the bridge can use is dropped by Zenoh's
    // defragmenter instead of being reassembled whole (its default allows 1 GiB).
    if cfg.rx_message_max > 0 {
        set("transport/link/rx/max_message_size", cfg.rx_message_max.to_string())?;
    }
    // One connection attempt per open: zn_open retries with its own logged
    // backoff, so a bridge started before its router waits for it, never exits.
    set("connect/timeout_ms", "0".into())?;
    set("connect/exit_on_failure", "false".into())?;
    // (retry is optional in the schema: set it as a whole object)
    set(
        "connect/retry",
        "{period_init_ms: 250, period_max_ms: 2000, period_increase_factor: 2}".into(),
    )?;
    check_tls_files(&config)?;
    check_protocols(&config)?;
    Ok(config)
}

/// The link protocols this build's Zenoh carries (Cargo.toml: TCP and TLS always, the
/// port's transport_* features for more).
fn built_protocols() -> Vec<&'static str> {
    let mut built = vec!["tcp", "tls"];
    for (on, protocol) in [
        (cfg!(feature = "transport_udp"), "udp"),
        (cfg!(feature = "transport_quic"), "quic"),
        (cfg!(feature = "transport_ws"), "ws"),
        (cfg!(feature = "transport_unixsock-stream"), "unixsock-stream"),
    ] {
        if on {
            built.push(protocol);
        }
    }
    built
}

/// Zenoh treats an endpoint of a protocol it was built without like an absent router, and a
/// client retries forever: refuse it here, naming what this build has.
fn check_protocols(config: &Config) -> Result<(), String> {
    let built = built_protocols();
    for key in ["connect/endpoints", "listen/endpoints"] {
        let Ok(json) = config.get_json(key) else { continue };
        // a list of endpoint strings, or one list per mode: every string with a '/' is one
        for endpoint in json_strings(&json) {
            let Some((protocol, _)) = endpoint.split_once('/') else { continue };
            if !built.contains(&protocol) {
                return Err(format!(
                    "{key}: {endpoint}: this build's Zenoh has no {protocol} links (it has {}; \
                     the port's Cargo features transport_udp, transport_quic, transport_ws add more)",
                    built.join(", ")
                ));
            }
        }
    }
    Ok(())
}

/// The string values of a JSON text (an escaped character is taken as itself).
fn json_strings(json: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut chars = json.chars();
    while let Some(c) = chars.next() {
        if c != '"' {
            continue;
        }
        let mut s = String::new();
        while let Some(c) = chars.next() {
            match c {
                '"' => break,
                '\\' => {
                    if let Some(escaped) = chars.next() {
                        s.push(escaped);
                    }
                }
                c => s.push(c),
            }
        }
        out.push(s);
    }
    out
}

/// Zenoh reads TLS files only when a link opens, and a client retries its
/// connection forever: an unreadable file would look like an absent router.
/// Read them here, so a wrong path is a configuration error at once.
fn check_tls_files(config: &Config) -> Result<(), String> {
    for field in [
        "root_ca_certificate",
        "listen_private_key",
        "listen_certificate",
        "connect_private_key",
        "connect_certificate",
    ] {
        let key = format!("transport/link/tls/{field}");
        let Ok(json) = config.get_json(&key) else { continue };
        // a set field is a JSON string ("/path"), an unset one null
        let Some(path) = json.strip_prefix('"').and_then(|j| j.strip_suffix('"')) else { continue };
        if let Err(e) = std::fs::File::open(&path) {
            return Err(format!("{key} = {path}: {e}"));
        }
    }
    Ok(())
}

/// The session with its connections, known from its transport events from now on.
fn watched(session: Session) -> zenoh::Result<ZnSession> {
    let connections = Arc::new(Connections::default());
    let (seen, linked) = (connections.clone(), connections.clone());
    // Links first: a transport whose Put is seen has its link seen too.
    session
        .info()
        .link_events_listener()
        .callback(move |event| linked.link(event.kind(), event.link().zid()))
        .background()
        .wait()?;
    // Closes from the transports, not the links: one closed by its peer, or the low-latency
    // transport's on a failure, tells no link event.
    session
        .info()
        .transport_events_listener()
        .callback(move |event| seen.event(event.kind(), event.transport()))
        .background()
        .wait()?;
    let info = session.info();
    connections.seed(info.routers_zid().wait().chain(info.peers_zid().wait()));
    Ok(ZnSession(session, connections))
}

#[no_mangle]
pub extern "C" fn zn_open(cfg: *const ZnSessionConfig, out: *mut *mut ZnSession) -> c_int {
    if cfg.is_null() || out.is_null() {
        return ERR;
    }
    // before anything starts Zenoh's runtimes; the C side starts no thread that reads the
    // environment before zn_open (edition 2021: set_var is safe, not yet `unsafe`)
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        std::env::set_var("ZENOH_RUNTIME", ZENOH_RUNTIME_DEFAULT);
    }
    let _ = zenoh::try_init_log_from_env();
    let config = match build_config(unsafe { &*cfg }) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("zenoh-node: invalid Zenoh configuration: {e}");
            return ERR_CONFIG;
        }
    };
    let mut backoff = OPEN_RETRY_MIN;
    loop {
        match zenoh::open(config.clone()).wait() {
            Ok(session) => match watched(session) {
                Ok(s) => {
                    unsafe { *out = Box::into_raw(Box::new(s)) };
                    return 0;
                }
                Err(e) => {
                    eprintln!("zenoh-node: cannot listen to the session's transport events: {e}");
                    return ERR;
                }
            },
            // only a client needs its router to open; anything else is a real error
            Err(e) if unsafe { (*cfg).mode } == 0 => {
                eprintln!("zenoh-node: router not reachable ({e}); retrying in {} ms", backoff.as_millis());
                std::thread::sleep(backoff);
                backoff = (backoff * 2).min(OPEN_RETRY_MAX);
            }
            Err(e) => {
                eprintln!("zenoh-node: cannot open Zenoh session: {e}");
                return ERR;
            }
        }
    }
}

fn priority(p: u8) -> Priority {
    match p {
        1 => Priority::RealTime,
        2 => Priority::InteractiveHigh,
        3 => Priority::InteractiveLow,
        4 => Priority::DataHigh,
        6 => Priority::DataLow,
        7 => Priority::Background,
        _ => Priority::Data,
    }
}

#[no_mangle]
pub extern "C" fn zn_declare_publisher(
    s: *mut ZnSession,
    key: *const c_char,
    qos: *const ZnQos,
    out: *mut *mut ZnPublisher,
) -> c_int {
    let (Some(s), Some(key), false, false) = (unsafe { s.as_ref() }, c_str(key), qos.is_null(), out.is_null())
    else {
        return ERR;
    };
    let qos = unsafe { &*qos };
    let congestion = if qos.congestion == 1 { CongestionControl::Block } else { CongestionControl::Drop };
    match s
        .0
        .declare_publisher(key.to_owned())
        .congestion_control(congestion)
        .priority(priority(qos.priority))
        .express(qos.express != 0)
        .reliability(if qos.best_effort != 0 { Reliability::BestEffort } else { Reliability::Reliable })
        // The node consumes none of what it publishes: a put need not match its own subscribers.
        .allowed_destination(Locality::Remote)
        .wait()
    {
        Ok(p) => {
            unsafe { *out = Box::into_raw(Box::new(ZnPublisher(p, s.1.clone()))) };
            0
        }
        Err(e) => {
            eprintln!("zenoh-node: declare publisher {key}: {e}");
            ERR
        }
    }
}

// A put's payload and attachment are copied into buffers its thread keeps from put to put
// (Zenoh shares a buffer by reference count): the two allocations of each (the Vec and the Arc
// that ZBytes wraps it in) and their frees were ~550 of the ~11 900 instructions a frame costs
// (docs/benchmark.md). Zenoh encodes a sample into its batch within the put, so the buffer is
// normally ours again when the put returns; a buffer Zenoh still holds is left to it and
// another one is taken, so no held bytes are ever written.
const PAYLOAD: usize = 0;
const ATTACHMENT: usize = 1;
// The bridge's largest put is a full batch (16 KiB of frames, ~8 KiB of stamps); a larger buffer
// (another caller of the port) is used once and not kept, so a thread never holds more than this.
const REUSED_MAX: usize = 64 * 1024;

thread_local! {
    static PUT_BUFFERS: RefCell<[Option<Arc<Vec<u8>>>; 2]> = const { RefCell::new([None, None]) };
}

fn reused_bytes(slot: usize, data: &[u8]) -> ZBytes {
    PUT_BUFFERS.with(|buffers| {
        let mut buffers = buffers.borrow_mut();
        let kept = &mut buffers[slot];
        if let Some(buf) = kept.as_mut().and_then(Arc::get_mut) {
            buf.clear();
            buf.extend_from_slice(data);
        } else {
            *kept = Some(Arc::new(data.to_vec()));
        }
        let shared = kept.clone().expect("just filled");
        if data.len() > REUSED_MAX {
            *kept = None;
        }
        ZBytes::from(ZBuf::from(shared))
    })
}

#[no_mangle]
pub extern "C" fn zn_put(
    p: *mut ZnPublisher,
    payload: *const u8,
    len: usize,
    attachment: *const u8,
    attachment_len: usize,
) -> c_int {
    let Some(p) = (unsafe { p.as_ref() }) else { return ERR };
    if payload.is_null() && len > 0 {
        return ERR;
    }
    // no connection to anyone: the put returns Ok and goes nowhere. Put all the same (should the
    // count be wrong, nothing is lost for it), but said; only when none was open before and after
    // it, so a put that a connection opening meanwhile carried is never said to be lost.
    let none_before = p.1.none_open();
    let data = if len == 0 { &[][..] } else { unsafe { slice::from_raw_parts(payload, len) } };
    let mut put = p.0.put(reused_bytes(PAYLOAD, data));
    if !attachment.is_null() && attachment_len > 0 {
        put = put.attachment(reused_bytes(ATTACHMENT, unsafe { slice::from_raw_parts(attachment, attachment_len) }));
    }
    match put.wait() {
        Ok(()) if none_before && p.1.none_open() => UNROUTED,
        Ok(()) => 0,
        Err(_) => ERR,
    }
}

#[no_mangle]
pub extern "C" fn zn_declare_subscriber(
    s: *mut ZnSession,
    key: *const c_char,
    cb: Option<SampleCb>,
    ctx: *mut c_void,
    out: *mut *mut ZnSubscriber,
) -> c_int {
    let (Some(s), Some(key), Some(cb), false) = (unsafe { s.as_ref() }, c_str(key), cb, out.is_null()) else {
        return ERR;
    };
    let ctx = Ctx(ctx);
    let result = s
        .0
        .declare_subscriber(key.to_owned())
        .callback(move |sample| {
            let ctx = ctx;
            if sample.kind() == SampleKind::Delete {
                return; // a key's deletion carries no command (it was counted as one of length 0)
            }
            let payload = sample.payload().to_bytes();
            let source_time_ns = sample.timestamp().map_or(0, |t| t.get_time().as_nanos());
            match sample.attachment() {
                Some(att) => {
                    let att = att.to_bytes();
                    cb(payload.as_ptr(), payload.len(), att.as_ptr(), att.len(), source_time_ns, ctx.0)
                }
                None => cb(payload.as_ptr(), payload.len(), ptr::null(), 0, source_time_ns, ctx.0),
            }
        })
        .wait();
    match result {
        Ok(sub) => {
            unsafe { *out = Box::into_raw(Box::new(ZnSubscriber(sub))) };
            0
        }
        Err(e) => {
            eprintln!("zenoh-node: declare subscriber {key}: {e}");
            ERR
        }
    }
}

#[no_mangle]
pub extern "C" fn zn_declare_token(s: *mut ZnSession, key: *const c_char, out: *mut *mut ZnToken) -> c_int {
    let (Some(s), Some(key), false) = (unsafe { s.as_ref() }, c_str(key), out.is_null()) else {
        return ERR;
    };
    match s.0.liveliness().declare_token(key.to_owned()).wait() {
        Ok(t) => {
            unsafe { *out = Box::into_raw(Box::new(ZnToken(t))) };
            0
        }
        Err(e) => {
            eprintln!("zenoh-node: declare liveliness token {key}: {e}");
            ERR
        }
    }
}

/// The callback's reply, in a buffer grown to the length it asks for (zn_query_cb's contract:
/// a length of cap or more did not fit; 0 no answer, as a node stopping gives), at most
/// STATS_REPLY_MAX; None when there is none or it never fits: no reply (an empty one read as
/// an answer that is not JSON).
fn reply_text(cb: QueryCb, ctx: *mut c_void) -> Option<Vec<u8>> {
    let mut cap = STATS_REPLY_FIRST;
    for _ in 0..3 {
        // counters may grow a digit between two calls: a little room over what it asked for
        let mut buf = vec![0u8; cap];
        let n = cb(buf.as_mut_ptr() as *mut c_char, buf.len(), ctx);
        if n == 0 {
            return None;
        }
        if n < cap {
            buf.truncate(n);
            return Some(buf);
        }
        if cap == STATS_REPLY_MAX {
            break;
        }
        cap = n.saturating_add(256).min(STATS_REPLY_MAX);
    }
    eprintln!("zenoh-node: a query's reply does not fit in {STATS_REPLY_MAX} bytes: not replied");
    None
}

#[no_mangle]
pub extern "C" fn zn_declare_queryable(
    s: *mut ZnSession,
    key: *const c_char,
    cb: Option<QueryCb>,
    ctx: *mut c_void,
    out: *mut *mut ZnQueryable,
) -> c_int {
    let (Some(s), Some(key), Some(cb), false) = (unsafe { s.as_ref() }, c_str(key), cb, out.is_null()) else {
        return ERR;
    };
    let ctx = Ctx(ctx);
    // Replies go out on the queryable's own key, never the query's: a query with wildcards
    // (`vehicle/can/bridges/*/stats`, as the bench asks) then gets one reply per bridge, each
    // naming its bridge, where replies that all carried the query's wildcard key were merged
    // into one by the querier's consolidation (one bridge's stats standing for all of them).
    let reply_key = match KeyExpr::try_from(key.to_owned()) {
        Ok(k) => k,
        Err(e) => {
            eprintln!("zenoh-node: declare queryable {key}: {e}");
            return ERR;
        }
    };
    let result = s
        .0
        .declare_queryable(reply_key.clone())
        .callback(move |query| {
            let ctx = ctx;
            if let Some(text) = reply_text(cb, ctx.0) {
                let _ = query.reply(reply_key.clone(), text).wait();
            }
        })
        .wait();
    match result {
        Ok(q) => {
            unsafe { *out = Box::into_raw(Box::new(ZnQueryable(q))) };
            0
        }
        Err(e) => {
            eprintln!("zenoh-node: declare queryable {key}: {e}");
            ERR
        }
    }
}

#[no_mangle]
pub extern "C" fn zn_routers(s: *mut ZnSession, ids: *mut c_char, cap: usize) -> c_int {
    let Some(s) = (unsafe { s.as_ref() }) else { return ERR };
    let mut zids: Vec<String> = s.0.info().routers_zid().wait().map(|z| z.to_string()).collect();
    zids.sort();
    copy_c_string(&zids.join(","), ids, cap);
    zids.len() as c_int
}

#[no_mangle]
pub extern "C" fn zn_poll_connections(s: *mut ZnSession) {
    if let Some(s) = unsafe { s.as_ref() } {
        s.1.poll();
    }
}

/// The calling thread's puts until zn_batch_stop leave as one write (zenoh-transport's held direct
/// writes: patched/zenoh-transport, docs/upstream/README.md). Held per thread, whatever the session.
#[no_mangle]
pub extern "C" fn zn_batch_start(_s: *mut ZnSession) {
    zenoh_transport::unicast::hold_direct_writes();
}

#[no_mangle]
pub extern "C" fn zn_batch_stop(_s: *mut ZnSession) {
    zenoh_transport::unicast::release_direct_writes();
}

#[no_mangle]
pub extern "C" fn zn_connections_closed(s: *mut ZnSession) -> u64 {
    let Some(s) = (unsafe { s.as_ref() }) else { return 0 };
    s.1.closed.load(Ordering::Relaxed)
}

/// Writes text into a C buffer of cap bytes, truncated and NUL-terminated.
fn copy_c_string(text: &str, buf: *mut c_char, cap: usize) {
    if buf.is_null() || cap == 0 {
        return;
    }
    let n = text.len().min(cap - 1);
    unsafe {
        ptr::copy_nonoverlapping(text.as_ptr(), buf as *mut u8, n);
        *buf.add(n) = 0;
    }
}

#[no_mangle]
pub extern "C" fn zn_session_id(s: *mut ZnSession, buf: *mut c_char, cap: usize) -> c_int {
    let Some(s) = (unsafe { s.as_ref() }) else { return ERR };
    if buf.is_null() || cap == 0 {
        return ERR;
    }
    copy_c_string(&s.0.zid().to_string(), buf, cap);
    0
}

#[no_mangle]
pub extern "C" fn zn_undeclare_publisher(p: *mut ZnPublisher) {
    if !p.is_null() {
        let p = unsafe { Box::from_raw(p) };
        let _ = p.0.undeclare().wait();
    }
}

#[no_mangle]
pub extern "C" fn zn_undeclare_subscriber(sub: *mut ZnSubscriber) {
    if !sub.is_null() {
        let sub = unsafe { Box::from_raw(sub) };
        // returns once no callback of it runs or will (one dispatched before the undeclare but not
        // yet run included): the component's command callback never blocks, so this is short
        let _ = sub.0.undeclare().wait_callbacks().wait();
    }
}

#[no_mangle]
pub extern "C" fn zn_undeclare_token(t: *mut ZnToken) {
    if !t.is_null() {
        let t = unsafe { Box::from_raw(t) };
        let _ = t.0.undeclare().wait();
    }
}

#[no_mangle]
pub extern "C" fn zn_undeclare_queryable(q: *mut ZnQueryable) {
    if !q.is_null() {
        let q = unsafe { Box::from_raw(q) };
        let _ = q.0.undeclare().wait();
    }
}

#[no_mangle]
pub extern "C" fn zn_close(s: *mut ZnSession) {
    if !s.is_null() {
        let s = unsafe { Box::from_raw(s) };
        let _ = s.0.close().wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_put_buffer_is_reused_once_zenoh_let_it_go_and_never_while_it_holds_it() {
        let first = reused_bytes(PAYLOAD, b"frame one");
        let held = reused_bytes(ATTACHMENT, b"stamps one");
        let second = reused_bytes(PAYLOAD, b"frame two"); // `first` still held: another buffer
        assert_eq!(first.to_bytes().as_ref(), b"frame one");
        assert_eq!(second.to_bytes().as_ref(), b"frame two");
        let at = second.to_bytes().as_ptr();
        drop(second);
        let third = reused_bytes(PAYLOAD, b"frame 3"); // let go: the same buffer again
        assert_eq!(third.to_bytes().as_ptr(), at);
        assert_eq!(third.to_bytes().as_ref(), b"frame 3");
        assert_eq!(held.to_bytes().as_ref(), b"stamps one"); // the other slot untouched
        drop(third);
        let large = vec![7u8; REUSED_MAX + 1];
        assert_eq!(reused_bytes(PAYLOAD, &large).len(), large.len());
        PUT_BUFFERS.with(|b| assert!(b.borrow()[PAYLOAD].is_none())); // a large buffer is not kept
    }

    extern "C" fn no_answer(_: *mut c_char, _: usize, _: *mut c_void) -> usize {
        0
    }

    extern "C" fn two_bytes(buf: *mut c_char, cap: usize, _: *mut c_void) -> usize {
        if cap >= 2 {
            unsafe { ptr::copy_nonoverlapping(b"{}".as_ptr() as *const c_char, buf, 2) };
        }
        2
    }

    /// How `puts_from_threads` loads the link.
    struct Load {
        threads: u32,
        each: u32,
        size: fn(u32) -> usize,    // a sample's size by its number
        stall_every: u32,          // the subscriber stalls 100 ms at every such number (0: never)
        express: bool,
        config: &'static [(&'static str, &'static str)], // both sessions'
        held: u32,                                        // puts between zn_batch_start and stop (0: none)
    }

    impl Load {
        /// threads x each samples of this size, no stall, no express, no hold, default config
        fn of(threads: u32, each: u32, size: fn(u32) -> usize) -> Self {
            Load { threads, each, size, stall_every: 0, express: false, config: &[], held: 0 }
        }
    }

    /// Two peer sessions over loopback (no scouting): the publisher's and the subscriber's. The
    /// lease is long: a batch left unwritten would wait for a keep-alive (lease / 4), longer
    /// than the tests wait, where the default's 2.5 s would hide it.
    fn peer_pair(extra: &[(&str, &str)]) -> (Session, Session) {
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let config = |endpoints: &str| {
            let mut c = Config::default();
            c.insert_json5("mode", "\"peer\"").unwrap();
            c.insert_json5("scouting/multicast/enabled", "false").unwrap();
            c.insert_json5("scouting/gossip/enabled", "false").unwrap();
            c.insert_json5("transport/link/tx/lease", "60000").unwrap();
            c.insert_json5(endpoints, &format!("[\"tcp/127.0.0.1:{port}\"]")).unwrap();
            for (key, value) in extra {
                c.insert_json5(key, value).unwrap();
            }
            c
        };
        let listener = zenoh::open(config("listen/endpoints")).wait().unwrap();
        let connector = zenoh::open(config("connect/endpoints")).wait().unwrap();
        (listener, connector)
    }

    /// Puts from several application threads at once, each numbering its samples, while the
    /// subscriber stalls now and then (the socket fills: a write is not taken at once); returns
    /// each thread's numbers in the order they arrived, all of them or what came within 10 s of
    /// the last put.
    fn puts_from_threads(load: Load) -> Vec<Vec<u32>> {
        let (publishing, subscribing) = peer_pair(load.config);
        let got = Arc::new(Mutex::new(vec![Vec::new(); load.threads as usize]));
        let sink = got.clone();
        let stall_every = load.stall_every;
        let _sub = subscribing
            .declare_subscriber("bench/direct")
            .callback(move |s| {
                let b = s.payload().to_bytes();
                let (t, n) = (b[0] as usize, u32::from_le_bytes(b[1..5].try_into().unwrap()));
                if stall_every > 0 && n % stall_every == 0 {
                    std::thread::sleep(std::time::Duration::from_millis(100)); // a reader that stalls
                }
                sink.lock().unwrap()[t].push(n);
            })
            .wait()
            .unwrap();
        let publisher = publishing
            .declare_publisher("bench/direct")
            .congestion_control(CongestionControl::Block)
            .reliability(Reliability::Reliable)
            .express(load.express)
            .wait()
            .unwrap();
        // the subscriber's interest has reached the publisher's side before the first put
        let matched = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while !publisher.matching_status().wait().unwrap().matching() {
            assert!(std::time::Instant::now() < matched, "the subscriber never matched");
            std::thread::yield_now();
        }
        let publisher = Arc::new(publisher);
        let (each, size, held) = (load.each, load.size, load.held);
        let workers: Vec<_> = (0..load.threads)
            .map(|t| {
                let publisher = publisher.clone();
                std::thread::spawn(move || {
                    for n in 0..each {
                        if held > 0 && n % held == 0 {
                            zn_batch_start(ptr::null_mut());
                        }
                        let mut payload = vec![t as u8];
                        payload.extend_from_slice(&n.to_le_bytes());
                        payload.resize(size(n).max(5), 0);
                        publisher.put(payload).wait().unwrap();
                        if held > 0 && (n % held == held - 1 || n == each - 1) {
                            zn_batch_stop(ptr::null_mut());
                        }
                    }
                })
            })
            .collect();
        for w in workers {
            w.join().unwrap();
        }
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while got.lock().unwrap().iter().map(Vec::len).sum::<usize>() < (load.threads * each) as usize
            && std::time::Instant::now() < deadline
        {
            std::thread::sleep(std::time::Duration::from_millis(5)); // polls the count, bounded
        }
        let got = got.lock().unwrap().clone();
        got
    }

    /// Each thread's samples all arrived, in its order (a short summary where they did not).
    fn assert_all_in_order(got: &[Vec<u32>], each: u32) {
        for (t, arrived) in got.iter().enumerate() {
            let in_order = arrived.windows(2).all(|w| w[1] == w[0] + 1) && arrived.first() == Some(&0);
            assert!(
                in_order && arrived.len() == each as usize,
                "thread {t}: {} of {each} samples, in order: {in_order}, last {:?}",
                arrived.len(),
                arrived.last()
            );
        }
    }

    // The universal transport's put writes its batch itself when the link's writer is free
    // (patched/zenoh-transport, DirectTx, docs/upstream/README.md): batches keep their order,
    // none is lost or left unwritten, whatever the link and the other producers do.

    #[test]
    fn samples_put_from_many_threads_arrive_all_and_in_each_threads_order() {
        let load = Load::of(4, 5000, |_| 64);
        assert_all_in_order(&puts_from_threads(load), 5000);
    }

    #[test]
    fn samples_put_while_the_link_is_full_arrive_all_and_in_order() {
        let load = Load { stall_every: 1000, ..Load::of(3, 3000, |_| 8192) };
        assert_all_in_order(&puts_from_threads(load), 3000);
    }

    #[test]
    fn samples_in_fragments_between_small_ones_arrive_all_and_in_order() {
        // a put larger than a batch waits for free batches, one per fragment, while a write the
        // link did not take at once still holds one
        let load = Load { stall_every: 100, ..Load::of(1, 400, |n| if n % 4 == 3 { 200_000 } else { 100 }) };
        assert_all_in_order(&puts_from_threads(load), 400);
    }

    #[test]
    fn express_samples_through_a_queue_of_one_batch_arrive_all_and_in_order() {
        // every put its own batch, and a producer waits for the only one while others notify
        let load = Load {
            stall_every: 500,
            express: true,
            config: &[("transport/link/tx/queue/size/data", "1")],
            ..Load::of(3, 2000, |_| 512)
        };
        assert_all_in_order(&puts_from_threads(load), 2000);
    }

    // Puts held by zn_batch_start until zn_batch_stop (a reader's burst as one write): each leaves
    // at the stop at the latest (a held batch left unwritten would wait for a keep-alive, 15 s,
    // past the 10 s the load waits), in order, among other threads' holds and direct puts.

    #[test]
    fn samples_put_in_holds_from_many_threads_arrive_all_and_in_each_threads_order() {
        let load = Load { held: 16, ..Load::of(4, 5000, |_| 64) };
        assert_all_in_order(&puts_from_threads(load), 5000);
    }

    #[test]
    fn samples_held_arrive_only_at_the_stop() {
        // a quiet link: nothing writes a hold's batch before its stop (the lease's keep-alive is 15 s)
        let (publishing, subscribing) = peer_pair(&[]);
        let got = Arc::new(AtomicUsize::new(0));
        let sink = got.clone();
        let _sub = subscribing
            .declare_subscriber("bench/held")
            .callback(move |_| {
                sink.fetch_add(1, Ordering::SeqCst);
            })
            .wait()
            .unwrap();
        let publisher = publishing.declare_publisher("bench/held").wait().unwrap();
        wait_for("the subscriber's match", || publisher.matching_status().wait().unwrap().matching());
        zn_batch_start(ptr::null_mut());
        for n in 0..10u8 {
            publisher.put(vec![n; 8]).wait().unwrap();
        }
        std::thread::sleep(std::time::Duration::from_millis(100)); // the window a write of the hold would show in
        let early = got.load(Ordering::SeqCst);
        zn_batch_stop(ptr::null_mut());
        wait_for("the held samples", || got.load(Ordering::SeqCst) == 10);
        assert_eq!(early, 0, "{early} of 10 held samples arrived before the stop");
    }

    #[test]
    fn a_few_samples_held_leave_at_the_stop() {
        // no batch fills, no other thread writes: the stop alone writes them
        let load = Load { held: 16, ..Load::of(1, 40, |_| 64) };
        assert_all_in_order(&puts_from_threads(load), 40);
    }

    #[test]
    fn samples_held_past_a_full_batch_while_the_link_is_full_arrive_all_and_in_order() {
        // 12 samples of 8 KiB are more than a batch: one moves out (written at once) mid-hold
        let load = Load { stall_every: 1000, held: 12, ..Load::of(3, 3000, |_| 8192) };
        assert_all_in_order(&puts_from_threads(load), 3000);
    }

    /// A session on loopback (no scouting) in this mode, with these endpoints on these ports and
    /// no others (a router's default listener is on every interface).
    fn on_loopback(mode: &str, endpoints: &[(&str, u16)], extra: &[(&str, &str)]) -> Session {
        let mut c = Config::default();
        c.insert_json5("mode", &format!("{mode:?}")).unwrap();
        c.insert_json5("listen/endpoints", "[]").unwrap();
        c.insert_json5("scouting/multicast/enabled", "false").unwrap();
        c.insert_json5("scouting/gossip/enabled", "false").unwrap();
        for (key, port) in endpoints {
            c.insert_json5(key, &format!("[\"tcp/127.0.0.1:{port}\"]")).unwrap();
        }
        for (key, value) in extra {
            c.insert_json5(key, value).unwrap();
        }
        zenoh::open(c).wait().unwrap()
    }

    fn free_port() -> u16 {
        std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
    }

    /// Waits until `done`, failing after 10 s with `what`.
    fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while !done() {
            assert!(std::time::Instant::now() < deadline, "{what} never came");
            std::thread::sleep(std::time::Duration::from_millis(10)); // polls a state, bounded
        }
    }

    /// A client takes one router: a second one that connects to it is told to the session's
    /// transport events, then refused, and no event says it closed.
    fn refused_then_accepted(extra: &[(&str, &str)]) {
        let (first_port, client_port) = (free_port(), free_port());
        let first = on_loopback("router", &[("listen/endpoints", first_port)], extra);
        let endpoints = [("connect/endpoints", first_port), ("listen/endpoints", client_port)];
        let client = on_loopback("client", &endpoints, extra);
        let client = Box::into_raw(Box::new(watched(client).unwrap()));
        let connections = unsafe { (*client).1.clone() };
        let second = on_loopback("router", &[("connect/endpoints", client_port)], extra);
        let second_id = second.zid();
        wait_for("the second router's transport event", || connections.holds(&second_id));
        second.close().wait().unwrap(); // no more attempts
        first.close().wait().unwrap();
        wait_for("the first router's close", || connections.closed.load(Ordering::Relaxed) >= 1);

        let qos = ZnQos { priority: 5, congestion: 1, express: 0, best_effort: 0 };
        let mut publisher = ptr::null_mut();
        assert_eq!(zn_declare_publisher(client, c"test/unrouted".as_ptr(), &qos, &mut publisher), 0);
        let mut ids = [0 as c_char; 256];
        let put = || zn_put(publisher, b"frame".as_ptr(), 5, ptr::null(), 0);
        // no router connected: from the monitor's second poll on, a put goes nowhere
        assert_eq!(zn_routers(client, ids.as_mut_ptr(), ids.len()), 0);
        for _ in 0..2 {
            zn_poll_connections(client);
        }
        let unrouted = put() == UNROUTED;
        let refused_held = connections.holds(&second_id);

        // a router the client connects to after its listeners were declared stays, poll after poll
        let third = on_loopback("router", &[("listen/endpoints", first_port)], extra);
        wait_for("the client's reconnection", || zn_routers(client, ids.as_mut_ptr(), ids.len()) == 1);
        let mut routed = 0;
        for _ in 0..4 {
            std::thread::sleep(std::time::Duration::from_millis(100)); // the monitor's polls, faster
            zn_poll_connections(client);
            routed += (put() == 0) as u32;
        }
        zn_undeclare_publisher(publisher);
        zn_close(client);
        third.close().wait().unwrap();
        assert!(unrouted, "a put with no connection open counted routed (the refused router held: {refused_held})");
        assert_eq!(routed, 4, "puts over a connection counted unrouted");
    }

    #[test]
    fn a_connection_zenoh_refuses_as_it_opens_counts_no_longer_than_two_polls_an_accepted_one_stays() {
        refused_then_accepted(&[]);
    }

    #[test]
    fn the_same_over_the_low_latency_transport() {
        refused_then_accepted(&[("transport/unicast/lowlatency", "true"), ("transport/unicast/qos/enabled", "false")]);
    }

    #[test]
    fn a_query_callback_without_an_answer_gives_no_reply_not_an_empty_one() {
        // a node stopping answers 0: an empty reply was read as an answer that is not JSON
        assert_eq!(reply_text(no_answer, ptr::null_mut()), None);
        assert_eq!(reply_text(two_bytes, ptr::null_mut()).as_deref(), Some(&b"{}"[..]));
    }
}
