//! `magcomp-fuzz`: mutation fuzzing of every decoder, the acquisition stream and the
//! trace reader, on stable Rust (cargo-fuzz needs nightly; see fuzz/README.md).
//!
//! ```text
//! magcomp-fuzz [--seconds S] [--target NAME]... [--corpus PATH]... [--seed N]
//! magcomp-fuzz --target NAME --run FILE     # replay one input (a saved finding)
//! ```
//! Each target runs for S seconds (default 4) on mutated windows of its seeds; a panic or
//! a failed invariant saves the input to `fuzz/artifacts/` and the run exits 1.

mod mutate;
mod targets;

use magcomp_core::protocol::capture::{decode_line, Port, MAX_CHUNK};
use magcomp_core::protocol::command::{
    encode_blob, encode_command, flux_blob_id, flux_temp_blob_id, lag_blob_id, Command, Mode,
};
use magcomp_core::protocol::fluxgate::encode_spi_frame;
use magcomp_core::protocol::multi_record::{
    encode_multi_record, ChannelRecord, MultiRecord, MAX_MULTI_RECORD_LEN,
};
use magcomp_core::protocol::record::{encode_record, Record};
use magcomp_core::{Flags, MagCounts};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use targets::{Seeds, TARGETS};

fn usage() -> ! {
    eprintln!("usage: magcomp-fuzz [--seconds S] [--target NAME]... [--corpus PATH]... [--seed N] [--run FILE]");
    eprintln!(
        "targets: {}",
        TARGETS.iter().map(|t| t.0).collect::<Vec<_>>().join(", ")
    );
    std::process::exit(2)
}

fn nmea(body: &str) -> Vec<u8> {
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{x:02X}\r\n").into_bytes()
}

/// Seeds that need no file: one valid example of every frame type.
fn builtin(kind: Seeds) -> Vec<Vec<u8>> {
    let mut v = Vec::new();
    match kind {
        Seeds::Gps => {
            for b in [
                "GNGGA,171926.00,4404.14063,N,12118.85478,W,1,12,0.91,1147.2,M,-21.3,M,,",
                "GNRMC,171926.00,A,4404.14063,N,12118.85478,W,0.117,,180315,,,A",
                "GNGLL,4404.14066,N,12118.85481,W,171925.00,A,A",
                "GNGNS,171927.00,4404.14066,N,12118.85481,W,AAN,14,0.9,1147.2,-21.3,,,S",
                "GNVTG,,T,,M,0.117,N,0.216,K,A",
                "GNGST,223745.00,228650,2.5,2.4,126,0.98,1.0,3.1",
            ] {
                v.push(nmea(b));
            }
        }
        Seeds::Scalar => v.push(
            b"53620.4401\r\n48000.0000\r\n99999.9999\r\nM,53620.4401,,53619.9043\r\nM,53620.4,5362X.1\r\n"
                .to_vec(),
        ),
        Seeds::Flux => v.push(b"12345.678,-123.400,45678.900\r\n0,0,0\r\n1,2,3,21.5*04\r\n".to_vec()),
        Seeds::Spi => {
            let mut s = Vec::new();
            for (st, c) in [(0x0007, [1, -1, 8_388_607]), (0x0200, [0, 0, -8_388_608])] {
                s.extend_from_slice(&encode_spi_frame(st, c));
            }
            v.push(s);
        }
        Seeds::Command => {
            let mut s = Vec::new();
            let mut out = [0u8; 128];
            for c in [
                Command::Mode(Mode::Survey),
                Command::Mode(Mode::Cal),
                Command::Status,
                Command::GetCoef(None),
                Command::GetCoef(Some(3)),
                Command::SetCoef {
                    index: 5,
                    value: -1.25e-3,
                },
                Command::Save,
                Command::Reset,
                Command::Flush,
                Command::FactoryReset,
                Command::Raw(true),
                Command::Raw(false),
                Command::GetFlux(Some(11)),
                Command::SetFlux {
                    index: 0,
                    value: 1.0001,
                },
                Command::GetLag,
                Command::SetLag(0.205),
                Command::GetFluxTemp(None),
                Command::SetFluxTemp {
                    index: 4,
                    value: 2.5e-5,
                },
                Command::GetSensorCoef {
                    sensor: 2,
                    index: None,
                },
                Command::SetSensorCoef {
                    sensor: 1,
                    index: 15,
                    value: -1.25e-2,
                },
            ] {
                let n = encode_command(&c, &mut out).unwrap();
                s.extend_from_slice(&out[..n]);
            }
            v.push(s);
        }
        Seeds::Blob => {
            let mut out = vec![0u8; 256];
            let coef: Vec<f32> = (0..16).map(|i| i as f32 * 0.5 - 3.0).collect();
            let n = encode_blob(0x5A5A_0000, &coef, &mut out).unwrap();
            v.push(out[..n].to_vec());
            let n = encode_blob(flux_blob_id(), &coef[..12], &mut out).unwrap();
            v.push(out[..n].to_vec());
            let n = encode_blob(lag_blob_id(), &[0.205], &mut out).unwrap();
            v.push(out[..n].to_vec());
            let ft = [21.5, 0.4, -0.2, 0.8, 1e-5, -2e-5, 3e-6];
            let n = encode_blob(flux_temp_blob_id(), &ft, &mut out).unwrap();
            v.push(out[..n].to_vec());
        }
        Seeds::Record => {
            let mut s = Vec::new();
            let mut out = [0u8; MAX_MULTI_RECORD_LEN];
            for (i, mag) in [Some(MagCounts(536_204_401)), None].into_iter().enumerate() {
                let r = Record {
                    seq: i as u32,
                    t_s: 43_200.1 + i as f64,
                    mag,
                    interference_nt: -12.3456,
                    compensated: Record::compensate(mag, -12.3456),
                    anomaly_nt: 1.5,
                    innovation_nt: -0.0123,
                    sigma_nt: 0.25,
                    flags: Flags(if mag.is_none() { Flags::MAG_MISSING } else { 0 }),
                };
                let n = encode_record(&r, &mut out).unwrap();
                s.extend_from_slice(&out[..n]);
            }
            // a counter line's record, channel 1 missing
            let ch = |mag: Option<MagCounts>| ChannelRecord {
                mag,
                interference_nt: -12.3456,
                compensated: Record::compensate(mag, -12.3456),
                sigma_nt: 0.25,
                flags: Flags(if mag.is_none() { Flags::MAG_MISSING } else { 0 }),
            };
            let c = [
                ch(Some(MagCounts(536_204_401))),
                ch(None),
                ch(Some(MagCounts(536_199_043))),
            ];
            let m = MultiRecord::new(2, 43_202.1, 3, c);
            let n = encode_multi_record(&m, &mut out).unwrap();
            s.extend_from_slice(&out[..n]);
            s.extend_from_slice(
                b"$MCRAW,0,43200.000000,51468.8597,10873.9941,-12026.2393,48954.7461,45.28550633,-75.72062967,3001.2700,60.0120,0000*A8B2\r\n",
            );
            v.push(s);
        }
        Seeds::Capture => {
            v.push(
                b"# magcomp-capture v1\n# scalar_hz: 10\n1000 flux 312C322C330D0A\n2000 scalar 35333632302E343430310D0A\n"
                    .to_vec(),
            );
            // a counter line of three magnetometers, channel 1 dead
            v.push(
                b"# magcomp-capture v1\n# scalar_hz: 10\n1000 flux 312C322C330D0A\n2000 scalar 4D2C35333632302E343430312C2C35333631392E393034330D0A\n3000 scalar 35333632302E343430310D0A\n"
                    .to_vec(),
            );
        }
        Seeds::Trace => v.push(
            b"t,mag,flux_x,flux_y,flux_z,lat,lon,alt\n0,50000.1,1,2,3,45,7,1000\n0.1,50000.2,1,2,3,45,7,1000\n"
                .to_vec(),
        ),
    }
    v
}

