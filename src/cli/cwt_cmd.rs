//! `wtmm cwt IMAGE --scales LIST --out DIR`: modulus and argument images.

use std::path::PathBuf;

use clap::Args;
use serde_json::json;

use super::common::save_raster_chart;
use super::common::{file_label, header, make_out_dir, parse_list, progress, write_json};
use super::{OutDir, Outcome};
use crate::cwt::{CwtPlan, Wavelet, default_margin, modulus_argument};
use crate::error::{Error, Result};
use crate::io::write_npy;
use crate::plot::{ColorBar, Raster, RasterChart};

/// Most scales one `cwt` run writes (the analysis grid has 50).
const MAX_SCALES: usize = 1000;

#[derive(Args, Debug)]
pub struct CwtArgs {
    /// Input image.
    pub image: PathBuf,
    /// Scales in pixels: `a,b,c` or `start:stop:step`.
    #[arg(long, default_value = "2,4,8,16")]
    pub scales: String,
    /// Analysing wavelet (gauss: 1 vanishing moment; mexican: 3).
    #[arg(long, value_enum, default_value_t = Wavelet::Gauss)]
    pub wavelet: Wavelet,
    /// Trend removed before the transform (`plane`: the least-squares plane,
    /// as analyze --detrend).
    #[arg(long, value_enum, default_value_t = crate::field::Trend::None)]
    pub detrend: crate::field::Trend,
    #[command(flatten)]
    pub read: super::ReadOpts,
    #[command(flatten)]
    pub out: OutDir,
}

