//! The pixel spacing a georeferenced file declares (GeoTIFF tags, an ESRI
//! grid's `cellsize` and its `.prj`): what the commands quote lengths in.
//! Only the spacing is read; the exponents never depend on it.

use std::path::Path;

/// The ground size of a pixel a file declares.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelSpacing {
    /// Along the columns (x).
    pub x: f64,
    /// Along the rows (y).
    pub y: f64,
    /// The unit (`m`, `ft`, `US survey ft`, `km`), `None` when the file
    /// does not say (an ESRI grid without `.prj`, a GeoTIFF without units).
    pub units: Option<String>,
    /// Where the numbers come from, e.g. `GeoTIFF ModelPixelScale
    /// 0.000833 x 0.000833 deg at latitude 36.1 (WGS84)`.
    pub source: String,
    /// What the caller may want to say, e.g. that a geographic pixel's
    /// width changes across the image.
    pub warnings: Vec<String>,
}

/// Metres in one `unit` (m, km, cm, mm, ft, US survey ft, mi and their
/// spellings), `None` for a name not known as a length.
pub fn unit_metres(unit: &str) -> Option<f64> {
    let u = unit.trim().to_ascii_lowercase().replace(['_', '-'], " ");
    Some(match u.as_str() {
        "m" | "metre" | "metres" | "meter" | "meters" => 1.0,
        "km" | "kilometre" | "kilometres" | "kilometer" | "kilometers" => 1000.0,
        "cm" | "centimetre" | "centimetres" | "centimeter" | "centimeters" => 0.01,
        "mm" | "millimetre" | "millimetres" | "millimeter" | "millimeters" => 0.001,
        "ft" | "foot" | "feet" => 0.3048,
        "us survey ft" | "us ft" | "ftus" | "foot us" | "us survey foot" => 1200.0 / 3937.0,
        "mi" | "mile" | "miles" => 1609.344,
        _ => return None,
    })
}

/// The ratio of two pixel sides' units, `a` in `b` (1 for the same name,
/// or either unnamed: numbers as they are), `None` when they cannot be
/// compared (different names, one not a length [`unit_metres`] knows).
pub fn unit_ratio(a: Option<&str>, b: Option<&str>) -> Option<f64> {
    match (a, b) {
        (None, _) | (_, None) => Some(1.0),
        (Some(a), Some(b)) if a.trim() == b.trim() => Some(1.0),
        (Some(a), Some(b)) => unit_metres(a).zip(unit_metres(b)).map(|(a, b)| a / b),
    }
}

/// WGS84 semi-major axis (m) and flattening (EPSG:7030).
const WGS84_A: f64 = 6_378_137.0;
const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// Ground lengths (m) of `dlon` x `dlat` degrees at latitude `lat`
/// (degrees), on the WGS84 ellipsoid: the parallel's radius N cos(phi)
/// and the meridian's M = a (1 - e^2) / (1 - e^2 sin^2 phi)^(3/2)
/// (e.g. Snyder 1987, Map Projections, eqs 4-18 and 4-20). Other datums
/// differ by far less than the spacing's own rounding.
pub fn degrees_to_metres(dlon: f64, dlat: f64, lat: f64) -> (f64, f64) {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let (s, c) = lat.to_radians().sin_cos();
    let w = 1.0 - e2 * s * s;
    let n = WGS84_A / w.sqrt();
    let m = WGS84_A * (1.0 - e2) / (w * w.sqrt());
    let rad = std::f64::consts::PI / 180.0;
    (n * c * dlon * rad, m * dlat * rad)
}

/// A geographic spacing (degrees) as metres at the image's middle
/// latitude, with a warning when the pixel's width changes by more than
/// 1 % between its top and bottom rows; `None` when `lat` is not a
/// latitude or the image reaches a pole.
pub(super) fn geographic(
    dlon: f64,
    dlat: f64,
    lat_mid: f64,
    lat_span: f64,
    what: &str,
) -> Option<PixelSpacing> {
    let (lo, hi) = (lat_mid - lat_span / 2.0, lat_mid + lat_span / 2.0);
    if !(lat_mid.is_finite() && lo > -90.0 && hi < 90.0) {
        return None;
    }
    let (x, y) = degrees_to_metres(dlon, dlat, lat_mid);
    Some(PixelSpacing {
        x,
        y,
        units: Some("m".into()),
        source: format!(
            "{what} {} x {} deg at latitude {lat_mid:.3} (WGS84)",
            sig(dlon),
            sig(dlat)
        ),
        warnings: cos_change(lo, hi, "geographic pixels: their width")
            .into_iter()
            .collect(),
    })
}

