//! Writes a synthetic sequence with default options, some overridable:
//! `cargo run --release -p colslam-synth --example generate -- OUT [--frames N] [--seed S] [--blur E] [--noise SIGMA] [--distortion K1 K2 P1 P2]`.

use colslam_synth::{SynthOptions, generate};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(out) = args.first() else {
        eprintln!("usage: generate OUT [--frames N] [--seed S] [--blur E] [--noise SIGMA] [--distortion K1 K2 P1 P2]");
        std::process::exit(2);
    };
    let mut opts = SynthOptions::default();
    let mut it = args.iter().skip(1);
    let mut next = |name: &str| -> Result<String, String> { it.next().cloned().ok_or(format!("{name} needs a value")) };
    while let Ok(flag) = next("") {
        match flag.as_str() {
            "--frames" => opts.frames = next("--frames")?.parse()?,
            "--seed" => opts.seed = next("--seed")?.parse()?,
            "--blur" => opts.motion_blur = next("--blur")?.parse()?,
            "--noise" => opts.noise_sigma = next("--noise")?.parse()?,
            "--distortion" => {
                let mut d = [0.0; 4];
                for v in d.iter_mut() {
                    *v = next("--distortion")?.parse()?;
                }
                opts.distortion = Some(d);
            }
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    let progress = |done: usize, total: usize| {
        if done.is_multiple_of(25) || done == total {
            eprintln!("{done}/{total}");
        }
    };
    let report = generate(&opts, std::path::Path::new(out), Some(&progress))?;
    println!("{report}");
    Ok(())
}
