//! zn-flood: publishes COUNT frames shaped like the bridge's (16-byte frame,
//! 8-byte sequence attachment) on each key of KEYS (comma separated, all keys
//! interleaved) at RATE frames/s per key (0 = as fast as it can), then exits. A benchmark load: bounded in count, loopback or the
//! bench's own router only, multicast scouting off.
//!
//!   zn-flood --connect tcp/127.0.0.1:7447 --key bench/flood --count 300000 --rate 100000
//!
//! The frame's 8 data bytes are the sequence number, or with --stamp-data the
//! send time (ns since the epoch, strictly increasing) and there is no
//! attachment (a valid command for the bridge's tx key): the stamp survives
//! the trip through the bridge and the CAN bus, so every capture point reads
//! the latency from the frame itself. --id sets the CAN id (hex, default 123;
//! ID+i on the i-th key, so a reader tells the keys' streams apart),
//! --mode client|peer the Zenoh mode (default client). --frames-per-sample N
//! (with --stamp-data) puts N frames in each sample, as a bridge in batching
//! mode publishes a period's frames: COUNT and RATE stay frames per key, one
//! sample per key every N / RATE seconds, each frame its own stamp.
//!
//! Prints "<frames> frames in <seconds> s (<samples> samples)" on stdout when done.
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use zenoh::qos::CongestionControl;
use zenoh::{Config, Wait};

fn usage() -> ! {
    eprintln!(
        "usage: zn-flood --connect ENDPOINT --key KEY[,KEY...] --count N_PER_KEY [--rate FRAMES_PER_S] [--block] [--stamp-data] \
         [--id HEX] [--mode client|peer] [--frames-per-sample N]"
    );
    std::process::exit(2);
}

fn main() {
    let (mut connect, mut key, mut count, mut rate, mut block) = (String::new(), String::new(), 0u64, 0u64, false);
    let (mut stamp_data, mut can_id, mut mode) = (false, 0x123u32, "client".to_string());
    let mut per_sample = 1u64;
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "--block" {
            block = true;
            continue;
        }
        if flag == "--stamp-data" {
            stamp_data = true;
            continue;
        }
        let value = it.next().unwrap_or_else(|| usage());
        match flag.as_str() {
            "--connect" => connect = value,
            "--key" => key = value,
            "--count" => count = value.parse().unwrap_or_else(|_| usage()),
            "--rate" => rate = value.parse().unwrap_or_else(|_| usage()),
            "--id" => can_id = u32::from_str_radix(&value, 16).unwrap_or_else(|_| usage()),
            "--mode" if value == "client" || value == "peer" => mode = value,
            "--frames-per-sample" => per_sample = value.parse().unwrap_or_else(|_| usage()),
            _ => usage(),
        }
    }
    // several frames per sample only as stamped commands (a sequence attachment numbers samples, not frames)
    if connect.is_empty() || key.is_empty() || count == 0 || per_sample == 0 || (per_sample > 1 && !stamp_data) {
        usage();
    }
    let mut config = Config::default();
    config.insert_json5("mode", &format!("{mode:?}")).unwrap();
    if mode == "peer" {
        // a peer listens (other peers link to it directly); loopback only
        config.insert_json5("listen/endpoints", "[\"tcp/127.0.0.1:0\"]").unwrap();
    }
    config.insert_json5("scouting/multicast/enabled", "false").unwrap();
    config.insert_json5("connect/endpoints", &format!("[{connect:?}]")).unwrap();
    let session = zenoh::open(config).wait().unwrap_or_else(|e| {
        eprintln!("zn-flood: cannot open a Zenoh session to {connect}: {e}");
        std::process::exit(1)
    });
    let publishers: Vec<_> = key
        .split(',')
        .map(|k| {
            session
                .declare_publisher(k.to_string())
                .congestion_control(if block { CongestionControl::Block } else { CongestionControl::Drop })
                .wait()
                .unwrap_or_else(|e| {
                    eprintln!("zn-flood: cannot declare a publisher on {k}: {e}");
                    std::process::exit(1)
                })
        })
        .collect();
    let keys = publishers.len() as u64;
    // samples in all (the last one per key may hold fewer frames) and their rate, all keys interleaved
    let samples = count.div_ceil(per_sample) * keys;
    let sample_rate = rate as f64 * keys as f64 / per_sample as f64;
    let start = Instant::now();
    let mut seq = 0u64;
    let mut last_stamp = 0u64;
    while seq < samples {
        // send what is due by now (everything when unpaced), then sleep until the next sample is due
        let due = if rate == 0 { samples } else { (start.elapsed().as_secs_f64() * sample_rate) as u64 + 1 };
        while seq < due.min(samples) {
            let slot = (seq % keys) as usize;
            let first = seq / keys * per_sample; // this key's frames before this sample
            let frames = per_sample.min(count - first);
            let mut payload = Vec::with_capacity(16 * frames as usize);
            for _ in 0..frames {
                // the bridge's wire format: id (LE u32), dlc, flags, 2 reserved, 8 data bytes
                let mut frame = [0u8; 16];
                frame[0..4].copy_from_slice(&(can_id + slot as u32).to_le_bytes());
                frame[4] = 8;
                let data = if stamp_data {
                    let now = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
                    last_stamp = now.max(last_stamp + 1);
                    last_stamp
                } else {
                    seq
                };
                frame[8..16].copy_from_slice(&data.to_le_bytes());
                payload.extend_from_slice(&frame);
            }
            let put = publishers[slot].put(payload);
            // a stamped frame is its own identity, and a bare payload is a valid bridge command
            let put = if stamp_data { put } else { put.attachment(seq.to_le_bytes().to_vec()) };
            if let Err(e) = put.wait() {
                eprintln!("zn-flood: put {seq}: {e}");
                std::process::exit(1);
            }
            seq += 1;
        }
        if seq < samples {
            // paced as can-load paces CAN frames (a deadline per sample), so raw Zenoh and the
            // bridge's CAN -> Zenoh path get loads of one shape: a sleep of one interval after
            // sending overran by the timer's slack and sent samples in pairs at high rates
            let next = start + Duration::from_secs_f64(seq as f64 / sample_rate);
            std::thread::sleep(next.saturating_duration_since(Instant::now()));
        }
    }
    let count = count * keys;
    // paced: the last sample carries the frames due up to the end of its interval, so the load
    // covers at least samples / sample_rate (one interval more than the last put's time)
    let elapsed = start.elapsed().as_secs_f64();
    let elapsed = if rate == 0 { elapsed } else { elapsed.max(samples as f64 / sample_rate) };
    println!("{count} frames in {elapsed:.3} s ({samples} samples)");
    drop(publishers);
    let _ = session.close().wait();
}