/// A warning when cos(latitude), which a geographic pixel's width and a
/// Web Mercator pixel's ground size follow, changes by more than 1 %
/// between latitudes `lo` and `hi` (the image's bottom and top rows).
pub(super) fn cos_change(lo: f64, hi: f64, what: &str) -> Option<String> {
    let (c_lo, c_hi) = (lo.to_radians().cos(), hi.to_radians().cos());
    // the widest row is the equator's when the image spans it
    let widest = if lo < 0.0 && hi > 0.0 {
        1.0
    } else {
        c_lo.max(c_hi)
    };
    let change = (widest - c_lo.min(c_hi)) / widest;
    (change > 0.01).then(|| {
        format!(
            "{what} changes by {:.1} % between the image's top and bottom rows (latitudes \
             {lo:.2} to {hi:.2}); lengths use the middle latitude",
            100.0 * change
        )
    })
}

/// A Web Mercator spacing (map metres, `dx` x `dy`) as ground metres:
/// times cos(latitude) at the middle row (map y `y_mid`, `ny` rows), the
/// sphere's scale factor (on the WGS84 ellipsoid the true one differs by
/// less than 0.2 %), with a warning when it changes by more than 1 %
/// across the image. `None` when the image reaches a pole.
pub(super) fn web_mercator(
    dx: f64,
    dy: f64,
    y_mid: f64,
    ny: f64,
    what: &str,
) -> Option<PixelSpacing> {
    let lat = |y: f64| (y / WGS84_A).sinh().atan().to_degrees();
    let half = dy * ny / 2.0;
    let (lo, mid, hi) = (lat(y_mid - half), lat(y_mid), lat(y_mid + half));
    if !(lo > -90.0 && hi < 90.0 && mid.is_finite()) {
        return None;
    }
    let c = mid.to_radians().cos();
    Some(PixelSpacing {
        x: dx * c,
        y: dy * c,
        units: Some("m".into()),
        source: format!(
            "{what} {} x {} m of Web Mercator at latitude {mid:.3} (ground = map x \
             cos(latitude))",
            sig(dx),
            sig(dy)
        ),
        warnings: cos_change(lo, hi, "Web Mercator pixels: their ground size")
            .into_iter()
            .collect(),
    })
}

/// A number with 6 significant digits, for the sources.
pub(super) fn sig(v: f64) -> String {
    let s = format!("{v:.5e}");
    s.parse::<f64>().map_or(s, |p| p.to_string())
}

/// A linear unit's name from its factor to metres (1, 0.3048, 1200/3937,
/// 1000), or `None` when it is none of those.
pub(super) fn linear_unit(to_metres: f64) -> Option<&'static str> {
    [
        (1.0, "m"),
        (0.3048, "ft"),
        (1200.0 / 3937.0, "US survey ft"),
        (1000.0, "km"),
    ]
    .into_iter()
    .find(|(f, _)| (to_metres / f - 1.0).abs() < 1e-9)
    .map(|(_, n)| n)
}

/// What an ESRI `.prj` (WKT 1, or WKT 2's `GEOGCRS`/`PROJCRS`) says of a
/// grid's units: `Some(Geographic)`, `Some(Linear(factor to metres))`
/// from the last `UNIT[...]` of a projected system (the linear one comes
/// after the geographic system's angular one), `None` when it says
/// neither.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum PrjUnits {
    Geographic,
    Linear(f64),
    /// Web Mercator (EPSG:3857, ESRI's Mercator_Auxiliary_Sphere): map
    /// metres, ground = map x cos(latitude).
    WebMercator,
}

