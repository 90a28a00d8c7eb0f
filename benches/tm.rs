//! Trace moments (`wtmm tm`) of one 1024x1024 fBm, single thread, as the
//! median of interleaved pairs against one bare inverse 2D complex FFT of
//! the image (the unit: the fractional derivative alone takes a forward
//! and an inverse real FFT of the 2048^2 mirror extension, about 4 such
//! FFTs, and the spectrum one more). Two paths: an image of an ensemble
//! (`add_field`), and a lone image with its jackknife tiles
//! (`field_tiles`, 4 tiles of 512 px, what `tm` runs on one DEM); their
//! ratio is the tiles' cost (one pass over the box pyramids serves all
//! tiles since 2026-11-29, so about 2: the whole, then the tiles; a pass
//! per tile would make it about 5 on 4 tiles).
//! Run: `cargo bench --bench tm`.

mod common;

use common::{FftFloor, one_thread_pool, paired};
use wtmm::Field;
use wtmm::synth::fbm::{FbmParams, fbm};
use wtmm::tracemoments::{
    TraceMomentAccumulator, TraceMomentConfig, TraceMomentFitConfig, tile_side,
};

fn main() {
    let n = 1024;
    let reps = 5;
    let floor = FftFloor::new(n, n);
    let pool = one_thread_pool();
    let cfg = TraceMomentConfig::default();
    let field = Field::new(fbm(FbmParams { hurst: 0.5 }, n, n, 1, 0).unwrap());
    let tile = tile_side(n, &TraceMomentFitConfig::default());
    println!(
        "tm bench: {n}x{n} fBm, {} q, {} eta, default flux (gradient after the auto derivative), 1 thread",
        cfg.q.len(),
        cfg.eta.len()
    );
    let add = || {
        let mut acc = TraceMomentAccumulator::new(cfg.clone()).unwrap();
        acc.add_field(&field).unwrap();
        std::hint::black_box(acc);
    };
    let tiles = || {
        std::hint::black_box(TraceMomentAccumulator::field_tiles(&cfg, &field, tile).unwrap());
    };
    let (ta, tf, ra) = pool.install(|| paired(reps, add, floor.runner()));
    let (tt, _, rt) = pool.install(|| paired(reps, tiles, floor.runner()));
    let (_, _, r_tiles) = pool.install(|| paired(reps, tiles, add));
    println!(
        "  one FFT {:5.1} ms | add_field {:6.1} ms -> {ra:5.1} FFTs | field_tiles ({tile} px tiles) {:6.1} ms -> {rt:5.1} FFTs | tiles / add_field {r_tiles:.2}",
        1e3 * tf,
        1e3 * ta,
        1e3 * tt
    );
}
