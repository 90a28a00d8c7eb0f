//! A second decoder for LZW-compressed TIFFs, used only when the `tiff`
//! crate's fails on a valid file: its LZW reader stops some tiles with "no
//! lzw end code found" (image-rs/image-tiff#395, open; tiff 0.11.3 with
//! weezl 0.1.12), which on files written by tifffile/imagecodecs struck 8
//! of 24 tiled LZW variants of a 40 x 56 DEM crop and 58 of 96 at 300 x
//! 400. The streams are valid (imagecodecs and libtiff read them), so the
//! chunks are decoded here with weezl itself, the same LZW codec the crate
//! wraps, filling each chunk's known size instead of waiting for the end
//! code (as libtiff does). Hand-written because no maintained crate
//! decodes TIFF chunks otherwise; it reads one band, strips or tiles,
//! predictors 1-3 (TIFF 6.0 §14; Adobe Technical Note 3 for 3).

use std::io::Cursor;

use super::tiff::{Ifd, type_size, uint};

/// Samples of the first image of the TIFF `b` as f64, with their dtype
/// name; `Err` says why it cannot (the caller reports the crate's error
/// beside it).
pub(super) fn decode(b: &[u8]) -> Result<(&'static str, Vec<f64>), String> {
    let ifd = Ifd::read(&mut Cursor::new(b), b.len() as u64)?.ok_or("not a TIFF")?;
    let one = |tag: u16, default: Option<u64>| -> Result<u64, String> {
        match values(&ifd, b, tag)?.first() {
            Some(&v) => Ok(v),
            None => default.ok_or_else(|| format!("tag {tag} missing")),
        }
    };
    let (w, h) = (one(256, None)? as usize, one(257, None)? as usize);
    let bits = one(258, Some(1))? as usize;
    let format = one(339, Some(1))?;
    let predictor = one(317, Some(1))?;
    if one(259, Some(1))? != 5 || one(277, Some(1))? != 1 {
        return Err("not a one-band LZW image".into());
    }
    let bps = bits / 8;
    let dtype = match (format, bits) {
        (1, 8) => "u8",
        (1, 16) => "u16",
        (1, 32) => "u32",
        (1, 64) => "u64",
        (2, 8) => "i8",
        (2, 16) => "i16",
        (2, 32) => "i32",
        (2, 64) => "i64",
        (3, 32) => "f32",
        (3, 64) => "f64",
        _ => return Err(format!("sample format {format} of {bits} bits")),
    };
    // chunks: tiles, or strips of RowsPerStrip rows the width of the image
    let tiled = ifd.entry(322).is_some();
    let (cw, ch, offsets, counts) = if tiled {
        (
            one(322, None)? as usize,
            one(323, None)? as usize,
            values(&ifd, b, 324)?,
            values(&ifd, b, 325)?,
        )
    } else {
        let rows = (one(278, Some(h as u64))? as usize).min(h);
        (w, rows, values(&ifd, b, 273)?, values(&ifd, b, 279)?)
    };
    if cw == 0 || ch == 0 || w == 0 || h == 0 {
        return Err("empty chunks".into());
    }
    let across = w.div_ceil(cw);
    let n_chunks = across * h.div_ceil(ch);
    if offsets.len() < n_chunks || counts.len() < n_chunks {
        return Err(format!(
            "{} chunk offsets for {n_chunks} chunks",
            offsets.len()
        ));
    }
    let mut out = vec![0.0f64; w * h];
    let mut raw = Vec::new();
    for c in 0..n_chunks {
        let (x0, y0) = ((c % across) * cw, (c / across) * ch);
        // a strip holds only the rows left in the image; a tile is whole
        let rows = if tiled { ch } else { ch.min(h - y0) };
        let row_bytes = cw * bps;
        let (at, n) = (offsets[c] as usize, counts[c] as usize);
        let src = at
            .checked_add(n)
            .and_then(|end| b.get(at..end))
            .ok_or_else(|| format!("chunk {c} lies past the end of the file"))?;
        // an LZW code of 9 bits or more yields at most 4096 bytes: a chunk
        // cannot hold more than 4096 times its bytes (io::tiff's bound)
        let size = rows
            .checked_mul(row_bytes)
            .filter(|&s| s <= 4096 * (n + 1))
            .ok_or_else(|| format!("chunk {c} of {cw} x {rows} samples in {n} bytes"))?;
        raw.clear();
        raw.resize(size, 0);
        inflate(src, &mut raw).map_err(|e| format!("chunk {c}: {e}"))?;
        for row in raw.chunks_exact_mut(row_bytes) {
            undo_predictor(row, predictor, bps, ifd.le)?;
        }
        for (r, row) in raw.chunks_exact(row_bytes).enumerate() {
            let y = y0 + r;
            if y >= h {
                break;
            }
            for (i, s) in row.chunks_exact(bps).enumerate().take(w.saturating_sub(x0)) {
                // predictor 3 leaves the samples big-endian
                let le = ifd.le && predictor != 3;
                out[y * w + x0 + i] = sample(s, dtype, le);
            }
        }
    }
    Ok((dtype, out))
}