pub(super) fn prj_units(text: &str) -> Option<PrjUnits> {
    let t = text
        .trim_start_matches('\u{feff}')
        .trim_start()
        .to_ascii_uppercase();
    // old ArcInfo .prj: `Units METERS` / `FEET` / `DD` lines
    if !t.starts_with(|c: char| c.is_ascii_alphabetic()) || !t.contains('[') && !t.contains('(') {
        return t.lines().find_map(|l| {
            let mut w = l.split_whitespace();
            (w.next()? == "UNITS").then_some(())?;
            match w.next()? {
                "METERS" | "METRES" => Some(PrjUnits::Linear(1.0)),
                "FEET" => Some(PrjUnits::Linear(0.3048)),
                "DD" => Some(PrjUnits::Geographic),
                _ => None,
            }
        });
    }
    // WKT: brackets or parentheses, blanks before them allowed
    let mut t: String = t.split_whitespace().collect::<Vec<_>>().join(" ");
    for (a, b) in [(" [", "["), (" (", "("), ("(", "["), (")", "]")] {
        t = t.replace(a, b);
    }
    // a compound system (horizontal + vertical): the horizontal part
    let t = if t.starts_with("COMPD_CS") || t.starts_with("COMPOUNDCRS") {
        let start = ["PROJCS[", "PROJCRS[", "GEOGCS[", "GEOGCRS[", "GEODCRS["]
            .iter()
            .filter_map(|k| t.find(k))
            .min()?;
        let end = ["VERT_CS[", "VERTCRS["]
            .iter()
            .filter_map(|k| t.find(k))
            .filter(|&e| e > start)
            .min()
            .unwrap_or(t.len());
        t[start..end].to_string()
    } else {
        t
    };
    if t.starts_with("GEOGCS") || t.starts_with("GEOGCRS") || t.starts_with("GEODCRS") {
        return Some(PrjUnits::Geographic);
    }
    if !(t.starts_with("PROJCS") || t.starts_with("PROJCRS")) {
        return None;
    }
    if [
        "AUXILIARY_SPHERE",
        "PSEUDO-MERCATOR",
        "PSEUDO_MERCATOR",
        "\"EPSG\",\"3857\"",
        "\"EPSG\",3857",
    ]
    .iter()
    .any(|k| t.contains(k))
    {
        return Some(PrjUnits::WebMercator);
    }
    // UNIT["Meter",1.0] or LENGTHUNIT["metre",1]
    let at = t.rfind("UNIT[")?;
    let inner = &t[at + 5..];
    let inner = &inner[..inner.find(']')?];
    let factor = inner.split(',').nth(1)?.trim().parse::<f64>().ok()?;
    (factor.is_finite() && factor > 0.0).then_some(PrjUnits::Linear(factor))
}

/// The `.prj` beside `path`, if there is one (case of the extension as the
/// file's, then lower, then upper case).
pub(super) fn read_prj(path: &Path) -> Option<String> {
    // a .prj is a few hundred bytes; a large file there is not one
    sidecar(path, "prj", 1 << 20).map(|(_, t)| t)
}

/// The text of the file beside `path` with extension `ext` (in the case
/// of `path`'s extension, then lower, then upper case) and its path, if
/// there is one of fewer than `max` bytes.
fn sidecar(path: &Path, ext: &str, max: u64) -> Option<(std::path::PathBuf, String)> {
    let upper = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.chars().all(|c| c.is_ascii_uppercase()));
    let first = if upper {
        ext.to_ascii_uppercase()
    } else {
        ext.to_ascii_lowercase()
    };
    [first, ext.to_ascii_lowercase(), ext.to_ascii_uppercase()]
        .into_iter()
        .find_map(|e| {
            let p = path.with_extension(e);
            let t = std::fs::metadata(&p)
                .ok()
                .filter(|m| m.len() < max)
                .and_then(|_| std::fs::read_to_string(&p).ok())?;
            Some((p, t))
        })
}

