//! Times the synthetic renderer: `cargo run --release -p colslam-synth --example synth_bench [frames] [out.png]`.
//! Builds the default sequence, renders `frames` frames (default 10) spread
//! over the path, prints the setup time and the time per frame, and writes
//! the first rendered frame to `out.png` when given.

use std::time::Instant;

use colslam_synth::{SynthOptions, SyntheticSequence};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let frames: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(10);
    let opts = SynthOptions::default();
    let t = Instant::now();
    let seq = SyntheticSequence::new(&opts)?;
    println!(
        "setup {:.3} s ({} boxes, {} surfaces, {:.1} M texels), threads {}",
        t.elapsed().as_secs_f64(),
        seq.scene().boxes().len(),
        seq.scene().num_surfaces(),
        seq.scene().texels() as f64 * 1e-6,
        rayon::current_num_threads()
    );
    let n = seq.num_frames();
    let cpu0 = cpu_seconds();
    let t = Instant::now();
    for k in 0..frames {
        let i = k * (n - 1) / frames.max(2).saturating_sub(1).max(1);
        let img = seq.render(i.min(n - 1))?;
        if let (0, Some(p)) = (k, args.get(2)) {
            img.write_png(std::path::Path::new(p))?;
        }
    }
    println!(
        "render {:.1} ms per frame ({}x{}, {}x{} supersampling)",
        t.elapsed().as_secs_f64() * 1e3 / frames as f64,
        opts.width,
        opts.height,
        opts.supersample,
        opts.supersample
    );
    println!(
        "cpu {:.1} ms per frame (all threads; on 2 free cores the wall time is about half)",
        (cpu_seconds() - cpu0) * 1e3 / frames as f64
    );
    println!("path length {:.3} m", seq.path_length());
    Ok(())
}

/// User + system CPU seconds of this process (Linux /proc; 0 elsewhere), to
/// time on a loaded machine.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    // Fields after the parenthesised command name; utime and stime are the
    // 14th and 15th fields of the whole line, in clock ticks (100 Hz on Linux).
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else { return 0.0 };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}
