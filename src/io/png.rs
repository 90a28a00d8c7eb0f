//! PNG reader (grey as raw integers; colour to luminance) with the optional
//! JSON sidecar that maps integers back to physical values, and the 16-bit
//! writer that produces such a pair.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use ndarray::Array2;
use png::{BitDepth, ColorType, Decoder, Transformations};
use serde::{Deserialize, Serialize};

use super::{ImageFormat, ReadInfo, check_pixels, read_bytes};
use crate::error::{Error, Result};
use crate::field::Field;

/// Same budget as the TIFF reader: room for large DEMs, not for a hostile header.
const MAX_DECODE_BYTES: usize = 1 << 30;

/// The 16-bit code for a missing pixel written by [`super::write_png16`].
pub const PNG16_NODATA: u16 = 65535;

/// How [`super::write_png16`] mapped values to 16-bit integers; also the
/// content of the sidecar JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Png16Mapping {
    /// Human-readable decoding rule.
    pub png_decode: String,
    /// `value = png*scale + offset`.
    pub scale: f64,
    /// `value = png*scale + offset`.
    pub offset: f64,
    /// The integer that means "missing" (65535).
    pub nodata: u16,
    /// `[rows, cols]`.
    pub shape: [usize; 2],
    /// Smallest finite value, `None` if there is none.
    pub min: Option<f64>,
    /// Largest finite value, `None` if there is none.
    pub max: Option<f64>,
}

/// The `(ny, nx)` of a PNG from its IHDR chunk (super::read_shape).
pub(super) fn shape(path: &Path) -> Result<(usize, usize)> {
    let file = std::fs::File::open(path).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })?;
    let bad = |reason: String| Error::format(path, format!("PNG: {reason}"));
    let file_len = file.metadata().map(|m| m.len()).ok();
    let mut head = Vec::with_capacity(26);
    std::io::Read::read_to_end(&mut std::io::Read::take(file, 26), &mut head).map_err(
        |source| Error::Read {
            path: path.into(),
            source,
        },
    )?;
    // the signature, then IHDR first (PNG spec 5.2, 5.6)
    if head.is_empty() {
        return Err(bad("empty file (0 bytes)".into()));
    }
    if head.len() < 24 || head[..8] != PNG_SIGNATURE || &head[12..16] != b"IHDR" {
        return Err(bad(
            "corrupt or unsupported: not a PNG file (no PNG signature and IHDR chunk)".into(),
        ));
    }
    let be =
        |i: usize| u32::from_be_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]) as usize;
    let (nx, ny) = (be(16), be(20));
    if nx == 0 || ny == 0 {
        return Err(bad(format!("empty image ({ny} x {nx})")));
    }
    check_pixels(path, ny, nx)?;
    if let Some(reason) = file_len.and_then(|len| too_small_for_its_header(&head, len)) {
        return Err(bad(reason));
    }
    Ok((ny, nx))
}

/// The most a zlib stream expands: DEFLATE's longest match (258 bytes)
/// costs at least 2 bits, so 1032:1 (RFC 1951; zlib's `deflateBound`).
const MAX_ZLIB_RATIO: u64 = 1032;

/// Why a file of `len` bytes cannot hold the image its IHDR declares, if it
/// cannot: the image data (one filter byte per row and the packed
/// samples, PNG spec 7.2) is more than the whole file can inflate to. Said
/// before the decoder sizes its buffer by the header (an 89-byte file had
/// declared 510 MiB); `None` when the IHDR is incomplete (the decoder says
/// why) or the size is possible.
fn too_small_for_its_header(ihdr: &[u8], len: u64) -> Option<String> {
    let be = |i: usize| -> Option<u64> {
        Some(u32::from_be_bytes(ihdr.get(i..i + 4)?.try_into().ok()?) as u64)
    };
    if ihdr.get(..8)? != PNG_SIGNATURE || ihdr.get(12..16)? != b"IHDR" {
        return None;
    }
    let (w, h) = (be(16)?, be(20)?);
    let (depth, colour) = (*ihdr.get(24)? as u64, *ihdr.get(25)?);
    let channels = match colour {
        0 | 3 => 1,
        2 => 3,
        4 => 2,
        6 => 4,
        _ => return None,
    };
    let row = (w * channels * depth).div_ceil(8) + 1;
    let need = row.checked_mul(h)?;
    (need > MAX_ZLIB_RATIO.saturating_mul(len)).then(|| {
        format!(
            "truncated or corrupt: the header declares {h} x {w} pixels ({need} bytes of \
             image data), more than a file of {len} bytes can hold (zlib expands at most \
             {MAX_ZLIB_RATIO}-fold)"
        )
    })
}