/// Files → seeds per kind: NMEA logs; captures whole and split by port; traces.
fn load(path: &Path, seeds: &mut Vec<(Seeds, Vec<u8>)>) {
    if path.is_dir() {
        let mut names: Vec<PathBuf> = std::fs::read_dir(path)
            .into_iter()
            .flatten()
            .filter_map(|e| Some(e.ok()?.path()))
            .collect();
        names.sort();
        for p in names {
            load(&p, seeds);
        }
        return;
    }
    let Ok(bytes) = std::fs::read(path) else {
        return;
    };
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    match ext {
        "log" => seeds.push((Seeds::Gps, bytes)),
        "csv" | "xyz" => {
            // The reader needs the header: keep the file's first 16 KiB, whole lines.
            let end = bytes.len().min(16 * 1024);
            let end = bytes[..end]
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(end, |e| e + 1);
            seeds.push((Seeds::Trace, bytes[..end].to_vec()));
        }
        "cap" => {
            let mut ports: [Vec<u8>; 3] = Default::default();
            let mut data = [0u8; MAX_CHUNK];
            for line in bytes.split(|&b| b == b'\n').take(20_000) {
                if let Ok(Some(c)) = decode_line(line, &mut data) {
                    let i = match c.port {
                        Port::Scalar => 0,
                        Port::Flux => 1,
                        Port::Gps => 2,
                        _ => continue,
                    };
                    ports[i].extend_from_slice(&data[..c.len]);
                }
            }
            let [s, f, g] = ports;
            seeds.push((Seeds::Scalar, s));
            seeds.push((Seeds::Flux, f));
            seeds.push((Seeds::Gps, g));
            seeds.push((Seeds::Capture, bytes));
        }
        _ => {}
    }
}

fn default_corpus() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    ["data/reference/nmea"]
        .iter()
        .map(|p| root.join(p))
        .filter(|p| p.is_dir())
        .take(1)
        .collect()
}

