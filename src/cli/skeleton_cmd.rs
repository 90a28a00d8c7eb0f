//! `wtmm skeleton IMAGE --out DIR`: WTMMM, maxima lines and II Fig 9-style
//! pictures (smoothed image, maxima chains, an arrow per WTMMM).

use std::collections::HashMap;
use std::path::PathBuf;

use clap::Args;
use serde_json::json;

use super::analyze_cmd::LineOpts;
use super::common::save_raster_chart;
use super::common::{f, header, make_out_dir, parse_list, write_csv, write_json};
use super::{OutDir, Outcome, PixelOpts, PixelSize};
use crate::cwt::CwtPlan;
use crate::error::{Error, Result};
use crate::plot::{ColorBar, Raster, RasterChart};
use crate::skeleton::{Parallelism, skeleton_with};

#[derive(Args, Debug)]
pub struct SkeletonArgs {
    /// Input image.
    pub image: PathBuf,
    #[command(flatten)]
    pub opts: LineOpts,
    /// Scales (px) to draw, each within half a voice of a grid scale: `a,b,c` (default: 1, 2 and 3 octaves above a_min, those within --octaves).
    #[arg(long)]
    pub scales: Option<String>,
    // the pixel: the drawn scales are also given as lengths
    #[command(flatten)]
    pub pixel: PixelOpts,
    #[command(flatten)]
    pub read: super::ReadOpts,
    #[command(flatten)]
    pub out: OutDir,
}