/// The decoder's message without its debug dumps: a bad chunk reads
/// `ChunkType { type: ..., critical: true, ... } chunk appeared before
/// IHDR chunk`, with the chunk's raw (often binary) name; that part is
/// said as "a chunk".
fn plain_png_error(e: &png::DecodingError) -> String {
    let mut s = e.to_string();
    // (the name's escapes, `\u{16}`, hold braces: the dump ends after
    // its last field)
    while let Some(a) = s.find("ChunkType {") {
        let from = s[a..].find("safecopy").map_or(a, |k| a + k);
        let Some(b) = s[from..].find('}') else { break };
        s.replace_range(a..from + b + 1, "a");
    }
    s
}

/// The eight bytes every PNG file starts with.
const PNG_SIGNATURE: [u8; 8] = [137, 80, 78, 71, 13, 10, 26, 10];

pub(super) fn read(path: &Path) -> Result<(Field, ReadInfo)> {
    let bytes = read_bytes(path)?;
    let bad = |reason: String| Error::format(path, format!("PNG: {reason}"));
    if bytes.is_empty() {
        return Err(bad("empty file (0 bytes)".into()));
    }
    // The png crate rejects a 0-pixel IHDR as "invalid dimensions"; say "empty".
    if bytes.len() >= 24 && &bytes[12..16] == b"IHDR" {
        let w = u32::from_be_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
        let h = u32::from_be_bytes([bytes[20], bytes[21], bytes[22], bytes[23]]);
        if w == 0 || h == 0 {
            return Err(bad(format!("empty image ({h} x {w})")));
        }
        check_pixels(path, h as usize, w as usize)?;
    }
    if let Some(reason) = too_small_for_its_header(&bytes, bytes.len() as u64) {
        return Err(bad(reason));
    }
    let mut dec = Decoder::new_with_limits(
        Cursor::new(&bytes[..]),
        png::Limits {
            bytes: MAX_DECODE_BYTES,
        },
    );
    // EXPAND: palette -> RGB(A), tRNS -> alpha, 1/2/4-bit grey -> 8-bit.
    dec.set_transformations(Transformations::EXPAND);
    let mut reader = dec
        .read_info()
        .map_err(|e| bad(format!("corrupt or unsupported: {}", plain_png_error(&e))))?;
    let (src_color, src_depth) = {
        let i = reader.info();
        check_pixels(path, i.height as usize, i.width as usize)?;
        (i.color_type, i.bit_depth)
    };
    // A tiny file can declare a huge image; refuse before allocating.
    let size = reader
        .output_buffer_size()
        .filter(|&n| n <= MAX_DECODE_BYTES)
        .ok_or_else(|| bad("image too large".into()))?;
    let mut buf = vec![0u8; size];
    let out = reader
        .next_frame(&mut buf)
        .map_err(|e| bad(format!("corrupt or truncated: {e}")))?;
    let (nx, ny) = (out.width as usize, out.height as usize);
    if nx == 0 || ny == 0 {
        return Err(bad(format!("empty image ({ny} x {nx})")));
    }
    let channels = out.color_type.samples();
    let sixteen = out.bit_depth == BitDepth::Sixteen;
    let bps = if sixteen { 2 } else { 1 };
    let need = nx * ny * channels * bps;
    if buf.len() < need || out.line_size != nx * channels * bps {
        return Err(bad("unexpected decoded layout".into()));
    }
    let sample = |k: usize| -> f64 {
        if sixteen {
            u16::from_be_bytes([buf[2 * k], buf[2 * k + 1]]) as f64
        } else {
            buf[k] as f64
        }
    };
    // EXPAND scaled 1/2/4-bit grey to 0..255; undo it to keep raw values.
    let low_bits = match src_depth {
        BitDepth::One => 1,
        BitDepth::Two => 2,
        BitDepth::Four => 4,
        _ => 0,
    };
    let grey_div = if low_bits > 0 && src_color == ColorType::Grayscale {
        255.0 / ((1u32 << low_bits) - 1) as f64
    } else {
        1.0
    };
    let depth_name = if sixteen { "u16" } else { "u8" };
    let mut info = ReadInfo::new(ImageFormat::Png, depth_name);
    let colour = matches!(out.color_type, ColorType::Rgb | ColorType::Rgba);
    if colour {
        let what = if src_color == ColorType::Indexed {
            "palette"
        } else {
            "colour"
        };
        info.dtype = format!("{depth_name} {what}");
        info.warnings.push(format!(
            "{what} PNG converted to luminance (Rec. 709 weights)"
        ));
    } else if low_bits > 0 {
        info.dtype = format!("u{low_bits}");
    }
    let has_alpha = matches!(out.color_type, ColorType::GrayscaleAlpha | ColorType::Rgba);
    let mut raw = Vec::with_capacity(nx * ny);
    // Alpha 0 = missing; alpha is otherwise ignored (no compositing).
    let mut transparent = Vec::with_capacity(if has_alpha { nx * ny } else { 0 });
    for p in 0..nx * ny {
        let k = p * channels;
        let v = if colour {
            let (r, g, b) = (sample(k), sample(k + 1), sample(k + 2));
            // a grey pixel is its own value exactly (the weighted sum is not:
            // 255 gives 254.99999999999997, which a sidecar nodata would miss)
            if r == g && g == b {
                r
            } else {
                0.2126 * r + 0.7152 * g + 0.0722 * b
            }
        } else {
            sample(k) / grey_div
        };
        raw.push(v);
        if has_alpha {
            transparent.push(sample(k + channels - 1) == 0.0);
        }
    }
    if has_alpha && !colour {
        info.dtype = format!("{depth_name} grey+alpha");
    }
    // the decoded bytes are not needed any more: a 16384^2 image peaks at
    // its f64 values and mask, not at those plus the buffer and a copy
    drop(buf);

    let mut nodata = None;
    let (scale, offset) = match sidecar(path, (ny, nx), &mut info)? {
        Some(sc) => {
            nodata = sc.nodata;
            (sc.scale, sc.offset)
        }
        None => (1.0, 0.0),
    };
    let mut mask: Vec<bool> = match nodata {
        Some(nd) => raw.iter().map(|&v| v == nd).collect(),
        None => vec![false; nx * ny],
    };
    for (m, &t) in mask.iter_mut().zip(&transparent) {
        *m |= t;
    }
    drop(transparent);
    let mut values = raw;
    for v in &mut values {
        *v = *v * scale + offset;
    }
    let data = Array2::from_shape_vec((ny, nx), values)
        .map_err(|e| bad(format!("internal shape error: {e}")))?;
    let mask = Array2::from_shape_vec((ny, nx), mask)
        .map_err(|e| bad(format!("internal shape error: {e}")))?;
    Ok((Field::with_mask(data, mask)?, info))
}

