//! `op3dsg bench remote`: what each keyframe encoding of remote detection
//! (`detector.remote.encoding`) costs: bytes per keyframe against the robot's CPU to encode it
//! (and the worker's to decode it), on keyframes of a profile's source (default: the synthetic
//! kitchen at 848x480, the D435i's depth mode on the Stretch), and the share of a link a stream
//! of them takes. The encoder is the daemon's own (`wire::encode_request`), timed by the
//! thread's CPU clock.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::source::SourceStatus;
use op3dsg_runtime::config;
use op3dsg_runtime::perception::remote::wire::{self, Contract, ImageEncoding};

use super::write_output;

#[derive(Debug, clap::Args)]
pub(super) struct RemoteBenchArgs {
    /// Profile whose source gives the keyframes (e.g. profiles/replay-icl.toml); default: the
    /// built-in synthetic kitchen at 848x480.
    #[arg(long)]
    profile: Option<PathBuf>,
    /// Override one profile value, TOML syntax (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Keyframes to encode with each encoding (every 10th frame of the source).
    #[arg(long, default_value_t = 30)]
    keyframes: usize,
    /// Keyframes per second of the stream whose link share is printed.
    #[arg(long, default_value_t = 5.0)]
    rate: f64,
    /// The link's capacity, Mbit/s.
    #[arg(long, default_value_t = 100.0)]
    link_mbit: f64,
    /// Also write the table to this file.
    #[arg(long, value_name = "FILE")]
    markdown: Option<PathBuf>,
}

/// CPU time of the calling thread, nanoseconds (`CLOCK_THREAD_CPUTIME_ID`).
fn thread_cpu_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map_or(0, |t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
}

fn quantile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(((values.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(0.0)
}

/// Every 10th frame of the profile's source, `count` of them.
fn keyframes(args: &RemoteBenchArgs) -> Result<Vec<Frame>> {
    let mut overrides = Vec::new();
    if args.profile.is_none() {
        overrides.push(
            "source.synthetic.intrinsics={ width = 848, height = 480, fx = 615.0, fy = 615.0, cx = 424.0, cy = 240.0 }"
                .to_owned(),
        );
    }
    overrides.extend(args.set.iter().cloned());
    overrides.push("source.rate_hz=0.0".to_owned());
    let backends = op3dsg_sim::backends();
    let loaded =
        config::load_with(&backends, args.profile.as_deref(), &overrides).map_err(|e| anyhow::anyhow!("{e}"))?;
    let opened = backends
        .source(&loaded.profile.source.kind)
        .and_then(|b| b.open(&loaded.profile))
        .context("opening the profile's source")?;
    let mut source = opened.source;
    let mut frame = Frame::new(source.intrinsics());
    let mut out = Vec::with_capacity(args.keyframes);
    let mut seen = 0usize;
    while out.len() < args.keyframes {
        match source.next_frame(&mut frame).context("reading a frame")? {
            SourceStatus::Frame => {
                if seen.is_multiple_of(10) {
                    out.push(frame.clone());
                }
                seen += 1;
            }
            SourceStatus::Pending => std::thread::sleep(std::time::Duration::from_millis(1)),
            SourceStatus::EndOfStream => break,
        }
    }
    if out.is_empty() {
        bail!("the source gave no frame");
    }
    Ok(out)
}

pub(super) fn run(args: RemoteBenchArgs) -> Result<()> {
    let frames = keyframes(&args)?;
    let k = frames[0].intrinsics;
    let contract = Contract { model: "yolox".into(), prompts: Vec::new(), embedding_dim: 0 };
    let mut table = format!(
        "Keyframe encodings of remote detection: {} keyframes of {}x{} ({} build)\n\n\
         | encoding | colour / depth | kB per keyframe | of raw | encode CPU ms p50 / p99 | decode CPU ms p50 | \
         Mbit/s at {} keyframes/s | share of {} Mbit/s |\n|---|---|---:|---:|---:|---:|---:|---:|\n",
        frames.len(),
        k.width,
        k.height,
        if cfg!(debug_assertions) { "debug: figures only check the harness" } else { "release" },
        args.rate,
        args.link_mbit
    );
    let mut raw_kb = 0.0;
    let mut bytes = Vec::new();
    for encoding in ImageEncoding::ALL {
        let (mut kb, mut encode_ms, mut decode_ms) = (Vec::new(), Vec::new(), Vec::new());
        for frame in &frames {
            let t0 = thread_cpu_ns();
            wire::encode_request(&mut bytes, 1, frame, &contract, encoding)?;
            let t1 = thread_cpu_ns();
            let decoded = wire::decode_request(&bytes)?;
            let t2 = thread_cpu_ns();
            std::hint::black_box(decoded);
            kb.push(bytes.len() as f64 / 1e3);
            encode_ms.push((t1 - t0) as f64 / 1e6);
            decode_ms.push((t2 - t1) as f64 / 1e6);
        }
        let size = kb.iter().sum::<f64>() / kb.len() as f64;
        if encoding == ImageEncoding::Raw {
            raw_kb = size;
        }
        let mbit = size * 1e3 * 8.0 * args.rate / 1e6;
        let kinds = match encoding {
            ImageEncoding::Jpeg => format!("JPEG q{} (lossy) / zstd", wire::JPEG_QUALITY),
            other => format!("{0} / {0} (lossless)", other.as_str()),
        };
        let _ = writeln!(
            table,
            "| {} | {kinds} | {size:.0} | {:.2} | {:.2} / {:.2} | {:.2} | {mbit:.1} | {:.1} % |",
            encoding.as_str(),
            size / raw_kb.max(1e-9),
            quantile(&mut encode_ms, 0.5),
            quantile(&mut encode_ms, 0.99),
            quantile(&mut decode_ms, 0.5),
            mbit / args.link_mbit * 100.0
        );
    }
    write_output(None, &table)?;
    if let Some(path) = &args.markdown {
        std::fs::write(path, &table).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
