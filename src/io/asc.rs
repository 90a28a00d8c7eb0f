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
    // some Windows editors start UTF-8 files with a byte-order mark
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut info = ReadInfo::new(ImageFormat::Asc, "text");

    // Header: lines whose first token is a key (starts with a letter).
    let mut lines = text.lines().peekable();
    let (mut ncols, mut nrows, mut nodata) = (None, None, None);
    while let Some(line) = lines.peek() {
        let mut parts = line.split_whitespace();
        let Some(key) = parts.next() else {
            lines.next();
            continue;
        };
        if !key.starts_with(|c: char| c.is_ascii_alphabetic()) || key.parse::<f64>().is_ok() {
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