pub fn run(args: CwtArgs, quiet: bool) -> Result<Outcome> {
    let nodata = args.read.value()?;
    let field = super::common::read_image(&args.image, nodata)?;
    let (ny, nx) = field.dim();
    super::common::check_cwt_memory(&args.image, ny, nx)?;
    super::common::refuse_constant(&field, &args.image, "its wavelet transform is zero")?;
    let scales = parse_list("scales", &args.scales)?;
    if scales.len() > MAX_SCALES {
        return Err(Error::param(
            "scales",
            format!(
                "{} scales: at most {MAX_SCALES} (each writes two full-size arrays and a picture)",
                scales.len()
            ),
        ));
    }
    let (ny, nx) = field.dim();
    let plan = CwtPlan::new(ny, nx, args.wavelet, &scales)
        .map_err(|e| super::common::in_file(&args.image, e))?;
    let margin = plan.default_margin();
    // the whole transform is written; where the wavelet reaches the border
    // it sees the image's periodic continuation (the FFT's), which is exact
    // for a periodic image (the synthetic cascades) and not for a DEM
    let mut warnings = Vec::new();
    let untrusted: Vec<f64> = scales
        .iter()
        .copied()
        .filter(|&a| 2 * default_margin(args.wavelet, a) >= ny.min(nx))
        .collect();
    if args.detrend == crate::field::Trend::Plane && field.fit_plane().is_none() {
        warnings.push(
            "--detrend plane: the valid pixels fix no plane (fewer than 3, or all on one \
             line): nothing removed"
                .to_string(),
        );
    }
    if !untrusted.is_empty() {
        warnings.push(format!(
            "at a = {} px the wavelet's support reaches the border from every pixel of the \
             {ny}x{nx} image: those transforms see its periodic continuation everywhere (exact \
             only for a periodic image)",
            untrusted
                .iter()
                .map(|a| format!("{a}"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let img = field
        .transform_input(args.detrend)
        .map_err(|e| super::common::in_file(&args.image, e))?;
    // the transform is not trusted where the wavelet's support (radius R a)
    // reaches a missing pixel: NaN there, as the analysis drops such maxima
    let mask_distance = field.mask.as_ref().map(crate::skeleton::distance_to_mask);
    let support = args.wavelet.support_radius();
    make_out_dir(&args.out.out)?;
    let pb = progress(scales.len() as u64, "cwt", quiet);
    let mut files = Vec::new();
    let mut err = None;
    plan.for_each_scale(img.view(), |j, a, t| {
        if err.is_some() {
            return;
        }
        let (mut m, mut arg) = modulus_argument(t);
        if let Some(d) = &mask_distance {
            let r = (support * a) as f32;
            for ((mv, av), &dv) in m.iter_mut().zip(arg.iter_mut()).zip(d.iter()) {
                if dv <= r {
                    (*mv, *av) = (f64::NAN, f64::NAN);
                }
            }
        }
        let stem = format!("{j:02}");
        let r = (|| {
            write_npy(args.out.out.join(format!("modulus_{stem}.npy")), &m)?;
            write_npy(args.out.out.join(format!("argument_{stem}.npy")), &arg)?;
            save_modulus_png(
                m.view(),
                a,
                default_margin(args.wavelet, a),
                &format!("{}, {} wavelet", file_label(&args.image), args.wavelet.name()),
                &args.out.out.join(format!("modulus_{stem}.png")),
            )
        })();
        match r {
            Ok(()) => {
                let mut f = json!({"index": j, "a": a, "modulus": format!("modulus_{stem}.npy"), "argument": format!("argument_{stem}.npy"), "png": format!("modulus_{stem}.png")});
                if super::common::svg_too() {
                    f["svg"] = json!(format!("modulus_{stem}.svg"));
                }
                files.push(f)
            }
            Err(e) => err = Some(e),
        }
        pb.inc(1);
    })?;
    pb.finish_and_clear();
    if let Some(e) = err {
        return Err(e);
    }
    let mut body = header(
        "cwt",
        json!({"image": super::common::path_json(&args.image), "wavelet": args.wavelet, "scales": scales, "detrend": args.detrend, "nodata": nodata}),
    );
    body["margin"] = json!(margin);
    body["margin_rule"] = json!(format!(
        "at each scale the transform feels the border within ceil({:.2} a) px of it (the \
         wavelet's support), outlined in the pictures, whose grey scale spans the values inside",
        args.wavelet.support_radius()
    ));
    body["warnings"] = json!(warnings);
    body["missing_pixels"] = json!(
        field
            .mask
            .as_ref()
            .map_or(0, |m| m.iter().filter(|&&v| v).count())
    );
    body["missing_rule"] = json!(format!(
        "modulus and argument are NaN where the wavelet support (radius {support:.2} a) reaches a missing pixel"
    ));
    body["shape"] = json!([ny, nx]);
    body["convention"] = json!(
        "T = a grad(phi_a * f), L1 normalisation (II eqs 1-3; README, Conventions); argument = atan2(T2, T1), y down"
    );
    body["scales"] = json!(files);
    write_json(&args.out.out.join("cwt.json"), &body)?;
    for w in &warnings {
        say!("warning: {}: {w}", args.image.display());
    }
    Ok(Outcome::Ok)
}

/// The modulus at scale `a` as a grey picture inside pixel axes, with a
/// grey bar giving the values: the grey scale spans the pixels farther
/// than `margin` px from the border (the border's periodic wrap makes
/// artefacts there that would otherwise set it), that interior outlined in
/// yellow; NaN teal, named in the axis label when there is any.
fn save_modulus_png(
    m: ndarray::ArrayView2<f64>,
    a: f64,
    margin: usize,
    what: &str,
    path: &std::path::Path,
) -> Result<()> {
    let (ny, nx) = m.dim();
    let inside = 2 * margin < ny.min(nx);
    let core = if inside {
        m.slice(ndarray::s![margin..ny - margin, margin..nx - margin])
    } else {
        m.view()
    };
    let (lo, hi) = crate::field::finite_range(core.iter()).unwrap_or((0.0, 0.0));
    let mut raster = Raster::grey_in(m, (0, 255), (lo, hi));
    if inside && margin > 0 {
        // as the skeleton pictures draw their domain
        raster.frame(margin, (255, 220, 0));
    }
    let mut key = Vec::new();
    if inside && margin > 0 {
        key.push("yellow: where the border is not felt (grey scale set inside)");
    }
    if m.iter().any(|v| v.is_nan()) {
        key.push("teal: no value (the wavelet reaches a missing pixel)");
    }
    let colorbar = (lo < hi).then(|| ColorBar {
        label: "M".into(),
        range: (lo, hi),
        colors: |t| {
            let g = (255.0 * t.clamp(0.0, 1.0)).round() as u8;
            plotters::style::RGBColor(g, g, g)
        },
    });
    save_raster_chart(
        &raster,
        &RasterChart {
            title: format!("modulus M(b, a), a = {a:.2} px, {what}"),
            x_label: "x (px)".into(),
            y_label: "y (px)".into(),
            caption: key.join("\n"),
            x_range: (0.0, nx as f64),
            y_range: (0.0, ny as f64),
            colorbar,
            ..Default::default()
        },
        path,
    )
}
