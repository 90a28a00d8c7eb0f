//! Netpbm greymap reader: P5 (binary, 1 or 2 bytes big-endian per sample)
//! and P2 (ASCII). Values are the raw integers (not divided by maxval).

use std::path::Path;

use super::{ImageFormat, ReadInfo, field_from, read_bytes, read_prefix, whole_lines};
use crate::error::{Error, Result};
use crate::field::Field;

/// A PGM header: raster format, size, maxval, and where the tokens after
/// maxval start.
struct Header {
    binary: bool,
    nx: u64,
    ny: u64,
    maxval: u64,
    end: usize,
}

impl Header {
    fn parse(bytes: &[u8]) -> std::result::Result<Header, String> {
        let mut t = Tokens { b: bytes, i: 0 };
        let magic = t.next().ok_or("empty file")?;
        let binary = match magic {
            b"P5" => true,
            b"P2" => false,
            b"P1" | b"P4" => return Err("bitmap (PBM) file; need a P2 or P5 greymap".into()),
            b"P3" | b"P6" => return Err("colour (PPM) file; need a P2 or P5 greymap".into()),
            b"P7" => return Err("PAM file; need a P2 or P5 greymap".into()),
            _ => return Err("not a PGM file (bad magic number)".into()),
        };
        let mut header = |what: &str| -> std::result::Result<u64, String> {
            let tok = t
                .next()
                .ok_or_else(|| format!("truncated header (no {what})"))?;
            std::str::from_utf8(tok)
                .ok()
                .and_then(|s| s.parse().ok())
                .ok_or_else(|| format!("bad {what} in header"))
        };
        let nx = header("width")?;
        let ny = header("height")?;
        let maxval = header("maxval")?;
        if !(1..=65535).contains(&maxval) {
            return Err(format!("maxval {maxval} outside 1..=65535"));
        }
        if nx == 0 || ny == 0 {
            return Err(format!("empty image ({ny} x {nx})"));
        }
        Ok(Header {
            binary,
            nx,
            ny,
            maxval,
            end: t.i,
        })
    }
}

/// The `(ny, nx)` of a PGM from its header (super::read_shape).
pub(super) fn shape(path: &Path) -> Result<(usize, usize)> {
    let (prefix, whole) = read_prefix(path)?;
    // a header the prefix does not hold whole (lines ended by CR or spaces
    // only, a long comment) is read from the whole file
    let h = match Header::parse(whole_lines(&prefix, whole)) {
        Err(_) if !whole => Header::parse(&read_bytes(path)?),
        h => h,
    }
    .map_err(|reason| Error::format(path, format!("PGM: {reason}")))?;
    let size = |n: u64| {
        usize::try_from(n).map_err(|_| Error::format(path, format!("PGM: size {n} is too large")))
    };
    Ok((size(h.ny)?, size(h.nx)?))
}

pub(super) fn read(path: &Path) -> Result<(Field, ReadInfo)> {
    let bytes = read_bytes(path)?;
    let bad = |reason: String| Error::format(path, format!("PGM: {reason}"));
    let Header {
        binary,
        nx,
        ny,
        maxval,
        end,
    } = Header::parse(&bytes).map_err(bad)?;
    let mut t = Tokens { b: &bytes, i: end };
    let n = usize::try_from(nx)
        .ok()
        .zip(usize::try_from(ny).ok())
        .and_then(|(a, b)| a.checked_mul(b))
        .ok_or_else(|| bad(format!("size {nx} x {ny} is too large")))?;
    let (nx, ny) = (nx as usize, ny as usize);
    let mut info = ReadInfo::new(ImageFormat::Pgm, if maxval > 255 { "u16" } else { "u8" });
    let mut values = Vec::with_capacity(n.min(bytes.len()));
    if binary {
        // After maxval: comments (`#` through the end of their line), then
        // exactly one whitespace byte before the raster (netpbm pgm(5): the
        // newline ending a comment does not delimit the raster).
        let mut i = t.i;
        while bytes.get(i) == Some(&b'#') {
            while i < bytes.len() && bytes[i] != b'\n' && bytes[i] != b'\r' {
                i += 1;
            }
            i += 1;
        }
        if !bytes.get(i).is_some_and(u8::is_ascii_whitespace) {
            return Err(bad(
                "no whitespace between maxval (or a comment after it) and the raster".into(),
            ));
        }
        let start = i + 1;
        let bps = if maxval > 255 { 2 } else { 1 };
        let need = n.checked_mul(bps).ok_or_else(|| bad("too large".into()))?;
        let avail = bytes.len().saturating_sub(start);
        if avail < need {
            return Err(bad(format!(
                "truncated: a {ny} x {nx} image needs {need} data bytes, the file has {avail}"
            )));
        }
        let raster = &bytes[start..start + need];
        if bps == 2 {
            values.extend(
                raster
                    .chunks_exact(2)
                    .map(|c| u16::from_be_bytes([c[0], c[1]]) as f64),
            );
        } else {
            values.extend(raster.iter().map(|&b| b as f64));
        }
        if avail > need {
            info.warnings.push(format!(
                "{} bytes after the image ignored (only the first image is read)",
                avail - need
            ));
        }
    } else {
        for k in 0..n {
            let tok = t.next().ok_or_else(|| {
                bad(format!(
                    "truncated: expected {n} values ({ny} rows x {nx} cols), found {k}"
                ))
            })?;
            let v: u32 = std::str::from_utf8(tok)
                .ok()
                .and_then(|s| s.parse().ok())
                .ok_or_else(|| {
                    bad(format!(
                        "value {} is not an integer: `{}`",
                        k + 1,
                        String::from_utf8_lossy(tok)
                    ))
                })?;
            values.push(v as f64);
        }
        if t.next().is_some() {
            info.warnings
                .push(format!("values after the first {n} ignored"));
        }
    }
    if let Some(v) = values.iter().find(|&&v| v > maxval as f64) {
        return Err(bad(format!("sample {v} exceeds maxval {maxval}")));
    }
    Ok((field_from(path, ny, nx, values, None)?, info))
}

/// Whitespace-separated tokens, skipping `#` comments to the end of the line.
struct Tokens<'a> {
    b: &'a [u8],
    i: usize,
}

impl<'a> Iterator for Tokens<'a> {
    type Item = &'a [u8];

    fn next(&mut self) -> Option<&'a [u8]> {
        loop {
            while self.i < self.b.len() && self.b[self.i].is_ascii_whitespace() {
                self.i += 1;
            }
            if self.b.get(self.i) == Some(&b'#') {
                while self.i < self.b.len() && self.b[self.i] != b'\n' && self.b[self.i] != b'\r' {
                    self.i += 1;
                }
                continue;
            }
            break;
        }
        let start = self.i;
        while self.i < self.b.len()
            && !self.b[self.i].is_ascii_whitespace()
            && self.b[self.i] != b'#'
        {
            self.i += 1;
        }
        (self.i > start).then(|| &self.b[start..self.i])
    }
}
