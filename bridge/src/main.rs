//! `bridge`: carries pipeline topics between this host and another over
//! zenoh (see the library's documentation).

use std::process::ExitCode;
use std::sync::atomic::AtomicBool;

use anyhow::Result;
use bridge::{Counters, Options, Tls};
use clap::Parser;
use secure_link::tls::Identity;
use stages::bridge::{Args, FrameCompression};

fn run(args: Args) -> Result<()> {
    let options = Options {
        namespace: args
            .namespace
            .unwrap_or_else(|| format!("mirror/{}", args.prefix)),
        prefix: args.prefix,
        send: args.send,
        receive: args.receive,
        listen: args.listen,
        connect: args.connect,
        lease_ms: args.lease_ms,
        tls: args.certs.as_ref().zip(args.side).map(|(dir, side)| Tls {
            identity: Identity::of_side(dir, side.name()),
            peer: side.other().name().into(),
        }),
        insecure: args.insecure,
        frame_encoding: match args.compress_frames {
            FrameCompression::Zstd => bridge::envelope::Encoding::Zstd,
            FrameCompression::None => bridge::envelope::Encoding::Raw,
        },
    };
    let counters = Counters::default();
    let stop = AtomicBool::new(false);
    let result = bridge::run(&options, &counters, &stop);
    counters.into_stats(&options).finish();
    result.map_err(anyhow::Error::from)
}

fn main() -> ExitCode {
    runtime::stage_main("bridge", || run(Args::parse()))
}