struct Outcome {
    execs: u64,
    bytes: u64,
    failures: u32,
}

fn run_target(
    name: &str,
    f: targets::Target,
    kind: Seeds,
    seeds: &[Vec<u8>],
    secs: f64,
    rng: &mut SmallRng,
) -> Outcome {
    let deadline = Instant::now() + Duration::from_secs_f64(secs);
    // Inputs kept beside the seeds: a random sample of what was tried, so mutations stack.
    let mut pool: Vec<Vec<u8>> = Vec::new();
    let mut o = Outcome {
        execs: 0,
        bytes: 0,
        failures: 0,
    };
    let whole = matches!(kind, Seeds::Trace | Seeds::Spi | Seeds::Blob);
    let checksummed = matches!(kind, Seeds::Gps | Seeds::Command | Seeds::Record);
    let max = if kind == Seeds::Capture { 8192 } else { 2048 };
    while !o.execs.is_multiple_of(64) || Instant::now() < deadline {
        let from_pool = !pool.is_empty() && rng.gen_bool(0.3);
        let mut input = if from_pool {
            pool[rng.gen_range(0..pool.len())].clone()
        } else {
            let s = &seeds[rng.gen_range(0..seeds.len())];
            match whole {
                true => s[..s.len().min(mutate::MAX_LEN)].to_vec(),
                false => mutate::window(rng, s, max).to_vec(),
            }
        };
        if o.execs == 0 || rng.gen_bool(0.9) {
            let other = &seeds[rng.gen_range(0..seeds.len())];
            let other = mutate::window(rng, other, 512).to_vec();
            mutate::mutate(rng, &mut input, &other);
        }
        if checksummed && rng.gen_bool(0.5) {
            mutate::fix_checksums(&mut input);
        }
        o.execs += 1;
        o.bytes += input.len() as u64;
        if std::panic::catch_unwind(|| f(&input)).is_err() {
            o.failures += 1;
            let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("artifacts");
            let _ = std::fs::create_dir_all(&dir);
            let p = dir.join(format!("{name}-{}.bin", o.execs));
            let _ = std::fs::write(&p, &input);
            eprintln!("FAIL {name}: input saved to {}", p.display());
            if o.failures >= 5 {
                break;
            }
        }
        if rng.gen_ratio(1, 32) {
            if pool.len() < 256 {
                pool.push(input);
            } else {
                let i = rng.gen_range(0..pool.len());
                pool[i] = input;
            }
        }
    }
    o
}

fn main() {
    let mut secs = 4.0;
    let mut only: Vec<String> = Vec::new();
    let mut corpus: Vec<PathBuf> = Vec::new();
    let mut seed: Option<u64> = None;
    let mut run_file: Option<PathBuf> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--seconds" => secs = val().parse().unwrap_or_else(|_| usage()),
            "--target" => only.push(val()),
            "--corpus" => corpus.push(val().into()),
            "--seed" => seed = Some(val().parse().unwrap_or_else(|_| usage())),
            "--run" => run_file = Some(val().into()),
            _ => usage(),
        }
    }
    for t in &only {
        if !TARGETS.iter().any(|x| x.0 == t) {
            eprintln!("unknown target '{t}'");
            usage();
        }
    }
    if let Some(file) = run_file {
        let data = std::fs::read(&file).unwrap_or_else(|e| {
            eprintln!("{}: {e}", file.display());
            std::process::exit(2)
        });
        for (name, f, _) in TARGETS.iter().filter(|t| only.contains(&t.0.to_string())) {
            f(&data);
            println!("{name}: {} passes", file.display());
        }
        return;
    }
    if corpus.is_empty() {
        corpus = default_corpus();
    }
    let mut files = Vec::new();
    for p in &corpus {
        load(p, &mut files);
    }
    let seed = seed.unwrap_or_else(|| {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_nanos() as u64)
    });
    println!(
        "magcomp-fuzz: seed {seed}, {secs} s per target, corpus {} files from {:?}",
        files.len(),
        corpus
    );
    let mut rng = SmallRng::seed_from_u64(seed);
    let mut failed = 0;
    let mut total = 0u64;
    for (name, f, kind) in TARGETS {
        if !only.is_empty() && !only.contains(&name.to_string()) {
            continue;
        }
        let mut seeds = builtin(*kind);
        seeds.extend(
            files
                .iter()
                .filter(|(k, s)| k == kind && !s.is_empty())
                .map(|(_, s)| s.clone()),
        );
        let o = run_target(name, *f, *kind, &seeds, secs, &mut rng);
        total += o.execs;
        println!(
            "{name:<12} {:>10} execs {:>9.0}/s {:>7.1} MB  seeds {:>3}  failures {}",
            o.execs,
            o.execs as f64 / secs,
            o.bytes as f64 / 1e6,
            seeds.len(),
            o.failures
        );
        failed += o.failures;
    }
    println!("total {total} execs, {failed} failures");
    if failed > 0 {
        std::process::exit(1);
    }
}
