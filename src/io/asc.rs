//! ESRI ASCII grid reader: a `key value` header (keys case-insensitive),
//! then `nrows` x `ncols` numbers, first row = north (= row 0 of the field).

use std::path::Path;

use super::georef::PixelSpacing;
use super::{ImageFormat, ReadInfo, field_from, read_bytes, read_prefix, whole_lines};
use crate::error::{Error, Result};
use crate::field::Field;

const KNOWN: &[&str] = &[
    "ncols",
    "nrows",
    "xllcorner",
    "xllcenter",
    "yllcorner",
    "yllcenter",
    "cellsize",
    "dx",
    "dy",
    "nodata_value",
];

/// An ESRI ASCII grid header: lines whose first token is a key (starts
/// with a letter); `body` is the byte offset of the first data line.
struct Header {
    nx: usize,
    ny: usize,
    nodata: Option<f64>,
    /// `cellsize`, or `dx` and `dy`.
    cell: Option<(f64, f64)>,
    /// The lower edge's y (`yllcorner`), or its centre's (`yllcenter`).
    yll: Option<(f64, bool)>,
    body: usize,
    warnings: Vec<String>,
}

impl Header {
    fn parse(text: &str) -> std::result::Result<Header, String> {
        let (mut ncols, mut nrows, mut nodata) = (None, None, None);
        let (mut cellsize, mut dx, mut dy, mut yll) = (None, None, None, None);
        let (mut body, mut warnings) = (0, Vec::new());
        for line in text.split_inclusive('\n') {
            let mut parts = line.split_whitespace();
            if let Some(key) = parts.next() {
                if !key.starts_with(|c: char| c.is_ascii_alphabetic()) || key.parse::<f64>().is_ok()
                {
                    break;
                }
                let key = key.to_ascii_lowercase();
                let value = parts.next().unwrap_or("");
                let number = || {
                    value
                        .parse::<f64>()
                        .map_err(|_| format!("header `{key}` has no numeric value"))
                };
                match key.as_str() {
                    "ncols" | "nrows" => {
                        let n: usize = value
                            .parse()
                            .map_err(|_| format!("header `{key}` is not a count: `{value}`"))?;
                        if key == "ncols" {
                            ncols = Some(n)
                        } else {
                            nrows = Some(n)
                        }
                    }
                    "nodata_value" => nodata = Some(number()?),
                    "cellsize" => cellsize = Some(number()?),
                    "dx" => dx = Some(number()?),
                    "dy" => dy = Some(number()?),
                    "yllcorner" => yll = Some((number()?, false)),
                    "yllcenter" => yll = Some((number()?, true)),
                    k if KNOWN.contains(&k) => {
                        number()?;
                    }
                    k => warnings.push(format!("unknown header key `{k}` ignored")),
                }
            }
            body += line.len();
        }
        let (Some(nx), Some(ny)) = (ncols, nrows) else {
            return Err(format!(
                "header lacks {}",
                match (ncols, nrows) {
                    (None, None) => "ncols and nrows",
                    (None, _) => "ncols",
                    _ => "nrows",
                }
            ));
        };
        let given = cellsize.map(|c| (c, c)).or(dx.zip(dy));
        let cell = given.filter(|&(x, y)| x.is_finite() && y.is_finite() && x > 0.0 && y > 0.0);
        if let (Some((x, y)), None) = (given, cell) {
            // said, not silently read as "no pixel declared"
            let what = match cellsize {
                Some(c) => format!("cellsize {c}"),
                None => format!("dx {x}, dy {y}"),
            };
            warnings.push(format!(
                "the header's {what} is no pixel size (need > 0): no pixel is taken from it \
                 (give --pixel-size)"
            ));
        }
        Ok(Header {
            nx,
            ny,
            nodata,
            cell,
            yll,
            body,
            warnings,
        })
    }
}

/// The text of `bytes` without a byte-order mark (some Windows editors
/// start UTF-8 files with one).
fn text(bytes: &[u8]) -> std::result::Result<&str, String> {
    let text = std::str::from_utf8(bytes).map_err(|_| "not a text file".to_string())?;
    Ok(text.strip_prefix('\u{feff}').unwrap_or(text))
}