/// Fills `out` from the LZW stream `src` (TIFF's variant: MSB-first codes,
/// the code width switching one code early), stopping when it is full.
fn inflate(src: &[u8], out: &mut [u8]) -> Result<(), String> {
    let mut d = weezl::decode::Configuration::with_tiff_size_switch(weezl::BitOrder::Msb, 8)
        .with_yield_on_full_buffer(true)
        .build();
    let (mut i, mut o) = (0, 0);
    while o < out.len() {
        let r = d.decode_bytes(&src[i..], &mut out[o..]);
        i += r.consumed_in;
        o += r.consumed_out;
        match r.status {
            Ok(weezl::LzwStatus::Ok) if r.consumed_in + r.consumed_out > 0 => {}
            Ok(_) if o < out.len() => {
                return Err(format!("{o} of {} bytes decoded", out.len()));
            }
            Ok(_) => {}
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok(())
}

/// Undoes the predictor on one row of a chunk: 2, horizontal differences
/// of the samples (in the file's byte order); 3, the floating-point
/// predictor: byte differences over the row, whose samples are stored as
/// byte planes, most significant first (Adobe Technical Note 3).
fn undo_predictor(row: &mut [u8], predictor: u64, bps: usize, le: bool) -> Result<(), String> {
    match predictor {
        1 => {}
        2 => {
            let mask = if bps == 8 {
                u64::MAX
            } else {
                (1u64 << (8 * bps)) - 1
            };
            let mut prev = 0u64;
            for s in row.chunks_exact_mut(bps) {
                prev = prev.wrapping_add(uint(s, le)) & mask;
                for k in 0..bps {
                    let byte = (prev >> (8 * k)) as u8;
                    s[if le { k } else { bps - 1 - k }] = byte;
                }
            }
        }
        3 => {
            for i in 1..row.len() {
                row[i] = row[i].wrapping_add(row[i - 1]);
            }
            let n = row.len() / bps;
            let planes = row.to_vec();
            for i in 0..n {
                for k in 0..bps {
                    row[i * bps + k] = planes[k * n + i];
                }
            }
        }
        p => return Err(format!("predictor {p}")),
    }
    Ok(())
}

/// One sample of `dtype` from its bytes.
fn sample(s: &[u8], dtype: &str, le: bool) -> f64 {
    let v = uint(s, le);
    match dtype {
        "u8" | "u16" | "u32" | "u64" => v as f64,
        "i8" => v as u8 as i8 as f64,
        "i16" => v as u16 as i16 as f64,
        "i32" => v as u32 as i32 as f64,
        "i64" => v as i64 as f64,
        "f32" => f32::from_bits(v as u32) as f64,
        _ => f64::from_bits(v),
    }
}

/// The unsigned values of `tag` (BYTE, SHORT, LONG or LONG8) in the file
/// `b`, from the entry or where its offset points; empty when absent.
fn values(ifd: &Ifd, b: &[u8], tag: u16) -> Result<Vec<u64>, String> {
    let Some(e) = ifd.entry(tag) else {
        return Ok(Vec::new());
    };
    let size = match e.typ {
        1 | 3 | 4 | 13 | 16 | 18 => type_size(e.typ).unwrap_or(1) as usize,
        t => return Err(format!("tag {tag} has type {t}")),
    };
    let len = (e.count as usize)
        .checked_mul(size)
        .filter(|&l| l <= b.len())
        .ok_or_else(|| format!("tag {tag}: {} values", e.count))?;
    let data = if len <= e.field.len() {
        &e.field[..len]
    } else {
        let at = uint(&e.field, ifd.le) as usize;
        at.checked_add(len)
            .and_then(|end| b.get(at..end))
            .ok_or_else(|| format!("tag {tag} lies past the end of the file"))?
    };
    Ok(data.chunks_exact(size).map(|s| uint(s, ifd.le)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(name: &str) -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures")
            .join(name)
    }

    /// Every LZW fixture through this decoder alone (the crate reads the
    /// floating-point one itself, so `read_field` never sends it here):
    /// the DEM crop of `dem_f8.npy`, exactly; the integer files hold the
    /// original values at its three holes.
    #[test]
    fn lzw_fixtures_decode_to_the_crop() {
        let reference = crate::io::read_field(fixture("dem_f8.npy")).unwrap();
        for (name, dtype, holes) in [
            ("dem_u16_tiled_lzw.tif", "u16", false),
            ("dem_i16_tiled_lzw_pred.tif", "i16", false),
            ("dem_f32_tiled_lzw_fpred.tif", "f32", true),
        ] {
            let b = std::fs::read(fixture(name)).unwrap();
            let (dt, v) = decode(&b).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(dt, dtype, "{name}");
            assert_eq!(v.len(), 40 * 56, "{name}");
            for ((y, x), &r) in reference.data.indexed_iter() {
                let got = v[y * 56 + x];
                if r.is_nan() {
                    assert_eq!(got.is_nan(), holes, "{name} ({y},{x}): {got}");
                } else {
                    assert_eq!(got, r, "{name} ({y},{x})");
                }
            }
        }
    }

    /// The predictors undone on hand-made rows: horizontal differences of
    /// 16-bit samples in either byte order (wrapping), and the
    /// floating-point predictor's byte planes (most significant first).
    #[test]
    fn predictors_undone() {
        for le in [true, false] {
            let vals = [1000u16, 65535, 3, 3];
            // differences mod 2^16: 1000, 64535, 4, 0
            let mut row: Vec<u8> = [1000u16, 64535, 4, 0]
                .iter()
                .flat_map(|d| if le { d.to_le_bytes() } else { d.to_be_bytes() })
                .collect();
            undo_predictor(&mut row, 2, 2, le).unwrap();
            let got: Vec<u16> = row.chunks_exact(2).map(|s| uint(s, le) as u16).collect();
            assert_eq!(got, vals, "le {le}");
        }
        let vals = [1.5f32, -2.25, 1e-3];
        // byte planes of the big-endian samples, then byte differences
        let be: Vec<[u8; 4]> = vals.iter().map(|v| v.to_be_bytes()).collect();
        let planes: Vec<u8> = (0..4).flat_map(|k| be.iter().map(move |s| s[k])).collect();
        let mut row: Vec<u8> = (0..planes.len())
            .map(|i| {
                if i == 0 {
                    planes[0]
                } else {
                    planes[i].wrapping_sub(planes[i - 1])
                }
            })
            .collect();
        undo_predictor(&mut row, 3, 4, true).unwrap();
        let got: Vec<f32> = row
            .chunks_exact(4)
            .map(|s| f32::from_bits(uint(s, false) as u32))
            .collect();
        assert_eq!(got, vals);
    }
}