pub fn run(args: SkeletonArgs, quiet: bool) -> Result<Outcome> {
    let mut opts = args.opts.clone();
    let origin = super::analyze_cmd::torus_for_synth(&mut opts, std::slice::from_ref(&args.image));
    let cfg = opts.analysis()?;
    let (px, mut warnings) = args.pixel.resolve(std::slice::from_ref(&args.image))?;
    warnings.extend(
        px.as_ref()
            .and_then(|p| p.warning(super::Isotropic::Wavelet)),
    );
    let nodata = args.read.value()?;
    let field = super::common::read_image(&args.image, nodata)?;
    super::common::refuse_constant(&field, &args.image, crate::skeleton::CONSTANT)?;
    super::common::check_image_memory(&args.image, &field, true)?;
    let share: Vec<f64> = field.plane_share().into_iter().collect();
    warnings.extend(cfg.plane_warning(&share, 1));
    let grid = cfg.scale_list();
    let want: Vec<f64> = match &args.scales {
        Some(s) => parse_list("scales", s)?,
        None => {
            // 1, 2, 3 octaves above a_min, those the grid holds (else its top)
            let top = grid[grid.len() - 1];
            let v: Vec<f64> = [2.0, 4.0, 8.0]
                .iter()
                .map(|k| k * cfg.a_min)
                .filter(|&a| a <= top * (1.0 + 1e-9))
                .collect();
            if v.is_empty() { vec![top] } else { v }
        }
    };
    // nearest grid scale of each, which must be within half a voice (a
    // scale off the grid is not drawn silently at the grid's end) and
    // distinct from the others'
    let half_voice = 0.5 / cfg.voices as f64 + 1e-9;
    let mut draw: Vec<usize> = Vec::with_capacity(want.len());
    for &a in &want {
        let nearest = |i: usize| (grid[i].log2() - a.log2()).abs();
        let j = (0..grid.len())
            .min_by(|&i, &k| nearest(i).total_cmp(&nearest(k)))
            .expect("non-empty grid");
        if !(a > 0.0) || nearest(j) > half_voice {
            return Err(Error::param(
                "scales",
                format!(
                    "{} px is not on the analysis grid {:.3}-{:.3} px (within half a voice)",
                    crate::error::short(a),
                    grid[0],
                    grid[grid.len() - 1]
                ),
            ));
        }
        if draw.contains(&j) {
            return Err(Error::param(
                "scales",
                format!(
                    "{a} px is the grid scale {:.3} px of another value",
                    grid[j]
                ),
            ));
        }
        // drawn at the grid scale, said when it is not the value given
        if (grid[j] - a).abs() > 5e-4 * a {
            say!(
                "note: --scales {a} px drawn at the grid scale {:.3} px",
                grid[j]
            );
        }
        draw.push(j);
    }
    draw.sort_unstable();
    let all: Vec<usize> = (0..grid.len()).collect();
    let sk = skeleton_with(&field, &cfg, Parallelism::Scales, &all)
        .map_err(|e| super::common::in_file(&args.image, e))?;
    if sk.lines.is_empty() {
        return Err(Error::format(&args.image, cfg.why_no_maxima(&field)));
    }
    PixelSize::say_note(px.as_ref(), quiet);
    make_out_dir(&args.out.out)?;
    // line id of each (scale, x, y)
    let mut on_line: HashMap<(usize, u32, u32), usize> = HashMap::new();
    for (id, l) in sk.lines.iter().enumerate() {
        for (j, p) in l.points.iter().enumerate() {
            on_line.insert((j, p.x, p.y), id);
        }
    }
    let mut rows = Vec::new();
    for sm in &sk.kept {
        for w in &sm.wtmmm {
            let line = on_line
                .get(&(sm.j, w.x, w.y))
                .map_or("-1".to_string(), |l| l.to_string());
            rows.push(vec![
                sm.j.to_string(),
                f(sm.a),
                w.x.to_string(),
                w.y.to_string(),
                f(w.m),
                f(w.arg),
                w.chain.to_string(),
                line,
            ]);
        }
    }
    write_csv(
        &args.out.out.join("wtmmm.csv"),
        &["j", "a", "x", "y", "M", "A", "chain", "line"],
        &rows,
    )?;
    let mut rows = Vec::new();
    for (id, l) in sk.lines.iter().enumerate() {
        let death = sk.scales[l.points.len() - 1];
        for (j, p) in l.points.iter().enumerate() {
            rows.push(vec![
                id.to_string(),
                f(sk.scales[0]),
                f(death),
                j.to_string(),
                f(sk.scales[j]),
                p.x.to_string(),
                p.y.to_string(),
                f(p.m),
                f(p.sup),
                f(p.arg),
            ]);
        }
    }
    write_csv(
        &args.out.out.join("lines.csv"),
        &[
            "line", "birth_a", "death_a", "j", "a", "x", "y", "M", "sup", "A",
        ],
        &rows,
    )?;
    // pictures
    let (ny, nx) = field.dim();
    let plan = CwtPlan::new(ny, nx, cfg.wavelet, &grid)?;
    let fi = plan.forward(cfg.input(&field)?.view())?;
    let mut pictures = Vec::new();
    for &j in &draw {
        let sm = &sk.kept[j];
        let mut smooth = plan.smoothed(&fi, sm.a);
        // missing pixels (filled for the transform) in the pictures' teal
        if let Some(mask) = &field.mask {
            smooth.zip_mut_with(mask, |v, &m| {
                if m {
                    *v = f64::NAN
                }
            });
        }
        let mut r = Raster::from_grey(smooth.view());
        // the grey's key: the smoothed values it spans
        let colorbar = crate::field::finite_range(smooth.iter())
            .filter(|(lo, hi)| lo < hi)
            .map(|range| ColorBar::background_grey("phi_a * f", range));
        // the analysis domain
        r.frame(sk.margin, (255, 220, 0));
        for ch in &sm.chains {
            for &(x, y) in &ch.pixels {
                r.put(x as isize, y as isize, (220, 30, 30));
            }
        }
        let mmax = sm.wtmmm.iter().map(|w| w.m).fold(0.0, f64::max);
        let len = 0.04 * nx.min(ny) as f64;
        for w in &sm.wtmmm {
            let l = len * w.m / mmax;
            let (x0, y0) = (w.x as f64, w.y as f64);
            r.line(
                x0,
                y0,
                x0 + l * w.arg.cos(),
                y0 + l * w.arg.sin(),
                (30, 90, 255),
            );
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (-1, 0), (0, -1)] {
                r.put(w.x as isize + dx, w.y as isize + dy, (0, 200, 60));
            }
        }
        let name = format!("skeleton_j{j:02}_a{:.2}.png", sm.a);
        save_raster_chart(
            &r,
            &RasterChart {
                title: format!(
                    "{} smoothed at a = {:.2} px{}: chains and WTMMM, {} (II Figs 9, 15)",
                    super::common::file_label(&args.image),
                    sm.a,
                    px.as_ref()
                        .map_or(String::new(), |p| format!(" ({})", p.length(sm.a))),
                    cfg.wavelet.name()
                ),
                // the colour key in the picture, not only in skeleton.json
                x_label: format!("x (px{})", super::px_is(px.as_ref().map(PixelSize::plot))),
                y_label: "y (px)".into(),
                // the arrows' scale is the picture's own largest M: said, so
                // that pictures of different scales are compared rightly
                caption: format!(
                    "red: chains, green: WTMMM, blue: M along A ({:.0} px = M {}), \
                     yellow: domain{}",
                    len,
                    super::short_num(mmax),
                    if field.mask.is_some() {
                        ", teal: no data"
                    } else {
                        ""
                    }
                ),
                x_range: (0.0, nx as f64),
                y_range: (0.0, ny as f64),
                colorbar,
                ..Default::default()
            },
            &args.out.out.join(&name),
        )?;
        let mut pic = json!({"j": j, "a": sm.a, "file": name,
            "a_length": px.as_ref().map(|p| sm.a * p.side())});
        if super::common::svg_too() {
            pic["svg"] = json!(name.replace(".png", ".svg"));
        }
        pictures.push(pic);
    }
    let mut body = header(
        "skeleton",
        json!({"image": super::common::path_json(&args.image), "analysis": super::common::analysis_json(&cfg),
            "scales_requested": want, "pixel_size": px.as_ref().map(PixelSize::json),
            "origin": origin.as_ref().map(super::common::PeriodicSynth::json), "nodata": nodata}),
    );
    body["shape"] = json!([ny, nx]);
    body["missing_pixels"] = json!(field.missing_count());
    body["margin"] = json!(sk.margin);
    body["lines"] = json!(sk.lines.len());
    body["per_scale"] = json!(sk.per_scale);
    // per_scale's `lines` counts every line alive, wherever it lies; the
    // partition functions (analyze's `lines`) count fewer: those that
    // reach a second scale, at their points inside the counting domain
    body["lines_counted"] = json!(
        crate::spectra::PartitionSums::from_skeleton_tiled(&sk, &[0.0], "", 0).images[0].lines
    );
    body["pictures"] = json!(pictures);
    body["legend"] = json!(
        "grey: smoothed image phi_a * f (dark = low); red: maxima chains; green dots: WTMMM; blue: arrow of length proportional to M in direction A; yellow: analysis domain; teal: missing pixels"
    );
    body["length_units"] = json!(px.as_ref().map(|p| &p.units));
    body["warnings"] = json!(warnings);
    write_json(&args.out.out.join("skeleton.json"), &body)?;
    for w in &warnings {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}