struct Sidecar {
    scale: f64,
    offset: f64,
    nodata: Option<f64>,
}

/// Reads `<stem>.json` beside the PNG if there is one. Keys: `scale`,
/// `offset`, and the nodata as `nodata` or as `png==N` in `png_decode`
/// (the convention of `shared/data/*.json`).
fn sidecar(
    png_path: &Path,
    (ny, nx): (usize, usize),
    info: &mut ReadInfo,
) -> Result<Option<Sidecar>> {
    let path: PathBuf = png_path.with_extension("json");
    if !path.is_file() {
        if path.exists() {
            info.warnings.push(format!(
                "{} is not a file; no sidecar applied, raw PNG values used",
                path.display()
            ));
        }
        return Ok(None);
    }
    let bytes = read_bytes(&path)?;
    let bad = |reason: String| Error::format(&path, format!("PNG sidecar: {reason}"));
    let json: serde_json::Value =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("invalid JSON: {e}")))?;
    let Some(obj) = json.as_object() else {
        return Err(bad("expected a JSON object".into()));
    };
    let number = |key: &str| -> Result<Option<f64>> {
        match obj.get(key) {
            None | Some(serde_json::Value::Null) => Ok(None),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| bad(format!("`{key}` is not a finite number"))),
        }
    };
    let (scale, offset) = (number("scale")?, number("offset")?);
    if scale == Some(0.0) {
        return Err(bad("`scale` is 0: every value would be the offset".into()));
    }
    // a sidecar written for another image (a stale one beside a new PNG)
    if let Some(shape) = obj.get("shape").filter(|v| !v.is_null()) {
        let dims: Option<Vec<u64>> = shape
            .as_array()
            .and_then(|a| a.iter().map(|v| v.as_u64()).collect());
        match dims.as_deref() {
            Some([r, c]) if (*r as usize, *c as usize) == (ny, nx) => {}
            Some([r, c]) => {
                return Err(bad(format!(
                    "`shape` [{r}, {c}] is not the PNG's {ny} x {nx}: a sidecar of another image?"
                )));
            }
            _ => return Err(bad("`shape` is not [rows, cols]".into())),
        }
    }
    // provenance keys (source, units, ...) are free; a near miss of a key
    // that changes the values (`offest`) is a typo that would misread them
    // (heights unscaled, a nodata code read as a height): refused while the
    // key it resembles is absent, named when both are there
    const READ: [&str; 5] = ["scale", "offset", "nodata", "png_decode", "shape"];
    for (key, value) in obj.iter().filter(|(k, _)| !READ.contains(&k.as_str())) {
        if let Some(meant) = ["scale", "offset", "nodata"]
            .into_iter()
            .find(|k| edit_distance(key, k) <= 2)
        {
            // a misspelling: one edit, or two in a key of the same length
            // (`offest`), holding a number as the key it resembles does;
            // `data: "SRTM"` or `scale_x` are provenance
            let d = edit_distance(key, meant);
            let typo = value.is_number() && (d <= 1 || key.len() == meant.len());
            let decoded = || {
                obj.get("png_decode")
                    .and_then(|v| v.as_str())
                    .and_then(nodata_from_text)
                    .is_some()
            };
            if typo && !(obj.contains_key(meant) || meant == "nodata" && decoded()) {
                return Err(bad(format!(
                    "key `{key}` is not one the reader knows: did you mean `{meant}`? (as it \
                     is, the values would be read without it)"
                )));
            }
            info.warnings.push(format!(
                "{}: key `{key}` ignored (did you mean `{meant}`?)",
                path.display()
            ));
        }
    }
    let nodata = match number("nodata")? {
        Some(n) => Some(n),
        None => obj
            .get("png_decode")
            .and_then(|v| v.as_str())
            .and_then(nodata_from_text),
    };
    if scale.is_none() && offset.is_none() && nodata.is_none() {
        info.warnings.push(format!(
            "{} has no `scale`, `offset` or `nodata`; raw PNG values used",
            path.display()
        ));
        return Ok(None);
    }
    info.sidecar = Some(path.clone());
    Ok(Some(Sidecar {
        scale: scale.unwrap_or(1.0),
        offset: offset.unwrap_or(0.0),
        nodata,
    }))
}

