//! Adam / AdamW trajectories against torch.optim (fixture from
//! tools/fixtures/optim_adam.py; layout documented there).

use nst3d_optim::Adam;

const N: usize = 7;
const STEPS: usize = 5;

/// (AdamW?, lr, beta1, beta2, eps, weight_decay): the script's CONFIGS.
const CONFIGS: [(bool, f32, f32, f32, f32, f32); 4] = [
    (false, 0.1, 0.9, 0.999, 1e-8, 0.0),
    (false, 0.05, 0.9, 0.999, 1e-8, 0.1),
    (true, 0.05, 0.9, 0.999, 1e-8, 0.1),
    (false, 0.01, 0.8, 0.99, 1e-6, 0.0),
];

fn load() -> Vec<f32> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/optim_adam.bin");
    let bytes = std::fs::read(path)
        .unwrap_or_else(|e| panic!("missing fixture {path} ({e}); run tools/fixtures/optim_adam.py"));
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect()
}

fn assert_close(got: &[f32], want: &[f32], what: &str) {
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        assert!((a - b).abs() <= 1e-6 * (1.0 + b.abs()), "{what}[{i}]: {a} vs torch {b}");
    }
}

#[test]
fn matches_torch_adam_and_adamw() {
    let data = load();
    assert_eq!(data.len(), N * (1 + STEPS) + CONFIGS.len() * N * (STEPS + 2), "fixture layout");
    let p0 = &data[..N];
    let grads = &data[N..N * (1 + STEPS)];
    let mut pos = N * (1 + STEPS);
    for (ci, &(adamw, lr, beta1, beta2, eps, wd)) in CONFIGS.iter().enumerate() {
        let mut opt = if adamw { Adam::adamw(N, lr, wd) } else { Adam::new(N, lr) };
        opt.beta1 = beta1;
        opt.beta2 = beta2;
        opt.eps = eps;
        opt.weight_decay = wd;
        opt.validate().unwrap();
        let mut p = p0.to_vec();
        for s in 0..STEPS {
            opt.step(&mut p, &grads[s * N..(s + 1) * N]);
            assert_close(&p, &data[pos..pos + N], &format!("config {ci} step {s} params"));
            pos += N;
        }
        let (m, v, step) = opt.state();
        assert_eq!(step, STEPS as u64);
        assert_close(m, &data[pos..pos + N], &format!("config {ci} exp_avg"));
        assert_close(v, &data[pos + N..pos + 2 * N], &format!("config {ci} exp_avg_sq"));
        pos += 2 * N;
    }
}