/// The world file beside an image (`a.tfw`, `a.tifw` or `a.wld` for
/// `a.tif`; `a.pgw`, `a.pngw`, `a.wld` for `a.png`; `a.wld` for `a.pgm`):
/// six numbers A, D, B, E, C, F mapping pixel (col, row) to X = A col +
/// B row + C, Y = D col + E row + F (the pixel's centre; ESRI's world
/// file convention, also GDAL's). The spacing is |(A, D)| x |(B, E)|, in
/// the units of the `.prj` beside the image (geographic: metres at the
/// middle latitude, from F and E and the image's `ny` rows); without a
/// `.prj`, units unknown. `None` without a world file or with one that is
/// not six finite numbers, or a degenerate one.
pub(super) fn world_file(path: &Path, ny: usize) -> Option<PixelSpacing> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    let stems: &[&str] = match ext.as_str() {
        "tif" => &["tfw", "tifw", "wld"],
        "tiff" => &["tfw", "tiffw", "wld"],
        "png" => &["pgw", "pngw", "wld"],
        "pgm" => &["wld"],
        _ => return None,
    };
    let (wf, text) = stems.iter().find_map(|e| sidecar(path, e, 4096))?;
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .ok()?;
    let [a, d, b, e, _c, f] = <[f64; 6]>::try_from(v).ok()?;
    if !(a.is_finite() && d.is_finite() && b.is_finite() && e.is_finite() && f.is_finite()) {
        return None;
    }
    let (x, y) = (a.hypot(d), b.hypot(e));
    if !(x > 0.0 && y > 0.0) {
        return None;
    }
    let name = wf.file_name()?.to_string_lossy().into_owned();
    // the middle row's y, from the first row's centre
    let mid = f + e * (ny as f64 - 1.0) / 2.0;
    with_prj(
        path,
        x,
        y,
        Some(mid),
        ny as f64,
        &format!("world file {name}"),
    )
}