/// The header of a grid without its values: `Err` when the file cannot
/// be read, `Ok(Err(why))` when the header is not a grid's.
fn header(path: &Path) -> Result<std::result::Result<Header, String>> {
    let (prefix, whole) = read_prefix(path)?;
    // whole lines (a prefix never ends inside a character); a header the
    // prefix does not hold whole (a line longer than it) is read from the
    // whole file
    Ok(
        match text(whole_lines(&prefix, whole)).and_then(Header::parse) {
            Err(_) if !whole => text(&read_bytes(path)?).and_then(Header::parse),
            h => h,
        },
    )
}

/// The `(ny, nx)` of a grid from its header (super::read_shape).
pub(super) fn shape(path: &Path) -> Result<(usize, usize)> {
    let h = header(path)?
        .map_err(|reason| Error::format(path, format!("ESRI ASCII grid: {reason}")))?;
    Ok((h.ny, h.nx))
}

/// The pixel spacing of a grid (super::read_pixel_spacing): `cellsize`
/// (or `dx`, `dy`), in the units of the `.prj` beside it: a projected
/// system's linear unit, or degrees made metres at the grid's middle
/// latitude; without a `.prj`, units unknown. `Ok(None)` for a header
/// without a spacing; a header that cannot be read is left to the
/// reader's error (also `Ok(None)`).
pub(super) fn pixel(path: &Path) -> Result<Option<PixelSpacing>> {
    use super::georef::with_prj;
    let Ok(Header {
        ny,
        cell: Some((dx, dy)),
        yll,
        ..
    }) = header(path)?
    else {
        return Ok(None);
    };
    // the middle row's y, from the lower edge (or its centre)
    let y_mid = yll.map(|(y, centre)| {
        let bottom = if centre { y - dy / 2.0 } else { y };
        bottom + dy * ny as f64 / 2.0
    });
    Ok(with_prj(path, dx, dy, y_mid, ny as f64, "ESRI grid cell"))
}

pub(super) fn read(path: &Path) -> Result<(Field, ReadInfo)> {
    let bytes = read_bytes(path)?;
    let bad = |reason: String| Error::format(path, format!("ESRI ASCII grid: {reason}"));
    let text = text(&bytes).map_err(bad)?;
    let mut info = ReadInfo::new(ImageFormat::Asc, "text");
    let Header {
        nx,
        ny,
        nodata,
        body,
        warnings,
        ..
    } = Header::parse(text).map_err(bad)?;
    info.warnings = warnings;
    let lines = text[body..].lines();
    if nx == 0 || ny == 0 {
        return Err(bad(format!("empty image ({ny} x {nx})")));
    }
    let n = nx
        .checked_mul(ny)
        .ok_or_else(|| bad(format!("size {ny} x {nx} is too large")))?;

    let mut values = Vec::with_capacity(n.min(bytes.len() / 2 + 1));
    // Values are read as one stream (as GDAL does: writers may wrap long
    // rows), but a data line that runs across the end of a row, when there
    // are several lines, means the rows are ragged or ncols and nrows
    // disagree with them.
    let (mut data_lines, mut misaligned) = (0usize, None);
    for line in lines {
        let first = values.len();
        for tok in line.split_whitespace() {
            if values.len() == n {
                return Err(bad(format!(
                    "wrong value count: expected {n} ({ny} rows x {nx} cols), found more"
                )));
            }
            let v = tok.parse::<f64>().map_err(|_| {
                bad(format!(
                    "value {} is not a number: `{tok}`",
                    values.len() + 1
                ))
            })?;
            values.push(v);
        }
        if values.len() > first {
            data_lines += 1;
            let spans = first / nx != (values.len() - 1) / nx;
            if spans && misaligned.is_none() {
                misaligned = Some(data_lines);
            }
        }
    }
    if let Some(line) = misaligned.filter(|_| data_lines > 1) {
        info.warnings.push(format!(
            "data line {line} runs across the end of a row (ncols = {nx}): rows are ragged \
             or ncols/nrows do not describe them; read as one stream in row order"
        ));
    }
    if values.len() != n {
        return Err(bad(format!(
            "wrong value count: expected {n} ({ny} rows x {nx} cols), found {}",
            values.len()
        )));
    }
    Ok((field_from(path, ny, nx, values, nodata)?, info))
}
