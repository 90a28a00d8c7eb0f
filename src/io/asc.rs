//! ESRI ASCII grid reader: a `key value` header (keys case-insensitive),
//! then `nrows` x `ncols` numbers, first row = north (= row 0 of the field).

use std::path::Path;

use super::{ImageFormat, ReadInfo, field_from, read_bytes};
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

pub(super) fn read(path: &Path) -> Result<(Field, ReadInfo)> {
    let bytes = read_bytes(path)?;
    let bad = |reason: String| Error::format(path, format!("ESRI ASCII grid: {reason}"));
    let text = std::str::from_utf8(&bytes).map_err(|_| bad("not a text file".into()))?;
    let mut info = ReadInfo::new(ImageFormat::Asc, "text");

    // Header: lines whose first token is not a number.
    let mut lines = text.lines().peekable();
    let (mut ncols, mut nrows, mut nodata) = (None, None, None);
    while let Some(line) = lines.peek() {
        let mut parts = line.split_whitespace();
        let Some(key) = parts.next() else {
            lines.next();
            continue;
        };
        if key.parse::<f64>().is_ok() {
            break;
        }
        let key = key.to_ascii_lowercase();
        let value = parts.next().unwrap_or("");
        let number = || {
            value
                .parse::<f64>()
                .map_err(|_| bad(format!("header `{key}` has no numeric value")))
        };
        match key.as_str() {
            "ncols" | "nrows" => {
                let n: usize = value
                    .parse()
                    .map_err(|_| bad(format!("header `{key}` is not a count: `{value}`")))?;
                if key == "ncols" {
                    ncols = Some(n)
                } else {
                    nrows = Some(n)
                }
            }
            "nodata_value" => nodata = Some(number()?),
            k if KNOWN.contains(&k) => {
                number()?;
            }
            k => info
                .warnings
                .push(format!("unknown header key `{k}` ignored")),
        }
        lines.next();
    }
    let (Some(nx), Some(ny)) = (ncols, nrows) else {
        return Err(bad(format!(
            "header lacks {}",
            match (ncols, nrows) {
                (None, None) => "ncols and nrows",
                (None, _) => "ncols",
                _ => "nrows",
            }
        )));
    };
    if nx == 0 || ny == 0 {
        return Err(bad(format!("empty image ({ny} x {nx})")));
    }
    let n = nx
        .checked_mul(ny)
        .ok_or_else(|| bad(format!("size {ny} x {nx} is too large")))?;

    let mut values = Vec::with_capacity(n.min(bytes.len() / 2 + 1));
    for tok in lines.flat_map(str::split_whitespace) {
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
    if values.len() != n {
        return Err(bad(format!(
            "wrong value count: expected {n} ({ny} rows x {nx} cols), found {}",
            values.len()
        )));
    }
    Ok((field_from(path, ny, nx, values, nodata)?, info))
}