/// A spacing `x` x `y` in the units of the `.prj` beside `path`:
/// projected, its linear unit (an unknown one converted to metres by its
/// factor); geographic, metres at the middle row's latitude `y_mid` (in
/// the system's units: degrees; `ny` rows); Web Mercator, ground metres;
/// without a `.prj` (or one not understood), units unknown, said in the
/// source. `None` when a geographic or Web Mercator spacing has no
/// middle row, or reaches a pole.
pub(super) fn with_prj(
    path: &Path,
    x: f64,
    y: f64,
    y_mid: Option<f64>,
    ny: f64,
    what: &str,
) -> Option<PixelSpacing> {
    let prj = read_prj(path);
    let plain = |units: Option<String>, note: String| PixelSpacing {
        x,
        y,
        units,
        source: format!("{what} {} x {}{note}", sig(x), sig(y)),
        warnings: Vec::new(),
    };
    match prj.as_deref().and_then(prj_units) {
        Some(PrjUnits::Geographic) => {
            let g = geographic(x, y, y_mid?, y * ny, what)?;
            Some(PixelSpacing {
                source: format!("{} (.prj: geographic)", g.source),
                ..g
            })
        }
        Some(PrjUnits::WebMercator) => web_mercator(x, y, y_mid?, ny, what),
        Some(PrjUnits::Linear(f)) => Some(match linear_unit(f) {
            Some(u) => plain(Some(u.into()), " (.prj: projected)".into()),
            None => PixelSpacing {
                x: x * f,
                y: y * f,
                ..plain(
                    Some("m".into()),
                    format!(" (.prj: projected, a unit of {} m)", sig(f)),
                )
            },
        }),
        None => Some(plain(
            None,
            if prj.is_some() {
                " (a .prj whose units were not understood)".into()
            } else {
                " (no .prj: units unknown)".into()
            },
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One degree on WGS84: 111 320 m along the equator, 110 574 m of
    /// meridian there and 111 694 m at the pole (standard tables); 3 arc
    /// seconds at 36 N, 75.136 x 92.466 m (N cos phi and M by hand: 6 385 519 and 6 357 487 m).
    #[test]
    fn degrees_become_metres_on_wgs84() {
        let (x, y) = degrees_to_metres(1.0, 1.0, 0.0);
        assert!((x - 111_319.49).abs() < 0.01, "{x}");
        assert!((y - 110_574.3).abs() < 0.1, "{y}");
        let (_, y90) = degrees_to_metres(1.0, 1.0, 89.999_999);
        assert!((y90 - 111_693.9).abs() < 0.1, "{y90}");
        let s = 3.0 / 3600.0;
        let (x, y) = degrees_to_metres(s, s, 36.0);
        assert!(
            (x - 75.136).abs() < 0.001 && (y - 92.466).abs() < 0.001,
            "{x} {y}"
        );
        // a tall image at high latitude: warned about
        let g = geographic(s, s, 60.0, 2.0, "t").unwrap();
        assert!(g.warnings[0].contains("5.9 %"), "{:?}", g.warnings);
        assert!(
            geographic(s, s, 36.0, 0.3, "t")
                .unwrap()
                .warnings
                .is_empty()
        );
        assert!(geographic(s, s, 89.9, 1.0, "t").is_none());
        // across the equator the widest row is the equator's: -10 .. +10
        // changes the width by 1 - cos 10 = 1.5 %
        let w = geographic(s, s, 0.0, 20.0, "t").unwrap().warnings;
        assert!(w.len() == 1 && w[0].contains("1.5 %"), "{w:?}");
        assert!(geographic(s, s, f64::NAN, 1.0, "t").is_none());
    }

    /// The units of ESRI and WKT 2 `.prj` texts.
    #[test]
    fn prj_units_are_read() {
        let utm = r#"PROJCS["WGS_1984_UTM_Zone_33N",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["Central_Meridian",15.0],UNIT["Meter",1.0]]"#;
        assert_eq!(prj_units(utm), Some(PrjUnits::Linear(1.0)));
        let ft = r#"PROJCS["x",GEOGCS["y",UNIT["Degree",0.0174532925199433]],UNIT["Foot_US",0.3048006096012192]]"#;
        assert_eq!(
            prj_units(ft).map(|u| match u {
                PrjUnits::Linear(f) => linear_unit(f),
                _ => None,
            }),
            Some(Some("US survey ft"))
        );
        let geo = "GEOGCS[\"GCS_WGS_1984\",DATUM[\"D_WGS_1984\"],UNIT[\"Degree\",0.017453]]";
        assert_eq!(prj_units(geo), Some(PrjUnits::Geographic));
        let wkt2 = "PROJCRS[\"a\",BASEGEOGCRS[\"b\"],CS[Cartesian,2],LENGTHUNIT[\"metre\",1]]";
        assert_eq!(prj_units(wkt2), Some(PrjUnits::Linear(1.0)));
        assert_eq!(prj_units("nonsense"), None);
        // a byte-order mark, blanks before brackets, parentheses
        let bom = "\u{feff}PROJCS [\"a\", UNIT [\"Meter\", 1.0]]";
        assert_eq!(prj_units(bom), Some(PrjUnits::Linear(1.0)));
        assert_eq!(
            prj_units("PROJCS(\"a\",UNIT(\"Foot\",0.3048))"),
            Some(PrjUnits::Linear(0.3048))
        );
        // a compound system: the horizontal part's unit, not the vertical's
        let compd = "COMPD_CS[\"c\",PROJCS[\"u\",UNIT[\"US survey foot\",0.3048006096012192]],VERT_CS[\"v\",UNIT[\"metre\",1]]]";
        assert_eq!(prj_units(compd), Some(PrjUnits::Linear(0.3048006096012192)));
        // Web Mercator, ESRI's and EPSG's
        let aux = "PROJCS[\"WGS_1984_Web_Mercator_Auxiliary_Sphere\",PROJECTION[\"Mercator_Auxiliary_Sphere\"],UNIT[\"Meter\",1.0]]";
        assert_eq!(prj_units(aux), Some(PrjUnits::WebMercator));
        let epsg =
            "PROJCS[\"WGS 84 / Pseudo-Mercator\",UNIT[\"metre\",1],AUTHORITY[\"EPSG\",\"3857\"]]";
        assert_eq!(prj_units(epsg), Some(PrjUnits::WebMercator));
        // old ArcInfo
        let arc =
            "Projection    UTM\nZone          33\nDatum         WGS84\nUnits         METERS\n";
        assert_eq!(prj_units(arc), Some(PrjUnits::Linear(1.0)));
        assert_eq!(
            prj_units("Projection GEOGRAPHIC\nUnits DD\n"),
            Some(PrjUnits::Geographic)
        );
        assert_eq!(prj_units("PROJCS[\"a\",UNIT[\"m\",x]]"), None);
        assert_eq!(linear_unit(0.3048), Some("ft"));
        assert_eq!(linear_unit(0.5), None);
    }
}