/// Levenshtein distance of two short ASCII keys (a dozen characters: a
/// crate would be more than the job needs).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1];
        for (j, &cb) in b.iter().enumerate() {
            cur.push(
                (prev[j] + usize::from(ca != cb))
                    .min(prev[j + 1] + 1)
                    .min(cur[j] + 1),
            );
        }
        prev = cur;
    }
    prev[b.len()]
}

/// `"value = png*scale + offset; png==65535 -> NaN"` -> `Some(65535.0)`.
fn nodata_from_text(text: &str) -> Option<f64> {
    let t: String = text.chars().filter(|c| !c.is_whitespace()).collect();
    let rest = &t[t.find("png==")? + 5..];
    let end = rest
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(rest.len());
    rest[..end].parse().ok()
}

/// Encodes a 16-bit grey PNG in memory, with the mapping for its sidecar.
pub(super) fn encode_u16(path: &Path, a: &Array2<f64>) -> Result<(Vec<u8>, Png16Mapping)> {
    let (ny, nx) = a.dim();
    if ny == 0 || nx == 0 {
        return Err(Error::format(
            path,
            format!("cannot write an empty image ({ny} x {nx})"),
        ));
    }
    let (w, h) = match (u32::try_from(nx), u32::try_from(ny)) {
        (Ok(w), Ok(h)) => (w, h),
        _ => return Err(Error::format(path, "image too large for PNG")),
    };
    let finite = || a.iter().copied().filter(|v| v.is_finite());
    let min = finite().reduce(f64::min);
    let max = finite().reduce(f64::max);
    let top = f64::from(PNG16_NODATA - 1);
    let (scale, offset) = match (min, max) {
        // Divide before subtracting so that a huge range cannot overflow.
        (Some(lo), Some(hi)) if hi > lo => (hi / top - lo / top, lo),
        (Some(lo), _) => (1.0, lo),
        _ => (1.0, 0.0),
    };
    let mut pixels = Vec::with_capacity(2 * nx * ny);
    for &v in a.iter() {
        let q = if v.is_finite() {
            ((v - offset) / scale).round().clamp(0.0, top) as u16
        } else {
            PNG16_NODATA
        };
        pixels.extend_from_slice(&q.to_be_bytes());
    }
    let err = |e: png::EncodingError| Error::format(path, format!("cannot encode PNG: {e}"));
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(ColorType::Grayscale);
        enc.set_depth(BitDepth::Sixteen);
        let mut writer = enc.write_header().map_err(err)?;
        writer.write_image_data(&pixels).map_err(err)?;
        writer.finish().map_err(err)?;
    }
    let mapping = Png16Mapping {
        png_decode: format!("value = png*scale + offset; png=={PNG16_NODATA} -> NaN"),
        scale,
        offset,
        nodata: PNG16_NODATA,
        shape: [ny, nx],
        min,
        max,
    };
    Ok((out, mapping))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodata_text_convention() {
        assert_eq!(
            nodata_from_text("value = png*scale + offset; png==65535 -> NaN"),
            Some(65535.0)
        );
        assert_eq!(nodata_from_text("value = png*scale + offset"), None);
    }

    /// A chunk of a binary name before IHDR: said without the decoder's
    /// debug dump of the chunk type (its escapes hold braces).
    #[test]
    fn chunk_errors_are_said_plainly() {
        let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
        b.extend_from_slice(&[0x12, 0x45, 0x79, 0x45, 0x16, 0x69, 0xed, 0x73]);
        b.extend_from_slice(&[0; 24]);
        let e = Decoder::new(Cursor::new(&b[..])).read_info().err().unwrap();
        assert!(e.to_string().contains("ChunkType {"), "{e}");
        let s = plain_png_error(&e);
        assert_eq!(s, "a chunk appeared before IHDR chunk");
    }
}
