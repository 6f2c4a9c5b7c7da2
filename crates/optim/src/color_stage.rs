//! The core of the colour stage smoke and strands share: after the shape
//! (grey density or strands) is stylized and fixed, a colour is optimised
//! against the painting's colour Gram matrices from [`COLOR_VIEWS`] cameras
//! all around, one view per iteration in turn, with a grey guard of weight
//! [`GREY_GUARD`] keeping the grey look the shape stage gave.
//!
//! What differs between the two is how a view is drawn and differentiated
//! (volume rendering of a colour grid, splatting of coloured strands), so
//! each pipeline's adaptor brings one `step` (render, loss, gradient,
//! optimiser step) and [`optimise_in_turn`] runs the schedule and keeps the
//! losses. Why one view per step rather than all 16 summed: 160 such
//! iterations on smoke measured as strong (0.65–0.66 of the grey result's
//! colour loss from held-out views) as 40 steps that summed all 16 views
//! (640 passes, 0.65; docs/design/color.md).

/// Cameras the colour stage looks from. Colour placed for one camera is
/// averaged along other rays: optimised with the density from the job's
/// camera, the smoke's colour reached 0.61 of the grey result's colour loss
/// from that camera but 0.77 from held-out views; from 16 cameras around it
/// on the fixed density, 0.57 from the same held-out views
/// (docs/design/color.md). The strands stage takes the same count around the
/// groom (docs/design/strands.md).
pub const COLOR_VIEWS: usize = 16;

/// Weight of the grey guard: the Gram loss of the colour picture's
/// luminance to the painting's luminance, added to the colour loss. Free in
/// brightness, the colour moves towards a painting's dark colours, and
/// unguarded that takes the grey look with it. The weight was measured on
/// hair first (monkey_curly, `nst3d preview --color`, 8 views; hair-only
/// colour / grey judge, median against the grey result;
/// docs/design/strands.md):
///
/// | guard | Woman with a Hat | Starry Night | Shipwreck |
/// | --- | --- | --- | --- |
/// | none | 0.565 / 1.004 | | |
/// | hair only, 1 | 0.560 / 1.009 | | |
/// | **whole picture, 1** | **0.587 / 0.999** | **0.543 / 1.032** | **0.417 / 0.916** |
/// | whole picture, 3 | 0.638 / 0.993 | | |
/// | whole picture, only above the view's start, 3 | 0.642 / 0.993 | 0.563 / 1.015 | 0.416 / 0.917 |
/// | whole picture, only above the view's start, 10 | 0.692 / 0.995 | 0.600 / 1.011 | |
///
/// Weight 1 is the one that takes every painting 40 % nearer on the hair;
/// no weight measured keeps Starry Night's grey judge at 1. The same weight
/// on smoke_000003 at the defaults (`nst3d judge --color` against the grey
/// result, 8 held-out views, median; colour / colour on the smoke / grey;
/// docs/design/color.md):
///
/// | layer | painting | colour | colour on the smoke | grey |
/// | --- | --- | --- | --- | --- |
/// | luminance 1 (before) | Woman with a Hat | 0.595 | 0.490 | 1.000 |
/// | free, guard 1 | Woman with a Hat | 0.582 | 0.367 | 0.758 |
/// | luminance 1 (before) | Starry Night | 0.845 | 0.704 | 1.000 |
/// | free, guard 1 | Starry Night | 0.827 | 0.661 | 0.903 |
/// | free, guard 1 (not tuned on) | Shipwreck | 0.658 | 0.250 | 0.770 |
///
/// The colour gets closer to the painting and the grey look too: with
/// brightness free the stage also draws the painting's light and dark.
pub const GREY_GUARD: f32 = 1.0;

/// The losses of a run of [`optimise_in_turn`]: the mean loss of its first
/// sweep (as many iterations as there are views, the first one from the
/// starting colour) and of its last.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepLosses {
    /// Mean loss of the first sweep.
    pub first: f32,
    /// Mean loss of the last sweep.
    pub last: f32,
}

/// Runs `iterations` iterations of a stage that visits `views` in turn:
/// iteration `i` calls `step(i, &views[i % views.len()])`, which draws that
/// view, takes the loss and its gradient, steps the optimiser and returns
/// the loss. Sweeps shorter than the view list (fewer iterations than
/// views) cover all the iterations there are.
///
/// # Panics
/// If `views` is empty.
pub fn optimise_in_turn<V, E>(
    views: &[V],
    iterations: usize,
    mut step: impl FnMut(usize, &V) -> Result<f32, E>,
) -> Result<SweepLosses, E> {
    assert!(!views.is_empty(), "the colour stage needs at least one view");
    let n = views.len();
    let sweep = n.min(iterations).max(1);
    let (mut first, mut last) = (0.0f64, 0.0f64);
    for i in 0..iterations {
        let loss = step(i, &views[i % n])? as f64;
        if i < sweep {
            first += loss;
        }
        if i + sweep >= iterations {
            last += loss;
        }
    }
    Ok(SweepLosses { first: (first / sweep as f64) as f32, last: (last / sweep as f64) as f32 })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn visits_the_views_in_turn_and_averages_the_first_and_last_sweeps() {
        let mut seen = Vec::new();
        let r = optimise_in_turn(&['a', 'b', 'c'], 7, |i, v| {
            seen.push(*v);
            Ok::<f32, ()>(i as f32)
        })
        .unwrap();
        assert_eq!(seen, ['a', 'b', 'c', 'a', 'b', 'c', 'a']);
        assert_eq!(r, SweepLosses { first: 1.0, last: 5.0 });
        let short = optimise_in_turn(&[(); 4], 2, |i, _| Ok::<f32, ()>(i as f32)).unwrap();
        assert_eq!(short, SweepLosses { first: 0.5, last: 0.5 });
        assert_eq!(optimise_in_turn(&[()], 3, |i, _| if i == 1 { Err(i) } else { Ok(0.0) }), Err(1));
    }
}
