//! Lists a checkpoint's tensors and times reading it:
//! `cargo bench -p nst3d-weights --bench inspect -- [path]` (default: the
//! installed VGG-19 weights).

use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), nst3d_weights::WeightsError> {
    let path = match std::env::args_os().nth(1) {
        Some(p) => PathBuf::from(p),
        None => nst3d_weights::locate_vgg19()?,
    };
    let t = Instant::now();
    let bytes =
        std::fs::read(&path).map_err(|source| nst3d_weights::WeightsError::Io { path: path.clone(), source })?;
    let read_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let map = nst3d_weights::parse_tensors(&bytes, &path)?;
    let parse_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let hash = nst3d_weights::sha256_file(&path)?;
    let hash_s = t.elapsed().as_secs_f64();
    for (key, tensor) in &map {
        println!("{key:<24} {:?}", tensor.shape);
    }
    println!("{} tensors; {} bytes; sha256 {hash}", map.len(), bytes.len());
    println!("read {read_s:.3} s, parse {parse_s:.3} s, sha256 {hash_s:.3} s");
    println!("VGG-19 layout: {:?}", nst3d_weights::vgg19_layout(&map));
    Ok(())
}
