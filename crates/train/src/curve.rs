//! The loss curve drawn beside the model (`<out>.png`), so a TD can see at
//! a glance on the farm whether a training run is still improving, has
//! flattened or has diverged, without opening the CSV in a spreadsheet.

use nst3d_core::Image;

/// Plot size in pixels.
const WIDTH: usize = 640;
const HEIGHT: usize = 240;
/// Empty border around the plot area.
const BORDER: usize = 8;
/// Steps in the running mean drawn over the raw losses (the raw per-patch
/// loss varies by an order of magnitude between patches).
const SMOOTHING: usize = 50;

/// Per-channel colours (RGB in [0, 1]).
const BACKGROUND: [f32; 3] = [1.0, 1.0, 1.0];
const GRID: [f32; 3] = [0.88, 0.88, 0.88];
const RAW: [f32; 3] = [0.72, 0.78, 0.92];
const MEAN: [f32; 3] = [0.05, 0.15, 0.55];

/// The loss per step on a log scale: every step's loss as a pale band
/// (per pixel column, from its smallest to its largest loss), the running
/// mean of [`SMOOTHING`] steps as a dark line, and a grey line at every
/// power of ten between the smallest and largest loss. Non-finite and
/// non-positive losses are left out.
pub fn loss_curve(losses: &[f32]) -> Image {
    let mut img = Image::zeros(3, HEIGHT, WIDTH);
    let mut put = |x: usize, y: usize, c: [f32; 3]| {
        for (k, v) in c.iter().enumerate() {
            img.data[(k * HEIGHT + y) * WIDTH + x] = *v;
        }
    };
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            put(x, y, BACKGROUND);
        }
    }
    let logs: Vec<f32> = losses.iter().map(|l| if *l > 0.0 && l.is_finite() { l.log10() } else { f32::NAN }).collect();
    let (lo, hi) = logs.iter().filter(|v| v.is_finite()).fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
    if lo > hi {
        return img;
    }
    let (lo, hi) = if hi - lo < 1e-3 { (lo - 0.5, hi + 0.5) } else { (lo, hi) };
    let (pw, ph) = (WIDTH - 2 * BORDER, HEIGHT - 2 * BORDER);
    let row = |v: f32| BORDER + ((hi - v) / (hi - lo) * (ph - 1) as f32).round().clamp(0.0, (ph - 1) as f32) as usize;
    for decade in (lo.ceil() as i32)..=(hi.floor() as i32) {
        let y = row(decade as f32);
        for x in BORDER..BORDER + pw {
            put(x, y, GRID);
        }
    }
    // Running mean over the last SMOOTHING finite losses, in log space.
    let mut mean = Vec::with_capacity(logs.len());
    let (mut sum, mut n, mut window) = (0.0f64, 0usize, std::collections::VecDeque::new());
    for v in &logs {
        if v.is_finite() {
            window.push_back(*v as f64);
            sum += *v as f64;
            n += 1;
            if window.len() > SMOOTHING {
                sum -= window.pop_front().unwrap_or(0.0);
                n -= 1;
            }
        }
        mean.push(if n > 0 { (sum / n as f64) as f32 } else { f32::NAN });
    }
    let steps = logs.len();
    let mut last_mean: Option<usize> = None;
    for col in 0..pw {
        let (s0, s1) = (col * steps / pw, ((col + 1) * steps / pw).max(col * steps / pw + 1).min(steps));
        if s0 >= steps {
            break;
        }
        let x = BORDER + col;
        let finite = logs[s0..s1].iter().filter(|v| v.is_finite());
        let (a, b) = finite.fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
        if a <= b {
            for y in row(b)..=row(a) {
                put(x, y, RAW);
            }
        }
        let m = mean[s1 - 1];
        if m.is_finite() {
            let y = row(m);
            // Join to the previous column so the line has no gaps.
            let (y0, y1) = match last_mean {
                Some(p) => (p.min(y), p.max(y)),
                None => (y, y),
            };
            for yy in y0..=y1 {
                put(x, yy, MEAN);
            }
            last_mean = Some(y);
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn colour(img: &Image, x: usize, y: usize) -> [f32; 3] {
        std::array::from_fn(|k| img.data[(k * HEIGHT + y) * WIDTH + x])
    }

    #[test]
    fn a_falling_loss_is_drawn_from_top_left_to_bottom_right() {
        let losses: Vec<f32> = (0..1000).map(|i| 10f32.powf(2.0 - 2.0 * i as f32 / 999.0)).collect();
        let img = loss_curve(&losses);
        let dark_rows = |x: usize| (0..HEIGHT).filter(|&y| colour(&img, x, y) == MEAN).collect::<Vec<_>>();
        let (left, right) = (dark_rows(BORDER + 60), dark_rows(WIDTH - BORDER - 1));
        assert!(!left.is_empty() && !right.is_empty());
        assert!(left[0] < HEIGHT / 3 && right[0] > HEIGHT * 2 / 3, "{left:?} {right:?}");
        // Gridlines at 1, 10 and 100.
        assert_eq!((0..HEIGHT).filter(|&y| colour(&img, BORDER + 1, y) == GRID).count(), 2);
    }

    #[test]
    fn empty_and_non_finite_losses_give_a_blank_plot() {
        for losses in [vec![], vec![f32::NAN, 0.0, -1.0]] {
            let img = loss_curve(&losses);
            assert!(img.data.iter().all(|v| *v == 1.0));
        }
    }
}
