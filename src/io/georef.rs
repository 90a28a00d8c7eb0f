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
    let change = (c_lo - c_hi).abs() / c_lo.max(c_hi);
    (change > 0.01).then(|| {
        format!(
            "{what} changes by {:.1} % between the image's top and bottom rows (latitudes \
             {lo:.2} to {hi:.2}); lengths use the middle latitude",
            100.0 * change
        )
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
}

pub(super) fn prj_units(text: &str) -> Option<PrjUnits> {
    let t = text.trim_start().to_ascii_uppercase();
    if t.starts_with("GEOGCS") || t.starts_with("GEOGCRS") || t.starts_with("GEODCRS") {
        return Some(PrjUnits::Geographic);
    }
    if !(t.starts_with("PROJCS") || t.starts_with("PROJCRS")) {
        return None;
    }
    // UNIT["Meter",1.0] or LENGTHUNIT["metre",1]
    let at = t.rfind("UNIT[")?;
    let inner = &t[at + 5..];
    let inner = &inner[..inner.find(']')?];
    let factor = inner.split(',').nth(1)?.trim().parse::<f64>().ok()?;
    (factor.is_finite() && factor > 0.0).then_some(PrjUnits::Linear(factor))
}

/// The `.prj` beside `path`, if there is one (case of the extension as the
/// file's, then lower case).
pub(super) fn read_prj(path: &Path) -> Option<String> {
    let upper = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.chars().all(|c| c.is_ascii_uppercase()));
    let first = path.with_extension(if upper { "PRJ" } else { "prj" });
    // a .prj is a few hundred bytes; a large file there is not one
    let read = |p: &Path| {
        std::fs::metadata(p)
            .ok()
            .filter(|m| m.len() < 1 << 20)
            .and_then(|_| std::fs::read_to_string(p).ok())
    };
    read(&first).or_else(|| read(&path.with_extension("prj")))
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
        assert_eq!(prj_units("PROJCS[\"a\",UNIT[\"m\",x]]"), None);
        assert_eq!(linear_unit(0.3048), Some("ft"));
        assert_eq!(linear_unit(0.5), None);
    }
}
